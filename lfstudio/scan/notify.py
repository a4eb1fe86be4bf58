"""Notifications of a scan nobody watches: started, paused (why), resumed, failed, finished, aborted,
a view the live check flags.

Where they go (``lfstudio scan --notify URL``, repeatable; the window's Settings), by the URL's scheme:

- ``http://…``, ``https://…``: a JSON POST whose body has ``event``, ``dataset``, ``done``, ``total``,
  ``message``, ``time`` (ISO 8601, UTC), ``state``, ``resumes_by_itself`` and, for a flagged view,
  ``view``, ``verdict`` and ``reasons``;
- ``ntfy+https://HOST/TOPIC``: ntfy's own shape (the message as plain text, the title in the
  ``Title`` header, ``Priority`` high for a pause, a failure or an abort);
- ``slack+https://…``, ``matrix+https://…``: Slack-style incoming webhooks and Matrix webhook bridges,
  a JSON body with a ``text`` field;
- ``mailto:ADDRESS[,ADDRESS]``: a mail through the SMTP server (:class:`SmtpServer`).

A user name and password in a URL become HTTP basic authentication. Delivery never runs on the
scan's threads: :meth:`Notifier.on_scan_event` (an engine listener) only looks at the event's kind and,
for the few that matter, puts a :class:`Notice` on each target's bounded queue. Each target has a
thread of its own that sends with a time limit (for the whole delivery, not each read: an endpoint
that trickles its answer is cut off there) and retries with backoff, so a slow or dead endpoint
delays nothing but its own later notices; when its queue is full the oldest notice waiting is
dropped (and counted). What reaches a log names a target by :attr:`Target.shown` (scheme and host:
no path, query, user or password) and error texts are scrubbed of the URL's secrets.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import re
import http.client
import smtplib
import socket
import ssl
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
from base64 import b64encode
from collections import deque
from dataclasses import dataclass, field
from datetime import datetime, timezone
from email.message import EmailMessage
from typing import Any, Callable, Iterable

from lfstudio.dataset.paths import view_label
from lfstudio.errors import InputError
from lfstudio.scan.events import EventKind, ScanEvent, ScanState
from lfstudio.support.listeners import Listeners

log = logging.getLogger(__name__)

#: every event a notification can carry
EVENTS = ("started", "paused", "resumed", "failed", "finished", "aborted", "flagged", "on-finish-failed")
#: the URL forms --notify accepts (the end of a refusal's line)
VALID = ("http(s)://… (JSON POST), ntfy+https://HOST/TOPIC, slack+https://…, matrix+https://…, "
         "mailto:ADDRESS")
_SHAPES = {"http": "json", "https": "json", "ntfy+http": "ntfy", "ntfy+https": "ntfy",
           "slack+http": "text", "slack+https": "text", "matrix+http": "text", "matrix+https": "text",
           "mailto": "mail"}
_ADDRESS = re.compile(r"^[^@\s,;<>]+@[^@\s,;<>]+\.[^@\s,;<>]+$")
#: characters that end or break a header line (CR, LF, the other C0 controls, DEL)
_CONTROL = re.compile(r"[\x00-\x1f\x7f]+")
#: a live check can flag many views: this many are sent one by one, then one notice says the rest are not
MAX_FLAGGED = 20
#: events an operator must act on or know at once (ntfy priority, desktop urgency)
URGENT = frozenset({"paused", "failed", "aborted", "on-finish-failed"})


@dataclass(frozen=True)
class Notice:
    """One notification: what happened to which scan, how far it is."""

    event: str
    dataset: str
    done: int
    total: int
    message: str
    time: str
    state: str = ""
    resumes_by_itself: bool = False
    view: str | None = None
    verdict: str | None = None
    reasons: tuple[str, ...] = ()

    def title(self) -> str:
        """One line: a CR, LF or other control character of the dataset's name becomes a space (it
        would end an HTTP header or a mail's Subject and lose the notice)."""
        return _CONTROL.sub(" ", f"lfstudio: scan of {self.dataset} {self.event}")

    def text(self) -> str:
        """The message with the progress, for the shapes that carry text."""
        return f"{self.message} ({self.done} of {self.total} views captured)"

    def to_json(self) -> dict[str, Any]:
        body: dict[str, Any] = {"event": self.event, "dataset": self.dataset, "done": self.done,
                                "total": self.total, "message": self.message, "time": self.time,
                                "state": self.state, "resumes_by_itself": self.resumes_by_itself}
        if self.view is not None:
            body.update(view=self.view, verdict=self.verdict, reasons=list(self.reasons))
        return body


