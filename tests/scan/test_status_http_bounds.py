"""The status page is a bounded server (#42 items 3–5, #41 item 6): held-open connections cannot take
the scan's file descriptors, a symlink is never followed, a reset prints nothing, unknown methods get
405, and after the scan the page keeps showing its final state. Real sockets on 127.0.0.1 only; every
wait is on an answer or an end of file (a socket timeout only guards against a hang)."""

from __future__ import annotations

import json
import os
import socket
import struct
import subprocess
import sys
import textwrap
from pathlib import Path

from lfstudio.scan.events import EventKind, ScanEvent, ScanState
from lfstudio.scan.status_http import StatusBoard, StatusServer, open_inside
from tests.scan.test_notify import instant_engine
from tests.scan.test_status_http import fetch


def raw_request(port: int, data: bytes, timeout_s: float = 30) -> bytes:
    """Send ``data`` on a new connection and read the answer to its end."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout_s) as s:
        s.sendall(data)
        chunks = []
        while chunk := s.recv(65536):
            chunks.append(chunk)
    return b"".join(chunks)


def status_of(answer: bytes) -> int:
    return int(answer.split(b" ", 2)[1])


def board_with_thumb(root: Path, rel: str) -> StatusBoard:
    board = StatusBoard(root, total=4)
    board.on_scan_event(ScanEvent(EventKind.VIEW_DONE, row=0, column=0, done=1, total=4, thumb=rel))
    return board


SERVE_WITH_FEW_DESCRIPTORS = textwrap.dedent("""
    import resource, sys, tempfile, os
    resource.setrlimit(resource.RLIMIT_NOFILE, (256, 256))
    from lfstudio.scan.status_http import StatusBoard, StatusServer
    server = StatusServer("127.0.0.1:0")
    server.start(StatusBoard(sys.argv[1], total=10))
    print(server.port, flush=True)
    for line in sys.stdin:                     # "store": open 100 files as the scan storing views would
        held = []
        try:
            for i in range(100):
                held.append(open(os.path.join(sys.argv[1], f"view{i}.tmp"), "w"))
            print("stored", server.peak_connections, flush=True)
        except OSError as exc:
            print("error", exc, flush=True)
        finally:
            for f in held:
                f.close()
