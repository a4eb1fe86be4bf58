from PySide6.QtWidgets import QDockWidget

from lfstudio.gui.app import create_window
from lfstudio.gui.imageutil import qimage_to_rgb
from lfstudio.gui.panels import PANELS


def test_main_window_has_menus_and_panels(qtbot):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.show()
    qtbot.waitExposed(window)
    titles = [a.text().replace("&", "") for a in window.menuBar().actions()]
    assert titles[:3] == ["File", "View", "Rig"] and titles[-1] == "Help"
    docks = window.findChildren(QDockWidget)
    assert {d.objectName() for d in docks} == {p.object_name for p in PANELS}
    assert "simulated" in window.windowTitle()


def test_window_renders_not_blank(qtbot):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.show()
    qtbot.waitExposed(window)
    pixels = qimage_to_rgb(window.grab().toImage())
    assert pixels.std() > 5  # text, frames and panels, not a flat fill


def test_error_is_shown_not_raised(qtbot):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.report_error("Test", "something the operator must read")
    qtbot.waitUntil(lambda: "something the operator must read" in window.statusBar().currentMessage())


def test_simulated_studio_connects_rig_and_camera(qtbot):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    rig, camera = window.panels["rigDock"], window.panels["cameraDock"]
    rig.sim_time_scale = 0.02
    window.connect_simulated_studio()
    qtbot.waitUntil(lambda: window.state.devices.get("rig_simulator") is not None, timeout=10000)
    qtbot.waitUntil(lambda: camera.connected and "Connected" in camera.status_label.text(), timeout=60000)
    assert rig.connected and window.state.devices.get("rig") is rig.device
    assert window.state.devices.get("camera") is camera.device
    window.close()


def test_gui_hardware_flag(run_cli):
    from lfstudio.cli import build_parser

    assert build_parser().parse_args(["gui"]).simulated is True
    assert build_parser().parse_args(["gui", "--hardware"]).simulated is False


def test_every_menu_shortcut_is_unique(qtbot):
    """Two actions on one key make Qt fire neither ("ambiguous shortcut")."""
    from collections import Counter

    window = create_window(simulated=True)
    qtbot.addWidget(window)
    keys = Counter(a.shortcut().toString() for m in window.menuBar().actions() if m.menu()
                   for a in m.menu().actions() if not a.shortcut().isEmpty())
    assert keys and [k for k, n in keys.items() if n > 1] == []
