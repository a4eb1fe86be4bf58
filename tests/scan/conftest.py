"""Shared pieces of the scan engine tests: the simulated studio (GRBL simulator on a pty, the
simulated camera writing real DNGs) with a fresh scan dataset, and an engine with its events."""

from __future__ import annotations

import pytest

from lfstudio.rig.profile import load_rig
from lfstudio.scan.engine import ScanEngine
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.studio.devices import open_studio
from lfstudio.studio.session import create_scan_dataset

RIG = load_rig()


def open_sim_studio(root, columns: int, rows: int, width_px: int):
    """``(session, plan, dataset)``: a centred ``columns`` x ``rows`` plan on the default rig, the
    simulated studio at time scale 0 and a new scan dataset at ``root``; close the session after."""
    plan = ScanPlan.centered(columns, rows, (4.0, 6.0), RIG, settle_s=0.0)
    session = open_studio("sim", "sim", RIG, time_scale=0.0, exposure_s=0.5, transfer_s=2.5,
                          view_region_mm=plan.extent_mm(), sim_width_px=width_px)
    ds = create_scan_dataset(root, plan, rig={"name": RIG.name}, camera={"name": "sim"}, lens={"name": "virtual"})
    return session, plan, ds


def engine_with_events(session, plan, ds, **kw):
    """A scan engine at time scale 0 on the session's devices, and the list its events go to."""
    engine = ScanEngine(ds, plan, session.rig, session.camera, time_scale=0.0, backoff_s=0.01, **kw)
    events = []
    engine.subscribe(events.append)
    return engine, events


def fail_captures_from_setting(camera, n: int) -> None:
    """From the camera's ``n``-th setting change on (the engine sets a bracket frame's shutter time
    before each frame), every capture fails, until ``camera.clear_faults()``."""
    real_set = camera.set_setting
    calls = []

    def set_setting(name, value):
        calls.append((name, value))
        if len(calls) == n:
            camera.inject("capture_fails", None)
        return real_set(name, value)

    camera.set_setting = set_setting


@pytest.fixture
def small_studio(tmp_path):
    """``(session, plan, dataset)``: a 3 x 2 plan on the simulated studio at 64 px (the bracket tests)."""
    session, plan, ds = open_sim_studio(tmp_path / "ds", 3, 2, 64)
    yield session, plan, ds
    session.close()
