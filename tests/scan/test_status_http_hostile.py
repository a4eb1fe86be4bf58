"""The status page under hostile or slow peers, and its shutdown: ``close()`` never waits on the
page's loop (the window calls it on the GUI thread; it could wait there up to 10 s), slow or
half-sent requests never cut off an answer under way, a head trickled byte by byte is still read.
Real sockets on 127.0.0.1; the order of events is checked, never a duration."""

from __future__ import annotations

import json
import socket
import threading
from pathlib import Path

from lfstudio.scan.status_http import MAX_THUMB_BYTES, StatusBoard, StatusServer
from tests.scan.test_status_http_bounds import board_with_thumb, raw_request, status_of

HANG_GUARD_S = 15.0          # only against a hang (old code); nothing waits for it on the new code


class _WatchedLock:
    """The board's lock, held by the test: ``wanted`` is set when the page's loop asks for it (it
    builds a page while a scan event is being recorded, or anything else holds it for long)."""

    def __init__(self) -> None:
        self.real = threading.Lock()
        self.wanted = threading.Event()

    def acquire(self, *args, **kw) -> bool:
        self.wanted.set()
        return self.real.acquire(*args, **kw)

    def release(self) -> None:
        self.real.release()

    def __enter__(self) -> bool:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def test_close_returns_at_once_with_the_port_free_while_the_loop_is_busy(tmp_path):
    board = StatusBoard(tmp_path / "day1", total=3)
    lock = _WatchedLock()
    setattr(board, "_lock", lock)
    server = StatusServer("127.0.0.1:0")
    server.start(board)
    released = threading.Event()

    def release() -> None:
        if not released.is_set():
            released.set()
            lock.release()

    lock.real.acquire()
    guard = threading.Timer(HANG_GUARD_S, release)
    client = socket.create_connection(("127.0.0.1", server.port), timeout=HANG_GUARD_S * 2)
    try:
        client.sendall(b"GET /status.json HTTP/1.0\r\n\r\n")
        assert lock.wanted.wait(HANG_GUARD_S)           # the loop is building the page, held up
        guard.start()
        server.close()                                  # what the window does, on its GUI thread
        closed_while_held = not released.is_set()
        again = StatusServer(f"127.0.0.1:{server.port}")   # the next scan takes the port at once
        again.close()
    finally:
        guard.cancel()
        release()
        client.close()
    assert closed_while_held
    assert server.wait_closed(HANG_GUARD_S * 2) and not server.serving


def _slowloris(port: int) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=HANG_GUARD_S * 2)
    s.sendall(b"GET /status.json HTTP/1.1\r\nHost: x\r\n")      # and never the end of its head
    return s


def _closed_by_the_page(s: socket.socket) -> bool:
    """Blocks until the page closes ``s`` (a reset: it had an unread half request)."""
    try:
        return s.recv(10) == b""
    except ConnectionResetError:
        return True


def test_half_sent_requests_never_cut_off_an_answer_under_way(tmp_path):
    """The page is full (4 connections): a client taking a large thumbnail slowly is never the one
    closed to make room for new half-sent requests (it was, as the oldest connection)."""
    root = tmp_path / "day1"
    (root / "thumbs").mkdir(parents=True)
    body = bytes(range(256)) * (MAX_THUMB_BYTES // 256)
    (root / "thumbs" / "r00_c000.jpg").write_bytes(body)
    server = StatusServer("127.0.0.1:0", max_connections=4, read_timeout_s=120, idle_timeout_s=120)
    server.start(board_with_thumb(root, "thumbs/r00_c000.jpg"))
    reader = socket.socket()
    reader.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)   # takes its answer slowly
    reader.settimeout(HANG_GUARD_S * 2)
    flood: list[socket.socket] = []
    try:
        reader.connect(("127.0.0.1", server.port))
        reader.sendall(b"GET /thumbs/r00_c000.jpg HTTP/1.0\r\n\r\n")
        got = reader.recv(1024)                          # its answer is under way
        assert got.startswith(b"HTTP/1.1 200")
        flood = [_slowloris(server.port) for _ in range(6)]   # 7 connections for 4 places: 3 closed
        assert _closed_by_the_page(flood[0]) and _closed_by_the_page(flood[1])   # room was made
        while b"\r\n\r\n" not in got:
            got += reader.recv(65536)
        head, rest = got.split(b"\r\n\r\n", 1)
        length = int(head.lower().split(b"content-length: ")[1].split(b"\r\n")[0])
        chunks = [rest]
        received = len(rest)
        while received < length and (chunk := reader.recv(1 << 20)):
            chunks.append(chunk)
            received += len(chunk)
        assert received == length == len(body) and b"".join(chunks) == body
        answer = raw_request(server.port, b"GET /status.json HTTP/1.0\r\n\r\n")   # and the page still answers
        assert status_of(answer) == 200 and json.loads(answer.split(b"\r\n\r\n", 1)[1])["total"] == 4
        assert server.evicted >= 3
    finally:
        for s in flood:
            s.close()
        reader.close()
        server.close()


def test_a_head_trickled_byte_by_byte_is_answered(tmp_path: Path):
    server = StatusServer("127.0.0.1:0")
    server.start(StatusBoard(tmp_path / "day1", total=5))
    try:
        with socket.create_connection(("127.0.0.1", server.port), timeout=HANG_GUARD_S) as s:
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            for byte in b"GET /status.json HTTP/1.0\r\nHost: x\r\n\r\n":
                s.sendall(bytes([byte]))
            chunks = []
            while chunk := s.recv(65536):
                chunks.append(chunk)
        answer = b"".join(chunks)
        assert status_of(answer) == 200 and json.loads(answer.split(b"\r\n\r\n", 1)[1])["total"] == 5
    finally:
        server.close()
