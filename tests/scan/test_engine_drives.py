"""The engine on emulated CiA 402 drives (dryve D1 gateway telegrams over Modbus TCP to the emulator's
server; CANopen SDO on the virtual bus): a drive fault mid-scan pauses the scan with one line naming
the drive and its error code; after Reset fault and homing, resume completes every view exactly once.
A drive that stops answering pauses it too, and the scan resumes once it answers again."""

from __future__ import annotations

import threading

import pytest

from lfstudio.dataset import Dataset
from lfstudio.rig.profile import load_rig
from lfstudio.scan.engine import ScanEngine
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.scan_plan import ScanPlan, grid_order
from lfstudio.studio.devices import open_studio
from lfstudio.studio.session import create_scan_dataset

RIG = load_rig("dryve D1 gantry 4 m x 0.5 m")


@pytest.fixture(params=["sim-dryve", "sim-canopen"])
def studio(request, tmp_path):
    plan = ScanPlan.centered(4, 3, (4.0, 6.0), RIG, settle_s=0.0)
    session = open_studio(request.param, "sim", RIG, time_scale=0.0, exposure_s=0.5, transfer_s=2.5,
                          view_region_mm=plan.extent_mm(), sim_width_px=96, timeout_s=0.5)
    ds = create_scan_dataset(tmp_path / "ds", plan, rig={"name": RIG.name}, camera={"name": "sim"},
                             lens={"name": "virtual"})
    yield session, plan, ds
    session.close()


@pytest.mark.parametrize("fault, words", [("following_error", "fault 8611h"), ("limit_switch", "fault 8612h"),
                                          ("power_stage_off", "fault 3220h"), ("lost_connection", "does not answer")])
def test_a_drive_fault_mid_scan_pauses_it_with_one_line_then_resume_completes(studio, fault, words):
    session, plan, ds = studio
    emulator = session.simulator
    engine = ScanEngine(ds, plan, session.rig, session.camera, time_scale=0.0, backoff_s=0.01, retries=1)
    events = []
    engine.subscribe(events.append)
    paused = threading.Event()

    def on(ev):
        if ev.kind is EventKind.VIEW_DONE and ev.done == 4:
            emulator.pair.axes[1].inject(fault)
        if ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED:
            paused.set()
    engine.subscribe(on)
    engine.start()
    assert paused.wait(60), engine.message
    assert words in engine.message and "drive y (vertical)" in engine.message and "\n" not in engine.message
    assert engine.fault.device == "rig"
    assert ds.status_counts()["done"] < 12
    emulator.pair.axes[1].clear_faults()
    if fault == "lost_connection":
        session.rig.connect()                    # answers again: a new connection, not homed by it
        assert not session.rig.status().homed
        session.rig.accept_reference()           # the operator keeps the drives' reference (or homes)
    else:
        session.rig.reset()                      # Reset fault, then home: what the operator does
        session.rig.home()
    paused.clear()
    engine.resume()
    assert engine.wait(90) is ScanState.FINISHED, engine.message
    cells = [(e.row, e.column) for e in events if e.kind is EventKind.VIEW_DONE]
    assert sorted(cells) == sorted(grid_order(4, 3)) and len(cells) == 12     # every view exactly once
    again = Dataset.open(ds.root)
    assert again.verify_files() == []
    for v in again.views:
        assert v["reported_mm"] == pytest.approx(v["commanded_mm"], abs=0.011)
