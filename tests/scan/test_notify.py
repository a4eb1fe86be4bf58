"""Notifications of a scan (lfstudio/scan/notify.py) delivered to real local endpoints: an HTTP
receiver, a port that never answers, an SMTP server (aiosmtpd)."""

from __future__ import annotations

import json
import logging
import socket

import pytest

from lfstudio.errors import InputError
from lfstudio.rig.profile import load_rig
from lfstudio.scan.engine import ScanEngine
from lfstudio.scan.events import ScanState
from lfstudio.scan.notify import MAX_FLAGGED, Notifier, SmtpServer, parse_target
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.sim.instant import InstantCamera, InstantRig
from lfstudio.studio.session import create_scan_dataset
from tests.scan.receivers import DeadEndpoint, Receiver

RIG = load_rig()


@pytest.fixture
def receiver():
    r = Receiver()
    yield r
    r.close()


@pytest.fixture
def dead():
    d = DeadEndpoint()
    yield d
    d.close()


def instant_engine(tmp_path, cols=3, rows=2, **kw):
    plan = ScanPlan.centered(cols, rows, (4.0, 6.0), RIG, settle_s=0.0)
    ds = create_scan_dataset(tmp_path / "day1", plan, rig={"name": RIG.name}, camera={"name": "instant"},
                             lens={"name": "test"})
    rig = InstantRig(RIG)
    rig.connect()
    cam = InstantCamera(rig.true_position_mm)
    cam.connect()
    return ScanEngine(ds, plan, rig, cam, time_scale=0.0, **kw), ds


def test_a_scan_posts_started_and_finished_as_json_with_the_fields(tmp_path, receiver):
    engine, ds = instant_engine(tmp_path)
    notifier = Notifier([receiver.url()], dataset="day1")
    engine.subscribe(notifier.on_scan_event)
    engine.start()
    assert engine.wait(60) is ScanState.FINISHED
    assert notifier.close(30)
    assert receiver.json_events() == ["started", "finished"]
    finished = json.loads(receiver.posts[-1]["body"])
    assert {"event", "dataset", "done", "total", "message", "time"} <= set(finished)
    assert (finished["dataset"], finished["done"], finished["total"]) == ("day1", 6, 6)
    assert finished["message"].startswith("Finished: 6 of 6") and finished["time"].endswith("Z")
    assert receiver.posts[-1]["path"] == "/hook"


def test_pause_resume_and_abort_are_told_with_the_reason(tmp_path, receiver):
    engine, ds = instant_engine(tmp_path, cols=4, rows=3)
    notifier = Notifier([receiver.url()], dataset="day1")
    engine.subscribe(notifier.on_scan_event)
    engine.pause()                         # queued: lands before the first view
    engine.start()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=30)
    engine.resume().result(30)
    engine.abort()
    assert engine.wait(60) is ScanState.FINISHED
    notifier.close(30)
    events = receiver.json_events()
    assert events[:3] == ["started", "paused", "resumed"]
    # the abort lands after the current view (or the scan finishes first: then "finished")
    assert events[-1] in ("aborted", "finished") and len(events) == 4
    paused = json.loads(receiver.posts[1]["body"])
    assert "Resume continues" in paused["message"] and paused["resumes_by_itself"] is False


def test_ntfy_and_webhooks_get_their_own_shapes(receiver):
    notifier = Notifier([receiver.url("/lab-scans", "ntfy+http"), receiver.url("/slack", "slack+http"),
                         receiver.url("/matrix", "matrix+http")], dataset="day1")
    notifier.notify("paused", "Disk almost full", done=10, total=2121)
    assert notifier.close(30)
    by_path = {p["path"]: p for p in receiver.posts}
    ntfy = by_path["/lab-scans"]
    assert ntfy["body"].decode() == "Disk almost full (10 of 2121 views captured)"
    assert ntfy["headers"]["Title"] == "lfstudio: scan of day1 paused" and ntfy["headers"]["Priority"] == "high"
    for path in ("/slack", "/matrix"):
        body = json.loads(by_path[path]["body"])
        assert body == {"text": "lfstudio: scan of day1 paused: Disk almost full (10 of 2121 views captured)"}


