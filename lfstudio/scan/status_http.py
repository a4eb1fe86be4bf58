"""A read-only status page of a running scan, for a browser on this or another computer.

``lfstudio scan --status-http [HOST:]PORT`` (the window: Settings → Unattended scans) serves

- ``/``: the state, progress, ETA, the last thumbnails, the live check's verdicts and the log's tail
  (the page reloads itself every few seconds);
- ``/status.json``: ``state``, ``message``, ``done``, ``total``, ``eta_s``, ``dataset``, ``time``,
  ``thumbs``, ``verdicts``, ``flagged``, ``log``;
- ``/thumbs/NAME.jpg``: one of the last thumbnails (no other file of the dataset).

Nothing can be done through it: it answers GET and HEAD only (anything else: 405). It listens on
127.0.0.1 unless a host is given; an address other computers can reach needs a token
(:func:`check_address`), which every request must carry (``?token=…`` or ``Authorization: Bearer …``;
without it: 401). :class:`StatusBoard` is the scan's side: an engine (and live check) listener that
only stores references under a lock; the page is put together when a browser asks for it, on the
server's own threads.
"""

from __future__ import annotations

import hmac
import html
import ipaddress
import json
import logging
import secrets
import socket
import threading
import time
import urllib.parse
from collections import deque
from datetime import datetime
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from lfstudio.errors import InputError
from lfstudio.scan.events import EventKind, ScanEvent, ScanState
from lfstudio.scan.notify import entry_label

log = logging.getLogger(__name__)

DEFAULT_HOST = "127.0.0.1"
REFRESH_S = 5                  # the page reloads itself this often
THUMBS = 8                     # the last thumbnails shown
LOG_LINES = 40                 # the log's tail shown
MAX_FLAGGED_SHOWN = 20         # the views flagged last (each once)
MIN_TOKEN_CHARS = 16
_LOGGED = (EventKind.STATE, EventKind.FAULT, EventKind.VIEW_FAILED, EventKind.VIEW_SKIPPED, EventKind.LOG,
           EventKind.VIEW_DONE)


def is_local(host: str) -> bool:
    """True when only this computer can reach ``host`` (a loopback address or ``localhost``)."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def parse_address(text: str, option: str = "--status-http") -> tuple[str, int]:
    """``[HOST:]PORT`` → (host, port); the host is 127.0.0.1 when not given; port 0: any free port
    (the address said to the operator has the one taken)."""
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

    def on_scan_event(self, ev: ScanEvent) -> None:
        with self._lock:
            if ev.total:
                self.done, self.total = ev.done, ev.total
            kind = ev.kind
            if kind is EventKind.STATE and ev.state is not None:
                self.state, self.message = ev.state, ev.message
                if ev.state is not ScanState.RUNNING:
                    self._eta = None
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
                   "time": datetime.now().astimezone().strftime("%Y-%m-%d %H:%M:%S %Z"),
                   "thumbs": [{"view": v, "url": f"/thumbs/{Path(rel).name}"} for v, rel in self._thumbs],
                   "verdicts": dict(self.verdicts), "flagged": list(self._flagged.values())}
        doc["log"] = [f"{datetime.fromtimestamp(ev.time):%H:%M:%S}  {ev.describe()}" for ev in log_events]
        return doc

    def thumb_path(self, name: str) -> Path | None:
        """The file of a thumbnail the page shows now (None for any other name)."""
        with self._lock:
            rels = list(self._servable)
        for rel in rels:
            if Path(rel).name == name:
                path = self.root / rel
                return path if path.is_file() else None
        return None


# -- the server ----------------------------------------------------------------------------------------
class StatusServer:
    """The page's HTTP server, bound at once (a port in use is an :class:`InputError` naming
    ``option``); :meth:`start` serves ``board`` on a thread of its own."""

    def __init__(self, address: str, token: str = "", *, option: str = "--status-http",
                 token_option: str = "--status-token"):
        host, port = parse_address(address, option)
        self.token = check_token(host, token, option, token_option)
        self.board: StatusBoard | None = None
        handler = _handler(self)
        try:
            self.httpd = _Server((host, port), handler)
        except socket.gaierror:
            raise InputError(option, f"{host} is not a name or address of this computer",
                             "127.0.0.1, 0.0.0.0 or one of its addresses") from None
        except OSError as exc:
            if exc.errno in (98, 48, 10048):        # EADDRINUSE (Linux, macOS, Windows)
                raise InputError(option, f"port {port} on {host} is in use", "another port, or stop what listens "
                                 "there") from None
            raise InputError(option, f"cannot listen on {host}:{port}: {exc.strerror or exc}",
                             "an address of this computer and a free port") from None
        self.host, self.port = host, self.httpd.server_address[1]
        self._thread: threading.Thread | None = None
        self.requests = 0

    @property
    def url(self) -> str:
        """The page's address without the token (what logs may show)."""
        host = self.host if ":" not in self.host else f"[{self.host}]"
        if host in ("0.0.0.0", "::"):
            host = socket.gethostname()
        return f"http://{host}:{self.port}/"

    def url_with_token(self) -> str:
        """The address to open (with the token: say it once to the operator, never log it)."""
        return self.url + (f"?token={self.token}" if self.token else "")

    def start(self, board: StatusBoard) -> None:
        self.board = board
        self._thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.5},
                                        name="status-http", daemon=True)
        self._thread.start()
        log.info("status page at %s%s", self.url, " (token required)" if self.token else "")

    def close(self) -> None:
        if self._thread is not None:
            self.httpd.shutdown()
            self._thread.join(10)
        self.httpd.server_close()


