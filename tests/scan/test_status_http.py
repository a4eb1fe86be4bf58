"""The read-only status page (lfstudio/scan/status_http.py) during a real (instant) scan, fetched with
a real HTTP client, and screenshotted by Debian's headless chromium where it is installed."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import urllib.error
import urllib.request

import numpy as np
import pytest

from lfstudio.errors import InputError
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.status_http import StatusBoard, StatusServer
from tests.scan.test_notify import instant_engine


def fetch(url: str, method: str = "GET", headers: dict | None = None) -> tuple[int, bytes, dict]:
    req = urllib.request.Request(url, method=method, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=30) as reply:
            return reply.status, reply.read(), dict(reply.headers)
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read(), dict(exc.headers)


@pytest.fixture
def paused_scan(tmp_path):
    """A 4 x 3 scan paused after its first views, served on a free port of 127.0.0.1."""
    engine, ds = instant_engine(tmp_path, cols=4, rows=3)
    board = StatusBoard(ds.root, total=len(ds.views))
    engine.subscribe(board.on_scan_event)
    server = StatusServer("127.0.0.1:0")
    server.start(board)
    seen = []

    def pause_after_three(ev):
        seen.append(ev)
        if ev.kind is EventKind.VIEW_DONE and ev.done == 3:
            engine.pause()
    engine.subscribe(pause_after_three)
    engine.start()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=60)
    board.on_verdict({"view": "r00 c001", "verdict": "pass"})
    board.on_verdict({"view": "r00 c002", "verdict": "warn", "reasons": ["blurred: focus 0.41 of its neighbours'"]})
    yield engine, ds, board, server
    server.close()
    if engine.state is ScanState.PAUSED:
        engine.abort()
    engine.wait(60)


def test_status_json_and_page_during_a_scan(paused_scan):
    engine, ds, board, server = paused_scan
    status, body, headers = fetch(server.url + "status.json")
    assert status == 200 and headers["Content-Type"] == "application/json"
    doc = json.loads(body)
    assert {"state", "done", "total", "eta_s"} <= set(doc)
    assert (doc["state"], doc["total"]) == ("paused", 12) and doc["done"] == engine.done >= 3
    assert doc["eta_s"] is None                       # paused: no ETA
    assert doc["verdicts"] == {"pass": 1, "warn": 1, "fail": 0} and doc["flagged"][0]["view"] == "r00 c002"
    assert any("paused" in line for line in doc["log"]) and any("done (3/12)" in line for line in doc["log"])
    assert len(doc["thumbs"]) == engine.done
    status, page, _ = fetch(server.url)
    text = page.decode()
    assert status == 200 and "scan of day1" in text and f"<b>{engine.done}</b> of <b>12</b>" in text
    assert text.count("<img ") == engine.done and "blurred: focus 0.41" in text
    status, jpeg, headers = fetch(server.url.rstrip("/") + doc["thumbs"][0]["url"])
    assert status == 200 and jpeg[:2] == b"\xff\xd8" and headers["Content-Type"] == "image/jpeg"


def test_running_scan_has_an_eta_and_the_page_follows(paused_scan):
    engine, ds, board, server = paused_scan
    engine.resume().result(30)
    assert engine.wait(60) is ScanState.FINISHED
    doc = json.loads(fetch(server.url + "status.json")[1])
    assert (doc["state"], doc["done"], doc["total"]) == ("finished", 12, 12)
    assert doc["message"].startswith("Finished: 12 of 12")


def test_nothing_can_be_done_through_it_and_no_other_file_is_served(paused_scan):
    engine, ds, board, server = paused_scan
    for method in ("POST", "PUT", "DELETE"):
        assert fetch(server.url + "status.json", method)[0] == 405
    assert engine.state is ScanState.PAUSED                     # nothing changed
    for path in ("thumbs/../dataset.json", "thumbs/dataset.json", "dataset.json", "raw/"):
        assert fetch(server.url + path)[0] == 404


def test_another_computers_address_needs_a_token():
    with pytest.raises(InputError) as err:
        StatusServer("0.0.0.0:0")
    assert str(err.value).startswith("--status-http: 0.0.0.0 can be reached from other computers")
    with pytest.raises(InputError, match="--status-token: the token is 5 characters long"):
        StatusServer("0.0.0.0:0", "short")
    server = StatusServer("0.0.0.0:0", "new")
    try:
        assert len(server.token) >= 16 and server.token in server.url_with_token() and server.token not in server.url
        server.start(StatusBoard("/nonexistent/day1", total=5))
        base = f"http://127.0.0.1:{server.port}/status.json"
        assert fetch(base)[0] == 401
        assert fetch(base + "?token=wrong-token-of-some-length")[0] == 401
        assert fetch(base + f"?token={server.token}")[0] == 200
        assert fetch(base, headers={"Authorization": f"Bearer {server.token}"})[0] == 200
    finally:
        server.close()


def test_a_port_in_use_is_refused_naming_the_option():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        with pytest.raises(InputError, match=f"--status-http: port {port} on 127.0.0.1 is in use"):
            StatusServer(f"{port}")
    for bad in ("http://x", "127.0.0.1:99999", "localhost:"):
        with pytest.raises(InputError, match="--status-http: "):
            StatusServer(bad)


def test_cli_refuses_bad_status_options_before_anything_starts(run_cli, tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        for args, words in ((["--status-http", "0.0.0.0:8765"], "--status-http: 0.0.0.0 can be reached"),
                            (["--status-http", str(port)], f"--status-http: port {port} on 127.0.0.1 is in use"),
                            (["--status-token", "new"], "--status-token: is for the status page")):
            out = tmp_path / "day1"
            r = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "3x2", "--out", out,
                        "--time-scale", "0", *args)
            lines = r.stderr.strip().splitlines()
            assert r.returncode == 2 and len(lines) == 1 and words in lines[0], r.stderr
            assert not out.exists()


def test_chromium_shows_the_page_during_a_scan(paused_scan, tmp_path):
    """Debian's headless chromium renders the page (skipped where chromium is not installed)."""
    chromium = shutil.which("chromium")
    if chromium is None:
        pytest.skip("chromium is not installed (apt-get install chromium)")
    engine, ds, board, server = paused_scan
    shot = tmp_path / "status.png"
    flags = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             f"--user-data-dir={tmp_path / 'profile'}", "--hide-scrollbars", "--window-size=1000,800"]
    r = subprocess.run([*flags, f"--screenshot={shot}", server.url], capture_output=True, text=True, timeout=180)
    assert shot.is_file(), r.stderr[-2000:]
    dom = subprocess.run([*flags, "--dump-dom", server.url], capture_output=True, text=True, timeout=180).stdout
    assert "scan of day1" in dom and "paused" in dom.lower() and dom.count("<img") == engine.done
    import cv2

    picture = cv2.imread(str(shot))
    assert picture.shape[:2] == (800, 1000)
    # the thumbnails are drawn: the band under "Last views" is not just the page's background
    background = np.array([36, 32, 30])                     # #1e2024 in BGR
    assert (np.abs(picture.astype(int) - background).sum(axis=2) > 60).mean() > 0.03
    if (shot_dir := __import__("os").environ.get("LFSTUDIO_KEEP_SCREENSHOT")):
        shutil.copy(shot, shot_dir)


