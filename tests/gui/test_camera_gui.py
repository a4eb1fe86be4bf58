"""Camera panel and Live view with the real simulated camera on its device worker (offscreen Qt)."""

from __future__ import annotations

import numpy as np
import pytest
from PySide6.QtCore import Qt

from lfstudio.gui.panels.camera import CameraPanel, simulated_position
from lfstudio.gui.settings import settings
from lfstudio.gui.state import AppState
from lfstudio.gui.views.live_view import LiveView


@pytest.fixture
def panels(qtbot):
    state = AppState()
    settings().setValue("camera/kind", "sim")
    panel = CameraPanel(state)
    live = LiveView(state)
    qtbot.addWidget(panel)
    qtbot.addWidget(live)
    panel.sim_width.setValue(320)
    panel.sim_time_scale.setValue(0.0)
    yield state, panel, live
    live.shutdown()
    panel.shutdown()


def test_connect_test_shot_reaches_live_view(qtbot, panels):
    state, panel, live = panels
    panel.connect_camera()
    assert state.devices["camera"] is panel.device
    qtbot.waitUntil(lambda: panel.status_label.text().startswith("Connected"), timeout=30000)
    with qtbot.waitSignal(state.cameraFrame, timeout=30000) as blocker:
        panel.take_test_shot()
    image, caption = blocker.args
    assert image.dtype == np.uint8 and image.ndim == 3
    assert live.frame is not None and live.frame.shape == image.shape
    assert "test shot" in caption and ".dng" in panel.shot_label.text()
    assert "Sharpness" in live.sharp_label.text() and live.stats.sharpness > 0
    panel.disconnect_camera()
    assert "camera" not in state.devices


def test_live_view_polls_preview_through_the_worker(qtbot, panels):
    state, panel, live = panels
    live.live_button.setChecked(True)               # no camera yet: refused with a message
    qtbot.waitUntil(lambda: not live.live_button.isChecked(), timeout=5000)
    assert "Camera panel" in live.message.text()
    panel.connect_camera()
    qtbot.waitUntil(lambda: panel.status_label.text().startswith("Connected"), timeout=30000)
    live.live_button.setChecked(True)
    qtbot.waitUntil(lambda: live.caption == "live", timeout=30000)
    assert live.frame.shape[1] <= 640
    assert live.live_action.isChecked()
    live.live_button.setChecked(False)


def test_clipping_warning_and_overlay(qtbot, panels):
    _, _, live = panels
    frame = np.full((60, 80, 3), 120, np.uint8)
    frame[:20] = 255
    live.show_frame(frame, "synthetic")
    assert "highlights clipped" in live.clip_label.text()
    shown = live.image_item.image
    assert tuple(shown[0, 0]) == (255, 0, 0)            # clipped pixels painted red
    live.clip_check.setChecked(False)
    assert tuple(live.image_item.image[0, 0]) == (255, 255, 255)
    live.show_frame(np.full((60, 80, 3), 120, np.uint8), "ok")
    assert "Exposure OK" in live.clip_label.text()


def test_hot_folder_needs_a_folder_and_settings_persist(qtbot, panels):
    state, panel, _ = panels
    panel.kind.setCurrentIndex(panel.kind.findData("folder"))
    errors = []
    state.errorOccurred.connect(lambda title, message: errors.append(message))
    panel.folder_edit.setText("")
    panel.connect_camera()
    assert errors and "Folder" in errors[0] and not panel.connected
    assert settings().value(panel.kind_key) == "folder"
    panel.trigger_edit.setText('tool "unterminated')
    panel.folder_edit.setText("/tmp")
    panel.connect_camera()
    assert "Trigger command" in errors[-1]


def test_simulated_position_follows_the_rig_simulator():
    state = AppState()
    pos = simulated_position(state)
    assert pos() == (0.0, 0.0)

    class FakeSim:                                    # stands in for the GRBL simulator's one method
        def true_position_mm(self):
            return (12.5, 3.0)
    state.set_device("rig_simulator", FakeSim())
    assert pos() == (12.5, 3.0)


