"""A read-only status page of a running scan, for a browser on this or another computer.

``lfstudio scan --status-http [HOST:]PORT`` (the window: Settings → Unattended scans) serves

- ``/``: the state, progress, ETA, the last thumbnails, the live check's verdicts and the log's tail
  (the page reloads itself every few seconds);
- ``/status.json``: ``state``, ``message``, ``done``, ``total``, ``eta_s``, ``dataset``, ``time``,
  ``outcome`` and ``ended`` (finished, aborted or failed and when, once the scan has ended; else null),
  ``serving_until``, ``thumbs``, ``verdicts``, ``flagged``, ``log``;
- ``/thumbs/NAME.jpg``: one of the last thumbnails (no other file of the dataset; opened without
  following a symlink, inside the dataset: :func:`open_inside`).

Nothing can be done through it: it answers GET and HEAD only (anything else: 405). It listens on
127.0.0.1 unless a host is given; an address other computers can reach needs a token
(:func:`check_address`), which every request must carry (``?token=…`` or ``Authorization: Bearer …``;
without it: 401). :class:`StatusBoard` is the scan's side: an engine (and live check) listener that
only stores references under a lock; the page is put together when a browser asks for it, on the
server's own thread. :class:`StatusServer` is bounded (connections, timeouts, sizes: it can never take
the scan's file descriptors) and, after the scan, keeps showing its final state for
``--status-linger-s`` (:meth:`StatusServer.linger`).
"""

from __future__ import annotations

import hmac
import html
import ipaddress
import json
import logging
import os
import re
import secrets
import selectors
import socket
import stat
import threading
import time
import urllib.parse
from collections import deque
from datetime import datetime
from pathlib import Path
from typing import Any

from lfstudio.errors import InputError
from lfstudio.scan.events import TERMINAL, EventKind, ScanEvent, ScanState
from lfstudio.scan.notify import entry_label, is_local

log = logging.getLogger(__name__)

DEFAULT_HOST = "127.0.0.1"
REFRESH_S = 5                  # the page reloads itself this often
THUMBS = 8                     # the last thumbnails shown
LOG_LINES = 40                 # the log's tail shown
MAX_FLAGGED_SHOWN = 20         # the views flagged last (each once)
MIN_TOKEN_CHARS = 16
#: the bounds of the server (see :class:`StatusServer`)
MAX_CONNECTIONS = 64           # open at once; a new one past that closes the one open the longest
READ_TIMEOUT_S = 10.0          # a request's head must arrive within this (its answer be taken within twice)
IDLE_TIMEOUT_S = 5.0           # ... with no pause longer than this
MAX_HEAD_BYTES = 16384         # request line and headers (then 431, or 414 for a long address)
MAX_URL_BYTES = 8192
MAX_THUMB_BYTES = 16 << 20     # a thumbnail larger than this is not served
LISTEN_BACKLOG = 128
RECV_BYTES = 16384
DRAIN_S = 2.0                  # after the answer, how long a client may take to close its side
#: how long the page keeps showing a scan's final state after it ended (``--status-linger-s``)
LINGER_S = 600.0
_LOGGED = (EventKind.STATE, EventKind.FAULT, EventKind.VIEW_FAILED, EventKind.VIEW_SKIPPED, EventKind.LOG,
           EventKind.VIEW_DONE)


def parse_address(text: str, option: str = "--status-http") -> tuple[str, int]:
    """``[HOST:]PORT`` → (host, port); the host is 127.0.0.1 when not given, else an IP address of this
    computer or ``localhost`` (a name is refused: looking it up may wait on DNS, and the window opens
    the page on its own thread when a scan starts); port 0: any free port (the address said to the
    operator has the one taken)."""
    text = str(text).strip()
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host = DEFAULT_HOST
    host = host.strip("[]") or DEFAULT_HOST
    try:
        port = int(port_text)
    except ValueError:
        raise InputError(option, f"{text!r} is not [HOST:]PORT", "e.g. 8765 or 0.0.0.0:8765") from None
    if not 0 <= port <= 65535:
        raise InputError(option, f"port {port} is out of range", "1 … 65535, or 0 for any free port")
    if host.lower() != "localhost":
        try:
            ipaddress.ip_address(host)
        except ValueError:          # a name would be looked up (DNS) where the window starts a scan
            raise InputError(option, f"{host!r} is a name: the page listens on an address of this computer",
                             "127.0.0.1 (this computer only), 0.0.0.0 (every network) or one of its IP "
                             "addresses") from None
    return host, port


