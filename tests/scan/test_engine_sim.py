"""The engine end to end on the simulated studio: GRBL simulator on a real pty driven by the real
GRBL driver, and the simulated camera rendering DNGs. Device faults mid-scan pause the scan with a
message; after the fault is cleared, resume completes every view exactly once."""

from __future__ import annotations

import threading

import pytest
import rawpy

from lfstudio.dataset import Dataset
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.scan_plan import grid_order
from tests.scan.conftest import engine_with_events, open_sim_studio



@pytest.fixture
def studio(tmp_path):
    session, plan, ds = open_sim_studio(tmp_path / "ds", 4, 3, 96)
    yield session, plan, ds
    session.close()


run_engine = engine_with_events


def done_cells(events):
    return [(e.row, e.column) for e in events if e.kind is EventKind.VIEW_DONE]


def test_scan_end_to_end_on_the_simulated_studio(studio):
    session, plan, ds = studio
    engine, events = run_engine(session, plan, ds)
    assert engine.pipelined
    engine.start()
    assert engine.wait(60) is ScanState.FINISHED, engine.message
    assert done_cells(events) == grid_order(4, 3)
    again = Dataset.open(ds.root)
    assert again.verify_files() == [] and again.status_counts()["done"] == 12
    v = again.view(2, 1)
    assert v["file"] == "raw/r02_c001.dng" and v["sidecars"] == ["raw/r02_c001.jpg", "raw/r02_c001.truth.json"]
    assert v["reported_mm"] == pytest.approx(v["commanded_mm"], abs=1e-3)
    assert v["exposure_s"] == pytest.approx(0.5)
    assert (again.root / v["thumb"]).is_file()
    with rawpy.imread(str(again.path_of(v))) as raw:
        assert raw.raw_image_visible.shape[1] == 96
    assert session.camera.shots == 12


RIG_FAULTS = {
    # fault injected → (pauses the scan?, what the operator reads, how the operator fixes it)
    "silent": (True, "Rig", "clear"),
    "alarm_mid_move": (True, "alarm", "home"),
}


@pytest.mark.parametrize("fault", ["silent", "alarm_mid_move", "position_error", "garbage"])
def test_rig_fault_mid_scan(studio, fault):
    session, plan, ds = studio
    engine, events = run_engine(session, plan, ds, retries=1)
    paused = threading.Event()

    def on(ev):
        if ev.kind is EventKind.VIEW_DONE and ev.done == 4:
            session.simulator.inject(fault)
        if ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED:
            paused.set()
    engine.subscribe(on)
    engine.start()
    if fault in RIG_FAULTS:
        assert paused.wait(60), engine.message
        _, words, fix = RIG_FAULTS[fault]
        assert words in engine.message and "then Resume" in engine.message
        assert engine.fault.device == "rig"
        assert ds.status_counts()["done"] < 12
        session.simulator.clear_faults()
        if fix == "home":
            session.rig.home()          # what the operator does in the Rig panel
        paused.clear()
        engine.resume()
        # a reconnected controller may have lost its position: the scan asks for homing first
        finished = threading.Event()
        engine.subscribe(lambda ev: finished.set() if ev.state is ScanState.FINISHED else None)
        while not (paused.is_set() or finished.is_set()):
            paused.wait(0.05)
        if paused.is_set():
            assert "not homed" in engine.message
            session.rig.home()
            engine.resume()
    assert engine.wait(90) is ScanState.FINISHED, engine.message
    cells = done_cells(events)
    assert sorted(cells) == sorted(grid_order(4, 3)) and len(cells) == 12     # every view exactly once
    if fault == "position_error":
        assert any(e.kind is EventKind.VIEW_FAILED and e.will_retry for e in events)
    assert Dataset.open(ds.root).verify_files() == []


@pytest.mark.parametrize("fault", ["capture_fails", "silent"])
def test_camera_fault_mid_scan_pauses_then_resumes(studio, fault):
    session, plan, ds = studio
    engine, events = run_engine(session, plan, ds, retries=1, capture_timeout_s=1.0)
    paused = threading.Event()

    def on(ev):
        if ev.kind is EventKind.VIEW_DONE and ev.done == 5:
            session.camera.inject(fault, count=None)    # fails until cleared
        if ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED:
            paused.set()
    engine.subscribe(on)
    engine.start()
    assert paused.wait(60), engine.message
    assert "reconnect it, then Resume" in engine.message
    failures = [e for e in events if e.kind is EventKind.VIEW_FAILED]
    retries = [f.will_retry for f in failures]
    if fault == "silent":   # a camera that does not answer is not waited for again: the scan pauses at once
        assert engine.message.startswith("Camera does not answer: the picture of view r") and \
            "did not arrive within 1 s" in engine.message, engine.message
        assert retries[-1] is False and len(retries) in (1, 2), retries
    else:
        # the failing view's retry fails and pauses the scan; with the transfer overlapping the next
        # exposure, the next view may have failed once too (queued for its own retry)
        assert engine.message.startswith("Camera failed 2 time(s)")
        assert retries[-1] is False and all(retries[:-1]) and len(retries) in (2, 3), retries
    session.camera.clear_faults()
    engine.resume()
    assert engine.wait(60) is ScanState.FINISHED, engine.message
    cells = done_cells(events)
    assert sorted(cells) == sorted(grid_order(4, 3)) and len(cells) == 12
    assert Dataset.open(ds.root).verify_files() == []


def test_skip_a_failing_view_records_it_as_failed(studio):
    session, plan, ds = studio
    engine, events = run_engine(session, plan, ds, retries=0)

    def on(ev):
        if ev.kind is EventKind.VIEW_DONE and ev.done == 2:
            session.camera.inject("capture_fails", count=1)
        if ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED:
            engine.skip()
            engine.resume()
    engine.subscribe(on)
    engine.start()
    assert engine.wait(60) is ScanState.FINISHED
    again = Dataset.open(ds.root)
    counts = again.status_counts()
    assert (counts["done"], counts["failed"]) == (11, 1)
    failed = [v for v in again.views if v["status"] == "failed"][0]
    assert "capture failed" in failed["error"]
    assert "1 failed" in engine.message