def test_the_hot_folder_options_come_from_its_kinds_description(qtbot, panels, tmp_path):
    """The folder page's option rows are the kind's described options (HotFolderOptions): a bad value is
    named by its label and nothing connects; a good one reaches the driver."""
    state, panel, _ = panels
    panel.kind.setCurrentIndex(panel.kind.findData("folder"))
    assert set(panel.folder_options.fields) == {"timeout_s", "stable_s"}
    errors = []
    state.errorOccurred.connect(lambda title, message: errors.append(message))
    panel.folder_edit.setText(str(tmp_path))
    panel.folder_options.fields["stable_s"].setText("-1")
    panel.connect_camera()
    assert errors and "Unchanged for" in errors[-1] and not panel.connected
    panel.folder_options.fields["stable_s"].setText("2.5")
    panel.folder_options.fields["timeout_s"].setText("12")
    link = panel.build_link()
    try:
        assert (link.camera.stable_s, link.camera.timeout_s) == (2.5, 12.0)
    finally:
        link.close()


@pytest.mark.parametrize("width", [440, 600])
def test_a_short_page_has_no_gap_under_it_after_a_taller_one(qtbot, panels, width):
    """The kind's page takes its own height: the gphoto2 page (three lines of text) stood above an
    empty gap ~150 px tall at 1366 x 768, the height of the simulated camera's or GenICam's page,
    because QStackedWidget answers the height for a width with the tallest page's."""
    _, panel, _ = panels
    panel.resize(width, 700)
    panel.show()
    qtbot.waitExposed(panel)
    for kind in ("sim", "genicam", "gphoto2"):
        panel.kind.setCurrentIndex(panel.kind.findData(kind))
        panel.layout().activate()
        page = panel.pages.currentWidget()
        need = page.heightForWidth(panel.pages.width()) if page.hasHeightForWidth() else page.sizeHint().height()
        assert panel.pages.height() <= need + 2, kind
        gap = panel.connect_button.geometry().top() - panel.pages.geometry().bottom()
        assert gap < 30, (kind, gap)


def test_the_exposure_box_is_only_for_the_cameras_it_sets(qtbot, panels):
    """ISO, Shutter and Aperture with Apply to camera are for the simulated and the USB (gphoto2) camera; a
    hot folder's camera is set in its own software (its Apply stayed greyed out, the three fields did
    nothing) and a GenICam camera shows its own settings."""
    _, panel, _ = panels
    shown = {}
    for kind in ("sim", "gphoto2", "folder", "genicam"):
        panel.kind.setCurrentIndex(panel.kind.findData(kind))
        shown[kind] = not panel.exposure_group.isHidden()
    assert shown == {"sim": True, "gphoto2": True, "folder": False, "genicam": False}


def test_the_hot_folder_rows_line_up(qtbot, panels):
    """Folder, Trigger command and the kind's option rows share one label column: the option rows'
    fields stood 7 px to the right of Folder's (a form nested in a form)."""
    _, panel, _ = panels
    panel.kind.setCurrentIndex(panel.kind.findData("folder"))
    panel.resize(440, 700)
    panel.show()
    qtbot.waitExposed(panel)
    panel.layout().activate()
    lefts = {panel.folder_edit.mapTo(panel, panel.folder_edit.rect().topLeft()).x(),
             panel.trigger_edit.mapTo(panel, panel.trigger_edit.rect().topLeft()).x(),
             *(edit.mapTo(panel, edit.rect().topLeft()).x() for edit in panel.folder_options.fields.values())}
    assert len(lefts) == 1, lefts
    order, w = [], panel.kind                          # and Tab goes down the rows
    while len(order) < 5:
        w = w.nextInFocusChain()
        if w.isVisible() and w.isEnabled() and w.focusPolicy() & Qt.FocusPolicy.TabFocus:
            order.append(w)
    assert order == [panel.folder_edit, order[1], panel.trigger_edit, *panel.folder_options.fields.values()]
    assert order[1].text() == "Browse…"


def test_a_hot_folder_wait_saved_by_an_earlier_version_is_kept(qtbot):
    """The hot folder's 'Wait for the file' was saved as camera/hot_timeout_s until its page was made from
    the kind's description (devices/folder/timeout_s): an operator's 120 s for slow vendor software fell
    back to the 30 s default after the update, and captures timed out. The old value is taken over once."""
    s = settings()
    s.setValue("camera/kind", "folder")
    s.setValue("camera/hot_timeout_s", 120.0)
    s.remove("devices/folder/timeout_s")
    s.sync()
    panel = CameraPanel(AppState())
    qtbot.addWidget(panel)
    try:
        assert panel.folder_options.options() == {"timeout_s": 120.0}
        assert panel.folder_options.fields["timeout_s"].text() == "120"
    finally:
        panel.shutdown()
    again = settings()
    assert not again.contains("camera/hot_timeout_s")           # taken over once: the form's key holds it now
    assert again.value("devices/folder/timeout_s") == "120"
