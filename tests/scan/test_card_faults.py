"""--keep-on-card's faults (#40): a full card and a pulled cable lose nothing. The simulated camera keeps
its card as a camera body does (across a disconnect: the pictures stay in the camera); a full card
refuses the next capture as gphoto2 bodies do ("the camera's card is full"); a pulled cable makes the
camera answer nothing until it is plugged in again. Every view ends done exactly once with its file
verified; files still on the card when the cable came back are fetched by the resumed scan."""

from __future__ import annotations

import threading

from lfstudio.dataset import Dataset
from lfstudio.scan.card import CardBufferEngine
from lfstudio.scan.events import EventKind, ScanState
from tests.scan.test_card_buffer import _check_all_done, _studio


def test_a_full_card_downloads_what_waits_on_it_and_loses_nothing(tmp_path):
    studio, plan, ds = _studio(tmp_path, 6, 2)
    studio.camera.card_capacity = 2          # a row of 6 does not fit: full at the third picture
    try:
        engine = CardBufferEngine(ds, plan, studio.rig, studio.camera, time_scale=0.0)
        logs: list[str] = []
        engine.subscribe(lambda e: e.kind is EventKind.LOG and logs.append(e.message))
        engine.start()
        assert engine.wait(120) is ScanState.FINISHED, (engine.message, logs)
    finally:
        studio.close()
    _check_all_done(tmp_path / "ds", 12)
    assert any("the camera's card is full: downloading the 2 pictures" in m for m in logs), logs
    assert engine.downloads == 12                   # each picture downloaded once: none taken twice


def test_a_pulled_cable_loses_nothing_and_the_resumed_scan_fetches_the_card(tmp_path):
    studio, plan, ds = _studio(tmp_path, 4, 2)
    camera = studio.camera
    try:
        engine = CardBufferEngine(ds, plan, studio.rig, camera, time_scale=0.0, retries=1, backoff_s=0.01)
        pulled = threading.Event()

        def pull_after_two(event):              # two pictures on the card, none downloaded yet (same row)
            if event.kind is EventKind.VIEW_EXPOSED and not pulled.is_set():
                records = Dataset.open(ds.root).views
                if sum(1 for v in records if v.get("on_card")) >= 2:
                    camera.inject("unplugged", None)
                    pulled.set()

        engine.subscribe(pull_after_two)
        engine.start()
        # the camera fault pauses the scan (auto-resume would try the camera again; the operator stops)
        assert engine.wait_for_state(ScanState.PAUSED, ScanState.FINISHED, timeout_s=120), engine.message
        assert pulled.is_set(), engine.message
        engine.abort()
        assert engine.wait(120) is ScanState.FINISHED, engine.message
        cut = Dataset.open(ds.root)
        waiting = [v for v in cut.views if v.get("on_card") and v["status"] != "done"]
        assert waiting, [(v["status"], v.get("on_card")) for v in cut.views]   # on the card, not done
        assert all(cut.path_of(v).is_file() for v in cut.done_views())          # nothing done without its file
        # the cable is plugged in again; the scan is resumed
        camera.clear_faults()
        camera.connect()
        again = CardBufferEngine(Dataset.open(ds.root), plan, studio.rig, camera, time_scale=0.0)
        logs: list[str] = []
        again.subscribe(lambda e: e.kind is EventKind.LOG and logs.append(e.message))
        again.start()
        assert again.wait(120) is ScanState.FINISHED, (again.message, logs)
    finally:
        studio.close()
    _check_all_done(tmp_path / "ds", 8)
    assert again.fetched_on_resume == len(waiting), logs
    assert any("fetched from the card, where the last run left it" in m for m in logs)
