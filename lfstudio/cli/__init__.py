"""The ``lfstudio`` command line: one module per subcommand.

A subcommand module defines ``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``.
Register it by adding its module name to :data:`COMMANDS` (the CLI name is the module name with
``_`` replaced by ``-``). ``lfstudio`` with no arguments opens the GUI.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import logging
import sys
from typing import NoReturn

from lfstudio import __version__
from lfstudio.cli.args import CONVENTIONS
from lfstudio.errors import DatasetNotFound, InputError, LfError

#: subcommand modules, in the order ``lfstudio --help`` lists them
COMMANDS: list[str] = [
    "gui",
    "plan",
    "rig",
    "sim_rig",
    "sim_drive",
    "scan",
    "info",
    "calibrate",
    "check",
    "simulate_calibration",
    "process",
    "depth",
    "camera",
    "virtual_dataset",
    "import_images",
    "export",
    "import_hevc",
    "doctor",
]


class _Parser(argparse.ArgumentParser):
    """argparse with its errors (an unknown option, a value out of range) as one line, exit status 2."""

    def error(self, message: str) -> NoReturn:
        prog = self.prog
        if message.startswith("unrecognized arguments:"):
            message += did_you_mean(self, message.split(":", 1)[1].split())
            prog = typed_command(self) or prog       # the top parser reports a command's unknown options
        if message.startswith("the following arguments are required:"):    # name what each missing one takes
            for action in self._actions:
                if action.choices and action.option_strings and action.option_strings[0] in message:
                    name = action.option_strings[0]
                    message = message.replace(name, f"{name} (one of {', '.join(map(str, action.choices))})", 1)
        self.exit(2, f"{prog}: error: {message} (see '{prog} --help')\n")


def typed_command(parser: argparse.ArgumentParser) -> str:
    """"lfstudio scan" when the command line names the command scan ("" when none)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                if name in sys.argv[1:]:
                    return sub.prog
    return ""


def did_you_mean(parser: argparse.ArgumentParser, words: list[str]) -> str:
    """``"; did you mean --grid?"`` for options typed wrong (``--gird``): the closest option of the
    command on the command line (argparse's suggest_on_error is Python 3.14's)."""
    options = {o for a in parser._actions for o in a.option_strings}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            typed = [c for c in action.choices if c in sys.argv[1:]]
            for name in typed[:1]:
                options |= {o for a in action.choices[name]._actions for o in a.option_strings}
    hints = []
    for word in words:
        if word.startswith("-"):
            close = difflib.get_close_matches(word.split("=", 1)[0], sorted(options), n=1, cutoff=0.6)
            if close:
                hints.append(f"{word.split('=', 1)[0]}: did you mean {close[0]}?")
    return f" ({'; '.join(hints)})" if hints else ""