def check_token(host: str, token: str, option: str = "--status-http", token_option: str = "--status-token") -> str:
    """The token requests must carry ("" for none): ``token`` "new" makes one. An address other computers
    can reach without a token, or a short token, is refused (:class:`InputError`)."""
    if token == "new":
        return secrets.token_urlsafe(18)
    if token and len(token) < MIN_TOKEN_CHARS:
        raise InputError(token_option, f"the token is {len(token)} characters long", f"at least {MIN_TOKEN_CHARS}, "
                         f"or {token_option} new to have one made")
    if not token and not is_local(host):
        raise InputError(option, f"{host} can be reached from other computers: the status page needs a token there",
                         f"add {token_option} new (a token is made and printed once), or listen on 127.0.0.1")
    return token


# -- the scan's side ---------------------------------------------------------------------------------
class StatusBoard:
    """What the page shows, kept up to date by ``engine.subscribe(board.on_scan_event)`` and
    ``checker.subscribe(board.on_verdict)``. Each event costs a few assignments under a lock."""

    def __init__(self, dataset_root: str | Path, *, total: int = 0, done: int = 0):
        self.root = Path(dataset_root)
        self.name = self.root.name
        self._lock = threading.Lock()
        self.state = ScanState.IDLE
        self.message = "not started"
        self.done, self.total = done, total
        self._eta: tuple[float, float] | None = None       # (eta_s, monotonic time it was told)
        self._thumbs: deque[tuple[str, str]] = deque(maxlen=THUMBS)   # (view label, relative path)
        # thumbnails a page shown a moment ago may still ask for (the scan moved on meanwhile)
        self._servable: deque[str] = deque(maxlen=8 * THUMBS)
        self._log: deque[ScanEvent] = deque(maxlen=LOG_LINES)
        self.verdicts = {"pass": 0, "warn": 0, "fail": 0}
        self._verdict_of: dict[str, str] = {}
        self._flagged: dict[str, dict[str, Any]] = {}        # view -> its entry, the latest change last
        self.started = time.time()
        self.outcome: str | None = None          # finished, aborted or failed, once the scan has ended
        self.ended: float | None = None          # time.time() it ended
        self.serving_until: float | None = None  # time.time() the page stops showing the final state

    def on_scan_event(self, ev: ScanEvent) -> None:
        with self._lock:
            if ev.total:
                self.done, self.total = ev.done, ev.total
            kind = ev.kind
            if kind is EventKind.STATE and ev.state is not None:
                self.state, self.message = ev.state, ev.message
                if ev.state is not ScanState.RUNNING:
                    self._eta = None
                if ev.state in TERMINAL:
                    self.outcome = ("failed" if ev.state is ScanState.FAILED else
                                    "aborted" if ev.extra.get("aborted") else "finished")
                    self.ended = ev.time
                else:
                    self.outcome = self.ended = None
            elif kind is EventKind.VIEW_DONE:
                if ev.eta_s is not None:
                    self._eta = (ev.eta_s, time.monotonic())
                if ev.thumb:
                    self._thumbs.append((f"r{ev.row:02d} c{ev.column:03d}", ev.thumb))
                    self._servable.append(ev.thumb)
            if kind in _LOGGED:
                self._log.append(ev)

    def on_verdict(self, entry: dict[str, Any]) -> None:
        view, verdict = entry_label(entry), str(entry.get("verdict", ""))
        with self._lock:
            before = self._verdict_of.get(view)
            if before in self.verdicts:
                self.verdicts[before] -= 1
            if verdict in self.verdicts:
                self.verdicts[verdict] += 1
                self._verdict_of[view] = verdict
            self._flagged.pop(view, None)        # judged again: listed once, with its latest verdict
            if verdict in ("warn", "fail"):
                self._flagged[view] = {"view": view, "verdict": verdict,
                                       "reasons": [str(r) for r in entry.get("reasons") or ()]}
                if len(self._flagged) > MAX_FLAGGED_SHOWN:
                    del self._flagged[next(iter(self._flagged))]

    def eta_s(self) -> float | None:
        with self._lock:
            if self._eta is None:
                return None
            eta, at = self._eta
        return max(0.0, eta - (time.monotonic() - at))

    def snapshot(self) -> dict[str, Any]:
        """``/status.json``'s body."""
        eta = self.eta_s()
        with self._lock:
            log_events = list(self._log)
            doc = {"dataset": self.name, "state": self.state.value, "message": self.message, "done": self.done,
                   "total": self.total, "eta_s": None if eta is None else round(eta, 1),
                   "time": _when(time.time()), "outcome": self.outcome,
                   "ended": None if self.ended is None else _when(self.ended),
                   "serving_until": None if self.serving_until is None else _when(self.serving_until),
                   "thumbs": [{"view": v, "url": f"/thumbs/{Path(rel).name}"} for v, rel in self._thumbs],
                   "verdicts": dict(self.verdicts), "flagged": list(self._flagged.values())}
        doc["log"] = [f"{datetime.fromtimestamp(ev.time):%H:%M:%S}  {ev.describe()}" for ev in log_events]
        return doc

    def thumb_bytes(self, name: str) -> bytes | None:
        """The bytes of a thumbnail the page shows now (None for any other name, and for a file that is
        a symlink or lies outside the dataset: :func:`open_inside`)."""
        with self._lock:
            rels = list(self._servable)
        for rel in reversed(rels):
            if Path(rel).name == name:
                return open_inside(self.root, rel, MAX_THUMB_BYTES)
        return None


