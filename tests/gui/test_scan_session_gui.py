"""The window's scan runs a studio ScanSession: the "Resume it now?" offer never silently continues on
other devices (the simulated studio included), and a dataset or port another process holds is
refused naming it (real processes, real Qt event loop)."""

from __future__ import annotations

import os
import tty

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QMessageBox

from lfstudio.dataset import Dataset
from lfstudio.gui.panels.rig import RigPanel
from lfstudio.gui.panels.scan import ACTIVE_KEY, ScanPanel
from lfstudio.gui.settings import settings
from lfstudio.gui.state import AppState
from tests.support.test_locks import hold_in_child
from tests.studio.test_scan_processes import partial_dataset


def click(qtbot, box, which) -> None:
    qtbot.mouseClick(box.button(which), Qt.LeftButton)


def test_resume_offer_on_other_devices_asks_first_and_records_the_change(qtbot, tmp_path):
    ds = partial_dataset(tmp_path / "half", "instant", "instant", 2)        # captured on other devices
    manifest = (ds.root / "dataset.json").read_bytes()
    settings().setValue(ACTIVE_KEY, str(ds.root))
    state = AppState(simulated=True)                   # the window has only the simulated studio
    panel = ScanPanel(state)
    qtbot.addWidget(panel)
    panel.time_scale.setValue(0.0)
    try:
        qtbot.waitUntil(lambda: getattr(panel, "resume_box", None) is not None and panel.resume_box.isVisible(),
                        timeout=5000)
        click(qtbot, panel.resume_box, QMessageBox.Yes)
        qtbot.waitUntil(lambda: getattr(panel, "device_change_box", None) is not None
                        and panel.device_change_box.isVisible(), timeout=60000)
        text = panel.device_change_box.text()
        assert "the instant rig and the instant camera" in text and "simulated" in text
        panel.device_change_box.grab().save("/tmp/studio-device-change.png")
        assert panel.engine is None and (ds.root / "dataset.json").read_bytes() == manifest   # nothing ran
        errors = []
        state.errorOccurred.connect(lambda title, message: errors.append(message))
        click(qtbot, panel.device_change_box, QMessageBox.Yes)
        qtbot.waitUntil(lambda: "Finished" in panel.state_label.text() or bool(errors), timeout=60000)
        assert not errors
        resumed = Dataset.open(ds.root)
        assert resumed.status_counts()["done"] == 6
        assert [c["devices"]["camera"]["kind"] for c in resumed.manifest["device_changes"]] == ["sim"]
        assert sum(1 for v in resumed.views if (v.get("devices") or {}).get("rig", {}).get("kind") == "sim") == 4
    finally:
        panel.shutdown()


def test_window_refuses_a_dataset_and_a_port_another_process_holds(qtbot, tmp_path):
    ds = partial_dataset(tmp_path / "busy", "instant", "instant", 2)
    manifest = (ds.root / "dataset.json").read_bytes()
    holder = hold_in_child("dataset_lock", ds.root)
    master, slave = os.openpty()
    tty.setraw(slave)
    port = os.ttyname(slave)
    port_holder = hold_in_child("port_lock", port)
    try:
        settings().setValue(ACTIVE_KEY, str(ds.root))
        state = AppState(simulated=True)
        panel = ScanPanel(state)
        qtbot.addWidget(panel)
        # not offered for resume: it is not interrupted, another lfstudio is scanning it
        qtbot.waitUntil(lambda: f"pid {holder.pid}" in panel.log_view.toPlainText(), timeout=5000)
        assert getattr(panel, "resume_box", None) is None
        panel.folder.setText(str(ds.root))
        panel.columns.setValue(3)
        panel.rows.setValue(2)
        panel.spacing_h.setValue(4.0)
        panel.spacing_v.setValue(6.0)
        panel.time_scale.setValue(0.0)
        with qtbot.waitSignal(state.errorOccurred, timeout=60000) as error:
            panel.start()
        assert f"dataset {ds.root} is in use by" in error.args[1] and f"pid {holder.pid}" in error.args[1]
        assert (ds.root / "dataset.json").read_bytes() == manifest
        panel.shutdown()

        rig = RigPanel(state)
        qtbot.addWidget(rig)
        rig.port_combo.setEditText(port)
        with qtbot.waitSignal(state.errorOccurred, timeout=10000) as error:
            rig.connect_rig()
        assert f"rig port {port} is in use by" in error.args[1] and f"pid {port_holder.pid}" in error.args[1]
        assert not rig.connected
        rig.shutdown()
    finally:
        for proc in (holder, port_holder):
            proc.kill()
            proc.wait(10)
            proc.stdin.close()
            proc.stdout.close()
        os.close(master)
        os.close(slave)
