"""The form of a device kind (:mod:`lfstudio.studio.kinds`): its argument (what follows ``NAME:`` in the
device word) and one field per described connection option, built from the kind's own description, so
a kind added by a plugin gets its page in the Camera panel (and its options in the Rig panel) without
any code here.

Every field is text checked by the same rules as ``--camera-option NAME=VALUE``
(:func:`lfstudio.studio.kinds.parse_options`); an empty field keeps the option's default. Values are kept
per kind in the window's settings (``devices/KIND/FIELD``)."""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

from PySide6.QtCore import Signal
from PySide6.QtWidgets import QCheckBox, QComboBox, QFormLayout, QHBoxLayout, QLabel, QLineEdit, QPushButton, QWidget

from lfstudio.errors import InputError
from lfstudio.gui.settings import read_text, settings
from lfstudio.studio.kinds import CameraKind, RigKind, parse_options

log = logging.getLogger(__name__)


class KindForm(QWidget):
    """The argument and options of ``kind`` (see the module docstring); once a camera is connected, its
    described settings as data and one row to change any of them (``settingRequested(name, value)``)."""

    settingRequested = Signal(str, object)

    def __init__(self, kind: CameraKind | RigKind, parent: QWidget | None = None, *, argument: bool = True):
        """``argument``: a field for what follows ``NAME:`` (False: the panel has its own, the Rig panel's
        Port field)."""
        super().__init__(parent)
        self.kind = kind
        s = settings()
        form = QFormLayout(self)
        form.setContentsMargins(0, 0, 0, 0)
        about = kind.help or kind.label or kind.name          # a sentence of its own here: a capital first
        info = self.info = QLabel(about[:1].upper() + about[1:] + ("" if kind.origin == "built-in" else
                                                                   f" <i>({kind.origin})</i>"))
        info.setWordWrap(True)
        form.addRow(info)
        self.argument: QLineEdit | None = None
        #: the argument's field label: "ID", "Path", "Arguments"
        self.argument_label = kind.argument if len(kind.argument) <= 3 else kind.argument.capitalize()
        if kind.argument and argument:
            self.argument = QLineEdit(read_text(self._key("argument"), "", s))
            self.argument.setObjectName(f"{kind.name}-argument")
            self.argument.setPlaceholderText(f"required: the {kind.argument}")    # no "genicam:" (typed, it was doubled)
            self.argument.setToolTip(f"The {kind.argument} alone: what follows '{kind.name}:' in the device word")
            form.addRow(self.argument_label, self.argument)
        self.fields: dict[str, QLineEdit] = {}
        self.flags: dict[str, QCheckBox] = {}          # true/false options: a check box (ticked: true)
        if kind.options is not None:
            for f in dataclasses.fields(kind.options):
                param = f.metadata.get("lfstudio.param")
                if param is None:
                    continue
                if param.flag:
                    box = QCheckBox(param.label or f.name)
                    box.setObjectName(f"{kind.name}-{f.name}")
                    saved = read_text(self._key(f.name), "", s) if param.remember else ""
                    box.setChecked(saved == "true" or (saved == "" and f.default is True))
                    box.setToolTip(param.tip)
                    form.addRow("", box)
                    self.flags[f.name] = box
                    continue
                edit = QLineEdit(self._saved(f.name, s))
                edit.setObjectName(f"{kind.name}-{f.name}")
                default = param.to_text(f.default) if f.default is not dataclasses.MISSING else ""
                edit.setPlaceholderText(default)
                unit = param.number.unit if param.number is not None else ""
                edit.setToolTip(f"{param.tip} (valid: {param.valid()}; empty: {default or 'required'})")
                form.addRow(f"{param.label or f.name}" + (f" ({unit})" if unit else ""), edit)
                self.fields[f.name] = edit
        self.settings_label = QLabel("")
        self.settings_label.setWordWrap(True)
        self.settings_label.setVisible(False)          # an empty row left a gap above the panel's Connect
        form.addRow(self.settings_label)
        self.setting_name = QComboBox()
        self.setting_name.setObjectName(f"{kind.name}-setting")
        self.setting_name.setToolTip("A setting the connected camera offers")
        self.setting_value = QComboBox()
        self.setting_value.setEditable(True)
        self.setting_value.setObjectName(f"{kind.name}-setting-value")
        self.setting_value.setToolTip("Its new value: one of the camera's choices, or a number in its range")
        self.set_button = QPushButton("Set")
        self.set_button.setToolTip("Send this setting to the connected camera")
        row = QHBoxLayout()
        row.addWidget(self.setting_name, 2)
        row.addWidget(self.setting_value, 2)
        row.addWidget(self.set_button)
        self.setting_row = QWidget()
        self.setting_row.setLayout(row)
        row.setContentsMargins(0, 0, 0, 0)
        self.setting_row.setVisible(False)
        form.addRow(self.setting_row)
        self._described: dict[str, Any] = {}
        self.setting_name.currentIndexChanged.connect(lambda _i: self._fill_value())
        self.set_button.clicked.connect(self._request)

    def _key(self, name: str) -> str:
        return f"devices/{self.kind.name}/{name}"

    def _saved(self, name: str, s: Any) -> str:
        """The text saved for field ``name``; a saved text its option refuses (a garbled settings file)
        is dropped with a warning naming the key, so the field shows its default."""
        text = read_text(self._key(name), "", s).strip()
        if text:
            try:
                parse_options(self.kind, {name: text}, option=name)
            except InputError as exc:
                log.warning("settings: %s = %r is not valid (%s); using the default", self._key(name), text, exc)
                return ""
        return text

    def _param(self, name: str) -> Any:
        return next(f.metadata["lfstudio.param"] for f in dataclasses.fields(self.kind.options)
                    if f.name == name)

    def label_of(self, name: str) -> str:
        for f in dataclasses.fields(self.kind.options) if self.kind.options is not None else ():
            if f.name == name:
                param = f.metadata.get("lfstudio.param")
                return param.label if param is not None and param.label else name
        return name

    def word(self) -> str:
        """The device word the form names (InputError naming the argument field when it is needed and empty)."""
        if self.argument is None:
            return self.kind.name
        text = self.argument.text().strip()
        if text.lower().startswith(f"{self.kind.name}:"):     # the whole device word typed: its argument
            text = text[len(self.kind.name) + 1:].strip()
        if not text:
            raise InputError(self.argument_label, f"the {self.kind.label or self.kind.name} needs its "
                             f"{self.kind.argument}: type it in the {self.argument_label} field")
        return f"{self.kind.name}:{text}"

    def options(self) -> dict[str, Any]:
        """The options typed (empty fields left out) and the ticked check boxes, checked; InputError naming
        the field's label."""
        out: dict[str, Any] = {name: True for name, box in self.flags.items() if box.isChecked()}
        for name, edit in self.fields.items():
            text = edit.text().strip()
            if not text:
                continue
            try:
                out.update(parse_options(self.kind, {name: text}, option=self.label_of(name)))
            except InputError as exc:      # named by the field's label, as the form shows it
                raise InputError(self.label_of(name), str(exc).split(": ", 1)[-1]) from None
        return out

    def save(self) -> None:
        """Remember the fields for the next time; a flag that is an act on one connection (``remember``
        False: Keep drive reference) is never saved and is unticked here, once used."""
        s = settings()
        if self.argument is not None:
            s.setValue(self._key("argument"), self.argument.text())
        for name, edit in self.fields.items():
            s.setValue(self._key(name), edit.text())
        for name, box in self.flags.items():
            if self._param(name).remember:
                s.setValue(self._key(name), "true" if box.isChecked() else "false")
            else:
                box.setChecked(False)

    def show_settings(self, described: Any) -> None:
        """The connected camera's settings as data: name, value, its choices or range."""
        lines = []
        for d in described or ():
            extra = (f" ({', '.join(map(str, d.choices))})" if getattr(d, "choices", ()) else
                     f" ({d.range[0]:g} … {d.range[1]:g})" if getattr(d, "range", None) else "")
            unit = f" {d.unit}" if getattr(d, "unit", "") else ""
            lines.append(f"{d.label}: {d.value}{unit}{extra}")
        self.settings_label.setText("\n".join(lines))
        self.settings_label.setVisible(bool(lines))
        chosen = self.setting_name.currentData()
        self._described = {d.name: d for d in described or () if not getattr(d, "read_only", False)}
        self.setting_name.blockSignals(True)
        self.setting_name.clear()
        for d in self._described.values():
            self.setting_name.addItem(d.label, d.name)
        index = self.setting_name.findData(chosen)
        self.setting_name.setCurrentIndex(max(0, index))
        self.setting_name.blockSignals(False)
        self._fill_value()
        self.setting_row.setVisible(bool(self._described))

    def set_editable(self, connection: bool, settings: bool) -> None:
        """The argument and options (fixed while connected) and the settings row (while the camera is
        free) enabled or not."""
        for edit in ([self.argument] if self.argument is not None else []) + list(self.fields.values()):
            edit.setEnabled(connection)
        for box in self.flags.values():
            box.setEnabled(connection)
        self.setting_row.setEnabled(settings)

    def clear_settings(self) -> None:
        """The camera is gone: no settings to show or change."""
        self.settings_label.setText("")
        self.settings_label.setVisible(False)
        self._described = {}
        self.setting_row.setVisible(False)

    def _fill_value(self) -> None:
        d = self._described.get(str(self.setting_name.currentData()))
        self.setting_value.clear()
        if d is None:
            return
        for choice in getattr(d, "choices", ()) or ():
            self.setting_value.addItem(str(choice))
        self.setting_value.setEditText(str(d.value))

    def _request(self) -> None:
        name = str(self.setting_name.currentData() or "")
        d = self._described.get(name)
        if d is None:
            return
        text = self.setting_value.currentText().strip()
        value: Any = text
        if d.type in ("float", "int"):
            try:
                value = int(text) if d.type == "int" else float(text)
            except ValueError:
                value = text            # the camera's own check names it
        self.settingRequested.emit(name, value)
