"""Unattended scans in the window: Settings → Unattended scans (checked, stored), a Scan panel scan
that notifies a real local receiver and serves the status page, a bad setting refused at Start, the
desktop notification on a private session D-Bus."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import threading
import urllib.request

import pytest

from lfstudio.gui.settings import settings
from lfstudio.gui.unattended import NAMES, PREFIX, desktop_notify, load_options
from tests.gui.test_scan_gui import scan_panel, start_then_pause
from tests.scan.receivers import Receiver


@pytest.fixture
def receiver():
    r = Receiver()
    yield r
    r.close()


def set_unattended(**values):
    s = settings()
    for key, value in values.items():
        s.setValue(PREFIX + key, value)
    s.sync()


@pytest.fixture(autouse=True)
def clean_settings():
    yield
    s = settings()
    s.remove("unattended")
    s.sync()


def test_settings_refuse_a_bad_url_naming_the_field_then_store(qtbot, tmp_path):
    from lfstudio.gui.dialogs.settings_dialog import SettingsDialog

    dialog = SettingsDialog()
    qtbot.addWidget(dialog)
    box = dialog.unattended
    box.notify.setPlainText("https://hooks.example.com/services/T0/B0/xyz\nftp://files.example.com/x")
    box.status.setChecked(True)
    box.address.setText("0.0.0.0:8765")
    box.auto_resume.setValue(3)
    box.on_finish.setText("lights off")
    box.linger.setValue(120)
    dialog.show()
    dialog.accept()
    assert dialog.isVisible() and not dialog.problem.isHidden()
    assert dialog.problem.text().startswith(f"{NAMES['notify']}: unknown scheme 'ftp'")
    dialog.grab().save(str(tmp_path / "settings.png"))
    # the rows and the refusals say the labels of the scan options' descriptions (lfstudio scan's options)
    from PySide6.QtWidgets import QFormLayout, QLabel

    from lfstudio.studio.scan_options import PARAMS

    form = box.layout()
    assert isinstance(form, QFormLayout)
    rows = []
    for i in range(form.rowCount()):
        item = form.itemAt(i, QFormLayout.ItemRole.LabelRole)
        if item is not None and isinstance(item.widget(), QLabel):
            rows.append(item.widget().text())
    for name in ("notify", "smtp", "auto_resume", "on_finish"):
        assert PARAMS[name].label in rows and NAMES[name].endswith(f"→ {PARAMS[name].label}"), name
    if os.environ.get("LFSTUDIO_KEEP_SCREENSHOT_DIR"):
        shutil.copy(tmp_path / "settings.png", os.environ["LFSTUDIO_KEEP_SCREENSHOT_DIR"])
    box.notify.setPlainText("https://hooks.example.com/services/T0/B0/xyz")
    with qtbot.waitSignal(dialog.accepted):
        dialog.accept()
    dialog.store()
    options = load_options()
    assert options.notify == ["https://hooks.example.com/services/T0/B0/xyz"]
    assert (options.status_http, options.status_token) == ("0.0.0.0:8765", "new")   # another computer: a token
    assert (options.auto_resume, options.on_finish, options.status_linger_s) == (3, "lights off", 120)


def test_a_scan_from_the_panel_notifies_and_serves_the_status_page(qtbot, tmp_path, instant_devices, receiver):
    devices, rig, cam = instant_devices
    set_unattended(notify=receiver.url("/hook"), status=True, status_address="127.0.0.1:0")
    state, panel = scan_panel(qtbot, devices, 4, 3, tmp_path / "day1")
    start_then_pause(qtbot, panel)
    server = panel.unattended.status
    with urllib.request.urlopen(server.url + "status.json", timeout=30) as reply:
        doc = json.loads(reply.read())
    assert (doc["state"], doc["total"], doc["dataset"]) == ("paused", 12, "day1")
    state.liveVerdicts.emit([{"row": 0, "column": 1, "view": "r00_c001", "verdict": "fail", "reasons": ["blurred"]}])
    assert receiver.wait_for(lambda posts: len(posts) == 3)          # the grid view's live check flagged a view
    with urllib.request.urlopen(server.url + "status.json", timeout=30) as reply:
        assert json.loads(reply.read())["flagged"] == [{"view": "r00 c001", "verdict": "fail", "reasons": ["blurred"]}]
    panel.resume()
    qtbot.waitUntil(lambda: "Finished" in panel.state_label.text(), timeout=30000)
    assert receiver.wait_for(lambda posts: len(posts) == 5)
    assert receiver.json_events() == ["started", "paused", "flagged", "resumed", "finished"]
    qtbot.waitUntil(lambda: "status page (read-only): http://127.0.0.1:" in panel.log_view.toPlainText(),
                    timeout=5000)


def test_the_panel_shows_the_pages_address_during_and_after_the_scan(qtbot, tmp_path, instant_devices):
    """#41 item 6: the window names the status page's address (click opens it, Copy copies it) and the
    page keeps serving the final state after the scan; the next scan takes the port back."""
    from PySide6.QtGui import QGuiApplication

    devices, rig, cam = instant_devices
    set_unattended(status=True, status_address="127.0.0.1:0", status_linger_s=600)
    state, panel = scan_panel(qtbot, devices, 3, 2, tmp_path / "day1")
    panel.resize(1366 // 3, 700)
    start_then_pause(qtbot, panel)
    server = panel.unattended.status
    assert panel.status_page.isVisibleTo(panel) and server.url in panel.status_page.text()
    panel.status_page.linkActivated.emit("copy")
    assert QGuiApplication.clipboard().text() == server.url
    panel.resume()
    qtbot.waitUntil(lambda: "Finished" in panel.state_label.text(), timeout=30000)
    assert panel.unattended is None and panel.status_page.server is server
    assert "the final state, until" in panel.status_page.text() and panel.status_page.isVisibleTo(panel)
    qtbot.waitUntil(lambda: server.board.serving_until is not None, timeout=30000)   # close() made it linger
    with urllib.request.urlopen(server.url + "status.json", timeout=30) as reply:
        doc = json.loads(reply.read())
    assert (doc["outcome"], doc["done"], doc["total"]) == ("finished", 6, 6) and doc["ended"]
    if (shots := os.environ.get("LFSTUDIO_KEEP_SCREENSHOT")):
        panel.grab().save(os.path.join(shots, "scan-panel-status-page.png"))
    panel.shutdown()                                     # the window closes: so does the page
    assert server.wait_closed(30) and not panel.status_page.isVisibleTo(panel)


def test_a_port_in_use_refuses_to_start_naming_the_setting(qtbot, tmp_path, instant_devices):
    devices, rig, cam = instant_devices
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        set_unattended(status=True, status_address=f"127.0.0.1:{port}")
        state, panel = scan_panel(qtbot, devices, 3, 2, tmp_path / "day1")
        with qtbot.waitSignal(state.errorOccurred) as error:
            panel.start()
    assert error.args[1].startswith(f"{NAMES['status_http']}: port {port} on 127.0.0.1 is in use")
    assert panel.engine is None and not (tmp_path / "day1").exists() and panel.start_button.isEnabled()


def test_desktop_notification_on_a_private_session_bus(monkeypatch):
    daemon, monitor_tool = shutil.which("dbus-daemon"), shutil.which("dbus-monitor")
    if daemon is None or monitor_tool is None or shutil.which("gdbus") is None:
        pytest.skip("dbus-daemon, dbus-monitor or gdbus is not installed")
    bus = subprocess.Popen([daemon, "--session", "--nofork", "--print-address"], stdout=subprocess.PIPE, text=True)
    try:
        address = bus.stdout.readline().strip()
        monkeypatch.setenv("DBUS_SESSION_BUS_ADDRESS", address)
        monitor = subprocess.Popen([monitor_tool, "--address", address, "interface='org.freedesktop.Notifications'"],
                                   stdout=subprocess.PIPE, text=True)
        lines: list[str] = []
        seen = threading.Event()

        def read():
            for line in monitor.stdout:
                lines.append(line)
                if "int32 -1" in line:
                    seen.set()
        threading.Thread(target=read, daemon=True).start()
        ready = threading.Event()
        # the monitor is listening once its own NameAcquired/NameLost arrived: poke the bus until a call shows
        for _ in range(50):
            assert desktop_notify("Scan of day1 paused", "Disk almost full (10 of 2121 views)", urgent=True)
            if seen.wait(0.5):
                ready.set()
                break
        assert ready.is_set(), "".join(lines)
        text = "".join(lines)
        assert "member=Notify" in text and 'string "Scan of day1 paused"' in text
        assert "uint32 0" in text and "byte 2" in text and 'string "Disk almost full (10 of 2121 views)"' in text
        monitor.terminate()
        monitor.wait(10)
    finally:
        bus.terminate()
        bus.wait(10)


def test_no_session_bus_means_no_desktop_notification(monkeypatch):
    monkeypatch.delenv("DBUS_SESSION_BUS_ADDRESS", raising=False)
    assert desktop_notify("Scan of day1 finished", "done") is False
