"""The Rig panel drives CANopen nodes served by another process (issue 38): ``lfstudio sim-drive
--canopen udp_multicast --enabled-unhomed`` in its own process, the panel (real Qt loop, real worker
thread) in a pytest process of its own, both inside a network namespace the outer test makes
(tests/netns.py: only loopback, so the multicast frames never leave the machine)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from PySide6.QtCore import Qt

from tests.conftest import REPO_ROOT
from tests.netns import canopen_sim_drive, own_network_namespace
from tests.scankill import lfstudio_env

RIG_NAME = "dryve D1 gantry 4 m x 0.5 m"
WORD = os.environ.get("LFSTUDIO_TEST_CANOPEN_WORD", "")
T = 20000


@pytest.mark.skipif(not WORD, reason="the inner half: run by test_the_rig_panel_on_canopen_nodes_of_another_process")
def test_inner_rig_panel_on_the_other_process_drives(qtbot):
    from lfstudio.gui.panels.rig import RigPanel
    from lfstudio.gui.state import AppState
    from lfstudio.rig.motion import RigState

    panel = RigPanel(AppState(simulated=True))
    qtbot.addWidget(panel)
    panel.show()
    try:
        panel.rig_combo.setCurrentText(RIG_NAME)
        panel.port_combo.setEditText(WORD)
        qtbot.mouseClick(panel.connect_button, Qt.LeftButton)
        qtbot.waitUntil(lambda: panel.last_status is not None and "power_state" in panel.last_status.extra,
                        timeout=T)
        # found enabled by the other process, never homed here: not homed, its reference can be kept
        assert "x: operation enabled" in panel.drive_label.text() and not panel.last_status.homed
        assert panel.keep_button.isVisible() and not panel.goto_button.isEnabled()
        qtbot.mouseClick(panel.home_button, Qt.LeftButton)
        qtbot.waitUntil(lambda: panel.last_status.state is RigState.IDLE and panel.last_status.homed, timeout=T)
        assert panel.state_label.text() == "homed"
        panel.goto_x.setValue(120)
        panel.goto_y.setValue(40)
        qtbot.mouseClick(panel.goto_button, Qt.LeftButton)
        qtbot.waitUntil(lambda: panel.last_status.position_mm == (120.0, 40.0)
                        and panel.last_status.state is RigState.IDLE, timeout=T)
        assert "udp_multicast node 1" in str(panel.last_status.extra["addresses"])
    finally:
        panel.shutdown()


def test_the_rig_panel_on_canopen_nodes_of_another_process():
    with own_network_namespace() as prefix, canopen_sim_drive(prefix, "--enabled-unhomed") as word:
        env = dict(lfstudio_env(), LFSTUDIO_TEST_CANOPEN_WORD=word, QT_QPA_PLATFORM="offscreen")
        r = subprocess.run([*prefix, sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:randomly",
                            f"{__file__}::test_inner_rig_panel_on_the_other_process_drives"],
                           capture_output=True, text=True, timeout=240, env=env, cwd=REPO_ROOT)
    assert r.returncode == 0 and "1 passed" in r.stdout, r.stdout[-3000:] + r.stderr[-2000:]