def test_a_view_judged_again_is_listed_once_with_its_latest_verdict(tmp_path):
    board = StatusBoard(tmp_path / "day1", total=10)
    board.on_verdict({"row": 0, "column": 4, "verdict": "warn", "reasons": ["position"]})
    board.on_verdict({"row": 0, "column": 5, "verdict": "warn", "reasons": ["position"]})
    board.on_verdict({"row": 0, "column": 4, "verdict": "fail", "reasons": ["position", "blurred"]})
    board.on_verdict({"row": 0, "column": 5, "verdict": "pass"})
    doc = board.snapshot()
    assert doc["flagged"] == [{"view": "r00 c004", "verdict": "fail", "reasons": ["position", "blurred"]}]
    assert doc["verdicts"] == {"pass": 1, "warn": 0, "fail": 1}


def test_a_host_name_is_refused_without_being_looked_up(monkeypatch):
    """The window binds the page when Start is pressed, on its own thread: a name (studio-pc.lab) was looked
    up there (getaddrinfo), and with DNS not answering the window froze for the resolver's timeout. The
    page listens on an address of this computer: a name is refused naming the option, never looked up."""
    looked_up: list[str] = []
    real = socket.getaddrinfo

    def spy(host, *args, **kwargs):
        looked_up.append(str(host))
        return real(host, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", spy)
    with pytest.raises(InputError, match=r"^--status-http: 'studio-pc.lab' is a name: the page listens on an "
                                         r"address of this computer \(valid: 127.0.0.1"):
        StatusServer("studio-pc.lab:0", "a-token-of-enough-length")
    assert "studio-pc.lab" not in looked_up
    for address in ("localhost:0", "127.0.0.1:0", "[::1]:0"):
        try:
            server = StatusServer(address)
        except InputError as exc:                  # a machine without IPv6 loopback: not this test's concern
            assert "[::1]" in address and "cannot listen" in str(exc)
            continue
        server.close()