def test_a_dead_endpoint_never_slows_the_scan_and_its_queue_is_bounded(tmp_path, dead, receiver):
    engine, ds = instant_engine(tmp_path, cols=5, rows=3)
    results = []
    notifier = Notifier([dead.url(), receiver.url()], dataset="day1", timeout_s=600, max_queue=10)
    notifier.subscribe(results.append)
    engine.subscribe(notifier.on_scan_event)
    engine.start()
    assert engine.wait(120) is ScanState.FINISHED        # while the dead endpoint holds its first notice
    assert dead.accepted.wait(30)
    assert results == [] or all(r.target.startswith("http://127.0.0.1:%d" % receiver.port) for r in results)
    assert receiver.wait_for(lambda posts: len(posts) == 2)       # the live one got both meanwhile
    # the dead one's thread holds "started"; "finished" waits; 20 more: the oldest waiting are dropped
    for i in range(20):
        notifier.notify("flagged", f"test {i}")
    assert notifier.dropped[f"http://127.0.0.1:{dead.port}/…"] == 11      # 1 + 20 waiting, 10 kept
    assert notifier.close(0.2) is False    # gives up at once on the dead endpoint
    dead.close()                            # its held notice fails now, and its warning is logged in this test
    assert notifier.wait_idle(30)


def test_a_failing_endpoint_is_retried_and_no_secret_reaches_the_log(caplog):
    receiver = Receiver(fail_first=2)
    try:
        results = []
        url = receiver.url("/services/T000/B000/SeCrEtPaTh?token=Qu3ryS3cret").replace(
            "http://", "http://alice:PaSsWoRd@")
        notifier = Notifier([url], dataset="day1", backoff_s=0.01)
        notifier.subscribe(results.append)
        with caplog.at_level(logging.DEBUG):
            notifier.notify("failed", "Unexpected error")
            assert notifier.close(30)
        assert [(r.ok, r.attempts) for r in results] == [(True, 3)]
        assert receiver.posts[0]["headers"]["Authorization"].startswith("Basic ")
        assert receiver.posts[0]["path"] == "/services/T000/B000/SeCrEtPaTh?token=Qu3ryS3cret"
        text = caplog.text + repr(notifier.targets) + results[0].target
        assert "failed (attempt 1)" in caplog.text                   # the failures were logged ...
        for secret in ("SeCrEtPaTh", "Qu3ryS3cret", "PaSsWoRd", "alice"):
            assert secret not in text                                # ... without the URL's secrets
    finally:
        receiver.close()


def test_mail_through_a_local_smtp_server():
    aiosmtpd = pytest.importorskip("aiosmtpd.controller")
    from aiosmtpd.handlers import Message

    got = []

    class Keep(Message):
        def handle_message(self, message):
            got.append(message)

    with socket.socket() as probe:          # a free port (aiosmtpd's controller cannot take port 0)
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    controller = aiosmtpd.Controller(Keep(), hostname="127.0.0.1", port=port)
    controller.start()
    try:
        smtp = SmtpServer.parse(f"smtp+plain://127.0.0.1:{port}", sender="rig@lab.example")
        notifier = Notifier(["mailto:alice@lab.example,bob@lab.example"], dataset="day1", smtp=smtp)
        notifier.notify("finished", "Finished: 2121 of 2121 views captured.", done=2121, total=2121)
        assert notifier.close(30)
    finally:
        controller.stop()
    assert len(got) == 1
    mail = got[0]
    assert mail["Subject"] == "lfstudio: scan of day1 finished"
    assert mail["To"] == "alice@lab.example, bob@lab.example" and mail["From"] == "rig@lab.example"
    assert "Finished: 2121 of 2121 views captured." in mail.get_payload()