def _when(t: float) -> str:
    return datetime.fromtimestamp(t).astimezone().strftime("%Y-%m-%d %H:%M:%S %Z")


# -- the server ----------------------------------------------------------------------------------------
class StatusServer:
    """The page's HTTP server, bound at once (a port in use is an :class:`InputError` naming
    ``option``); :meth:`start` serves ``board`` on one thread of its own, an event loop
    (:mod:`selectors`) that never blocks on a client:

    - at most ``max_connections`` connections are open (a new one past that closes the one open the
      longest), so however many clients connect, the page holds at most that many descriptors and
      the scan's own files are never refused ("Too many open files");
    - a request's head must arrive within ``read_timeout_s`` with no pause longer than
      ``idle_timeout_s``, and be at most :data:`MAX_HEAD_BYTES`; the answer must be taken within
      ``read_timeout_s`` too; one request per connection (``Connection: close``);
    - a client that resets or drops its connection is closed without a word (no traceback);
    - when a new connection needs room, a connection still sending its request head (a slow or
      hostile client) is closed first, the oldest of them; one being answered only when there is
      no other;
    - :meth:`close` never waits on the loop: the port is free when it returns.

    After the scan, :meth:`linger` keeps it serving the final state for a while."""

    def __init__(self, address: str, token: str = "", *, option: str = "--status-http",
                 token_option: str = "--status-token", max_connections: int = MAX_CONNECTIONS,
                 read_timeout_s: float = READ_TIMEOUT_S, idle_timeout_s: float = IDLE_TIMEOUT_S):
        host, port = parse_address(address, option)
        self.token = check_token(host, token, option, token_option)
        self.board: StatusBoard | None = None
        self.max_connections = max(1, int(max_connections))
        self.read_timeout_s, self.idle_timeout_s = float(read_timeout_s), float(idle_timeout_s)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        try:
            infos = socket.getaddrinfo(host, port, family, socket.SOCK_STREAM)
        except socket.gaierror:
            raise InputError(option, f"{host} is not a name or address of this computer",
                             "127.0.0.1, 0.0.0.0 or one of its addresses") from None
        sock = socket.socket(family, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(infos[0][4])
            sock.listen(LISTEN_BACKLOG)
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            if exc.errno in (98, 48, 10048):        # EADDRINUSE (Linux, macOS, Windows)
                raise InputError(option, f"port {port} on {host} is in use", "another port, or stop what listens "
                                 "there") from None
            raise InputError(option, f"cannot listen on {host}:{port}: {exc.strerror or exc}",
                             "an address of this computer and a free port") from None
        self._sock = sock
        self.host, self.port = host, sock.getsockname()[1]
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._sock_lock = threading.Lock()       # the listening socket: accepted from (loop) or closed (close())
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._until: float | None = None          # monotonic time the lingering page ends
        self._closed = threading.Event()
        self.requests = 0
        self.open_connections = 0
        self.peak_connections = 0
        self.evicted = 0                          # connections closed to make room for a new one
        self.timed_out = 0                        # connections closed for their read or idle timeout

    @property
    def url(self) -> str:
        """The page's address without the token (what logs may show)."""
        host = self.host if ":" not in self.host else f"[{self.host}]"
        if host in ("0.0.0.0", "[::]"):
            host = socket.gethostname()
        return f"http://{host}:{self.port}/"

    def url_with_token(self) -> str:
        """The address to open (with the token: say it once to the operator, never log it)."""
        return self.url + (f"?token={self.token}" if self.token else "")

    @property
    def serving(self) -> bool:
        """True while the page answers (started and neither closed nor past its linger time)."""
        return self._thread is not None and not self._closed.is_set() and not self._stop.is_set()

    def start(self, board: StatusBoard) -> None:
        self.board = board
        self._thread = threading.Thread(target=self._serve, name="status-http", daemon=True)
        self._thread.start()
        log.info("status page at %s%s", self.url, " (token required)" if self.token else "")

    def linger(self, seconds: float) -> None:
        """Keep serving (the board's final state) for ``seconds`` more, then close; 0: close now."""
        if seconds <= 0 or self._thread is None:
            self.close()
            return
        if self._closed.is_set() or self._stop.is_set():     # closed meanwhile (the next scan took the port)
            return
        self._until = time.monotonic() + seconds
        if self.board is not None:
            self.board.serving_until = time.time() + seconds
        self._wake()
        log.info("status page at %s: showing the final state for %g s more", self.url, seconds)

    def wait_closed(self, timeout_s: float | None = None) -> bool:
        """Wait until the page has closed (its linger time over, or :meth:`close`); False after ``timeout_s``."""
        if self._thread is None:
            return True
        return self._closed.wait(timeout_s)

    def close(self, wait_s: float = 0.0) -> None:
        """Stop serving now and free the port (any thread, the GUI's too; more than once is harmless).

        Never waits on the loop nor on a client: the listening socket is closed here (the port is
        free on return; the lock only ever covers a few non-blocking ``accept`` calls), and the loop
        closes its connections on its own thread as soon as its current step ends. ``wait_s``: wait
        at most that long for that too (:meth:`wait_closed`)."""
        self._stop.set()
        with self._sock_lock:
            try:
                self._sock.close()
            except OSError:
                pass
        self._wake()
        thread = self._thread
        if thread is None:
            self._release()
        elif wait_s > 0 and thread is not threading.current_thread():
            thread.join(wait_s)

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"x")
        except OSError:             # closed, or its buffer is full: the loop wakes anyway
            pass

    def _release(self) -> None:
        with self._sock_lock:
            for s in (self._sock, self._wake_r, self._wake_w):
                try:
                    s.close()
                except OSError:
                    pass
        self._closed.set()

    # -- the event loop ---------------------------------------------------------------------------
    def _serve(self) -> None:
        sel = selectors.DefaultSelector()
        conns: dict[socket.socket, _Conn] = {}
        try:
            with self._sock_lock:
                if self._stop.is_set():             # closed before it started
                    return
                sel.register(self._sock, selectors.EVENT_READ, None)
            sel.register(self._wake_r, selectors.EVENT_READ, None)
            while not self._stop.is_set():
                now = time.monotonic()
                if self._until is not None and now >= self._until:
                    break
                deadlines = [c.deadline(self) for c in conns.values()]
                if self._until is not None:
                    deadlines.append(self._until)
                wait = max(0.0, min(deadlines, default=now + 1.0) - now)
                for key, events in sel.select(min(wait, 1.0)):
                    sock = key.fileobj
                    if sock is self._wake_r:
                        try:
                            self._wake_r.recv(4096)
                        except OSError:
                            pass
                    elif sock is self._sock:
                        self._accept(sel, conns)
                    elif isinstance(sock, socket.socket) and sock in conns:
                        self._step(sel, conns, conns[sock], events)
                now = time.monotonic()
                for conn in [c for c in conns.values() if now >= c.deadline(self)]:
                    self.timed_out += conn.phase != "drain"
                    self._drop(sel, conns, conn)
        except Exception:           # never a traceback on the scan's terminal: one line in the log
            log.warning("status page at %s stopped: %s", self.url, _one_line(), exc_info=log.isEnabledFor(10))
        finally:
            for conn in list(conns.values()):
                self._drop(sel, conns, conn)
            sel.close()
            self._release()

    def _accept(self, sel: selectors.BaseSelector, conns: dict[socket.socket, "_Conn"]) -> None:
        for _ in range(64):         # a burst at a time: the others wait in the listen queue
            with self._sock_lock:   # close() may have closed it (from another thread) meanwhile
                if self._stop.is_set() or self._sock.fileno() < 0:
                    return
                try:
                    sock, _addr = self._sock.accept()
                except (BlockingIOError, InterruptedError):
                    return
                except OSError as exc:  # EMFILE/ENFILE (descriptors short elsewhere), ECONNABORTED: not ours to fix
                    log.debug("status page: accept: %s", exc)
                    short = True
                else:
                    short = False
            if short:
                self._stop.wait(0.05)   # do not spin while the process is short of descriptors
                return
            if len(conns) >= self.max_connections:
                # room for it: a connection still sending its head goes first (a slow or hostile
                # client; a browser's arrives at once), one being answered only when none is left
                victim = min(conns.values(), key=lambda c: (c.phase != "read", c.opened))
                self.evicted += 1
                self._drop(sel, conns, victim)
            sock.setblocking(False)
            conn = _Conn(sock)
            conns[sock] = conn
            sel.register(sock, selectors.EVENT_READ, None)
            self.open_connections = len(conns)
            self.peak_connections = max(self.peak_connections, len(conns))

    def _drop(self, sel: selectors.BaseSelector, conns: dict[socket.socket, "_Conn"], conn: "_Conn") -> None:
        conns.pop(conn.sock, None)
        try:
            sel.unregister(conn.sock)
        except (KeyError, ValueError, OSError):
            pass
        try:
            conn.sock.close()
        except OSError:
            pass
        self.open_connections = len(conns)

    def _step(self, sel: selectors.BaseSelector, conns: dict[socket.socket, "_Conn"], conn: "_Conn",
              events: int) -> None:
        """One readiness event of ``conn``: read its head, answer, send, drain; a client error closes it."""
        try:
            if conn.phase == "read" and events & selectors.EVENT_READ:
                data = conn.sock.recv(RECV_BYTES)
                if not data:
                    self._drop(sel, conns, conn)
                    return
                conn.buf += data
                conn.last = time.monotonic()
                answer = self._parse(conn, len(data))
                if answer is not None:
                    conn.out = memoryview(answer)
                    conn.phase = "write"
                    sel.modify(conn.sock, selectors.EVENT_WRITE, None)
            elif conn.phase == "write" and events & selectors.EVENT_WRITE:
                sent = conn.sock.send(conn.out)
                conn.out = conn.out[sent:]
                conn.last = time.monotonic()
                if not conn.out:                  # all said: let the client close first (no reset of the answer)
                    conn.sock.shutdown(socket.SHUT_WR)
                    conn.phase = "drain"
                    conn.drain_until = time.monotonic() + DRAIN_S
                    sel.modify(conn.sock, selectors.EVENT_READ, None)
            elif conn.phase == "drain" and events & selectors.EVENT_READ:
                if not conn.sock.recv(RECV_BYTES):
                    self._drop(sel, conns, conn)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:             # reset, broken pipe, ...: the client went away; nothing to say
            self._drop(sel, conns, conn)

    def _parse(self, conn: "_Conn", new: int | None = None) -> bytes | None:
        """The answer to ``conn``'s request once its head is complete (None: not yet). ``new``: how many
        bytes just arrived (only they and the 3 before are searched for the head's end: a head
        trickled byte by byte costs no more than one sent at once)."""
        start = 0 if new is None else max(0, len(conn.buf) - new - 3)
        end = conn.buf.find(b"\r\n\r\n", start)
        if end < 0:
            end = conn.buf.find(b"\n\n", start)
        if end < 0 and len(conn.buf) <= MAX_HEAD_BYTES:
            return None
        line_end = conn.buf.find(b"\n")
        if line_end < 0 or line_end > MAX_URL_BYTES + 32:
            return _plain(414, "414: the address is too long\n")
        if end < 0 or end > MAX_HEAD_BYTES:
            return _plain(431, "431: the request's header is too large\n")
        head = bytes(conn.buf[:end]).decode("latin-1")
        lines = head.replace("\r\n", "\n").split("\n")
        words = lines[0].split(" ")
        if len(words) != 3 or not words[2].startswith("HTTP/") or not _TOKEN.fullmatch(words[0]):
            return _plain(400, "400: not an HTTP request\n")
        method, target = words[0], words[1]
        if len(target) > MAX_URL_BYTES:
            return _plain(414, "414: the address is too long\n")
        headers: dict[str, str] = {}
        for line in lines[1:]:
            name, sep, value = line.partition(":")
            if not sep:
                return _plain(400, "400: a malformed header line\n")
            headers[name.strip().lower()] = value.strip()
        self.requests += 1
        if method not in ("GET", "HEAD"):
            return _plain(405, "405: this page is read-only\n", extra={"Allow": "GET, HEAD"})
        try:
            return self._answer(target, headers, head_only=method == "HEAD")
        except Exception:            # a bug of the page must not stop it (nor reach the scan's terminal)
            log.warning("status page: %s failed: %s", target.split("?", 1)[0], _one_line())
            return _plain(500, "500: the page could not be made (see lfstudio.log)\n")

    def _authorised(self, query: dict[str, list[str]], headers: dict[str, str]) -> bool:
        if not self.token:
            return True
        given = (query.get("token") or [""])[0]
        auth = headers.get("authorization", "")
        if auth.startswith("Bearer "):
            given = auth[7:].strip()
        return hmac.compare_digest(given.encode(), self.token.encode())

    def _answer(self, target: str, headers: dict[str, str], head_only: bool) -> bytes:
        try:
            parts = urllib.parse.urlsplit(target)
        except ValueError:          # e.g. "//[": an address nobody's page links to; not the page's failure
            return _plain(400, "400: not an address of this page\n", head_only)
        query = urllib.parse.parse_qs(parts.query)
        if not self._authorised(query, headers):
            return _plain(401, "401: this status page needs its token (?token=...)\n", head_only)
        board = self.board
        if board is None:
            return _plain(503, "503: the scan has not started\n", head_only)
        token = f"?token={urllib.parse.quote(self.token)}" if self.token else ""
        if parts.path in ("/", "/index.html"):
            return _response(200, render_page(board.snapshot(), token).encode(), "text/html; charset=utf-8",
                             head_only)
        if parts.path == "/status.json":
            return _response(200, json.dumps(board.snapshot()).encode(), "application/json", head_only)
        if parts.path.startswith("/thumbs/"):
            body = board.thumb_bytes(urllib.parse.unquote(parts.path[len("/thumbs/"):]))
            if body is None:
                return _plain(404, "404: not one of the last thumbnails\n", head_only)
            return _response(200, body, "image/jpeg", head_only)
        return _plain(404, "404: / and /status.json are here\n", head_only)


