"""Engine state machine on the instant devices (no timing): order, pause/resume, abort + resume,
skip, re-capture, disk-full pause. The timed, pty-based end-to-end runs are in test_engine_sim.py."""

from __future__ import annotations

import threading

import pytest

from lfstudio.dataset import Dataset
from lfstudio.rig.profile import load_rig
from lfstudio.scan.engine import ScanEngine
from lfstudio.studio.session import create_scan_dataset
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.scan_plan import ScanPlan, grid_order
from lfstudio.sim.instant import InstantCamera, InstantRig

RIG = load_rig()


@pytest.fixture
def setup(tmp_path):
    def make(cols=4, rows=3, **kw):
        plan = ScanPlan.centered(cols, rows, (4.0, 6.0), RIG, settle_s=0.0)
        ds = create_scan_dataset(tmp_path / "ds", plan, rig={"name": RIG.name}, camera={"name": "instant"},
                                 lens={"name": "test"})
        rig = InstantRig(RIG)
        rig.connect()
        cam = InstantCamera(rig.true_position_mm)
        cam.connect()
        engine = ScanEngine(ds, plan, rig, cam, time_scale=0.0, **kw)
        events = []
        engine.subscribe(events.append)
        return engine, ds, plan, rig, cam, events
    return make


def done_order(events):
    return [(e.row, e.column) for e in events if e.kind is EventKind.VIEW_DONE]


def test_scan_captures_every_view_once_in_meander_order(setup):
    engine, ds, plan, rig, cam, events = setup()
    engine.start()
    assert engine.wait(30) is ScanState.FINISHED
    assert done_order(events) == grid_order(4, 3, "row-meander")
    again = Dataset.open(ds.root)
    assert again.status_counts()["done"] == 12 and again.verify_files() == []
    for v in again.views:
        assert (again.root / v["thumb"]).is_file()
        assert v["commanded_mm"] == list(plan.position_mm(v["row"], v["column"]))
        assert v["reported_mm"] == pytest.approx(v["commanded_mm"])
        assert set(v["timings_s"]) >= {"move", "settle", "expose", "transfer", "store"}
    assert cam.captures == 12
    states = [e.state for e in events if e.kind is EventKind.STATE]
    assert states[0] is ScanState.RUNNING and states[-1] is ScanState.FINISHED
    last = [e for e in events if e.kind is EventKind.VIEW_DONE][-1]
    assert (last.done, last.total, last.index) == (12, 12, 11)


def test_pause_lands_after_the_current_view_and_resume_completes(setup):
    engine, ds, plan, rig, cam, events = setup()
    paused = threading.Event()

    def on(ev):
        if ev.kind is EventKind.VIEW_EXPOSED and ev.index == 2:
            engine.pause()
        if ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED:
            paused.set()
    engine.subscribe(on)
    engine.start()
    assert paused.wait(30)
    at_pause = cam.captures
    assert engine.state is ScanState.PAUSED
    assert at_pause == 3                # the view being captured when the pause came is finished, no more
    assert ds.status_counts()["done"] == 3      # every captured view is stored before "paused"
    engine.resume()
    assert engine.wait(30) is ScanState.FINISHED
    assert sorted(done_order(events)) == sorted(grid_order(4, 3))
    assert cam.captures == 12


def test_abort_then_a_new_engine_resumes_the_rest_exactly_once(setup, tmp_path):
    engine, ds, plan, rig, cam, events = setup()

    def on(ev):
        if ev.kind is EventKind.VIEW_DONE and ev.done == 5:
            engine.abort()
    engine.subscribe(on)
    engine.start()
    assert engine.wait(30) is ScanState.FINISHED
    assert engine.message.startswith("Aborted")
    first = done_order(events)
    assert 5 <= len(first) < 12
    reopened = Dataset.open(ds.root)
    engine2 = ScanEngine(reopened, plan, rig, cam, time_scale=0.0)
    events2 = []
    engine2.subscribe(events2.append)
    assert engine2.remaining == 12 - len(first)
    engine2.start()
    assert engine2.wait(30) is ScanState.FINISHED
    second = done_order(events2)
    assert sorted(first + second) == sorted(grid_order(4, 3)) and not set(first) & set(second)
    assert Dataset.open(ds.root).verify_files() == []