def test_flagged_views_are_told_once_each_and_then_summed_up(receiver):
    notifier = Notifier([receiver.url()], dataset="day1")
    notifier.on_verdict({"row": 0, "column": 1, "view": "r00_c001", "verdict": "pass"})
    notifier.on_verdict({"row": 0, "column": 2, "view": "r00_c002", "verdict": "warn", "reasons": ["blurred"]})
    notifier.on_verdict({"row": 0, "column": 2, "verdict": "warn", "reasons": ["blurred"]})   # the same again
    notifier.on_verdict({"view": "r00 c002", "verdict": "fail", "reasons": ["blurred", "dark"]})   # worse
    for i in range(MAX_FLAGGED + 5):
        notifier.on_verdict({"view": f"r01 c{i:03d}", "verdict": "fail"})
    assert notifier.close(30)
    bodies = [json.loads(p["body"]) for p in receiver.posts]
    assert [b["event"] for b in bodies] == ["flagged"] * (MAX_FLAGGED + 2)
    assert (bodies[0]["view"], bodies[0]["verdict"], bodies[0]["reasons"]) == ("r00 c002", "warn", ["blurred"])
    assert bodies[1]["verdict"] == "fail"
    assert "no further notice" in bodies[-1]["message"]


@pytest.mark.parametrize("url, words", [
    ("ftp://example.com/x", "unknown scheme 'ftp'"),
    ("hooks.example.com/services/x", "is not a URL"),
    ("alice@example.com", "write mailto:alice@example.com"),
    ("http://example.com:99999/x", "not a well-formed URL"),
    ("https:///path-only", "names no host"),
    ("mailto:nobody", "nobody is not a mail address"),
    ("ntfy+https://ntfy.sh/", "names its topic"),
])
def test_bad_urls_are_refused_naming_the_option(url, words):
    with pytest.raises(InputError) as err:
        parse_target(url)
    text = str(err.value)
    assert text.startswith("--notify: ") and words in text and "\n" not in text


def test_a_mailto_target_needs_an_smtp_server():
    with pytest.raises(InputError, match="--notify: a mailto: target needs an SMTP server"):
        Notifier(["mailto:alice@lab.example"])
    with pytest.raises(InputError, match="--smtp: a password does not go into the address"):
        SmtpServer.parse("smtp://alice:secret@mail.example")
    assert "secret" not in repr(SmtpServer.parse("smtp://alice@mail.example", password="secret"))


@pytest.mark.parametrize("what, outcome, connections", [("body", [(True, 1)], 1), ("head", [(False, 2)], 2)])
def test_an_endpoint_that_trickles_its_answer_is_given_up_at_the_time_limit(what, outcome, connections):
    """The time limit was per read: an endpoint answering a byte every 0.2 s (a slowloris in reverse)
    held its delivery thread and socket for as long as it liked (a 64 KiB body: hours; a head: for ever),
    and each scan's notifier left one more behind. The limit is for the whole delivery now, then the
    connection is closed: a trickled body after a 200 is a delivered notice; a trickled head is not
    (retried, then given up)."""
    from tests.scan.receivers import TricklingEndpoint

    slow = TricklingEndpoint(every_s=0.2, what=what)
    try:
        results = []
        notifier = Notifier([slow.url()], dataset="day1", timeout_s=1.0, retries=1, backoff_s=0.01)
        notifier.subscribe(results.append)
        notifier.notify("failed", "Unexpected error")
        assert notifier.wait_idle(60), "still delivering to the trickling endpoint"     # only against a hang
        assert [(r.ok, r.attempts) for r in results] == outcome
        assert slow.connections == connections
        assert slow.gone.wait(30)                     # the trickled connection was closed by the notifier
        notifier.close(0)
    finally:
        slow.close()