""")


def test_held_open_connections_never_take_the_scans_descriptors(tmp_path):
    """400 half-sent requests to a page in a process allowed 256 descriptors: the process can still
    open 100 files and the page still answers (the old thread-per-connection server took them all)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(Path.cwd()), os.environ.get("PYTHONPATH")) if p)}
    child = subprocess.Popen([sys.executable, "-c", SERVE_WITH_FEW_DESCRIPTORS, str(tmp_path)], env=env,
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    held: list[socket.socket] = []
    try:
        assert child.stdout is not None and child.stdin is not None
        port = int(child.stdout.readline())
        for _ in range(400):
            s = socket.create_connection(("127.0.0.1", port), timeout=30)
            s.sendall(b"GET /status.json HTTP/1.1\r\nHost: x\r\n")     # never finished
            held.append(s)
        answer = raw_request(port, b"GET /status.json HTTP/1.0\r\n\r\n")      # accepted after the 400
        assert status_of(answer) == 200 and json.loads(answer.split(b"\r\n\r\n", 1)[1])["total"] == 10
        child.stdin.write("store\n")
        child.stdin.flush()
        said = child.stdout.readline().split()
        assert said[0] == "stored", said
        assert int(said[1]) <= 64                                   # never more than its limit at once
    finally:
        for s in held:
            s.close()
        child.kill()
        child.wait(30)


def test_connections_past_the_limit_close_the_oldest_and_the_page_answers(tmp_path):
    server = StatusServer("127.0.0.1:0", max_connections=4)
    server.start(StatusBoard(tmp_path / "day1", total=3))
    idle = [socket.create_connection(("127.0.0.1", server.port), timeout=30) for _ in range(10)]
    try:
        assert status_of(raw_request(server.port, b"GET / HTTP/1.0\r\n\r\n")) == 200
        assert server.peak_connections <= 4 and server.evicted >= 7
        assert idle[0].recv(10) == b""                   # the oldest was closed by the page
    finally:
        for s in idle:
            s.close()
        server.close()


def test_a_silent_connection_is_closed_after_the_idle_time(tmp_path):
    server = StatusServer("127.0.0.1:0", idle_timeout_s=0.2, read_timeout_s=0.5)
    server.start(StatusBoard(tmp_path / "day1", total=3))
    try:
        with socket.create_connection(("127.0.0.1", server.port), timeout=30) as s:
            s.sendall(b"GET / HTTP/1.1\r\n")            # and then nothing
            assert s.recv(100) == b""                   # closed by the page (a hang would time out)
        assert server.timed_out == 1
    finally:
        server.close()


def test_a_symlink_in_thumbs_is_not_followed(tmp_path):
    root = tmp_path / "day1"
    (root / "thumbs").mkdir(parents=True)
    outside = tmp_path / "secret.txt"
    outside.write_bytes(b"not for the page")
    (root / "thumbs" / "r00_c000.jpg").symlink_to(outside)
    (root / "thumbs" / "r00_c001.jpg").write_bytes(b"\xff\xd8 a thumbnail")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "r00_c002.jpg").write_bytes(b"\xff\xd8 outside the dataset")
    (root / "linked").symlink_to(elsewhere)             # a folder link inside the dataset
    board = board_with_thumb(root, "thumbs/r00_c000.jpg")
    board.on_scan_event(ScanEvent(EventKind.VIEW_DONE, row=0, column=1, done=2, total=4, thumb="thumbs/r00_c001.jpg"))
    board.on_scan_event(ScanEvent(EventKind.VIEW_DONE, row=0, column=2, done=3, total=4, thumb="linked/r00_c002.jpg"))
    server = StatusServer("127.0.0.1:0")
    server.start(board)
    try:
        status, body, _ = fetch(server.url + "thumbs/r00_c000.jpg")
        assert status == 404 and b"not for the page" not in body
        assert fetch(server.url + "thumbs/r00_c002.jpg")[0] == 404
        assert fetch(server.url + "thumbs/r00_c001.jpg")[:2] == (200, b"\xff\xd8 a thumbnail")
    finally:
        server.close()
    assert open_inside(root, "thumbs/../../secret.txt", 1000) is None
    assert open_inside(root, str(outside), 1000) is None
    assert open_inside(root, "thumbs/r00_c001.jpg", 4) is None          # larger than allowed


def test_a_client_that_resets_prints_nothing_and_the_page_goes_on(tmp_path, capfd):
    server = StatusServer("127.0.0.1:0")
    server.start(board_with_thumb(tmp_path / "day1", "thumbs/none.jpg"))
    try:
        for data in (b"GET /status.json HTTP/1.1\r\nHost: x\r\n", b"GET / HTTP/1.0\r\n\r\n", b""):
            s = socket.create_connection(("127.0.0.1", server.port), timeout=30)
            if data:
                s.sendall(data)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))   # close = reset
            s.close()
        assert status_of(raw_request(server.port, b"GET /status.json HTTP/1.0\r\n\r\n")) == 200
    finally:
        server.close()
    out, err = capfd.readouterr()
    assert "Traceback" not in err + out and "ConnectionReset" not in err + out


def test_unknown_methods_get_405_and_malformed_requests_400(tmp_path):
    server = StatusServer("127.0.0.1:0")
    server.start(StatusBoard(tmp_path / "day1", total=3))
    try:
        for method in ("PROPFIND", "BREW", "TRACE", "POST"):
            answer = raw_request(server.port, f"{method} /status.json HTTP/1.1\r\nHost: x\r\n\r\n".encode())
            assert status_of(answer) == 405 and b"\r\nAllow: GET, HEAD\r\n" in answer, (method, answer[:80])
        assert status_of(raw_request(server.port, b"garbage\r\n\r\n")) == 400
        assert status_of(raw_request(server.port, b"GET /" + b"a" * 20000 + b" HTTP/1.1\r\n\r\n")) == 414
        assert status_of(raw_request(server.port, b"GET / HTTP/1.1\r\n" + b"X: y\r\n" * 3000 + b"\r\n")) == 431
        head = raw_request(server.port, b"HEAD /status.json HTTP/1.0\r\n\r\n")
        assert status_of(head) == 200 and head.endswith(b"\r\n\r\n")
    finally:
        server.close()