def test_skip_and_recapture(setup):
    engine, ds, plan, rig, cam, events = setup(retries=0)
    engine.skip([(2, 0), (2, 1)])
    engine.start()
    assert engine.wait(30) is ScanState.FINISHED
    counts = ds.status_counts()
    assert (counts["done"], counts["skipped"]) == (10, 2)
    sha_before = ds.view(0, 0)["sha256"]
    engine2 = ScanEngine(ds, plan.with_subset([(0, 0), (2, 0)]), rig, cam, time_scale=0.0, recapture=True)
    events2 = []
    engine2.subscribe(events2.append)
    engine2.start()
    assert engine2.wait(30) is ScanState.FINISHED
    assert sorted(done_order(events2)) == [(0, 0), (2, 0)]
    assert ds.view(2, 0)["status"] == "done" and ds.view(0, 0)["sha256"] == sha_before
    assert Dataset.open(ds.root).status_counts()["skipped"] == 1


def test_too_little_free_disk_space_pauses_with_a_message_then_resumes(setup):
    engine, ds, plan, rig, cam, events = setup()
    free = {"bytes": 10 * 2**30}
    engine.free_bytes_fn = lambda root: free["bytes"]
    paused = threading.Event()

    def on(ev):
        if ev.kind is EventKind.VIEW_DONE and ev.done == 4:
            free["bytes"] = 5 * 2**20           # the disk fills up: less than the 8 MB floor
        if ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED:
            paused.set()
    engine.subscribe(on)
    engine.start()
    assert paused.wait(30)
    assert "Disk almost full" in engine.message and "MB free" in engine.message
    assert engine.fault is not None and engine.fault.device == "disk"
    stuck = ds.status_counts()["done"]
    assert stuck < 12
    faults = [e for e in events if e.kind is EventKind.FAULT]
    assert faults and "Free disk space" in faults[0].message
    free["bytes"] = 10 * 2**30                  # the operator freed space
    engine.resume()
    assert engine.wait(30) is ScanState.FINISHED
    assert Dataset.open(ds.root).status_counts()["done"] == 12


def test_unhomed_rig_pauses_before_the_first_move(setup):
    engine, ds, plan, rig, cam, events = setup()
    rig.disconnect()
    engine.start()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=30)
    assert "Rig is not connected" in engine.message
    assert cam.captures == 0
    engine.resume()                              # reconnects the rig
    assert engine.wait(30) is ScanState.FINISHED
    assert cam.captures == 12


def test_an_instant_camera_that_describes_its_size_passes_the_disk_preflight_of_a_2121_view_scan():
    """benchmarks/grid_gui.py scans 2121 views with the instant camera from the window, whose scene plan
    says 84 MB an image: counted that way the scan needed 179 GB and was refused. With describe_size the
    camera's own 64 x 48 px count (and a camera that tells nothing still falls back to the plan)."""
    from lfstudio.scan.preflight import disk_shortfall, view_size
    from lfstudio.studio.session import describe_camera

    plan_bytes = 84 * 2**20
    told = describe_camera(InstantCamera(describe_size=True))[0].get("sensor_px")
    assert told == [64, 48]
    size = view_size(1, sensor_px=told, plan_bytes_per_image=plan_bytes)
    assert size is not None and size.bytes < 2**20 and "64 x 48" in size.source
    assert disk_shortfall("/tmp/x", 2121, size, free_bytes=20 * 2**30) is None
    silent = describe_camera(InstantCamera())[0].get("sensor_px")
    assert silent is None
    fallback = view_size(1, sensor_px=silent, plan_bytes_per_image=plan_bytes)
    assert fallback is not None and disk_shortfall("/tmp/x", 2121, fallback, free_bytes=20 * 2**30) is not None
