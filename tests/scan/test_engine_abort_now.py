"""``ScanEngine.abort(grace_s=...)``, what the CLI's Ctrl+C asks for, on the simulated studio (the
GRBL simulator on a real pty and the simulated camera): a move under way is stopped and its view is
not taken; a transfer that does not end within the grace time is cut short and its view stays not
done; the dataset stays valid and the rig usable (homed, idle) for the resume."""

from __future__ import annotations

import math
import threading
import time

import pytest

from lfstudio.dataset import Dataset
from lfstudio.rig.motion import RigState
from lfstudio.rig.profile import load_rig
from lfstudio.scan.engine import ScanEngine
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.studio.devices import open_studio
from lfstudio.studio.session import create_scan_dataset

RIG = load_rig()


def _studio(tmp_path, time_scale: float, transfer_s: float):
    plan = ScanPlan.centered(3, 2, (4.0, 6.0), RIG, settle_s=0.0)
    studio = open_studio("sim", "sim", RIG, time_scale=time_scale, exposure_s=0.05, transfer_s=transfer_s,
                         view_region_mm=plan.extent_mm(), sim_width_px=64)
    ds = create_scan_dataset(tmp_path / "ds", plan, rig={"name": RIG.name}, camera={"name": "sim"},
                             lens={"name": "virtual"})
    return studio, plan, ds


def test_abort_with_a_grace_time_stops_the_move_and_takes_no_view(tmp_path):
    studio, plan, ds = _studio(tmp_path, time_scale=0.3, transfer_s=1.0)
    try:
        engine = ScanEngine(ds, plan, studio.rig, studio.camera, time_scale=0.3)
        events = []
        engine.subscribe(events.append)
        first = plan.views()[0]
        start_mm = studio.simulator.true_position_mm()
        assert math.dist(start_mm, first.position_mm) > 100     # a long move to the first view
        assert engine.start().result(30) is ScanState.RUNNING
        while engine.rig.current_command != "move_to" and engine.state is ScanState.RUNNING:
            time.sleep(0.005)        # polling the worker's state, not synchronising on a duration
        assert engine.rig.current_command == "move_to"
        engine.abort(grace_s=0.5)
        assert engine.wait(60) is ScanState.FINISHED, engine.message
        assert engine.aborted and "Aborted: 0 of 6 views captured" in engine.message
        assert not [e for e in events if e.kind in (EventKind.VIEW_EXPOSED, EventKind.VIEW_DONE)]
        assert any("stopped by STOP" in e.message for e in events if e.kind is EventKind.LOG)  # the move's end
        stopped_at = studio.simulator.true_position_mm()
        assert math.dist(stopped_at, first.position_mm) > 1.0      # stopped on the way, not at the view
        status = studio.rig.status()
        assert status.state is RigState.IDLE and status.homed          # usable for the resume as it is
        assert {v["status"] for v in Dataset.open(ds.root).views} == {"pending"}
    finally:
        studio.close()


def test_abort_with_a_grace_time_cuts_a_long_transfer_short_and_leaves_the_view_not_done(tmp_path):
    studio, plan, ds = _studio(tmp_path, time_scale=0.2, transfer_s=60.0)     # a 12 s transfer
    try:
        engine = ScanEngine(ds, plan, studio.rig, studio.camera, time_scale=0.2)
        events = []
        exposed = threading.Event()

        def on_event(e) -> None:
            events.append(e)
            if e.kind is EventKind.VIEW_EXPOSED and not exposed.is_set():
                exposed.set()
                engine.abort(grace_s=0.2)         # from the engine's own thread, as any listener may

        engine.subscribe(on_event)
        engine.start()
        assert engine.wait(60) is ScanState.FINISHED, engine.message
        assert exposed.is_set()
        assert not [e for e in events if e.kind in (EventKind.VIEW_DONE, EventKind.VIEW_FAILED)]
        assert any("cut short" in e.message for e in events if e.kind is EventKind.LOG)
        again = Dataset.open(ds.root)
        assert {v["status"] for v in again.views} == {"pending"} and again.verify_files() == []
    finally:
        studio.close()


def test_a_grace_time_is_a_number_of_seconds(tmp_path):
    studio, plan, ds = _studio(tmp_path, time_scale=0.0, transfer_s=0.0)
    try:
        engine = ScanEngine(ds, plan, studio.rig, studio.camera, time_scale=0.0)
        with pytest.raises(Exception, match="grace_s"):
            engine.abort(grace_s=float("nan"))
    finally:
        studio.close()