def test_after_the_scan_the_page_keeps_serving_its_final_state(tmp_path):
    engine, ds = instant_engine(tmp_path, cols=3, rows=2)
    board = StatusBoard(ds.root, total=len(ds.views))
    engine.subscribe(board.on_scan_event)
    server = StatusServer("127.0.0.1:0")
    server.start(board)
    try:
        doc = json.loads(fetch(server.url + "status.json")[1])
        assert doc["outcome"] is None and doc["ended"] is None
        engine.start()
        assert engine.wait(60) is ScanState.FINISHED
        server.linger(600)
        assert server.serving
        doc = json.loads(fetch(server.url + "status.json")[1])
        assert (doc["state"], doc["outcome"], doc["done"]) == ("finished", "finished", 6)
        assert doc["ended"] and doc["serving_until"] and doc["serving_until"] > doc["ended"]
        page = fetch(server.url)[1].decode()
        assert f"The scan finished at {doc['ended']}" in page and "final state until" in page
    finally:
        server.close()
    assert not server.serving
    with socket.socket() as s:                      # the port is free again
        assert s.connect_ex(("127.0.0.1", server.port)) != 0


def test_an_aborted_scan_says_aborted_and_a_linger_of_0_closes_at_once(tmp_path):
    engine, ds = instant_engine(tmp_path, cols=4, rows=3)
    board = StatusBoard(ds.root, total=len(ds.views))
    engine.subscribe(board.on_scan_event)
    server = StatusServer("127.0.0.1:0")
    server.start(board)
    engine.abort()                       # queued: lands before the first view
    engine.start()
    assert engine.wait(60) is ScanState.FINISHED
    doc = json.loads(fetch(server.url + "status.json")[1])
    assert (doc["state"], doc["outcome"]) == ("finished", "aborted")
    assert "aborted" in fetch(server.url)[1].decode().split("<title>", 1)[1].split("</title>")[0]
    server.linger(0)
    assert server.wait_closed(30) and not server.serving


def test_the_lingering_page_closes_by_itself_when_its_time_is_over(tmp_path):
    server = StatusServer("127.0.0.1:0")
    board = StatusBoard(tmp_path / "day1", total=3)
    board.on_scan_event(ScanEvent(EventKind.STATE, "Failed: the disk is gone", state=ScanState.FAILED))
    server.start(board)
    assert json.loads(fetch(server.url + "status.json")[1])["outcome"] == "failed"
    server.linger(0.05)
    assert server.wait_closed(30)


def test_an_address_urllib_cannot_split_is_400_without_a_log_line(tmp_path, caplog):
    """'//[' (an unclosed IPv6 bracket) made urlsplit raise: any client, without the token, got a 500
    and put a warning line in the scan's log for each such request."""
    server = StatusServer("0.0.0.0:0", "t" * 20)
    server.start(StatusBoard(tmp_path / "day1", total=3))
    try:
        with caplog.at_level("WARNING", logger="lfstudio.scan.status_http"):
            for target in (b"//[", b"http://[::1/", b"//[/status.json?token=" + b"t" * 20):
                answer = raw_request(server.port, b"GET " + target + b" HTTP/1.1\r\nHost: x\r\n\r\n")
                assert status_of(answer) in (400, 401), (target, answer[:60])
        assert not [r for r in caplog.records if r.levelno >= 30], [r.getMessage() for r in caplog.records]
        assert status_of(raw_request(server.port, b"GET //[ HTTP/1.1\r\n\r\n")) == 400
    finally:
        server.close()