#: exit codes of every command (one convention, printed at the end of every --help)
EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
EXIT_CODES_HELP = ("Exit codes: 0 done; 1 the work failed (a device, a damaged dataset, the disk); "
                   "2 bad input (an option or value, or a path that does not exist or is not a dataset: "
                   "the message names it and what is valid); 130 interrupted (Ctrl+C).")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="lfstudio",
        description="Plan, capture, calibrate, process and export dense light fields. "
                    "Without a command, opens the application window.",
        epilog=f"{CONVENTIONS} {EXIT_CODES_HELP}",
    )
    parser.add_argument("--version", action="version", version=f"lfstudio {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="log everything (device traffic included) to the console too; the log file "
                             "always gets it (`lfstudio doctor` prints where the log file is)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        module = importlib.import_module(f"lfstudio.cli.{name}")
        p = sub.add_parser(name.replace("_", "-"), help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.epilog = f"{p.epilog} {EXIT_CODES_HELP}" if p.epilog else EXIT_CODES_HELP
        p.set_defaults(_run=module.run)
    return parser


def attach_dash_values(parser: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """``--spacing-mm -4x6`` -> ``--spacing-mm=-4x6``: argparse takes a value that starts with '-'
    for an option and stops with a usage dump ("expected one argument"); attached, the value
    reaches the command's own check, which names the option and what is valid in one line.
    Only for options that take one value, and never when the next word is itself an option."""
    sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
    command = sub.choices.get(argv[0]) if sub and argv else None
    if command is None:
        return argv
    known = {o for a in command._actions for o in a.option_strings}
    takes_value = {o for a in command._actions if a.option_strings and a.nargs is None
                   and not isinstance(a, (argparse._StoreConstAction, argparse._HelpAction, argparse._VersionAction))
                   for o in a.option_strings}
    out: list[str] = []
    i = 0
    while i < len(argv):
        word = argv[i]
        if word == "--":
            out.extend(argv[i:])
            break
        if word in takes_value and i + 1 < len(argv) and argv[i + 1].startswith("-") \
                and argv[i + 1] != "--" and argv[i + 1].split("=", 1)[0] not in known:
            out.append(f"{word}={argv[i + 1]}")
            i += 2
            continue
        out.append(word)
        i += 1
    return out


#: options whose value is a secret as a whole (never logged)
SECRET_OPTIONS = ("--status-token",)


def _secret_option(word: str) -> bool:
    """``word`` names a :data:`SECRET_OPTIONS` option, in full or abbreviated as argparse takes it
    (``--status-tok``: a unique prefix; an ambiguous one is refused before anything is recorded)."""
    return word.startswith("--") and len(word) > 2 and any(name.startswith(word) for name in SECRET_OPTIONS)


def loggable(argv: list[str]) -> list[str]:
    """The command line as the log file may keep it: URLs shown as scheme and host only (a webhook's
    path or a user's password is a secret), the values of :data:`SECRET_OPTIONS` masked."""
    out: list[str] = []
    for word in argv:
        option, eq, value = word.partition("=")
        if out and _secret_option(out[-1]):
            word = "…"
        elif eq and _secret_option(option):
            word = f"{option}=…"
        elif "://" in word or word.startswith("mailto:"):
            from lfstudio.scan.notify import mask_urls, shown_url

            word = (f"{option}={shown_url(value)}" if eq and option.startswith("--") and " " not in value
                    else shown_url(word) if " " not in word else mask_urls(word))
        out.append(str(word))
    return out


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    # --debug is global: accepted anywhere (lfstudio --debug, lfstudio scan --debug ...)
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    if not argv or argv[0].startswith("-") and argv[0] not in ("-h", "--help", "--version"):
        argv = ["gui", *argv]
    parser = build_parser()
    argv = attach_dash_values(parser, argv)
    args = parser.parse_args(argv)
    from lfstudio.support.logs import setup_logging

    from lfstudio.support.secrets import set_command_line

    shown = loggable(argv)          # what lock files, logs and messages may show of this command line
    set_command_line(["lfstudio", *shown])
    setup_logging(debug=debug)
    log = logging.getLogger("lfstudio.cli")
    log.info("lfstudio %s: %s", __version__, " ".join(shown))
    try:
        return int(args._run(args) or 0)
    except (InputError, DatasetNotFound) as exc:
        log.info("%s: input error: %s", args.command, exc)
        print(f"lfstudio {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except LfError as exc:
        log.info("%s failed: %s", args.command, exc)   # the file only: the console gets the line below
        print(f"lfstudio {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except OSError as exc:       # a folder that cannot be written, a full disk, ...: one line, not a traceback
        log.info("%s failed", args.command, exc_info=True)
        from lfstudio.dataset.storage import storage_error

        disk = storage_error(exc, then="run the command again (what is finished is kept)")
        where = f"{exc.filename}: " if exc.filename else ""
        text = str(disk) if disk is not None else (f"{where}{exc.strerror or exc} (check that the folder exists, "
                                                   "is writable and has free space; details in the log)")
        print(f"lfstudio {args.command}: error: {text}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        log.info("%s interrupted", args.command)
        print(f"lfstudio {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception:
        log.info("%s crashed", args.command, exc_info=True)  # the file; Python prints it on the console
        raise