class _Conn:
    """One client connection of :class:`StatusServer`'s loop."""

    __slots__ = ("sock", "buf", "out", "phase", "opened", "last", "drain_until")

    def __init__(self, sock: socket.socket):
        self.sock = sock
        self.buf = bytearray()
        self.out = memoryview(b"")
        self.phase = "read"                # read the head → write the answer → drain until the client closes
        self.opened = self.last = time.monotonic()
        self.drain_until = 0.0

    def deadline(self, server: StatusServer) -> float:
        if self.phase == "drain":
            return self.drain_until
        return min(self.opened + server.read_timeout_s * (2 if self.phase == "write" else 1),
                   self.last + server.idle_timeout_s)


_TOKEN = re.compile(r"[A-Za-z0-9!#$%&'*+.^_`|~-]{1,32}")
_REASONS = {200: "OK", 400: "Bad Request", 401: "Unauthorized", 404: "Not Found", 405: "Method Not Allowed",
            414: "URI Too Long", 431: "Request Header Fields Too Large", 500: "Internal Server Error",
            503: "Service Unavailable"}


def _response(status: int, body: bytes, ctype: str, head_only: bool = False,
              extra: dict[str, str] | None = None) -> bytes:
    lines = [f"HTTP/1.1 {status} {_REASONS.get(status, '')}", "Server: lfstudio-status",
             f"Content-Type: {ctype}", f"Content-Length: {len(body)}", "Cache-Control: no-store",
             "X-Content-Type-Options: nosniff",
             "Content-Security-Policy: default-src 'none'; img-src 'self'; style-src 'unsafe-inline'",
             "Connection: close", *(f"{k}: {v}" for k, v in (extra or {}).items())]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1") + (b"" if head_only else body)