def _now_iso() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def entry_label(entry: dict[str, Any]) -> str:
    """A live-check verdict entry's view as the operator reads it (``r01 c003``)."""
    if isinstance(entry.get("row"), int) and isinstance(entry.get("column"), int):
        return view_label(entry["row"], entry["column"])
    return str(entry.get("view", "?"))


def notice_event(before: ScanState | None, ev: ScanEvent) -> str | None:
    """The notice a scan's state event ``ev`` is worth (one of :data:`EVENTS`), given the state
    ``before`` it (None: none yet); None for the others (pausing, stopping, the same state again)."""
    state = ev.state
    if ev.kind is not EventKind.STATE or state is None:
        return None
    if state is ScanState.RUNNING and before in (None, ScanState.IDLE):
        return "started"
    if state is ScanState.RUNNING and before is ScanState.PAUSED:
        return "resumed"
    if state is ScanState.PAUSED and (before is not ScanState.PAUSED or ev.extra.get("fault_changed")):
        return "paused"
    if state is ScanState.FINISHED:
        return "aborted" if ev.extra.get("aborted") else "finished"
    if state is ScanState.FAILED:
        return "failed"
    return None


# -- where notices go --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Target:
    """A parsed notification URL (:func:`parse_target`). ``shown`` is what logs and messages print."""

    url: str = field(repr=False)
    shape: str                    # json, ntfy, text, mail
    shown: str
    addresses: tuple[str, ...] = ()

    def __repr__(self) -> str:
        return f"Target({self.shown!r}, {self.shape})"

    def scrub(self, text: str) -> str:
        """``text`` without any secret part of this target's URL (path, query, user, password)."""
        parts = urllib.parse.urlsplit(self.url.split("+", 1)[-1] if self.shape != "mail" else self.url)
        for secret in (self.url, parts.path, parts.query, parts.password, parts.username, parts.netloc):
            if secret and len(secret) > 1 and secret not in (self.shown, "/"):
                text = text.replace(secret, "…")
        return text


