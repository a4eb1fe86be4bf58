"""Real local endpoints for the unattended-scan tests: an HTTP server that records what it is sent
(JSON, ntfy's plain text, webhooks), one that accepts connections and never answers, an SMTP server."""

from __future__ import annotations

import itertools
import json
import socket
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


class Receiver:
    """``http://127.0.0.1:PORT/...``: records each POST (path, headers, body, time received);
    ``fail_first`` answers 500 to that many requests first."""

    def __init__(self, fail_first: int = 0):
        self.posts: list[dict] = []
        self.cond = threading.Condition()
        self.fail_first = fail_first
        receiver = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self):  # noqa: N802
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                with receiver.cond:
                    failing = receiver.fail_first > 0
                    receiver.fail_first -= 1
                    if not failing:
                        receiver.posts.append({"path": self.path, "headers": dict(self.headers), "body": body,
                                               "t": time.time()})
                    receiver.cond.notify_all()
                self.send_response(500 if failing else 200)
                self.send_header("Content-Length", "0")
                self.end_headers()

            def log_message(self, *args):
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def url(self, path: str = "/hook", scheme: str = "http") -> str:
        return f"{scheme}://127.0.0.1:{self.port}{path}"

    def wait_for(self, predicate, timeout_s: float = 30) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: predicate(self.posts), timeout_s)

    def json_events(self) -> list[str]:
        return [json.loads(p["body"])["event"] for p in self.posts if p["headers"].get("Content-Type") ==
                "application/json" and b'"event"' in p["body"]]

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


class DeadEndpoint:
    """A local port that accepts connections and never answers (``accepted`` is set at the first)."""

    def __init__(self):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(64)
        self.port = self.sock.getsockname()[1]
        self.accepted = threading.Event()
        self.conns: list[socket.socket] = []
        self._closed = False
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self):
        while not self._closed:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            self.accepted.set()

    def url(self, path: str = "/hook") -> str:
        return f"http://127.0.0.1:{self.port}{path}"

    def close(self):
        self._closed = True
        for c in self.conns:
            c.close()
        self.sock.close()


class TricklingEndpoint:
    """A local HTTP endpoint that sends its answer one byte every ``every_s`` (each byte well within a
    per-read timeout), until the client goes away or :meth:`close`: ``what`` "body", a 200 head at once
    and a long body trickled; "head", the head itself trickled (no status for ever)."""

    def __init__(self, every_s: float = 0.2, what: str = "body"):
        self.every_s = every_s
        self.what = what
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.port = self.sock.getsockname()[1]
        self.connections = 0
        self.gone = threading.Event()            # a client closed its connection while being trickled
        self._closed = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self):
        while not self._closed.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.connections += 1
            threading.Thread(target=self._trickle, args=(conn,), daemon=True).start()

    def _trickle(self, conn: socket.socket):
        with conn:
            try:
                conn.recv(65536)                 # the request (small: one segment)
                head = b"HTTP/1.1 200 OK\r\nContent-Length: 1000000\r\n"
                if self.what == "body":
                    conn.sendall(head + b"\r\n")
                    trickled = itertools.repeat(b"x")
                else:                           # the head, then header lines that never end it
                    trickled = itertools.chain((head[i:i + 1] for i in range(len(head))),
                                               (bytes([c]) for c in itertools.cycle(b"X-Slow: x\r\n")))
                for byte in trickled:
                    if self._closed.wait(self.every_s):      # bounded: ends with close()
                        return
                    conn.sendall(byte)
            except OSError:
                self.gone.set()

    def url(self, path: str = "/hook") -> str:
        return f"http://127.0.0.1:{self.port}{path}"

    def close(self):
        self._closed.set()
        self.sock.close()
