"""Real local endpoints for the unattended-scan tests: an HTTP server that records what it is sent
(JSON, ntfy's plain text, webhooks), one that accepts connections and never answers, an SMTP server."""

from __future__ import annotations

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
