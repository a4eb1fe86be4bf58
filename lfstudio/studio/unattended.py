"""A scan nobody watches: notifications, the status page, recovery by itself and the end-of-day command,
set up the same way by ``lfstudio scan`` and the window.

:class:`UnattendedOptions` holds what the operator gave (``--notify``, ``--smtp``, ``--status-http``,
``--status-token``, ``--auto-resume``, ``--on-finish``; the window's Settings → Unattended scans).
:meth:`Unattended.open` checks all of it and binds the status page's port *before* the scan session
takes the dataset or a device: a malformed URL, an unknown scheme, a port in use or another computer's
address without a token is one :class:`InputError` naming the option, and nothing starts.
:meth:`Unattended.attach` then listens to the engine (and :meth:`attach_checker` to the live check);
:meth:`Unattended.scan_ended` runs the end-of-day command; :meth:`Unattended.close` ends everything.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from lfstudio.errors import InputError
from lfstudio.scan.events import TERMINAL, EventKind, ScanState
from lfstudio.scan.notify import Notifier, SmtpServer, mask_urls, parse_target
from lfstudio.scan.status_http import StatusBoard, StatusServer
from lfstudio.studio.scan_options import PARAMS

log = logging.getLogger(__name__)

#: the options described in lfstudio.studio.scan_options (range, label, tip, command-line name)
DESCRIBED = ("notify", "smtp", "status_http", "status_token", "auto_resume", "on_finish", "on_finish_timeout_s")
#: how each option is named where the operator gave it (the CLI's options; the window passes its own)
CLI_NAMES = {name: PARAMS[name].option for name in DESCRIBED}
SMTP_PASSWORD_ENV = "LFSTUDIO_SMTP_PASSWORD"


@dataclass
class UnattendedOptions:
    """What the operator asked for; the defaults ask for nothing."""

    notify: list[str] = field(default_factory=list)
    smtp: str = ""                   # smtp://[USER@]HOST[:PORT]
    smtp_password: str = field(default="", repr=False)
    smtp_sender: str = ""
    status_http: str = ""            # [HOST:]PORT
    status_token: str = field(default="", repr=False)    # "new": make one (printed once)
    auto_resume: int = 0
    on_finish: str = ""
    on_finish_timeout_s: float = 300.0
    names: dict[str, str] = field(default_factory=lambda: dict(CLI_NAMES))

    @property
    def wanted(self) -> bool:
        return bool(self.notify or self.status_http or self.auto_resume or self.on_finish)


class Unattended:
    """See the module docstring. ``say``: where lines for the operator go (the CLI's stderr, the
    Scan panel's log); the status page's token is said once, never logged."""

    def __init__(self, options: UnattendedOptions, notifier: Notifier | None, say: Callable[[str], None],
                 status: StatusServer | None = None):
        self.options = options
        self.notifier = notifier
        self.status = status
        self.board: StatusBoard | None = None
        self.say = say
        self._removers: list[Callable[[], None]] = []
        self.engine: Any = None
        self.dataset: Any = None
        self.on_finish_thread: threading.Thread | None = None
        self.on_finish_result: dict[str, Any] | None = None     # returncode / timed_out / output / error

    @classmethod
    def open(cls, options: UnattendedOptions, *, dataset_name: str = "",
             say: Callable[[str], None] = lambda text: None, env: Mapping[str, str] | None = None) -> "Unattended":
        """Check ``options`` and set up what they ask for (see the module docstring)."""
        names = options.names
        env = os.environ if env is None else env
        for name in DESCRIBED:            # each by its description: the same rules as the command line's
            PARAMS[name].check(names[name], getattr(options, name))
        targets = [parse_target(url, names["notify"]) for url in options.notify]
        smtp = None
        if options.smtp:
            smtp = SmtpServer.parse(options.smtp, password=options.smtp_password or env.get(SMTP_PASSWORD_ENV, ""),
                                    sender=options.smtp_sender, option=names["smtp"])
        if any(t.shape == "mail" for t in targets) and smtp is None:
            raise InputError(names["notify"], "a mailto: target needs an SMTP server", f"{names['smtp']} smtp://USER@HOST")
        if options.on_finish and not options.on_finish.strip():
            raise InputError(names["on_finish"], "the command is empty", "a shell command, e.g. 'lights off'")
        if options.status_token and not options.status_http:
            raise InputError(names["status_token"], "is for the status page", f"add {names['status_http']} [HOST:]PORT")
        status = None
        if options.status_http:            # bound now: a port in use stops everything before it starts
            status = StatusServer(options.status_http, options.status_token, option=names["status_http"],
                                  token_option=names["status_token"])
        try:
            notifier = Notifier(targets, dataset=dataset_name, smtp=smtp) if targets else None
        except BaseException:
            if status is not None:
                status.close()
            raise
        if notifier is not None:
            say("notifications to " + ", ".join(t.shown for t in targets))
        if status is not None:             # the token is said this once (never logged)
            say(f"status page (read-only): {status.url_with_token()}")
        return cls(options, notifier, say, status)

    def attach(self, engine: Any, dataset: Any = None) -> None:
        """Listen to ``engine`` (before it starts)."""
        self.engine, self.dataset = engine, dataset
        if self.notifier is not None:
            if dataset is not None and not self.notifier.dataset:
                self.notifier.dataset = Path(dataset.root).name
            self._removers.append(engine.subscribe(self.notifier.on_scan_event))
        if self.options.on_finish:
            self._removers.append(engine.subscribe(self._on_scan_event))
        if self.status is not None and dataset is not None:
            self.board = StatusBoard(dataset.root, total=len(dataset.views), done=len(dataset.done_views()))
            self._removers.append(engine.subscribe(self.board.on_scan_event))
            self.status.start(self.board)

    def attach_checker(self, checker: Any) -> None:
        """Listen to a live check's verdicts (flagged views)."""
        if self.notifier is not None:
            self._removers.append(checker.subscribe(self.notifier.on_verdict))
        if self.board is not None:
            self._removers.append(checker.subscribe(self.board.on_verdict))

    # -- the end-of-day command --------------------------------------------------------------------
    def _on_scan_event(self, ev: Any) -> None:
        """Engine listener: when the scan ends (finished, aborted, failed), start the command."""
        if ev.kind is not EventKind.STATE or ev.state not in TERMINAL or self.on_finish_thread is not None:
            return
        outcome = "failed" if ev.state is ScanState.FAILED else "aborted" if ev.extra.get("aborted") else "finished"
        env = {"LFSTUDIO_SCAN_OUTCOME": outcome, "LFSTUDIO_SCAN_MESSAGE": ev.message,
               "LFSTUDIO_DONE": str(ev.done), "LFSTUDIO_TOTAL": str(ev.total),
               "LFSTUDIO_DATASET": str(getattr(self.dataset, "root", ""))}
        self.on_finish_thread = threading.Thread(target=self.run_on_finish, args=(env,), name="on-finish",
                                                 daemon=True)
        self.on_finish_thread.start()

    def run_on_finish(self, env: dict[str, str]) -> dict[str, Any]:
        """Run the ``on_finish`` shell command with ``env`` added (``LFSTUDIO_SCAN_OUTCOME`` finished,
        aborted or failed; ``LFSTUDIO_DATASET``, ``LFSTUDIO_DONE``, ``LFSTUDIO_TOTAL``,
        ``LFSTUDIO_SCAN_MESSAGE``): at most ``on_finish_timeout_s`` (then it and its children are
        ended), its output logged and said, a failure notified."""
        command, limit = self.options.on_finish, float(self.options.on_finish_timeout_s)
        shown = mask_urls(command)
        name = self.options.names["on_finish"]
        log.info("%s: running %s", name, shown)
        self.say(f"{name}: running {shown}")
        result: dict[str, Any] = {"returncode": None, "timed_out": False, "output": "", "error": ""}
        try:
            proc = subprocess.Popen(command, shell=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL, env={**os.environ, **env}, start_new_session=True,
                                    cwd=str(getattr(self.dataset, "root", "") or os.getcwd()))
        except OSError as exc:
            result["error"] = f"could not start: {exc.strerror or exc}"
        else:
            try:
                out, _ = proc.communicate(timeout=limit)
            except subprocess.TimeoutExpired:
                result["timed_out"] = True
                _end_group(proc)
                out, _ = proc.communicate()
            result["returncode"] = proc.returncode
            result["output"] = out.decode(errors="replace")
            for line in result["output"].splitlines():
                log.info("%s: | %s", name, line)
                self.say(f"{name}: | {line}")
            if result["timed_out"]:
                result["error"] = f"did not end within {limit:g} s: stopped"
            elif proc.returncode:
                result["error"] = f"failed with exit status {proc.returncode}"
        self.on_finish_result = result
        if result["error"]:
            text = f"the command run when the scan ends ({shown}) {result['error']}"
            log.warning("%s: %s", name, text)
            self.say(f"{name}: {text}")
            if self.notifier is not None:
                self.notifier.notify("on-finish-failed", text[:1].upper() + text[1:] + ".")
        else:
            self.say(f"{name}: done")
        return result

    def wait_on_finish(self, timeout_s: float | None = None) -> bool:
        """Wait for the end-of-day command (if it was started); False after ``timeout_s``."""
        thread = self.on_finish_thread
        if thread is not None:
            thread.join(timeout_s)
            return not thread.is_alive()
        return True

    def on_verdicts(self, entries: list[dict[str, Any]]) -> None:
        """Live-check verdicts handed over by a front end (the window's grid view checks the views)."""
        for entry in entries:
            if self.notifier is not None:
                self.notifier.on_verdict(entry)
            if self.board is not None:
                self.board.on_verdict(entry)

    def close(self, timeout_s: float = 10.0) -> None:
        """Stop listening; let the end-of-day command end (its own time limit); deliver what is queued
        within ``timeout_s``; stop the status page."""
        self.wait_on_finish(float(self.options.on_finish_timeout_s) + 15.0)
        for remove in self._removers:

            remove()
        self._removers.clear()
        if self.notifier is not None:
            self.notifier.close(timeout_s)
        if self.status is not None:
            self.status.close()


def _end_group(proc: subprocess.Popen) -> None:
    """End a command that ran too long, and whatever it started (its process group)."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError, AttributeError):
            return
        try:
            proc.wait(5)
            return
        except subprocess.TimeoutExpired:
            continue