class _Server(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, address: tuple[str, int], handler: Any):
        if ":" in address[0]:
            self.address_family = socket.AF_INET6
        super().__init__(address, handler)


def _handler(server: StatusServer) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        server_version = "lfstudio-status"
        sys_version = ""

        def log_message(self, format: str, *args: Any) -> None:   # the query holds the token: not logged
            pass

        def _authorised(self, query: dict[str, list[str]]) -> bool:
            if not server.token:
                return True
            given = (query.get("token") or [""])[0]
            auth = self.headers.get("Authorization", "")
            if auth.startswith("Bearer "):
                given = auth[7:].strip()
            return hmac.compare_digest(given.encode(), server.token.encode())

        def _send(self, status: int, body: bytes, ctype: str, head: bool = False) -> None:
            self.send_response(status)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.send_header("Content-Security-Policy", "default-src 'none'; img-src 'self'; style-src 'unsafe-inline'")
            self.end_headers()
            if not head:
                self.wfile.write(body)

        def do_GET(self, head: bool = False) -> None:  # noqa: N802
            server.requests += 1
            parts = urllib.parse.urlsplit(self.path)
            query = urllib.parse.parse_qs(parts.query)
            if not self._authorised(query):
                self._send(401, b"401: this status page needs its token (?token=...)\n", "text/plain", head)
                return
            board = server.board
            if board is None:
                self._send(503, b"503: the scan has not started\n", "text/plain", head)
                return
            token = f"?token={urllib.parse.quote(server.token)}" if server.token else ""
            if parts.path in ("/", "/index.html"):
                self._send(200, render_page(board.snapshot(), token).encode(), "text/html; charset=utf-8", head)
            elif parts.path == "/status.json":
                self._send(200, json.dumps(board.snapshot()).encode(), "application/json", head)
            elif parts.path.startswith("/thumbs/"):
                path = board.thumb_path(parts.path[len("/thumbs/"):])
                if path is None:
                    self._send(404, b"404: not one of the last thumbnails\n", "text/plain", head)
                else:
                    self._send(200, path.read_bytes(), "image/jpeg", head)
            else:
                self._send(404, b"404: / and /status.json are here\n", "text/plain", head)

        def do_HEAD(self) -> None:  # noqa: N802
            self.do_GET(head=True)

        def _refuse(self) -> None:
            self._send(405, b"405: this page is read-only\n", "text/plain")

        do_POST = do_PUT = do_DELETE = do_PATCH = do_OPTIONS = _refuse  # noqa: N815

    return Handler


def _duration(seconds: float | None) -> str:
    if seconds is None:
        return "–"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


_COLOURS = {"running": "#3a9d4f", "paused": "#d08a00", "pausing": "#d08a00", "stopping": "#d08a00",
            "failed": "#c83c3c", "finished": "#3b6fd0", "idle": "#777"}


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
    colour = _COLOURS.get(doc["state"], "#777")
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><meta http-equiv="refresh" content="{REFRESH_S}">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{e(doc['state'])} {done}/{total} · scan of {e(doc['dataset'])}</title>
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
<p><span class="state">{e(doc['state'])}</span> {e(doc['message'])}</p>
<div class="bar"><div class="fill"></div></div>
<p><b>{done}</b> of <b>{total}</b> views ({percent:.1f} %) · ETA {_duration(doc['eta_s'])} ·
<span class="dim">as of {e(doc['time'])}, reloads every {REFRESH_S} s · read-only</span></p>
<h2>Last views</h2>{thumbs}
<h2>Live check</h2>{verdicts}
<h2>Log</h2><pre>{e(chr(10).join(doc['log'])) or '–'}</pre>
</body></html>
"""