def is_local(host: str) -> bool:
    """True when only this computer can reach ``host`` (a loopback address or ``localhost``)."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def shown_url(text: str) -> str:
    """A URL as logs may show it: scheme and host only (``https://hooks.example.com/…``)."""
    try:
        parts = urllib.parse.urlsplit(text.strip())
        host = parts.hostname or ""
        port = f":{parts.port}" if parts.port else ""
    except ValueError:             # a bad port: the host part as typed, without user and password
        try:
            parts = urllib.parse.urlsplit(text.strip())
            host, port = parts.netloc.rsplit("@", 1)[-1], ""
        except ValueError:
            return "(a malformed URL)"
    if parts.scheme.lower() == "mailto":
        return f"mailto:{parts.path}"
    if not parts.scheme or not host:
        return "(not a URL)"
    rest = "/…" if (parts.path.strip("/") or parts.query) else ""
    return f"{parts.scheme}://{host}{port}{rest}"


_URL = re.compile(r"\b[a-zA-Z][a-zA-Z0-9+.-]*://[^\s'\"]+")


def mask_urls(text: str) -> str:
    """``text`` with every URL in it shown as :func:`shown_url` (for logs: a command line, a message)."""
    return _URL.sub(lambda m: shown_url(m.group(0)), text)


def parse_target(text: str, option: str = "--notify") -> Target:
    """``text`` as a notification target; :class:`InputError` naming ``option`` (one line, the URL
    shown without its secrets) when it is malformed or its scheme unknown."""
    text = str(text).strip()
    try:
        parts = urllib.parse.urlsplit(text)
        port = parts.port                 # a bad port raises here
    except ValueError as exc:
        raise InputError(option, f"{shown_url(text)} is not a well-formed URL ({exc})", VALID) from None
    scheme = parts.scheme.lower()
    if any(ch.isspace() or _CONTROL.match(ch) for ch in text):     # urllib sends them as they are
        raise InputError(option, f"{shown_url(text)!r} holds a space or a control character, which a URL cannot "
                         "(write a space in a path as %20)", VALID)
    if not scheme or ":" not in text:
        raise InputError(option, f"{text[:40]!r} is not a URL" if "@" not in text or "/" in text
                         else f"{text!r} is not a URL (write mailto:{text})", VALID)
    shape = _SHAPES.get(scheme)
    if shape is None:
        raise InputError(option, f"unknown scheme {scheme!r} in {shown_url(text)}", VALID)
    if shape == "mail":
        addresses = tuple(a.strip() for a in urllib.parse.unquote(parts.path).split(",") if a.strip())
        bad = [a for a in addresses if not _ADDRESS.match(a)]
        if not addresses or bad:
            raise InputError(option, f"{text!r}: {bad[0] if bad else 'no address'} is not a mail address", VALID)
        return Target(text, shape, f"mailto:{','.join(addresses)}", addresses)
    if not parts.hostname:
        raise InputError(option, f"{shown_url(text)}: the URL names no host", VALID)
    if not all(ch.isalnum() or ch in "-._:%" for ch in parts.hostname):
        raise InputError(option, f"{shown_url(text)}: {parts.hostname!r} is not a host name", VALID)
    if shape == "ntfy" and not parts.path.strip("/"):
        raise InputError(option, f"{shown_url(text)}: an ntfy URL names its topic (ntfy+https://HOST/TOPIC)", VALID)
    del port
    return Target(text, shape, shown_url(text))


@dataclass(frozen=True)
class SmtpServer:
    """The SMTP server mail goes through. ``security``: ``starttls`` (port 587), ``ssl`` (465) or
    ``none`` (a local relay). The password never appears in ``repr`` or a log."""

    host: str
    port: int = 587
    security: str = "starttls"
    user: str = ""
    password: str = field(default="", repr=False)
    sender: str = ""

    @classmethod
    def parse(cls, text: str, *, password: str = "", sender: str = "", option: str = "--smtp") -> "SmtpServer":
        """``smtp://[USER@]HOST[:PORT]`` (STARTTLS when the server offers it; 587), ``smtps://…`` (SSL,
        465) or ``smtp+plain://…`` (no encryption: a relay on this network)."""
        try:
            parts = urllib.parse.urlsplit(str(text).strip())
            port = parts.port
        except ValueError as exc:
            raise InputError(option, f"not a well-formed address ({exc})", "smtp://[USER@]HOST[:PORT]") from None
        security = {"smtp": "starttls", "smtps": "ssl", "smtp+plain": "none"}.get(parts.scheme.lower())
        if security is None or not parts.hostname:
            raise InputError(option, f"{shown_url(text)} is not an SMTP server address",
                             "smtp://[USER@]HOST[:PORT], smtps://… or smtp+plain://…")
        if parts.password:
            raise InputError(option, "a password does not go into the address (it would show in the process list)",
                             "the LFSTUDIO_SMTP_PASSWORD environment variable, or the window's Settings")
        default_port = {"starttls": 587, "ssl": 465, "none": 25}[security]
        user = urllib.parse.unquote(parts.username or "")
        if security == "none" and user and not is_local(parts.hostname):
            raise InputError(option, f"smtp+plain:// would send {user}'s password unencrypted to {parts.hostname}",
                             "smtp://… (STARTTLS) or smtps://…; smtp+plain:// only to a relay on this computer "
                             "(127.0.0.1) or without a user")
        return cls(parts.hostname, port or default_port, security, user, password,
                   sender or (user if "@" in user else f"lfstudio@{parts.hostname}"))


# -- sending -------------------------------------------------------------------------------------------
def header_value(text: str) -> str:
    """``text`` as an HTTP header value: one line (control characters become spaces), and a text that is
    not ASCII as an RFC 2047 encoded-word (``=?utf-8?b?…?=``, which ntfy decodes): http.client sends
    headers as Latin-1 and refuses anything else, so a dataset named ``Stühle ✓`` lost every notice."""
    text = _CONTROL.sub(" ", text)
    if text.isascii():
        return text
    return "=?utf-8?b?" + b64encode(text.encode("utf-8")).decode("ascii") + "?="


class NotDelivered(Exception):
    """A notice that cannot be delivered however often it is tried (a redirect, a refusal): not retried."""


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    """Redirects are not followed: the request would carry the URL's credentials to wherever the
    answer points (and urllib turns a redirected POST into a GET without its body)."""

    def redirect_request(self, req: urllib.request.Request, fp: Any, code: int, msg: str, headers: Any,
                         newurl: str) -> urllib.request.Request | None:
        raise NotDelivered(f"the endpoint answered {code} {msg} (a redirect to {shown_url(newurl)}): not followed, "
                           "so neither the notice nor the URL's credentials go there; give --notify the address "
                           "it redirects to")


class _Deadline:
    """One delivery's time limit over everything it reads (a socket's timeout is per read: an endpoint
    answering a byte at a time within it would hold the delivery thread and its connection for as long as
    it liked). At ``timeout_s`` the connections the delivery opened on this thread are shut down, so
    whatever read is blocked ends there (the delivery fails and is retried or given up)."""

    _current = threading.local()

    def __init__(self, timeout_s: float):
        self._socks: list[socket.socket] = []
        self._lock = threading.Lock()
        self._expired = False
        self._timer = threading.Timer(timeout_s, self._expire)
        self._timer.daemon = True

    def __enter__(self) -> "_Deadline":
        _Deadline._current.value = self
        self._timer.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._timer.cancel()
        _Deadline._current.value = None

    @classmethod
    def watch(cls, sock: socket.socket) -> None:
        """``sock`` ends at the time limit of the delivery under way on this thread (if any)."""
        deadline = getattr(cls._current, "value", None)
        if deadline is not None:
            with deadline._lock:
                deadline._socks.append(sock)
                if not deadline._expired:
                    return
            _shut(sock)

    def _expire(self) -> None:
        with self._lock:
            self._expired = True
            socks = list(self._socks)
        for sock in socks:
            _shut(sock)


def _shut(sock: socket.socket) -> None:
    try:
        sock.shutdown(socket.SHUT_RDWR)
    except OSError:                 # closed meanwhile
        pass


class _Watched:
    """An ``http.client`` connection whose socket ends at the delivery's time limit (:class:`_Deadline`)."""

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        create = self._create_connection

        def watched(*a: Any, **kw: Any) -> socket.socket:
            sock = create(*a, **kw)
            _Deadline.watch(sock)
            return sock
        self._create_connection = watched


class _HTTPConnection(_Watched, http.client.HTTPConnection):
    pass


class _HTTPSConnection(_Watched, http.client.HTTPSConnection):
    pass


class _HTTPHandler(urllib.request.HTTPHandler):
    def http_open(self, req: urllib.request.Request) -> Any:
        return self.do_open(_HTTPConnection, req)


class _HTTPSHandler(urllib.request.HTTPSHandler):
    def https_open(self, req: urllib.request.Request) -> Any:
        return self.do_open(_HTTPSConnection, req, context=getattr(self, "_context", None))


class _SMTP(smtplib.SMTP):
    def _get_socket(self, host: str, port: int, timeout: float) -> socket.socket:
        sock = getattr(super(), "_get_socket")(host, port, timeout)
        _Deadline.watch(sock)
        return sock


class _SMTP_SSL(smtplib.SMTP_SSL, _SMTP):    # its raw socket is _SMTP's: watched before the TLS handshake
    pass


_OPENER = urllib.request.build_opener(_NoRedirect(), _HTTPHandler(), _HTTPSHandler())

def _request(target: Target, body: bytes, headers: dict[str, str]) -> urllib.request.Request:
    url = target.url.split("+", 1)[1] if "+" in target.url.split(":", 1)[0] else target.url
    parts = urllib.parse.urlsplit(url)
    if parts.username is not None:
        netloc = (parts.hostname or "") + (f":{parts.port}" if parts.port else "")
        url = urllib.parse.urlunsplit(parts._replace(netloc=netloc))
        pair = f"{urllib.parse.unquote(parts.username)}:{urllib.parse.unquote(parts.password or '')}"
        headers["Authorization"] = "Basic " + b64encode(pair.encode()).decode()
    headers.setdefault("User-Agent", "lfstudio")
    return urllib.request.Request(url, data=body, headers=headers, method="POST")


def send(target: Target, notice: Notice, *, timeout_s: float = 10.0, smtp: SmtpServer | None = None) -> None:
    """Deliver ``notice`` to ``target`` once (raises on failure: an HTTP status >= 300 too), all of it
    within ``timeout_s`` (:class:`_Deadline`)."""
    with _Deadline(timeout_s):
        _send(target, notice, timeout_s, smtp)


def _send(target: Target, notice: Notice, timeout_s: float, smtp: SmtpServer | None) -> None:
    if target.shape == "mail":
        _send_mail(target, notice, smtp, timeout_s)
        return
    if target.shape == "ntfy":
        body = notice.text().encode()
        headers = {"Title": header_value(notice.title()), "Content-Type": "text/plain; charset=utf-8",
                   "Priority": "high" if notice.event in URGENT else "default",
                   "Tags": {"finished": "white_check_mark", "flagged": "mag"}.get(
                       notice.event, "warning" if notice.event in URGENT else "camera")}
    elif target.shape == "text":
        body = json.dumps({"text": f"{notice.title()}: {notice.text()}"}).encode()
        headers = {"Content-Type": "application/json"}
    else:
        body = json.dumps(notice.to_json()).encode()
        headers = {"Content-Type": "application/json"}
    with _OPENER.open(_request(target, body, headers), timeout=timeout_s) as reply:
        reply.read(65536)


def _send_mail(target: Target, notice: Notice, smtp: SmtpServer | None, timeout_s: float) -> None:
    if smtp is None:
        raise RuntimeError("no SMTP server is set (Settings → Notifications, or --smtp)")
    mail = EmailMessage()
    mail["Subject"] = notice.title()
    mail["From"] = smtp.sender
    mail["To"] = ", ".join(target.addresses)
    lines = [notice.text(), "", f"event: {notice.event}", f"state: {notice.state}", f"time: {notice.time}"]
    if notice.view:
        lines += [f"view: {notice.view} ({notice.verdict})", *notice.reasons]
    mail.set_content("\n".join(lines) + "\n")
    if smtp.security == "ssl":
        client: smtplib.SMTP = _SMTP_SSL(smtp.host, smtp.port, timeout=timeout_s,
                                         context=ssl.create_default_context())
    else:
        client = _SMTP(smtp.host, smtp.port, timeout=timeout_s)
    with client:
        if smtp.security == "starttls":
            client.ehlo()
            if client.has_extn("starttls"):
                client.starttls(context=ssl.create_default_context())
                client.ehlo()
            elif smtp.user:
                raise RuntimeError(f"{smtp.host} offers no STARTTLS: the password is not sent unencrypted")
        if smtp.user and smtp.security == "none" and not is_local(smtp.host):
            raise NotDelivered(f"{smtp.host} is not this computer: the password is not sent unencrypted")
        if smtp.user:
            client.login(smtp.user, smtp.password)
        client.send_message(mail)


@dataclass(frozen=True)
class Delivery:
    """What became of one notice at one target (told to :meth:`Notifier.subscribe` listeners)."""

    target: str                   # Target.shown
    notice: Notice
    ok: bool
    attempts: int
    error: str = ""               # scrubbed of the URL's secrets
    sent_at: float = 0.0          # time.time() when it was delivered or given up


class _Channel:
    """One target's bounded queue and the thread that delivers it."""

    def __init__(self, target: Target, notifier: "Notifier"):
        self.target = target
        self.notifier = notifier
        self.queue: deque[Notice] = deque()
        self.dropped = 0
        self.cond = threading.Condition()
        self.closing = False
        self.busy = False
        self.thread = threading.Thread(target=self._run, name=f"notify {target.shown}", daemon=True)
        self.thread.start()

    def put(self, notice: Notice) -> None:
        with self.cond:
            if len(self.queue) >= self.notifier.max_queue:
                self.queue.popleft()
                self.dropped += 1
                if self.dropped == 1 or self.dropped % 100 == 0:
                    log.warning("notifications to %s: %d dropped (the queue of %d is full: it does not answer)",
                                self.target.shown, self.dropped, self.notifier.max_queue)
            self.queue.append(notice)
            self.cond.notify_all()

    def idle(self) -> bool:
        return not self.queue and not self.busy

    def _run(self) -> None:
        n = self.notifier
        while True:
            with self.cond:
                self.cond.wait_for(lambda: self.queue or self.closing)
                if not self.queue:
                    return
                notice = self.queue.popleft()
                self.busy = True
            error, attempt = "", 0
            for attempt in range(1, n.retries + 2):
                try:
                    send(self.target, notice, timeout_s=n.timeout_s, smtp=n.smtp)
                    error = ""
                    break
                except Exception as exc:       # any failure of the endpoint: retried, then given up
                    error = self.target.scrub(str(exc) if isinstance(exc, NotDelivered) else
                                              f"{type(exc).__name__}: {exc}")
                    log.info("notification %s to %s failed (attempt %d): %s", notice.event, self.target.shown,
                             attempt, error)
                    with self.cond:
                        if self.closing or attempt > n.retries or isinstance(exc, NotDelivered):
                            break
                        self.cond.wait(n.backoff_s * 2 ** (attempt - 1))
            if error:
                log.warning("notification %s to %s not delivered after %d attempt(s): %s", notice.event,
                            self.target.shown, attempt, error)
            n._delivered(Delivery(self.target.shown, notice, not error, attempt, error, time.time()))
            with self.cond:
                self.busy = False
                self.cond.notify_all()


class Notifier:
    """Sends :class:`Notice` objects to ``targets`` (URLs or :class:`Target` objects) off the caller's
    thread. ``dataset``: the name notices carry. Listen to a scan with
    ``engine.subscribe(notifier.on_scan_event)`` and to a live check with
    ``checker.subscribe(notifier.on_verdict)``; :meth:`notify` sends anything else."""

    def __init__(self, targets: Iterable[Target | str], *, dataset: str = "", smtp: SmtpServer | None = None,
                 max_queue: int = 100, retries: int = 3, backoff_s: float = 2.0, timeout_s: float = 10.0):
        parsed = [t if isinstance(t, Target) else parse_target(t) for t in targets]
        if smtp is None and any(t.shape == "mail" for t in parsed):
            raise InputError("--notify", "a mailto: target needs an SMTP server",
                             "--smtp smtp://USER@HOST (or the window's Settings → Notifications)")
        self.dataset = dataset
        self.smtp = smtp
        self.max_queue = max(1, int(max_queue))
        self.retries = max(0, int(retries))
        self.backoff_s = float(backoff_s)
        self.timeout_s = float(timeout_s)
        self._listeners: Listeners[Delivery] = Listeners("notification listener", log)
        self._lock = threading.Lock()
        self._last_state: ScanState | None = None
        self._flagged: dict[str, str] = {}
        self._progress = (0, 0)
        self._channels = [_Channel(t, self) for t in parsed]

    @property
    def targets(self) -> list[Target]:
        return [c.target for c in self._channels]

    def subscribe(self, listener: Callable[[Delivery], Any]) -> Callable[[], None]:
        """``listener(delivery)`` for each notice delivered or given up (on a delivery thread)."""
        return self._listeners.add(listener)

    def _delivered(self, delivery: Delivery) -> None:
        self._listeners.notify(delivery)

    @property
    def dropped(self) -> dict[str, int]:
        """Notices dropped so far (the queue was full), per target (:attr:`Target.shown`)."""
        return {c.target.shown: c.dropped for c in self._channels}

    # -- what is sent -----------------------------------------------------------------------------
    def notify(self, event: str, message: str, *, done: int | None = None, total: int | None = None,
               state: str = "", resumes_by_itself: bool = False, view: str | None = None,
               verdict: str | None = None, reasons: Iterable[str] = ()) -> Notice:
        d, t = self._progress
        notice = Notice(event, self.dataset, d if done is None else int(done), t if total is None else int(total),
                        message, _now_iso(), state, resumes_by_itself, view, verdict, tuple(reasons))
        for channel in self._channels:
            channel.put(notice)
        return notice

    def on_scan_event(self, ev: ScanEvent) -> None:
        """A scan engine listener (on the engine's threads): quick, never waits for a delivery."""
        if ev.total:
            self._progress = (ev.done, ev.total)
        if ev.kind is not EventKind.STATE or ev.state is None:
            return
        with self._lock:
            before, self._last_state = self._last_state, ev.state
        event = notice_event(before, ev)
        if event is not None:
            self.notify(event, ev.message, done=ev.done, total=ev.total, state=ev.state.value,
                        resumes_by_itself=bool(ev.extra.get("auto_resume")) and event == "paused")

    def on_verdict(self, entry: dict[str, Any]) -> None:
        """A live check listener: a view judged ``warn`` or ``fail`` (again only when it gets worse);
        after :data:`MAX_FLAGGED` views one notice says further ones are not sent."""
        verdict = entry.get("verdict")
        if verdict not in ("warn", "fail"):
            return
        view = entry_label(entry)
        with self._lock:
            before = self._flagged.get(view)
            if before == verdict or before == "fail":
                return
            self._flagged[view] = verdict
            n = len(self._flagged)
        if n > MAX_FLAGGED + 1:
            return
        reasons = [str(r) for r in entry.get("reasons") or ()]
        if n == MAX_FLAGGED + 1:
            self.notify("flagged", f"more views flagged by the live check ({n} so far): no further notice of "
                                   "single views; lfstudio check names them all")
            return
        self.notify("flagged", f"view {view} {verdict}s the live check" + (f": {'; '.join(reasons)}" if reasons
                                                                           else ""),
                    view=view, verdict=verdict, reasons=reasons)

    # -- end ---------------------------------------------------------------------------------------
    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Wait until every queued notice is delivered or given up; False after ``timeout_s``."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        for c in self._channels:
            with c.cond:
                left = None if deadline is None else max(0.0, deadline - time.monotonic())
                if not c.cond.wait_for(c.idle, left):
                    return False
        return True

    def close(self, timeout_s: float = 10.0) -> bool:
        """Deliver what is queued within ``timeout_s`` (the last notice of a scan matters), then stop
        (retries are not waited for); True when everything was delivered or given up."""
        delivered = self.wait_idle(timeout_s)
        for c in self._channels:
            with c.cond:
                c.closing = True
                if not delivered:
                    left = len(c.queue)
                    if left:
                        log.warning("notifications to %s: %d not sent (it did not answer in time)", c.target.shown,
                                    left)
                    c.queue.clear()
                c.cond.notify_all()
        return delivered