def _plain(status: int, text: str, head_only: bool = False, extra: dict[str, str] | None = None) -> bytes:
    return _response(status, text.encode(), "text/plain", head_only, extra)


def _one_line() -> str:
    import sys

    exc = sys.exc_info()[1]
    return f"{type(exc).__name__}: {exc}".splitlines()[0] if exc is not None else "?"


def open_inside(root: str | Path, relative: str | Path, max_bytes: int) -> bytes | None:
    """The bytes of the ordinary file ``root/relative`` (at most ``max_bytes``), or None when it is not
    one: every part of ``relative`` is opened without following a symlink (``O_NOFOLLOW``, relative to
    the folder opened before it), so the file read lies inside ``root`` whatever links anyone places
    there; ``..`` and absolute parts are refused."""
    parts = Path(relative).parts
    if not parts or any(p in ("", ".", "..") or "/" in p or "\\" in p for p in parts) or Path(relative).is_absolute():
        return None
    nofollow = getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    fds: list[int] = []
    try:
        fds.append(os.open(root, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0)))
        for part in parts[:-1]:
            fds.append(os.open(part, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | nofollow, dir_fd=fds[-1]))
        fd = os.open(parts[-1], os.O_RDONLY | os.O_NONBLOCK | nofollow, dir_fd=fds[-1])
        fds.append(fd)
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode) or info.st_size > max_bytes:
            return None
        chunks, left = [], max_bytes + 1
        while left > 0:
            chunk = os.read(fd, min(left, 1 << 20))
            if not chunk:
                break
            chunks.append(chunk)
            left -= len(chunk)
        data = b"".join(chunks)
        return data if len(data) <= max_bytes else None
    except OSError:                     # a symlink (ELOOP, ENOTDIR), gone, unreadable: not served
        return None
    finally:
        for fd in fds:
            os.close(fd)


