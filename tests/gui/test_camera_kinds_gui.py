"""The Camera panel lists every registered camera kind with a form built from its described options: the
GenICam camera (aravis's fake GigE Vision camera over the real protocol) connected, described and shot
through it; a bad option named by its field's label (offscreen Qt, real loop and worker)."""

from __future__ import annotations

import pytest

from lfstudio.gui.panels.camera import CameraPanel
from lfstudio.gui.settings import settings
from lfstudio.gui.state import AppState


@pytest.fixture
def panel(qtbot):
    state = AppState()
    panel = CameraPanel(state)
    qtbot.addWidget(panel)
    panel.kind.setCurrentIndex(panel.kind.findData("genicam"))
    yield state, panel
    panel.shutdown()


def test_the_genicam_kind_has_a_form_from_its_options(qtbot, panel):
    state, panel = panel
    assert panel.current_kind() == "genicam"
    assert panel.kind.currentText() == "Machine-vision camera (GenICam)"
    form = panel.forms["genicam"]
    assert set(form.fields) == {"timeout_s", "retries", "packet_size", "buffers"}
    assert form.fields["packet_size"].placeholderText() == "auto"
    assert "576 … 65536 B" in form.fields["packet_size"].toolTip()
    errors: list[str] = []
    state.errorOccurred.connect(lambda _title, message: errors.append(message))
    assert form.argument is not None
    form.argument.setText("")
    panel.connect_camera()
    assert errors[-1].startswith("ID: the Machine-vision camera (GenICam) needs its ID") and not panel.connected
    form.argument.setText("Aravis-Fake-GV01")
    form.fields["packet_size"].setText("12")
    panel.connect_camera()
    assert errors[-1].startswith("Packet size: 12 B is out of range") and not panel.connected
    panel.grab().save("/tmp/kinds39-camera-panel-genicam.png")


def test_the_fake_genicam_camera_connects_shows_its_nodes_and_takes_a_test_shot(qtbot, panel):
    from tests.fakegv import fake_gv_camera

    state, panel = panel
    form = panel.forms["genicam"]
    assert form.argument is not None
    with fake_gv_camera() as fake:
        form.argument.setText(fake.device_id)
        form.fields["timeout_s"].setText("3")
        panel.connect_camera()
        qtbot.waitUntil(lambda: panel.status_label.text().startswith("Connected"), timeout=30000)
        qtbot.waitUntil(lambda: "Pixel format: Mono8" in form.settings_label.text(), timeout=10000)
        assert "Trigger source: Software (Line0, Software)" in form.settings_label.text()
        assert not panel.apply_button.isEnabled() and panel.exposure_group.isHidden()   # a DSLR's exposure
        assert not form.setting_row.isHidden() and form.set_button.isEnabled()
        assert not form.argument.isEnabled()                             # the connection is fixed while connected
        form.setting_name.setCurrentIndex(form.setting_name.findData("pixel_format"))
        assert form.setting_value.findText("BayerRG8") >= 0             # the camera's own choices
        form.setting_value.setEditText("BayerRG8")
        form.set_button.click()
        qtbot.waitUntil(lambda: "Pixel format: BayerRG8" in form.settings_label.text(), timeout=10000)
        form.setting_name.setCurrentIndex(form.setting_name.findData("exposure_s"))
        form.setting_value.setEditText("100")                            # beyond its 10 s
        form.set_button.click()
        qtbot.waitUntil(lambda: "out of the camera's range" in panel.status_label.text(), timeout=10000)
        with qtbot.waitSignal(state.cameraFrame, timeout=30000):
            panel.take_test_shot()
        assert ".dng" in panel.shot_label.text()                         # Bayer kept raw
        form.setting_name.setCurrentIndex(form.setting_name.findData("pixel_format"))
        form.setting_value.setEditText("Mono8")
        form.set_button.click()
        qtbot.waitUntil(lambda: "Pixel format: Mono8" in form.settings_label.text(), timeout=10000)
        with qtbot.waitSignal(state.cameraFrame, timeout=30000):
            panel.take_test_shot()
        assert ".png" in panel.shot_label.text()
        panel.resize(420, 700)
        panel.grab().save("/tmp/kinds39-camera-panel-genicam-connected.png")
        panel.disconnect_camera()
        assert form.setting_row.isHidden() and form.settings_label.text() == ""
    assert settings().value("devices/genicam/argument") == fake.device_id


def test_the_id_field_takes_the_id_and_shows_no_empty_row(qtbot, panel):
    """The ID field showed 'genicam:ID' as its example and its error said '(valid: genicam:ID)': an
    operator typing that got the device word 'genicam:genicam:…'. The field takes the ID; the whole word
    typed is read as its ID. The settings row, empty until a camera is connected, is hidden (it left a
    gap above Connect)."""
    state, panel = panel
    form = panel.forms["genicam"]
    assert form.argument is not None
    assert "genicam:" not in form.argument.placeholderText()
    form.argument.setText("genicam:Aravis-Fake-GV01")
    assert form.word() == "genicam:Aravis-Fake-GV01"
    form.argument.setText(" Aravis-Fake-GV01 ")
    assert form.word() == "genicam:Aravis-Fake-GV01"
    errors: list[str] = []
    state.errorOccurred.connect(lambda _title, message: errors.append(message))
    form.argument.setText("genicam:")
    panel.connect_camera()
    assert errors and "ID field" in errors[-1] and "genicam:" not in errors[-1] and not panel.connected
    panel.resize(440, 700)
    panel.show()
    qtbot.waitExposed(panel)
    assert form.settings_label.isHidden()
    form.show_settings([])
    assert form.settings_label.isHidden()
