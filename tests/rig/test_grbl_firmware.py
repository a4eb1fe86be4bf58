"""The GRBL driver against the real GRBL 1.1h firmware (its official simulator, built from
../shared/vendor/grbl by tests/grbl_firmware.py) at the firmware's own defaults: what a new operator
meets on a freshly flashed board. The protocol checks shared with our simulator are in
test_grbl_protocol.py."""

from __future__ import annotations

import pytest

from lfstudio.dataset import Dataset
from lfstudio.rig.grbl import GrblController
from lfstudio.rig.motion import RigState, SoftLimitError
from lfstudio.rig.profile import load_rig
from lfstudio.scan.engine import ScanEngine
from lfstudio.scan.events import ScanState
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.sim.instant import InstantCamera
from lfstudio.studio.session import create_scan_dataset
from tests.grbl_firmware import (FIRMWARE_DEFAULTS, REPO_ROOT, FirmwareUnavailable, build_firmware_simulator,
                                 find_grbl_source)

GANTRY = load_rig()                         # the reference gantry: 4 m x 0.5 m, 200 mm/s, switches
#: limit switches 1 mm beyond both ends of GRBL's default 200 mm travel, powered up 20 mm from home
SWITCHES = ((-181.0, 21.0), (-181.0, 21.0), (-196.0, 5.0))


def connected(fw, rig=GANTRY) -> GrblController:
    controller = GrblController(fw.port, rig, timeout_s=3.0)
    controller.connect()
    return controller


def test_the_official_simulator_is_built_outside_the_repo_from_untouched_sources(grbl_firmware_exe):
    assert REPO_ROOT not in grbl_firmware_exe.parents
    assert grbl_firmware_exe.name == "grbl_sim.exe"
    assert not list((find_grbl_source() / "grbl").rglob("*.o"))          # nothing built in the sources


def test_the_harness_reports_why_it_cannot_build(tmp_path):
    with pytest.raises(FirmwareUnavailable, match="holds no GRBL sources"):
        build_firmware_simulator(tmp_path, cache_root=tmp_path / "cache")
    sim_dir = tmp_path / "grbl" / "grbl-sim"
    sim_dir.mkdir(parents=True)
    (sim_dir / "Makefile").write_text("main:\n\t@echo 'grbl_sim.c:1: error: broken on purpose' >&2; exit 1\n"
                                      "lfstudio_shim.o:\n\ttrue\n")
    with pytest.raises(FirmwareUnavailable, match="(broken on purpose|build-essential)"):
        build_firmware_simulator(tmp_path, cache_root=tmp_path / "cache")
    assert not list((tmp_path / "cache").glob("*/grbl"))        # nothing half-built left in the cache


def test_a_fresh_board_boots_with_error_7_and_its_defaults_and_the_handshake_copes(grbl_firmware):
    fw = grbl_firmware(reset_on_open=True)    # first boot on an empty EEPROM happens as the port opens
    c = connected(fw)
    try:
        assert c.board_resets == 1 and not c.locked
        assert {k: c.settings[k] for k in FIRMWARE_DEFAULTS} == FIRMWARE_DEFAULTS
        assert c.firmware.max_rate_mm_min["X"] == 500 and not c.firmware.soft_limits and not c.firmware.homing
        assert "error:7" in fw.lines_sent            # "EEPROM read failed, defaults restored", then $$
        text = "\n".join(c.warnings)
        assert "$110 = 500 mm/min (8.333 mm/s)" in text and "homing is off in the controller ($22 = 0)" in text
        assert c.status().extra["warnings"] == c.warnings
    finally:
        c.disconnect()


def test_homing_with_switches_then_a_scan_inside_grbls_soft_limits(grbl_firmware, tmp_path):
    """$22 = 1, $20 = 1 and GRBL's default 200 mm travel, with the reference gantry's 4 m profile:
    after homing the frame is 0 … 200 mm, a scan inside it runs, and a target beyond it is refused
    by the driver before anything is sent (GRBL would answer it with ALARM 2)."""
    fw = grbl_firmware(switches=SWITCHES, reset_on_open=True)
    fw.configure({22: 1, 20: 1})
    c = connected(fw)
    assert c.locked and c.board_resets == 1 and any("$130 = 200 mm" in w for w in c.warnings)
    c.home()
    assert c.status().position_mm == pytest.approx((199.0, 199.0))
    plan = ScanPlan(3, 2, (40.0, 50.0), (60.0, 80.0), settle_s=0.0)
    ds = create_scan_dataset(tmp_path / "ds", plan, rig={"name": GANTRY.name}, camera={"name": "instant"},
                             lens={"name": "test"})
    camera = InstantCamera(lambda: c.status().position_mm)
    camera.connect()
    engine = ScanEngine(ds, plan, c, camera, time_scale=0.0, backoff_s=0.01)
    engine.start()
    assert engine.wait(120) is ScanState.FINISHED, engine.message
    views = Dataset.open(ds.root).views
    assert len(views) == 6 and all(v["status"] == "done" for v in views)
    assert all(v["reported_mm"] == pytest.approx(v["commanded_mm"], abs=0.004) for v in views)
    sent = len(fw.lines_received)
    with pytest.raises(SoftLimitError, match=r"target x \(horizontal\): 250 mm is beyond the controller's soft "
                                             r"limit \(\$130 = 200 mm of travel, \$20 = 1\); nothing was sent"):
        c.move_to(250.0, 100.0)
    assert len(fw.lines_received) == sent and c.alarms == []
    c.disconnect()


def test_homing_without_switches_fails_with_alarm_9_and_the_operator_can_set_the_origin(grbl_firmware):
    fw = grbl_firmware()
    fw.configure({22: 1, 130: 20.0, 131: 20.0, 132: 20.0})   # a short search: 1.5 x 20 mm
    c = connected(fw)
    try:
        with pytest.raises(Exception, match="ALARM 9: homing failed: limit switch not found"):
            c.home()
        assert c.status().state is RigState.ALARM and c.alarms[-1] == 9
        c.unlock()
        c.set_origin()
        assert c.move_to(5.0, 5.0).position_mm == pytest.approx((5.0, 5.0))
        assert c.board_resets == 0              # GRBL's own reset after the alarm is not a board restart
    finally:
        c.disconnect()
