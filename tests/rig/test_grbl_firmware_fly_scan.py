"""End to end: a hardware-triggered fly scan on the real GRBL 1.1h firmware (#40). The firmware (its
official simulator, built from ../shared/vendor/grbl by tests/grbl_firmware.py) switches its spindle
output in laser mode as the carriage passes each view; the shim logs each change with the firmware's
simulated time and step counts, and :class:`tests.grbl_firmware.SpindleLineFollower` puts those changes
on the simulated camera's trigger line (dated when read: see there for the clocks). FlyScanEngine
(trigger="hardware") drives the firmware through the real driver on a pty.

Asserted: every view was flown (none taken standing still), each view's recorded position is where the
firmware's step counts put the carriage at the edge that took its frame (plus the travel during the
camera's line latency and half its exposure) within 2 steps, the frames' edges are the firmware's
rising edges in order, and every file is on disk and verified."""

from __future__ import annotations

import dataclasses
import json
from typing import Any

import pytest

from lfstudio.dataset import Dataset
from lfstudio.rig.grbl import GrblController
from lfstudio.rig.profile import load_rig
from lfstudio.scan.events import ScanState
from lfstudio.scan.fly import FlyScanEngine
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.sim.sim_camera import SimulatedCamera
from lfstudio.studio.session import create_scan_dataset
from lfstudio.studio.simulated import studio_kwargs_for
from tests.grbl_firmware import SpindleLineFollower

GANTRY = load_rig()
BENCH = dataclasses.replace(GANTRY, homing=False,
                            horizontal=dataclasses.replace(GANTRY.horizontal, repeatability_um=0.0),
                            vertical=dataclasses.replace(GANTRY.vertical, repeatability_um=0.0))
SPEEDUP = 2.0                   # the firmware runs at 2 x real time: the engine's time scale is 1/2
SPEED = 50.0                    # mm/s (simulated): views 5 mm apart, 0.1 s between edges


def test_a_hardware_triggered_fly_scan_on_the_grbl_firmware(grbl_firmware, tmp_path):
    log = tmp_path / "spindle.log"
    fw = grbl_firmware(spindle_log=log, speedup=SPEEDUP)
    # the gantry's rates and laser mode, as an operator sets them once
    fw.configure({32: 1, 110: 12000.0, 111: 6000.0, 120: 500.0, 121: 300.0, 130: 4000.0, 131: 500.0})
    rig = GrblController(fw.port, BENCH, timeout_s=5.0)
    rig.connect()
    rig.set_origin()
    wco = rig._wco or (0.0, 0.0, 0.0)
    steps = (rig.settings[100], rig.settings[101])
    follower = SpindleLineFollower(log, steps, (wco[0], wco[1])).start()
    plan = ScanPlan(columns=6, rows=2, spacing_mm=(5.0, 6.0), origin_mm=(20.0, 10.0), settle_s=0.05)
    scale = 1.0 / SPEEDUP
    camera = SimulatedCamera(None, follower.position_mm, exposure_s=0.001, transfer_s=0.05, time_scale=scale,
                             studio_kwargs=studio_kwargs_for(plan.extent_mm(), 64))
    camera.trigger_line = follower.line
    camera.connect()
    ds = create_scan_dataset(tmp_path / "ds", plan, rig={"name": BENCH.name}, camera={"name": "sim"},
                             lens={"name": "virtual"})
    try:
        assert rig.pulse_problem(5.0, SPEED) is None and camera.line_trigger_problem() is None
        engine = FlyScanEngine(ds, plan, rig, camera, time_scale=scale, backoff_s=0.01, speed_mm_s=SPEED,
                               trigger="hardware")
        engine.start()
        assert engine.wait(300) is ScanState.FINISHED, engine.message
    finally:
        follower.close()
        camera.disconnect()
        rig.disconnect()
    d = Dataset.open(ds.root)
    assert d.status_counts()["done"] == 12 and d.verify_files() == []
    assert all(d.path_of(v).is_file() for v in d.done_views())
    lead_s = camera.line_trigger_latency_s + 0.5 * camera.exposure_s
    rising = [e for e in follower.edges if e[2]]
    used = []
    for view in d.views:
        v: dict[str, Any] = dict(view)
        fly = v.get("fly") or {}
        assert "recorded_mm" in fly, v                      # flown: none taken standing still
        assert fly["trigger"] == "hardware" and fly["source"] == "trigger line"
        direction = 1 if v["row"] % 2 == 0 else -1          # meander
        # the firmware's edge that took this frame: the rising edge the frame's exposure centre follows
        edge_t = fly["t_s"] - lead_s * scale
        k = min(range(len(rising)), key=lambda i: abs(rising[i][0] - edge_t))
        assert abs(rising[k][0] - edge_t) < 2e-6, (v["row"], v["column"])
        used.append(k)
        x_edge, y_edge = rising[k][3]
        expected = x_edge + direction * SPEED * lead_s
        assert fly["recorded_mm"][0] == pytest.approx(expected, abs=2.0 / steps[0]), (v, rising[k])
        assert fly["recorded_mm"][1] == pytest.approx(y_edge, abs=1.0 / steps[1])
        assert abs(x_edge - v["commanded_mm"][0]) <= 2.0 / steps[0]    # the edge is at the view, to the step
        truth = json.loads((d.root / v["sidecars"][1]).read_text())
        assert truth["true_position_mm"][0] == pytest.approx(x_edge, abs=0.1)
    assert sorted(used) == list(range(12))                  # each frame its own edge of the firmware's twelve
