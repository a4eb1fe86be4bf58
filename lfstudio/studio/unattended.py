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
import threading
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from lfstudio.errors import InputError
from lfstudio.scan.events import TERMINAL, EventKind, ScanState
from lfstudio.scan.notify import Notifier, SmtpServer, mask_urls, parse_target
from lfstudio.scan.status_http import LINGER_S, StatusBoard, StatusServer
from lfstudio.studio.scan_options import PARAMS
from lfstudio.support.children import KILL_GRACE_S, run_contained
from lfstudio.support.secrets import Secret, reveal

log = logging.getLogger(__name__)

#: the options described in lfstudio.studio.scan_options (range, label, tip, command-line name)
DESCRIBED = ("notify", "smtp", "status_http", "status_token", "status_linger_s", "auto_resume", "on_finish",
             "on_finish_timeout_s")
#: how each option is named where the operator gave it (the CLI's options; the window passes its own)
CLI_NAMES = {name: PARAMS[name].option for name in DESCRIBED}
SMTP_PASSWORD_ENV = "LFSTUDIO_SMTP_PASSWORD"


@dataclass
class UnattendedOptions:
    """What the operator asked for; the defaults ask for nothing."""

    notify: list[str | Secret] = field(default_factory=list)     # Secret: shown by scheme and host only
    smtp: str = ""                   # smtp://[USER@]HOST[:PORT]
    smtp_password: str | Secret = field(default="", repr=False)
    smtp_sender: str = ""
    status_http: str = ""            # [HOST:]PORT
    status_token: str | Secret = field(default="", repr=False)    # "new": make one (printed once)
    auto_resume: int = 0
    on_finish: str = ""
    on_finish_timeout_s: float = 300.0
    status_linger_s: float = LINGER_S
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
            value = getattr(options, name)
            PARAMS[name].check(names[name], [reveal(v) for v in value] if isinstance(value, (list, tuple)) else
                               reveal(value) if isinstance(value, Secret) else value)
        # secrets known from here on: never in a log line, a message or a printed command
        targets = [parse_target(reveal(url), names["notify"]) for url in options.notify]
        token = reveal(options.status_token)
        if token and token != "new":
            Secret(token)
        password = reveal(options.smtp_password) or env.get(SMTP_PASSWORD_ENV, "")
        if password:
            Secret(password)
        for target in targets:
            if target.shape != "mail":          # a mail address is no secret; a URL's path and password are
                Secret(target.url, target.shown)
                secret_parts = urllib.parse.urlsplit(target.url)
                if secret_parts.password:
                    Secret(urllib.parse.unquote(secret_parts.password))
        smtp = None
        if options.smtp:
            smtp = SmtpServer.parse(options.smtp, password=password, sender=options.smtp_sender, option=names["smtp"])
        if any(t.shape == "mail" for t in targets) and smtp is None:
            raise InputError(names["notify"], "a mailto: target needs an SMTP server", f"{names['smtp']} smtp://USER@HOST")
        if options.on_finish and not options.on_finish.strip():
            raise InputError(names["on_finish"], "the command is empty", "a shell command, e.g. 'lights off'")
        if token and not options.status_http:
            raise InputError(names["status_token"], "is for the status page", f"add {names['status_http']} [HOST:]PORT")
        status = None
        if options.status_http:            # bound now: a port in use stops everything before it starts
            status = StatusServer(options.status_http, token, option=names["status_http"],
                                  token_option=names["status_token"])
        try:
            notifier = Notifier(targets, dataset=dataset_name, smtp=smtp) if targets else None
        except BaseException:
            if status is not None:
                status.close()
            raise
        if notifier is not None:
            say("notifications to " + ", ".join(t.shown for t in targets))
        if status is not None and token == "new":      # a token made here is said this once (never logged)
            Secret(status.token)
            say(f"status page (read-only): {status.url_with_token()}")
        elif status is not None:           # a token given is never repeated
            say(f"status page (read-only): {status.url}" + (f" (with ?token= the {names['status_token']} given)"
                                                            if token else ""))
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
        ``LFSTUDIO_SCAN_MESSAGE``), contained (:func:`lfstudio.support.children.run_contained`): at most
        ``on_finish_timeout_s``, then it and everything it started are ended; its output logged and
        said with a cap; a failure logged in one line and notified (``on-finish-failed``)."""
        command, limit = self.options.on_finish, float(self.options.on_finish_timeout_s)
        shown = mask_urls(command)
        name = self.options.names["on_finish"]
        log.info("%s: running %s", name, shown)
        self.say(f"{name}: running {shown}")

        def line(text: str) -> None:
            text = mask_urls(text)
            log.info("%s: | %s", name, text)
            self.say(f"{name}: | {text}")
        run = run_contained(command, limit_s=limit, env={**os.environ, **env}, on_line=line,
                            cwd=str(getattr(self.dataset, "root", "") or os.getcwd()))
        result: dict[str, Any] = {"returncode": run.returncode, "timed_out": run.timed_out, "output": run.output,
                                  "output_bytes": run.output_bytes, "lines": run.lines, "error": run.error}
        if run.error:
            result["error"] = run.error
        elif run.timed_out:
            result["error"] = (f"did not end within {limit:g} s: stopped" if run.returncode is None or
                               run.returncode < 0 else
                               f"left processes running past the {limit:g} s time limit: stopped")
        elif run.returncode:
            result["error"] = f"failed with exit status {run.returncode}"
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

    def close(self, timeout_s: float = 10.0, *, linger: bool = True) -> StatusServer | None:
        """Stop listening; let the end-of-day command end (it ends by its own time limit: this waits
        at most that, saying so); deliver what is queued within ``timeout_s``. The status page keeps
        showing the final state for ``status_linger_s`` (``linger``, and the scan was attached), then
        closes by itself: returned while it does (None once closed), so that a front end can show it
        and close it sooner (:meth:`StatusServer.close`, e.g. before the next scan takes the port)."""
        thread = self.on_finish_thread
        if thread is not None and thread.is_alive():
            left = float(self.options.on_finish_timeout_s) + 3 * KILL_GRACE_S
            self.say(f"{self.options.names['on_finish']}: waiting for the command to end (at most {left:g} s)")
            self.wait_on_finish(left)
        for remove in self._removers:
            remove()
        self._removers.clear()
        if self.notifier is not None:
            if not self.notifier.wait_idle(0):      # a notice still on its way: say why this takes a moment
                self.say(f"{self.options.names['notify']}: delivering the last notifications (at most {timeout_s:g} s)")
            self.notifier.close(timeout_s)
        status, self.status = self.status, None
        if status is None:
            return None
        if linger and self.board is not None and self.board.outcome is not None and self.options.status_linger_s > 0:
            status.linger(self.options.status_linger_s)
            return status
        status.close()
        return None
