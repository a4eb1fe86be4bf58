"""Camera panel with a USB camera: libgphoto2's virtual PTP camera (tests/vcamera.py), offscreen Qt."""

from __future__ import annotations

import numpy as np
import pytest

from lfstudio.gui.panels.camera import CameraPanel
from lfstudio.gui.settings import settings
from lfstudio.gui.state import AppState

# libgphoto2's virtual camera answers 'store full' after ~27 captures in one process: these files
# share one pytest-xdist worker, in order, as in a serial run
pytestmark = pytest.mark.xdist_group("vcamera")


def test_test_shot_and_settings_the_camera_refuses(qtbot, vcamera):
    state = AppState(simulated=False)           # a hardware session: its camera choice is gphoto2
    settings().setValue("camera/kind", "gphoto2")
    panel = CameraPanel(state)
    qtbot.addWidget(panel)
    try:
        panel.connect_camera()
        qtbot.waitUntil(lambda: panel.status_label.text().startswith("Connected"), timeout=30000)
        with qtbot.waitSignal(state.cameraFrame, timeout=30000) as shot:
            panel.take_test_shot()
        image, _caption = shot.args
        assert image.dtype == np.uint8 and image.shape[:2] == (240, 320)
        assert ".jpg" in panel.shot_label.text() and "exposure 0.01 s" in panel.shot_label.text()
        panel.shutter.setValue(0.5)        # the virtual camera offers 1 s, 0.1 s, ... and has no ISO
        panel.aperture.setValue(8.0)
        panel.apply_settings()
        qtbot.waitUntil(lambda: panel.shutter.value() == 0.01, timeout=30000)   # read back after the settings
        text = panel.status_label.text()
        assert "Settings applied" not in text
        assert "iso: Nikon DSC D750 has no such setting" in text
        assert "shutter_s: 0.5 s is not offered by Nikon DSC D750 (valid: 1.0000s, 0.1000s" in text
        assert panel.aperture.value() == 8.0
    finally:
        panel.shutdown()
