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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from lfstudio.errors import InputError
from lfstudio.scan.notify import Notifier, SmtpServer, parse_target
from lfstudio.scan.status_http import StatusBoard, StatusServer

log = logging.getLogger(__name__)

#: how each option is named where the operator gave it (the CLI's options; the window passes its own)
CLI_NAMES = {"notify": "--notify", "smtp": "--smtp", "status_http": "--status-http",
             "status_token": "--status-token", "auto_resume": "--auto-resume", "on_finish": "--on-finish",
             "on_finish_timeout_s": "--on-finish-timeout-s"}
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

    @classmethod
    def open(cls, options: UnattendedOptions, *, dataset_name: str = "",
             say: Callable[[str], None] = lambda text: None, env: dict[str, str] | None = None) -> "Unattended":
        """Check ``options`` and set up what they ask for (see the module docstring)."""
        names = options.names
        env = os.environ if env is None else env
        targets = [parse_target(url, names["notify"]) for url in options.notify]
        smtp = None
        if options.smtp:
            smtp = SmtpServer.parse(options.smtp, password=options.smtp_password or env.get(SMTP_PASSWORD_ENV, ""),
                                    sender=options.smtp_sender, option=names["smtp"])
        if any(t.shape == "mail" for t in targets) and smtp is None:
            raise InputError(names["notify"], "a mailto: target needs an SMTP server", f"{names['smtp']} smtp://USER@HOST")
        if options.auto_resume < 0 or options.auto_resume > 1000:
            raise InputError(names["auto_resume"], f"{options.auto_resume} is out of range", "0 … 1000")
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

    def close(self, timeout_s: float = 10.0) -> None:
        """Stop listening; deliver what is queued within ``timeout_s``; stop the status page."""
        for remove in self._removers:
            remove()
        self._removers.clear()
        if self.notifier is not None:
            self.notifier.close(timeout_s)
        if self.status is not None:
            self.status.close()