def _duration(seconds: float | None) -> str:
    if seconds is None:
        return "–"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


_COLOURS = {"running": "#3a9d4f", "paused": "#d08a00", "pausing": "#d08a00", "stopping": "#d08a00",
            "failed": "#c83c3c", "finished": "#3b6fd0", "aborted": "#8a6d3b", "idle": "#777"}


def render_page(doc: dict[str, Any], token: str = "") -> str:
    """The HTML page of a :meth:`StatusBoard.snapshot` (every text escaped; no script)."""
    e = html.escape
    done, total = doc["done"], doc["total"]
    percent = 100.0 * done / total if total else 0.0
    thumbs = "".join(f"<figure><img src='{e(t['url'])}{e(token)}' alt='{e(t['view'])}'><figcaption>{e(t['view'])}"
                     "</figcaption></figure>" for t in reversed(doc["thumbs"])) or "<p class='dim'>none yet</p>"
    v = doc["verdicts"]
    flagged = "".join(f"<li><b>{e(f['view'])}</b> {e(f['verdict'])}: {e('; '.join(f['reasons']) or '–')}</li>"
                      for f in reversed(doc["flagged"]))
    checked = sum(v.values())
    verdicts = (f"<p>{checked} views checked: {v['pass']} pass, {v['warn']} warn, {v['fail']} fail</p>"
                + (f"<ul>{flagged}</ul>" if flagged else "")) if checked else \
        "<p class='dim'>no live check (lfstudio scan --check, or the window's grid)</p>"
    shown_state = doc.get("outcome") or doc["state"]
    colour = _COLOURS.get(shown_state, "#777")
    ended = (f"<p><b>The scan {e(shown_state)} at {e(doc['ended'])}.</b>"
             + (f" <span class='dim'>This page shows its final state until {e(doc['serving_until'])}.</span>"
                if doc.get("serving_until") else "") + "</p>") if doc.get("ended") else ""
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><meta http-equiv="refresh" content="{REFRESH_S}">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{e(shown_state)} {done}/{total} · scan of {e(doc['dataset'])}</title>
<style>
body {{ font-family: sans-serif; margin: 1.2em; background: #1e2024; color: #e4e4e4; }}
h1 {{ font-size: 1.3em; margin: 0 0 .4em 0; }} h2 {{ font-size: 1.05em; margin: 1.2em 0 .4em 0; }}
.state {{ display: inline-block; padding: .15em .6em; border-radius: .3em; background: {colour}; color: white;
  font-weight: bold; text-transform: capitalize; }}
.bar {{ height: 1.2em; background: #3a3d44; border-radius: .3em; overflow: hidden; max-width: 60em; }}
.fill {{ height: 100%; width: {percent:.2f}%; background: #3a9d4f; }}
.dim {{ color: #999; }} figure {{ display: inline-block; margin: 0 .5em .5em 0; }}
img {{ height: 110px; border: 1px solid #555; }} figcaption {{ font-size: .8em; color: #bbb; }}
pre {{ background: #15171a; padding: .6em; max-width: 80em; white-space: pre-wrap; font-size: .85em; }}
</style></head><body>
<h1>lfstudio · scan of {e(doc['dataset'])}</h1>
<p><span class="state">{e(shown_state)}</span> {e(doc['message'])}</p>{ended}
<div class="bar"><div class="fill"></div></div>
<p><b>{done}</b> of <b>{total}</b> views ({percent:.1f} %) · ETA {_duration(doc['eta_s'])} ·
<span class="dim">as of {e(doc['time'])}, reloads every {REFRESH_S} s · read-only</span></p>
<h2>Last views</h2>{thumbs}
<h2>Live check</h2>{verdicts}
<h2>Log</h2><pre>{e(chr(10).join(doc['log'])) or '–'}</pre>
</body></html>
"""
