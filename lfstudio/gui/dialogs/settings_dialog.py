"""File → Settings…: default folders and default camera, lens and rig presets (QSettings).

OK stores the values (:mod:`lfstudio.gui.preferences`) and applies them to the open window: the
Scan panel's dataset folder moves into the datasets folder (unless a scan runs), the Planner
switches to the chosen presets, the Rig panel to the chosen rig profile (when disconnected).
"""

from __future__ import annotations

import logging
from pathlib import Path

from PySide6.QtWidgets import (QComboBox, QDialog, QDialogButtonBox, QFileDialog, QFormLayout, QGroupBox,
                               QHBoxLayout, QLabel, QLineEdit, QPushButton, QVBoxLayout, QWidget)

from lfstudio.errors import InputError
from lfstudio.gui import preferences
from lfstudio.gui.path_field import expand_on_edit, field_path
from lfstudio.gui.settings import settings

log = logging.getLogger(__name__)
KEEP = "(keep the current plan's)"


class SettingsDialog(QDialog):
    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.setObjectName("settingsDialog")
        self.setWindowTitle("lfstudio settings")

        folders = QGroupBox("Folders")
        form = QFormLayout(folders)
        self.datasets_edit = self._folder_row(form, "Datasets", str(preferences.datasets_folder()),
                                              "New scans are created in this folder; Open dataset starts here")
        export = preferences.export_folder()
        self.export_edit = self._folder_row(form, "Exports", str(export) if export else "",
                                            "File → Export dataset… writes here by default (it also remembers "
                                            "the last folder you exported to); empty: next to the dataset")
        self.export_edit.setPlaceholderText("next to the dataset")

        presets = QGroupBox("Defaults for new plans")
        pform = QFormLayout(presets)
        self.preset_combos: dict[str, QComboBox] = {}
        for kind, label, tip in (("cameras", "Camera", "The camera preset the Planner switches to"),
                                 ("lenses", "Lens", "The lens preset the Planner switches to"),
                                 ("rigs", "Rig", "The rig preset of the Planner and the Rig panel's profile")):
            combo = QComboBox()
            combo.setObjectName(f"default_{kind}")
            combo.addItem(KEEP, "")
            for name in _preset_names(kind):
                combo.addItem(name, name)
            index = combo.findData(preferences.default_preset(kind))
            combo.setCurrentIndex(max(index, 0))
            combo.setToolTip(f"{tip} (your own presets go in ~/.config/lfstudio/presets/{kind}.toml)")
            pform.addRow(label, combo)
            self.preset_combos[kind] = combo

        from lfstudio.support.logs import log_dir

        info = QLabel(f"Lengths are shown in millimetres (the rig's units).<br>Log files: <code>{log_dir()}</code> "
                      "(Help → Show log folder)")
        info.setWordWrap(True)

        from lfstudio.gui.unattended import UnattendedBox

        self.unattended = UnattendedBox()          # notifications, status page, auto-resume, end of the day
        self.problem = QLabel("")
        self.problem.setObjectName("settingsProblem")
        self.problem.setWordWrap(True)
        self.problem.setStyleSheet("color: #e06060")
        self.problem.hide()

        buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel)
        buttons.button(QDialogButtonBox.StandardButton.Ok).setToolTip("Store these settings and apply them to the open panels")
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        lay = QVBoxLayout(self)
        lay.addWidget(folders)
        lay.addWidget(presets)
        lay.addWidget(self.unattended)
        lay.addWidget(info)
        lay.addWidget(self.problem)
        lay.addStretch(1)
        lay.addWidget(buttons)
        self.resize(620, 10)

    def accept(self) -> None:
        """OK: only with well-formed unattended-scan settings (the problem is shown, naming the field)."""
        problem = self.unattended.check()
        if problem:
            self.problem.setText(problem)
            self.problem.show()
            return
        super().accept()

    def _folder_row(self, form: QFormLayout, label: str, value: str, tip: str) -> QLineEdit:
        edit = QLineEdit(value)
        edit.setObjectName(f"{label.lower()}Folder")
        edit.setToolTip(tip)
        expand_on_edit(edit, label)
        browse = QPushButton("Browse…")
        browse.setToolTip(f"Choose the {label.lower()} folder")
        browse.clicked.connect(lambda: self._browse(edit, label))
        row = QHBoxLayout()
        row.addWidget(edit, 1)
        row.addWidget(browse)
        form.addRow(label, row)
        return edit

    def _browse(self, edit: QLineEdit, label: str) -> None:
        folder = QFileDialog.getExistingDirectory(self, f"{label} folder", edit.text())
        if folder:
            edit.setText(folder)

    def values(self) -> dict[str, str]:
        out = {preferences.DATASETS_KEY: _typed(self.datasets_edit, "Datasets"),
               preferences.EXPORT_KEY: _typed(self.export_edit, "Exports")}
        for kind, combo in self.preset_combos.items():
            out[preferences.PRESET_KEYS[kind]] = str(combo.currentData() or "")
        return out

    def store(self) -> None:
        s = settings()
        for key, value in self.values().items():
            if value or key != preferences.EXPORT_KEY:
                s.setValue(key, value)
            else:
                s.remove(key)
        if self.values()[preferences.PRESET_KEYS["rigs"]]:
            s.setValue("rig/profile", self.values()[preferences.PRESET_KEYS["rigs"]])
        s.sync()
        self.unattended.store()
        log.info("settings changed: %s", self.values())


def _typed(edit: QLineEdit, label: str) -> str:
    """The folder typed in ``edit`` as the absolute path it means ("" when empty; as typed when it
    names no path, e.g. an unset variable)."""
    if not edit.text().strip():
        return ""
    try:
        return str(field_path(edit, label))
    except InputError:
        return edit.text().strip()


def _preset_names(kind: str) -> list[str]:
    from lfstudio.resources import load_presets

    try:
        return list(load_presets(kind))
    except InputError:
        return []


def apply_to_window(window, old: dict[str, str], new: dict[str, str]) -> list[str]:
    """Apply changed settings to the open panels; returns what was applied (for the status bar)."""
    done = []
    panels = getattr(window, "panels", {})
    scan = panels.get("scanPanel")
    datasets = new.get(preferences.DATASETS_KEY)
    if datasets and datasets != old.get(preferences.DATASETS_KEY):
        settings().setValue("datasets/last_dir", datasets)
        if scan is not None and not scan.running:
            current = Path(scan.folder.text().strip() or "lfstudio-scan")
            scan.folder.setText(str(Path(datasets) / current.name))
            done.append("Scan panel folder")
    planner = panels.get("plannerDock")
    for kind, key in preferences.PRESET_KEYS.items():
        name = new.get(key, "")
        if not name or name == old.get(key):
            continue
        combo = getattr(planner, "combos", {}).get({"cameras": "camera_name", "lenses": "lens_name",
                                                   "rigs": "rig_name"}[kind]) if planner is not None else None
        if combo is not None and combo.findText(name) >= 0:
            combo.setCurrentText(name)
            done.append(f"Planner {kind[:-1]}")
        rig = panels.get("rigDock")
        if kind == "rigs" and rig is not None and getattr(rig, "device", None) is None:
            combo = getattr(rig, "rig_combo", None)
            if combo is not None and combo.findText(name) >= 0:
                combo.setCurrentText(name)
                done.append("Rig profile")
    return done
