"""A bracket the camera cannot take is refused before the scan, in its own words (issue #41 item 1):
the camera's shutter range is checked against every frame at Start (Scan panel) and by `lfstudio scan
--bracket`; a frame refused during a scan (a camera that told no range) pauses with its real cause
and what to do, not cable advice; the suggested resume command carries the bracket as typed; the
greyed Bracket field says how to change it. Real Qt loop, real engine, real CLI subprocesses."""

from __future__ import annotations

import argparse
import shlex
from typing import Any

from lfstudio.dataset import Dataset
from lfstudio.errors import InputError
from lfstudio.gui.app import create_window
from lfstudio.gui.panels import scan as scan_panel
from lfstudio.gui.panels.scan import ScanPanel
from lfstudio.gui.state import AppState
from lfstudio.rig.profile import load_rig
from lfstudio.scan.events import ScanState
from lfstudio.sim.instant import InstantCamera, InstantRig
from tests.faults.conftest import assert_one_line_error
from tests.gui.conftest import close_devices, window_devices


def test_the_cli_refuses_a_bracket_beyond_the_cameras_shutter_range_before_the_scan(tmp_path, run_cli):
    """`scan --bracket -2,0,+9` showed the scan's time, paused at the first view after three tries of
    256 s ("check the camera's cable") and exited 3."""
    proc = run_cli("scan", "--port", "sim", "--camera", "sim", "--grid", "2x1", "--bracket=-2,0,+9",
                   "--time-scale", "0", "--out", tmp_path / "ds")
    line = assert_one_line_error(proc, 2, "--bracket", "frame 3 of -2, 0, +9 EV", "256 s", "1/10000 s … 60 s",
                                 "EV steps from -10.0 to +6.9")
    assert "cable" not in line and not (tmp_path / "ds").exists()


def test_the_resume_command_carries_the_bracket_as_typed_and_reads_back():
    """It printed --bracket 'Bracket(ev=(-2.0, 0.0, 9.0), shutter_s=())', refused when run."""
    from lfstudio.cli import scan

    parser = argparse.ArgumentParser()
    scan.add_arguments(parser)
    args = parser.parse_args(["--port", "sim", "--camera", "sim", "--bracket=-2,0,+9", "--out", "/tmp/ds"])
    command = scan.resume_command(args, "/tmp/ds")
    assert "--bracket=-2,0,+9" in command and "Bracket(" not in command, command
    again = parser.parse_args(shlex.split(command)[2:])
    assert again.resume and again.bracket == args.bracket


def test_the_scan_panel_refuses_it_at_start_naming_its_bracket_field(qtbot, tmp_path):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    panel = window.findChild(ScanPanel, "scanPanel")
    panel.columns.setValue(2)
    panel.rows.setValue(1)
    panel.from_plan.setChecked(False) if panel.from_plan.isCheckable() else None
    panel.folder.setText(str(tmp_path / "ds"))
    panel.bracket.setText("-2,0,+9")
    with qtbot.waitSignal(window.state.errorOccurred, timeout=60000) as said:
        panel.start_button.click()
    title, message = said.args
    assert message.startswith("Bracket: frame 3 of -2, 0, +9 EV needs a shutter time of 256 s"), message
    assert "--" not in message and "cable" not in message
    assert panel.engine is None and not (tmp_path / "ds" / "dataset.json").exists()


class _NoRangeCamera(InstantCamera):
    """An instant camera that refuses shutter times over 1 s but tells no range (as a camera whose
    driver lists no choices): only the frame itself finds out."""

    def settings(self) -> dict[str, Any]:
        return {"format": "PNG", "shutter_s": 0.5}

    def set_setting(self, name: str, value: Any) -> None:
        if name == "shutter_s" and float(value) > 1.0:
            raise InputError("shutter_s", f"{value} s is out of range", "0.0001 .. 1 s")


def test_a_frame_refused_during_a_scan_pauses_with_its_cause_and_the_greyed_field_says_how(qtbot, tmp_path):
    rig = InstantRig(load_rig())
    rig.connect()
    cam = _NoRangeCamera(rig.true_position_mm)
    cam.connect()
    devices = window_devices(rig, cam)
    try:
        state = AppState()
        state.devices.update(devices)
        panel = ScanPanel(state)
        qtbot.addWidget(panel)
        panel.columns.setValue(2)
        panel.rows.setValue(1)
        panel.settle.setValue(0.0)
        panel.folder.setText(str(tmp_path / "ds"))
        panel.bracket.setText("-1,0,+2")
        panel.start()
        qtbot.waitUntil(lambda: panel.engine is not None and panel.engine.state is ScanState.PAUSED, timeout=30000)
        message = panel.engine.message
        assert message.startswith("Camera refused frame 3 of the bracket (-1, 0, +2 EV) at view r00 c000"), message
        assert "stop this scan (Abort), then scan into a new folder" in message and "cable" not in message
        assert cam.captures == 2                 # frames 1 and 2 once: no retry of a value the camera refuses
        assert getattr(panel.engine.fault, "resumable", True) is False    # the CLI prints no resume command
        fixed_tip = getattr(scan_panel, "BRACKET_FIXED_TIP", None)
        assert fixed_tip
        # the panel shows the pause once its event is drained (the engine's state changes first)
        qtbot.waitUntil(lambda: panel.abort_button.isEnabled() and "Paused" in panel.state_label.text(), timeout=10000)
        assert not panel.bracket.isEnabled() and panel.bracket.toolTip() == fixed_tip
        assert "Abort" in fixed_tip
        engine = panel.engine
        panel.abort_button.click()
        qtbot.waitUntil(lambda: engine.state is ScanState.FINISHED, timeout=30000)
        qtbot.waitUntil(lambda: panel.bracket.isEnabled(), timeout=30000)
        assert panel.bracket.toolTip() != fixed_tip
        assert Dataset.open(tmp_path / "ds").status_counts()["done"] == 0
    finally:
        close_devices(devices)
