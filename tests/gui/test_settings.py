"""The settings file's typed readers, and the window's parts opening on a settings file edited by hand
(a value that is not a number gave a ValueError while the panel was built: the window did not open)."""

from __future__ import annotations

import logging

import pytest

from lfstudio.gui.settings import read_bool, read_float, read_int, read_text, settings
from lfstudio.gui.state import AppState


def test_each_reader_gives_the_stored_value_of_its_type():
    s = settings()
    s.setValue("t/int", 7)
    s.setValue("t/float", 0.25)
    s.setValue("t/bool", False)
    s.setValue("t/text", "row-meander")
    s.sync()
    s = settings()                      # read back from the file: the INI format keeps text
    assert read_int("t/int", 1, s) == 7
    assert read_float("t/float", 1.0, s) == 0.25
    assert read_bool("t/bool", True, s) is False
    assert read_text("t/text", "", s) == "row-meander"


def test_a_missing_value_gives_the_default():
    assert read_int("t/none", 3) == 3
    assert read_float("t/none", 2.5) == 2.5
    assert read_bool("t/none", True) is True
    assert read_text("t/none", "auto") == "auto"


@pytest.mark.parametrize("reader, text, default", [
    (read_int, "twelve", 12), (read_int, "8.5", 8), (read_float, "abc", 0.5), (read_float, "nan", 16.0),
    (read_float, "inf", 1.0), (read_bool, "maybe", True), (read_bool, "maybe", False)])
def test_a_value_not_of_the_type_gives_the_default_and_a_warning_naming_the_key(caplog, reader, text, default):
    s = settings()
    s.setValue("t/bad", text)
    with caplog.at_level(logging.WARNING, logger="lfstudio.gui.settings"):
        assert reader("t/bad", default, s) == default
    assert "t/bad" in caplog.text and repr(text) in caplog.text


GARBLED = {"camera/sim_width_px": "wide", "camera/sim_noise_pct": "x", "camera/shutter_s": "half",
           "camera/aperture": "nan", "devices/folder/timeout_s": "soon", "devices/folder/stable_s": "-1", "rig/step_mm": "ten", "rig/goto_x": "left",
           "liveview/fps": "fast", "liveview/clipping": "perhaps", "scan/time_scale": "slow"}


@pytest.fixture
def garbled_settings():
    s = settings()
    for key, text in GARBLED.items():
        s.setValue(key, text)
    s.setValue("camera/kind", "sim")
    s.sync()


def test_the_camera_panel_and_live_view_open_on_garbled_settings_with_the_defaults(qtbot, garbled_settings):
    from lfstudio.gui.panels.camera import CameraPanel
    from lfstudio.gui.views.live_view import LiveView

    state = AppState()
    panel = CameraPanel(state)
    qtbot.addWidget(panel)
    live = LiveView(state)
    qtbot.addWidget(live)
    assert panel.sim_width.value() == 2000
    assert panel.sim_noise.value() == pytest.approx(0.2)
    assert panel.shutter.value() == pytest.approx(0.5)
    assert panel.aperture.value() == pytest.approx(16.0)
    assert panel.folder_options.fields["timeout_s"].text() == ""            # the default shown (30 s)
    assert panel.folder_options.options() == {}                               # connects with the defaults
    assert live.fps_spin.value() == 4
    assert live.clip_check.isChecked()
    live.shutdown()
    panel.shutdown()


def test_the_rig_and_scan_panels_open_on_garbled_settings_with_the_defaults(qtbot, garbled_settings):
    from lfstudio.gui.panels.rig import RigPanel
    from lfstudio.gui.panels.scan import ScanPanel

    state = AppState(simulated=True)
    rig = RigPanel(state)
    qtbot.addWidget(rig)
    checked = [b for b in rig.step_group.buttons() if b.isChecked()]
    assert [b.property("step_mm") for b in checked] == [10.0]
    assert rig.goto_x.value() == pytest.approx(rig.rig_config.horizontal.soft_min_mm)
    scan = ScanPanel(state)
    qtbot.addWidget(scan)
    assert scan.time_scale.value() == pytest.approx(1.0)
    scan.shutdown()
    rig.shutdown()


def test_the_import_dialog_opens_on_garbled_settings_with_the_defaults(qtbot):
    from lfstudio.gui.dialogs.import_dialog import ImportImagesDialog

    s = settings()
    for key in ("columns", "intrinsics", "focal_length_mm", "zero_depth_m"):
        s.setValue(f"import_images/{key}", "?")
    s.sync()
    dialog = ImportImagesDialog(AppState())
    qtbot.addWidget(dialog)
    assert dialog.columns_spin.value() == 9
    assert dialog.intrinsics_combo.currentIndex() == 0
    assert dialog.focal_mm.value() == pytest.approx(50.0)
    assert dialog.zero_depth.value() == pytest.approx(3.0)


def test_the_settings_dialog_and_a_scan_s_options_take_the_defaults_for_garbled_unattended_values(qtbot):
    from lfstudio.gui.dialogs.settings_dialog import SettingsDialog
    from lfstudio.gui.unattended import PREFIX, load_options

    s = settings()
    s.setValue(PREFIX + "auto_resume", "twice")
    s.setValue(PREFIX + "on_finish_timeout_s", "long")
    s.sync()
    dialog = SettingsDialog()
    qtbot.addWidget(dialog)
    assert dialog.unattended.auto_resume.value() == 0
    assert dialog.unattended.timeout.value() == pytest.approx(300.0)
    options = load_options()
    assert options.auto_resume == 0 and options.on_finish_timeout_s == pytest.approx(300.0)
