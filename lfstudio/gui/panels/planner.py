"""The scene planner: inputs with units and ranges, live outputs, warnings next to their field, and
the "Plan plots" dock (depth of field and disparity against depth).

The panel builds a :class:`~lfstudio.planning.scene_plan.ScenePlan` from its fields on every edit
(debounced), derives it, shows the outputs and publishes valid plans with ``state.set_plan``.
The plots panel draws whatever plan the state holds.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import (QAbstractSpinBox, QBoxLayout, QComboBox, QDoubleSpinBox, QFileDialog, QFrame, QGridLayout,
                               QGraphicsItem, QGroupBox, QHBoxLayout, QLabel, QLineEdit, QPushButton, QScrollArea, QSizePolicy,
                               QSpinBox, QVBoxLayout, QWidget)

from lfstudio.errors import InputError, LfError
from lfstudio.jobs import format_duration
from lfstudio import optics
from lfstudio.planning.presets import (camera_fields, lens_fields, reference_plan, rig_fields)
from lfstudio.planning.scene_plan import PARAMS, PlanResult, ScenePlan, load_plan, save_plan
from lfstudio.scan.preflight import MIN_FREE_BYTES, disk_shortfall, view_size
from lfstudio.resources import load_presets

log = logging.getLogger(__name__)

SETTINGS_KEY = "planner/plan"
CUSTOM = "Custom"
DEBOUNCE_MS = 80

_PANEL_STYLE = """
QComboBox[severity="error"] { color: #b00020; }
QLabel[mark="error"] { color: #b00020; font-weight: 600; }
QLabel[mark="warning"] { color: #8a4b00; font-weight: 600; }
QLabel[msg="error"] { color: #b00020; }
QLabel[msg="warning"] { color: #9a5b00; }
QLabel[msg="info"] { color: #4a5a70; }
QLabel#planStatus[ok="true"] { color: #1b6e2a; font-weight: 600; }
QLabel#planStatus[ok="false"] { color: #b00020; font-weight: 600; }
QLabel[role="value"] { font-family: "DejaVu Sans Mono", monospace; }
QLabel[role="value"][flag="bad"] { color: #b00020; }
QLabel[role="value"][flag="warn"] { color: #9a5b00; }
QLabel[role="outlabel"] { color: #3c4450; }
"""

_SEVERITY_RANK = {"info": 0, "warning": 1, "error": 2}


@dataclass(frozen=True)
class _Input:
    """One input row: the ScenePlan attribute(s) it edits and how."""

    key: str                    # row key (= ScenePlan attribute, or "grid" for columns × rows)
    label: str
    kind: str                   # "double" | "int" | "pair" | "ipair"
    lo: float
    hi: float
    decimals: int = 2
    step: float = 1.0
    suffix: str = ""
    special: str = ""           # text shown at the minimum: means None ("auto")
    tip: str = ""


def _input(key: str, decimals: int = 2, step: float = 1.0, percent: bool = False) -> _Input:
    """One editor row made from the scene plan's own description of the field (its range, unit, label
    and tip: lfstudio.planning.scene_plan.PARAMS), so the window accepts exactly what the plan does.
    Only the presentation is the window's: decimals, step, and percent for a fraction. An optional
    field's editor shows its text (e.g. "auto") at the minimum, one step below the valid range."""
    param = PARAMS["grid_columns" if key == "grid" else key]
    number = param.number
    assert number is not None and number.low is not None and number.high is not None, key
    scale = 100.0 if percent else 1.0
    tick = 1.0 if number.integer else 10.0 ** -decimals
    lo = number.low * scale
    if param.optional:
        lo = lo if number.low_open else lo - tick
    elif number.low_open:
        lo += tick
    pair = param.pair or key == "grid"
    kind = ("ipair" if pair else "int") if number.integer else ("pair" if pair else "double")
    suffix = " %" if percent else (f" {number.unit}" if number.unit and key != "grid" else "")
    return _Input(key, param.label, kind, lo, number.high * scale, decimals, step, suffix, param.optional,
                  param.tip)


_CAMERA_INPUTS = [_input("sensor_px"), _input("sensor_mm", 2, 0.1), _input("pixel_pitch_um", 3, 0.01),
                  _input("raw_bits")]
_LENS_INPUTS = [_input("focal_length_mm", 1, 1)]
_SCENE_INPUTS = [_input("near_m", 2, 0.05), _input("far_m", 2, 0.1), _input("coc_mm", 3, 0.001),
                 _input("f_number", 1, 0.5), _input("focus_m", 2, 0.05)]
_GRID_INPUTS = [_input("grid"), _input("spacing_mm", 3, 0.5), _input("repeatability_um", 0, 5),
                _input("travel_mm", 0, 10), _input("max_speed_mm_s", 0, 5), _input("acceleration_mm_s2", 0, 10),
                _input("settle_s", 2, 0.05), _input("exposure_s", 3, 0.1), _input("transfer_s", 2, 0.1)]
#: fly scanning (continuous motion): what bounds the row speed, and the speed asked for
_FLY_INPUTS = [_input("blur_limit_px", 2, 0.05), _input("frame_rate_fps", 1, 1), _input("bandwidth_mb_s", 0, 10),
               _input("report_rate_hz", 0, 5), _input("fly_speed_mm_s", 1, 5)]
FLY_SETTINGS_KEY = "planner/continuous_motion"
_TARGET_INPUTS = [_input("max_error_px", 2, 0.1), _input("max_disparity_px", 2, 0.25),
                  _input("target_parallax_fraction", 1, 1, percent=True)]

#: ScenePlan attribute -> input row key (most are the same)
_ROW_OF_FIELD = {"grid_columns": "grid", "grid_rows": "grid"}


def _row_of(field: str) -> str:
    return _ROW_OF_FIELD.get(field, field)


def style_prop(widget: QWidget, name: str) -> str:
    """The style property ``name`` last set with :func:`_set_prop` ("" if never); kept on the Python
    side so code and tests read the field's state without a QVariant round trip."""
    return getattr(widget, "_lf_style", {}).get(name, "")


def _set_prop(widget: QWidget, name: str, value: str) -> None:
    """Set a string property used by the style sheet and re-polish the widget if it changed."""
    props = widget.__dict__.setdefault("_lf_style", {})
    if props.get(name) != value:
        props[name] = value
        widget.setProperty(name, value)
        widget.style().unpolish(widget)
        widget.style().polish(widget)


_TINTS = {"error": ("#ffe3e6", "#b00020"), "warning": ("#fff1d6", "#8a4b00")}


def _tint(box: QAbstractSpinBox, mark: str) -> None:
    """Colour a spin box's field (a palette, so the native frame and arrows stay as they are)."""
    from PySide6.QtGui import QColor, QPalette
    from PySide6.QtWidgets import QApplication

    palette = QPalette(QApplication.palette(box))
    if mark:
        base, text = _TINTS[mark]
        palette.setColor(QPalette.ColorRole.Base, QColor(base))
        palette.setColor(QPalette.ColorRole.Text, QColor(text))
    box.setPalette(palette)
    box.lineEdit().setPalette(palette)


class _Row:
    """The widgets of one input row: spin box(es) and the message line under them."""

    def __init__(self, spec: _Input, spins: list[QSpinBox | QDoubleSpinBox], message: QLabel):
        self.spec = spec
        self.spins = spins
        self.message = message
        self.label: QLabel | None = None


class PlannerPanel(QWidget):
    """Inputs → live outputs; warnings next to their field; valid plans published to the state."""

    planEvaluated = Signal(object, object)   # (ScenePlan, PlanResult or None) after every evaluation

    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.setObjectName("plannerPanel")
        self.setStyleSheet(_PANEL_STYLE)
        self.rows: dict[str, _Row] = {}
        self.combos: dict[str, QComboBox] = {}
        self.outputs: dict[str, QLabel] = {}
        self.plan: ScenePlan | None = None
        self.result: PlanResult | None = None
        self.error: InputError | None = None
        self._custom_names = {"camera_name": "custom camera", "lens_name": "custom lens", "rig_name": "custom rig"}
        self._extra: dict[str, Any] = {}        # plan fields without a widget (bytes_per_image)
        self._loading = False
        self._timer = QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(DEBOUNCE_MS)
        self._timer.timeout.connect(self.evaluate)
        self._save_timer = QTimer(self)            # the last plan goes to QSettings a moment after edits stop
        self._save_timer.setSingleShot(True)
        self._save_timer.setInterval(1000)
        self._save_timer.timeout.connect(lambda: self._remember(self.current_plan()))
        self._presets = self._load_presets()
        #: the disk the Scan panel will write to: (folder, free bytes, mount point), measured off the GUI
        #: thread (a network disk may take its time to answer)
        self.destination: tuple[str, int, str] | None = None
        self._measuring = None
        self._wanted = ""
        self._build()
        self.set_plan(self._restore_plan())
        self.evaluate()
        state.scanFolderChanged.connect(self.measure_destination)
        self.measure_destination(state.scan_folder)

    # -- construction ------------------------------------------------------------------------------
    def _load_presets(self) -> dict[str, list[str]]:
        names = {}
        for kind in ("cameras", "lenses", "rigs"):
            try:
                names[kind] = list(load_presets(kind))
            except InputError as exc:      # a broken user preset file: say so, keep going
                names[kind] = []
                QTimer.singleShot(0, lambda e=exc: self.state.report_error("Presets", str(e)))
        return names

    def _build(self) -> None:
        outer = QVBoxLayout(self)
        outer.setContentsMargins(4, 4, 4, 4)
        outer.setSpacing(6)
        results = self._build_results()
        outer.addWidget(results)

        body = QWidget()
        body.setObjectName("plannerInputs")
        lay = QVBoxLayout(body)
        lay.setContentsMargins(0, 0, 4, 0)
        lay.setSpacing(6)
        lay.addWidget(self._group("Camera and lens", [("camera_name", "Camera", "cameras"), *_CAMERA_INPUTS,
                                                       ("lens_name", "Lens", "lenses"), *_LENS_INPUTS]))
        lay.addWidget(self._group("Scene and aperture", _SCENE_INPUTS))
        timing = self._group("Grid, rig and timing", [("rig_name", "Rig", "rigs"), *_GRID_INPUTS])
        grid = timing.layout()
        assert isinstance(grid, QGridLayout)       # _group lays its box out on a grid
        self._add_bracket_row(grid)
        lay.addWidget(timing)
        self._fly_toggled_since = False     # Continuous motion changed since the plan was last published
        self.fly_box = self._group("Continuous motion (fly scan)", _FLY_INPUTS)
        self.fly_box.setObjectName("plannerFly")
        self.fly_box.setCheckable(True)
        self.fly_box.setChecked(self._restore_fly())
        self.fly_box.setToolTip("Plan a fly scan: each row crossed at one constant speed, a frame as the carriage "
                                "passes each view. The capture time is then the fly scan's; the row speed is the "
                                "fastest these limits allow (the Fly scan line says which binds). Scan panel: "
                                "Continuous motion")
        self.fly_box.toggled.connect(self._fly_toggled)
        lay.addWidget(self.fly_box)
        lay.addWidget(self._group("Targets", _TARGET_INPUTS))
        buttons = QHBoxLayout()
        self.reference_button = QPushButton("Reference setup")
        self.reference_button.setToolTip("Reset every input to the paper's setup (A7R II, 50 mm, 101 × 21 at 4 × 6 mm)")
        self.reference_button.clicked.connect(lambda: self.set_plan(reference_plan()))
        self.apply_spacing_button = QPushButton("Use proposed spacing")
        self.apply_spacing_button.setToolTip("Set the spacing to the one that gives the wanted neighbour disparity")
        self.apply_spacing_button.clicked.connect(self.apply_proposed_spacing)
        buttons.addWidget(self.reference_button)
        buttons.addWidget(self.apply_spacing_button)
        buttons.addStretch(1)
        lay.addLayout(buttons)
        lay.addStretch(1)

        scroll = QScrollArea()
        scroll.setObjectName("plannerScroll")
        scroll.setWidgetResizable(True)
        scroll.setFrameShape(QFrame.Shape.NoFrame)
        scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroll.setWidget(body)
        outer.addWidget(scroll, 1)
        self.setMinimumWidth(430)
        self._outer, self._results_box, self._body, self._body_scroll = outer, results, body, scroll

    def height_when_scrolled(self) -> int:
        """The panel's height with its inputs shown whole: when the dock is lower than the panel's
        minimum, the dock's scroll area lays it out at this height, so the inputs' own scroll area
        does not scroll as well (two scroll bars, one inside the other)."""
        margins = self._outer.contentsMargins()
        return (margins.top() + margins.bottom() + self._results_box.sizeHint().height()
                + self._outer.spacing() + self._body.sizeHint().height()
                + 2 * self._body_scroll.frameWidth())

    def _group(self, title: str, items: list) -> QGroupBox:
        box = QGroupBox(title)
        grid = QGridLayout(box)
        grid.setContentsMargins(8, 8, 8, 6)
        grid.setHorizontalSpacing(8)
        grid.setVerticalSpacing(3)
        grid.setColumnStretch(1, 1)
        grid.setColumnStretch(3, 1)
        r = 0
        for item in items:
            if isinstance(item, tuple):
                key, label, kind = item
                combo = QComboBox()
                combo.setObjectName(f"{key}Combo")
                combo.addItems(self._presets[kind] + [CUSTOM])
                combo.setToolTip(f"{label} preset (yours go in ~/.config/lfstudio/presets/{kind}.toml)")
                combo.currentTextChanged.connect(lambda text, k=key: self._preset_chosen(k, text))
                self.combos[key] = combo
                name = QLabel(label)
                grid.addWidget(name, r, 0)
                grid.addWidget(combo, r, 1, 1, 3)
                message = self._message_label()
                grid.addWidget(message, r + 1, 0, 1, 4)
                self.rows[key] = _Row(_Input(key, label, "combo", 0, 0), [], message)
                self.rows[key].label = name
                r += 2
                continue
            spec: _Input = item
            label = QLabel(spec.label)
            label.setToolTip(spec.tip)
            grid.addWidget(label, r, 0)
            spins = self._spins(spec)
            if len(spins) == 1:
                grid.addWidget(spins[0], r, 1, 1, 3)
            else:
                grid.addWidget(spins[0], r, 1)
                times = QLabel("×")
                times.setAlignment(Qt.AlignmentFlag.AlignCenter)
                grid.addWidget(times, r, 2)
                grid.addWidget(spins[1], r, 3)
            message = self._message_label()
            grid.addWidget(message, r + 1, 0, 1, 4)
            self.rows[spec.key] = _Row(spec, spins, message)
            self.rows[spec.key].label = label
            r += 2
        return box

    def _add_bracket_row(self, grid: QGridLayout) -> None:
        """The exposure bracket: text, as ``lfstudio scan --bracket`` takes it (time and disk count every frame)."""
        r = grid.rowCount()
        label = QLabel(PARAMS["bracket"].label)
        tip = PARAMS["bracket"].tip
        label.setToolTip(tip)
        self.bracket_edit = QLineEdit()
        self.bracket_edit.setObjectName("bracket")
        self.bracket_edit.setPlaceholderText("none — e.g. -2,0,+2")
        self.bracket_edit.setToolTip(tip)
        self.bracket_edit.textChanged.connect(self._changed)
        grid.addWidget(label, r, 0)
        grid.addWidget(self.bracket_edit, r, 1, 1, 3)
        message = self._message_label()
        grid.addWidget(message, r + 1, 0, 1, 4)
        self.rows["bracket"] = _Row(_Input("bracket", "Bracket", "text", 0, 0), [], message)
        self.rows["bracket"].label = label

    @staticmethod
    def _message_label() -> QLabel:
        label = QLabel("")
        label.setWordWrap(True)
        label.setVisible(False)
        label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        return label

    def _spins(self, spec: _Input) -> list[QSpinBox | QDoubleSpinBox]:
        count = 2 if spec.kind in ("pair", "ipair") else 1
        spins: list[QSpinBox | QDoubleSpinBox] = []
        for i in range(count):
            if spec.kind in ("int", "ipair"):
                box: QSpinBox | QDoubleSpinBox = QSpinBox()
                box.setRange(int(spec.lo), int(spec.hi))
            else:
                box = QDoubleSpinBox()
                box.setDecimals(spec.decimals)
                box.setRange(spec.lo, spec.hi)
                box.setSingleStep(spec.step)
            box.setSuffix(spec.suffix)
            if spec.special:
                box.setSpecialValueText(spec.special)
            box.setKeyboardTracking(True)
            box.setAccelerated(True)
            box.setMinimumWidth(96)
            box.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Fixed)
            axis = ("horizontal", "vertical")[i] if count == 2 else ""
            if spec.key in ("sensor_px", "sensor_mm"):
                axis = ("width", "height")[i]
            if spec.key == "grid":
                axis = ("columns", "rows")[i]
            box.setObjectName(f"{spec.key}{'_' + axis if axis else ''}")
            box.setToolTip(f"{spec.tip}{' — ' + axis if axis else ''}. Range {spec.lo:g} … {spec.hi:g}"
                           f"{spec.suffix.strip() and ' ' + spec.suffix.strip()}")
            box.valueChanged.connect(self._changed)
            spins.append(box)
        return spins

    def _build_results(self) -> QGroupBox:
        box = QGroupBox("Plan")
        box.setObjectName("planResults")
        grid = QGridLayout(box)
        grid.setContentsMargins(8, 8, 8, 6)
        grid.setHorizontalSpacing(10)
        grid.setVerticalSpacing(2)
        self.status_label = QLabel("")
        self.status_label.setObjectName("planStatus")
        self.status_label.setWordWrap(True)
        grid.addWidget(self.status_label, 0, 0, 1, 2)
        items = [
            ("aperture", "Aperture needed", "f-number that keeps the whole scene sharp, and where to focus"),
            ("sharp", "Sharp range", "Depth of field at the f-number and focus used"),
            ("hyperfocal", "Hyperfocal", "Hyperfocal distance at the f-number used (≈ f²/(N·c))"),
            ("min_distance", "Min. distance", "Closest scene distance at which the less precise axis stays "
                                              "below the repositioning-error target"),
            ("reposition", "Error at near", "Repositioning error in pixels at the near distance (h / v)"),
            ("neighbour", "Neighbour disp.", "Disparity between neighbouring views from near to far (h / v)"),
            ("row_parallax", "Row parallax", "Parallax of the whole row from near to far"),
            ("column_parallax", "Column parallax", "Parallax of the whole column from near to far"),
            ("proposed_spacing", "Spacing for target", "Spacing that gives the wanted neighbour disparity (h / v)"),
            ("proposed_grid", "Grid for target", "Grid that gives the wanted parallax at this spacing"),
            ("images", "Images", "Number of views, and whether the grid fits the travel"),
            ("time", "Capture time", "Estimated scan time in meander order (transfers overlap moves)"),
            ("fly", "Fly scan", "Continuous motion: the row speed that keeps motion blur within the blur limit "
                                "(0.5 px) at the near distance, within the camera's frame rate (one frame per "
                                "transfer time unless the plan says), the controller's position reports and the "
                                "axis; its scan time and which limit binds, or why no speed does (Scan panel: "
                                "Continuous motion)"),
            ("disk", "Disk space", "Raw files of the whole grid"),
        ]
        for i, (key, label, tip) in enumerate(items, start=1):
            name = QLabel(label)
            name.setProperty("role", "outlabel")
            name.setToolTip(tip)
            value = QLabel("—")
            value.setObjectName(f"out_{key}")
            value.setProperty("role", "value")
            value.setToolTip(tip)
            value.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
            if key in ("time", "fly"):       # long lines: wrapped in a narrow dock (1366 × 768)
                value.setWordWrap(True)
            grid.addWidget(name, i, 0)
            grid.addWidget(value, i, 1)
            self.outputs[key] = value
        grid.setColumnStretch(1, 1)
        return box

    # -- plan <-> widgets --------------------------------------------------------------------------
    def _value(self, key: str, i: int = 0) -> float:
        return self.rows[key].spins[i].value()

    def _optional(self, key: str) -> float | None:
        box = self.rows[key].spins[0]
        return None if box.value() == box.minimum() else box.value()

    def current_plan(self) -> ScenePlan:
        """The plan the fields describe (never raises; validation comes in :meth:`evaluate`)."""
        pair = lambda k: (self._value(k, 0), self._value(k, 1))  # noqa: E731
        parallax = self._optional("target_parallax_fraction")
        names = {}
        for key, combo in self.combos.items():
            text = combo.currentText()
            names[key] = self._custom_names[key] if text == CUSTOM else text
        return ScenePlan(
            camera_name=names["camera_name"], sensor_px=(int(self._value("sensor_px", 0)), int(self._value("sensor_px", 1))),
            sensor_mm=pair("sensor_mm"), pixel_pitch_um=self._optional("pixel_pitch_um"),
            lens_name=names["lens_name"], focal_length_mm=self._value("focal_length_mm"),
            near_m=self._value("near_m"), far_m=self._value("far_m"), coc_mm=self._value("coc_mm"),
            f_number=self._optional("f_number"), focus_m=self._optional("focus_m"),
            grid_columns=int(self._value("grid", 0)), grid_rows=int(self._value("grid", 1)),
            spacing_mm=pair("spacing_mm"), rig_name=names["rig_name"], repeatability_um=pair("repeatability_um"),
            travel_mm=pair("travel_mm"), max_speed_mm_s=pair("max_speed_mm_s"),
            acceleration_mm_s2=pair("acceleration_mm_s2"), settle_s=self._value("settle_s"),
            exposure_s=self._value("exposure_s"), transfer_s=self._value("transfer_s"),
            max_error_px=self._value("max_error_px"), max_disparity_px=self._value("max_disparity_px"),
            target_parallax_fraction=None if parallax is None else parallax / 100.0,
            raw_bits=int(self._value("raw_bits")), bracket=self.bracket_edit.text().strip(),
            blur_limit_px=self._value("blur_limit_px"), frame_rate_fps=self._optional("frame_rate_fps"),
            bandwidth_mb_s=self._optional("bandwidth_mb_s"), report_rate_hz=self._optional("report_rate_hz"),
            fly_speed_mm_s=self._optional("fly_speed_mm_s"), **self._extra)

    def set_plan(self, plan: ScenePlan) -> None:
        """Show ``plan`` in the fields (values beyond a field's range are clamped to it)."""
        self._loading = True
        try:
            values: dict[str, Any] = {
                "sensor_px": plan.sensor_px, "sensor_mm": plan.sensor_mm, "pixel_pitch_um": plan.pixel_pitch_um,
                "raw_bits": plan.raw_bits, "focal_length_mm": plan.focal_length_mm, "near_m": plan.near_m,
                "far_m": plan.far_m, "coc_mm": plan.coc_mm, "f_number": plan.f_number, "focus_m": plan.focus_m,
                "grid": (plan.grid_columns, plan.grid_rows), "spacing_mm": plan.spacing_mm,
                "repeatability_um": plan.repeatability_um, "travel_mm": plan.travel_mm,
                "max_speed_mm_s": plan.max_speed_mm_s, "acceleration_mm_s2": plan.acceleration_mm_s2,
                "settle_s": plan.settle_s, "exposure_s": plan.exposure_s, "transfer_s": plan.transfer_s,
                "max_error_px": plan.max_error_px, "max_disparity_px": plan.max_disparity_px,
                "target_parallax_fraction": None if plan.target_parallax_fraction is None
                else plan.target_parallax_fraction * 100.0,
                "blur_limit_px": plan.blur_limit_px, "frame_rate_fps": plan.frame_rate_fps,
                "bandwidth_mb_s": plan.bandwidth_mb_s, "report_rate_hz": plan.report_rate_hz,
                "fly_speed_mm_s": plan.fly_speed_mm_s}
            for key, value in values.items():
                spins = self.rows[key].spins
                vals = value if isinstance(value, (tuple, list)) else (value,)
                for box, v in zip(spins, vals):
                    box.blockSignals(True)
                    if isinstance(box, QSpinBox):      # (the same call: one box takes int, the other float)
                        box.setValue(box.minimum() if v is None else v)
                    else:
                        box.setValue(box.minimum() if v is None else v)
                    box.blockSignals(False)
            for key, name in (("camera_name", plan.camera_name), ("lens_name", plan.lens_name),
                              ("rig_name", plan.rig_name)):
                combo = self.combos[key]
                combo.blockSignals(True)
                if combo.findText(name) >= 0 and name != CUSTOM:
                    combo.setCurrentText(name)
                else:
                    self._custom_names[key] = name
                    combo.setCurrentText(CUSTOM)
                combo.blockSignals(False)
            self._extra = {"bytes_per_image": plan.bytes_per_image} if plan.bytes_per_image is not None else {}
            self.bracket_edit.blockSignals(True)
            self.bracket_edit.setText(plan.bracket or "")
            self.bracket_edit.blockSignals(False)
        finally:
            self._loading = False
        self._changed()

    def _preset_chosen(self, key: str, name: str) -> None:
        if self._loading or name == CUSTOM:
            self._changed()
            return
        try:
            fields = {"camera_name": camera_fields, "lens_name": lens_fields, "rig_name": rig_fields}[key](name)
        except InputError as exc:
            self._show_message(key, [("error", str(exc))])
            return
        self.set_plan(self.current_plan().replace(**fields))

    def _sync_combos(self, plan: ScenePlan) -> None:
        """Switch a preset combo to "Custom" once its fields no longer match the preset."""
        loaders = {"camera_name": camera_fields, "lens_name": lens_fields, "rig_name": rig_fields}
        for key, combo in self.combos.items():
            name = combo.currentText()
            if name == CUSTOM:
                continue
            try:
                fields = loaders[key](name)
            except InputError:
                continue
            if any(_differs(getattr(plan, k), v) for k, v in fields.items() if k != key):
                combo.blockSignals(True)
                self._custom_names[key] = f"{name} (modified)"
                combo.setCurrentText(CUSTOM)
                combo.blockSignals(False)

    # -- evaluation --------------------------------------------------------------------------------
    def _changed(self, *args) -> None:
        if not self._loading:
            self._timer.start()

    def evaluate(self) -> None:
        """Derive the plan from the fields now; show outputs, errors and warnings; publish it if valid."""
        self._timer.stop()
        plan = self.current_plan()
        self._sync_combos(plan)
        plan = self.current_plan()
        try:
            result, error = plan.derive(check_travel=False), None
        except InputError as exc:
            result, error = None, exc
        self.plan, self.result, self.error = plan, result, error
        self._show(plan, result, error)
        self._save_timer.start()
        fly_toggled, self._fly_toggled_since = self._fly_toggled_since, False
        if result is not None and result.fits_travel and (plan != self.state.plan or fly_toggled):
            self.state.set_plan(plan)       # also when only Continuous motion changed: the Scan panel follows it
        self.planEvaluated.emit(plan, result)

    def _show(self, plan: ScenePlan, result: PlanResult | None, error: InputError | None) -> None:
        messages: dict[str, list[tuple[str, str]]] = {}
        if error is not None:
            text = str(error)
            prefix = f"{error.field}: "
            messages.setdefault(_row_of(error.field), []).append(
                ("error", text[len(prefix):] if text.startswith(prefix) else text))
        if result is not None:
            for w in result.warnings:
                messages.setdefault(_row_of(w.field), []).append((w.severity, w.message))
        for key in self.rows:
            self._show_message(key, messages.get(key, []))
        self.apply_spacing_button.setEnabled(result is not None)
        if result is None:
            label = self.rows[_row_of(error.field)].spec.label if error and _row_of(error.field) in self.rows \
                else (error.field if error else "")
            self._set_status(False, f"✖ Fix {label}: the plan is not valid")
            for value in self.outputs.values():
                value.setText("—")
                _set_prop(value, "flag", "")
            return
        self._fill_outputs(plan, result)
        errors = [w for w in result.warnings if w.severity == "error"]
        warnings = [w for w in result.warnings if w.severity == "warning"]
        if errors:
            self._set_status(False, "✖ The grid does not fit the rig's travel")
        elif warnings:
            self._set_status(True, f"✔ Plan valid — {len(warnings)} warning{'s' if len(warnings) > 1 else ''} below")
        else:
            self._set_status(True, "✔ Plan valid")

    def _set_status(self, ok: bool, text: str) -> None:
        self.status_label.setText(text)
        _set_prop(self.status_label, "ok", "true" if ok else "false")

    def _show_message(self, key: str, items: list[tuple[str, str]]) -> None:
        row = self.rows.get(key)
        if row is None:
            return
        worst = max((s for s, _ in items), key=lambda s: _SEVERITY_RANK.get(s, 0), default="")
        marks = {"error": "✖", "warning": "⚠", "info": "ℹ"}
        row.message.setText("\n".join(f"{marks.get(s, '')} {m}" for s, m in items))
        row.message.setVisible(bool(items))
        _set_prop(row.message, "msg", worst)
        widgets = row.spins or ([self.combos[key]] if key in self.combos else [])
        mark = worst if worst in ("error", "warning") else ""
        for w in widgets:
            if style_prop(w, "severity") == mark and hasattr(w, "_lf_style"):
                continue                # unchanged: no re-polish, no new palette (each repaints the field)
            _set_prop(w, "severity", mark)
            if isinstance(w, QAbstractSpinBox):
                _tint(w, mark)
        if row.label is not None:
            _set_prop(row.label, "mark", mark)

    def _fill_outputs(self, plan: ScenePlan, r: PlanResult) -> None:
        def put(key: str, text: str, flag: str = "") -> None:
            self.outputs[key].setText(text)
            _set_prop(self.outputs[key], "flag", flag)

        far = "∞" if math.isinf(r.dof_far_m) else f"{r.dof_far_m:.2f}"
        put("aperture", f"f/{r.f_number_required:.1f} focused at {r.focus_distance_m:.2f} m")
        put("sharp", f"{r.dof_near_m:.2f} – {far} m at f/{r.f_number_used:.1f}",
            "" if r.scene_sharp else "bad")
        put("hyperfocal", f"{r.hyperfocal_m:.2f} m")
        put("min_distance", f"{r.min_distance_m:.2f} m ({r.min_distance_axis} axis)",
            "warn" if r.min_distance_m > plan.near_m * (1 + 1e-9) else "")
        rep = r.reposition_error_px
        put("reposition", f"{rep['horizontal']:.2f} / {rep['vertical']:.2f} px",
            "warn" if max(rep.values()) > plan.max_error_px * (1 + 1e-9) else "")
        nd = r.neighbour_disparity_px
        put("neighbour", f"{nd['horizontal']:.2f} / {nd['vertical']:.2f} px")
        put("row_parallax", f"{r.row_parallax_px:.0f} px ({100 * r.row_parallax_fraction:.1f} % of width)")
        put("column_parallax", f"{r.column_parallax_px:.0f} px ({100 * r.column_parallax_fraction:.1f} % of height)")
        ps = r.proposed_spacing_mm
        put("proposed_spacing", f"{ps['horizontal']:.3g} / {ps['vertical']:.3g} mm for ≤ {plan.max_disparity_px:g} px")
        grid, fraction = r.proposed_grid, plan.target_parallax_fraction
        put("proposed_grid", "— (set a wanted parallax)" if grid is None or fraction is None
            else f"{grid.columns} × {grid.rows} for {100 * fraction:g} %")
        frames = f", {r.frames} frames" if r.frames_per_view > 1 else ""
        put("images", f"{plan.grid_columns} × {plan.grid_rows} = {r.images}{frames}"
            + ("" if r.fits_travel else "  — beyond travel"), "" if r.fits_travel else "bad")
        fly = r.fly
        step = f"{format_duration(r.capture_time_s)} ({r.capture_time_s / max(r.images, 1):.2f} s/view)"
        if not self.fly_box.isChecked():
            put("time", step)
        elif fly is not None and fly.possible:
            put("time", f"{format_duration(fly.time_s)} fly scan (step by step {format_duration(r.capture_time_s)})")
        else:
            put("time", f"{step}: no fly speed (see Fly scan)", "warn")
        if fly is not None and fly.possible:
            put("fly", f"{format_duration(fly.time_s)} at {fly.speed_mm_s:.3g} mm/s ({fly.binding} binds)")
            self.outputs["fly"].setToolTip(self.outputs["fly"].toolTip().split("\n\n")[0])
        elif fly is not None:
            put("fly", f"not possible: {fly.binding} allows {fly.speed_mm_s:.3g} mm/s",
                "warn" if self.fly_box.isChecked() else "")      # plain when nobody asked for a fly scan
            self.outputs["fly"].setToolTip(self.outputs["fly"].toolTip().split("\n\n")[0] + "\n\n" + fly.refusal)
        self._fill_disk(r)

    def _fill_disk(self, r: PlanResult) -> None:
        """The disk row: the raw files of the whole grid, and whether the disk of the Scan panel's
        dataset folder holds them with the free space the scan keeps (:mod:`lfstudio.scan.preflight`)."""
        text = f"{_bytes(r.storage_bytes)} ({_bytes(r.bytes_per_image)}/image" + \
            (f", {r.frames_per_view} a view" if r.frames_per_view > 1 else "") + ")"
        tip, flag = "Raw files of the whole grid", ""
        if self.destination is not None:
            folder, free, mount = self.destination
            size = view_size(r.frames_per_view, plan_bytes_per_image=r.bytes_per_image)
            short = disk_shortfall(folder, r.images, size, free, min_free_bytes=MIN_FREE_BYTES) if size else None
            where = mount if len(mount) <= 26 else "…" + mount[-25:]      # the whole path in the tooltip
            if short is None:
                text += f"\n{_bytes(free)} free: enough\non the disk at {where}"
                tip += f", for the dataset folder {folder} (the Scan panel's): its disk at {mount} holds them"
            else:
                text += f"\n{_bytes(free)} free: too little\non the disk at {where}"
                tip, flag = str(short), "bad"
        else:
            tip += " (choose the dataset folder in the Scan panel to check its disk)"
        self.outputs["disk"].setText(text)
        self.outputs["disk"].setToolTip(tip)
        _set_prop(self.outputs["disk"], "flag", flag)

    def measure_destination(self, folder: str) -> None:
        """Measure the free space of ``folder``'s disk off the GUI thread; the disk row follows."""
        from lfstudio.dataset.storage import mount_point
        from lfstudio.dataset.store import free_bytes
        from lfstudio.gui.bridge import run_off_gui

        folder = (folder or "").strip()
        self._wanted = folder
        if not folder:
            self.destination = None
            if self.result is not None:
                self._fill_disk(self.result)
            return

        def measure() -> tuple[str, int, str]:
            path = Path(folder).expanduser()
            return folder, free_bytes(path), str(mount_point(path))

        def measured(value: tuple[str, int, str]) -> None:
            if value[0] != self._wanted:      # the folder changed meanwhile: its own measure follows
                return
            self.destination = value
            if self.result is not None:
                self._fill_disk(self.result)

        self._measuring = run_off_gui(self, measure, measured,
                                      lambda message: log.info("free space of %s not measured: %s", folder, message))

    def apply_proposed_spacing(self) -> None:
        if self.result is None:
            return
        ps = self.result.proposed_spacing_mm
        self.set_plan(self.current_plan().replace(spacing_mm=(ps["horizontal"], ps["vertical"])))

    # -- persistence and files -----------------------------------------------------------------------
    def _restore_plan(self) -> ScenePlan:
        from lfstudio.gui.settings import settings

        text = settings().value(SETTINGS_KEY)
        if text:
            try:
                return ScenePlan.from_dict(json.loads(str(text)))
            except (ValueError, InputError) as exc:
                log.warning("last plan not restored: %s", exc)
        try:
            return reference_plan()
        except InputError:
            return ScenePlan()

    def _remember(self, plan: ScenePlan) -> None:
        from lfstudio.gui.settings import settings

        settings().setValue(SETTINGS_KEY, json.dumps(plan.to_dict()))

    @staticmethod
    def _restore_fly() -> bool:
        from lfstudio.gui.settings import settings

        return str(settings().value(FLY_SETTINGS_KEY, "false")).lower() == "true"

    def _fly_toggled(self, on: bool) -> None:
        from lfstudio.gui.settings import settings

        settings().setValue(FLY_SETTINGS_KEY, "true" if on else "false")
        self._fly_toggled_since = True
        self._changed()

    @property
    def continuous_motion(self) -> bool:
        """Whether the plan is for a fly scan (the "Continuous motion" box is ticked)."""
        return self.fly_box.isChecked()

    def save_plan_file(self, path: str | Path) -> bool:
        try:
            save_plan(path, self.current_plan())
        except (OSError, LfError) as exc:
            self.state.report_error("Save plan", f"Could not write {path}: {exc}. Choose another folder.")
            return False
        self.state.show_status(f"Plan saved to {path}")
        return True

    def open_plan_file(self, path: str | Path) -> bool:
        try:
            plan = load_plan(path)
        except LfError as exc:
            self.state.report_error("Open plan", str(exc))
            return False
        self.set_plan(plan)
        self.evaluate()
        self.state.show_status(f"Plan loaded from {path}")
        return True

    def _open_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Open plan", str(Path.home()), "Plan files (*.toml *.json)")
        if path:
            self.open_plan_file(path)

    def _save_dialog(self) -> None:
        path, chosen = QFileDialog.getSaveFileName(self, "Save plan as", str(Path.home() / "plan.toml"),
                                                   "TOML plan (*.toml);;JSON plan (*.json)")
        if path:
            if not Path(path).suffix:
                path += ".json" if "json" in chosen.lower() else ".toml"
            self.save_plan_file(path)

    def install_menus(self, window) -> None:
        menu = window.menu("File")
        open_action = QAction("Open plan…", window)
        open_action.setObjectName("actionOpenPlan")
        open_action.setShortcut(QKeySequence("Ctrl+Shift+O"))
        open_action.setToolTip("Load a scene plan (.toml or .json) into the Planner")
        open_action.triggered.connect(self._open_dialog)
        save_action = QAction("Save plan as…", window)
        save_action.setObjectName("actionSavePlan")
        save_action.setShortcut(QKeySequence("Ctrl+Shift+S"))
        save_action.setToolTip("Write the Planner's plan to a .toml or .json file")
        save_action.triggered.connect(self._save_dialog)
        reset_action = QAction("Reset plan to the reference setup", window)
        reset_action.setObjectName("actionReferencePlan")
        reset_action.setToolTip("The paper's setup: A7R II, 50 mm, 1.77–4.77 m, 101 × 21 at 4 × 6 mm")
        reset_action.triggered.connect(lambda: self.set_plan(reference_plan()))
        for action in (open_action, save_action, reset_action):
            menu.addAction(action)
        menu.addSeparator()
        plots = getattr(window, "docks", {}).get("planPlotsDock")
        if plots is not None:       # first start: give the plots room (a saved layout overrides this)
            window.resizeDocks([plots], [560], Qt.Orientation.Vertical)

    def shutdown(self) -> None:
        self._timer.stop()
        self._save_timer.stop()
        self._remember(self.current_plan())


def _differs(a: Any, b: Any) -> bool:
    if isinstance(a, (tuple, list)) and isinstance(b, (tuple, list)):
        return any(_differs(x, y) for x, y in zip(a, b))
    if a is None or b is None:
        return a is not b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return abs(float(a) - float(b)) > 1e-6 * max(1.0, abs(float(b)))
    return a != b


def _bytes(n: float) -> str:
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{int(n)} B"


# -- plots -------------------------------------------------------------------------------------------

_COLORS = {"scene": (70, 130, 200, 45), "sharp": (60, 160, 90, 50), "blur": "#1f5fa8", "coc": "#b00020",
           "pixels": "#7a7a7a", "airy": "#9a5b00", "h": "#1f5fa8", "v": "#6a3d9a", "row": "#c0392b",
           "col": "#e67e22", "focus": "#2e7d32", "zmin": "#b00020"}


PLOT_MIN_HEIGHT_PX = 220     # a plan plot below this showed a 40 px strip of curves under its title and legend
SIDE_BY_SIDE_PLOT_PX = 380   # the plots sit side by side only when each gets this width (their titles and legends)


class PlanPlotsPanel(QWidget):
    """Depth of field (blur against distance, with the scene and the sharp range) and disparity against
    depth (neighbour spacing and whole row/column, with the 0.5 px and 1 px lines) of the state's plan.

    Typing in the Planner must cost less than a frame (16.7 ms, ``benchmarks/planner_update.py``):

    - the plot items are built once and updated in place (``setData``, ``setValue``, ``setRegion``);
      plan changes are coalesced, so typing never queues up redraws;
    - the axes are cached as pixmaps (re-drawing their tick labels is most of a plot's paint) and
      the view ranges are sticky (:func:`sticky_range`): they move only when the curves leave them
      or would fill too little of them, so most keystrokes leave the axes as they are;
    - titles and the note are set only when their text changes."""

    REDRAW_MS = 30

    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(parent)
        import pyqtgraph as pg

        self.state = state
        self.setObjectName("planPlotsPanel")
        lay = QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        lay.setSpacing(4)
        self.plots_layout = QBoxLayout(QBoxLayout.Direction.LeftToRight)   # side by side when wide, stacked when tall
        self.plots_layout.setSpacing(6)
        lay.addLayout(self.plots_layout, 1)
        # colours set per plot: pyqtgraph's global options would restyle other panels' image views
        # each plot's item made here, so its view box is at hand (PlotWidget declares its item optional)
        self._views = {"dof": pg.PlotItem(), "disparity": pg.PlotItem()}
        self.dof_plot = pg.PlotWidget(background="w", plotItem=self._views["dof"])
        self.dof_plot.setObjectName("dofPlot")
        self.disparity_plot = pg.PlotWidget(background="w", plotItem=self._views["disparity"])
        self.disparity_plot.setObjectName("disparityPlot")
        for plot in (self.dof_plot, self.disparity_plot):
            for side in ("left", "bottom"):
                axis = plot.getAxis(side)
                axis.setPen(pg.mkPen("#30343a"))
                axis.setTextPen(pg.mkPen("#30343a"))
            plot.setMinimumSize(240, PLOT_MIN_HEIGHT_PX)   # title, axes, legend and a readable plot area
            plot.showGrid(x=True, y=True, alpha=0.25)
            plot.setMenuEnabled(False)
            for side in ("left", "bottom"):         # painted from a pixmap until their range changes
                plot.getAxis(side).setCacheMode(QGraphicsItem.CacheMode.DeviceCoordinateCache)
            self.plots_layout.addWidget(plot, 1)
        self.note = QLabel("")
        self.note.setWordWrap(True)
        lay.addWidget(self.note)
        self._build_dof()
        self._build_disparity()
        self._texts: dict[str, str] = {}                     # titles and note as last set
        self._pending = None
        self._timer = QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(self.REDRAW_MS)
        self._timer.timeout.connect(lambda: self.draw(self._pending))
        state.planChanged.connect(self._schedule)
        self.draw(state.plan)

    def _legend(self, plot):
        """The plot's legend in two columns below its axis (inside the plot it covered the curves as
        soon as the plot was narrow); the named curves add themselves to it."""
        import pyqtgraph as pg

        item = plot.getPlotItem()
        legend = pg.LegendItem(labelTextSize="8pt", labelTextColor="#30343a", colCount=2,
                               horSpacing=18, verSpacing=-6)
        item.legend = legend
        item.layout.addItem(legend, 4, 1)
        return legend

    def _build_dof(self) -> None:
        import pyqtgraph as pg

        p = self.dof_plot
        p.setTitle("Depth of field: blur against distance", color="#30343a", size="10pt")
        p.setLabel("bottom", "distance from the camera plane", units="m")
        p.setLabel("left", "blur circle", units="µm")
        self._legend(p)
        self.scene_region = pg.LinearRegionItem((1, 2), movable=False, brush=pg.mkBrush(*_COLORS["scene"]),
                                                pen=pg.mkPen(_COLORS["scene"][:3], width=1))
        self.sharp_region = pg.LinearRegionItem((1, 2), movable=False, brush=pg.mkBrush(*_COLORS["sharp"]),
                                                pen=pg.mkPen(None))
        self.sharp_region.setZValue(-5)
        p.addItem(self.scene_region)
        p.addItem(self.sharp_region)
        self.blur_curve = p.plot([], [], pen=pg.mkPen(_COLORS["blur"], width=2), name="blur circle", antialias=True)
        self.airy_curve = p.plot([], [], pen=pg.mkPen(_COLORS["airy"], width=1, style=Qt.PenStyle.DashDotLine),
                                 name="Airy disk (diffraction)")
        p.plot([], [], pen=pg.mkPen(_COLORS["scene"][:3], width=8), name="scene near – far")
        p.plot([], [], pen=pg.mkPen(_COLORS["sharp"][:3], width=8), name="sharp range")
        self.coc_line = pg.InfiniteLine(29, angle=0, pen=pg.mkPen(_COLORS["coc"], width=1.5, style=Qt.PenStyle.DashLine),
                                        label="circle of confusion {value:.0f} µm",
                                        labelOpts={"position": 0.2, "color": _COLORS["coc"],
                                                   "anchors": [(0, 1), (0, 1)]})
        self.pixels_line = pg.InfiniteLine(9, angle=0, pen=pg.mkPen(_COLORS["pixels"], width=1, style=Qt.PenStyle.DotLine),
                                           label="2 pixels", labelOpts={"position": 0.9, "color": _COLORS["pixels"],
                                                                        "anchors": [(1, 1), (1, 1)]})
        self.focus_line = pg.InfiniteLine(2, angle=90, pen=pg.mkPen(_COLORS["focus"], width=1),
                                          label="focus {value:.2f} m",
                                          labelOpts={"position": 0.93, "color": _COLORS["focus"]})
        for item in (self.coc_line, self.pixels_line, self.focus_line):
            p.addItem(item)

    def _build_disparity(self) -> None:
        import pyqtgraph as pg

        q = self.disparity_plot
        q.setTitle("Disparity from infinity against depth (log scale)", color="#30343a", size="10pt")
        q.setLabel("bottom", "depth", units="m")
        q.setLabel("left", "disparity (px)")
        q.setLogMode(x=False, y=True)
        self._legend(q)
        self.disparity_scene = pg.LinearRegionItem((1, 2), movable=False, brush=pg.mkBrush(*_COLORS["scene"]),
                                                   pen=pg.mkPen(None))
        q.addItem(self.disparity_scene)
        self.disparity_curves = {}
        self.pixel_lines: dict[float, Any] = {}
        for key, name in (("h", "neighbour, horizontal"), ("v", "neighbour, vertical"), ("row", "whole row"),
                          ("col", "whole column")):
            self.disparity_curves[key] = q.plot(
                [], [], pen=pg.mkPen(_COLORS[key], width=2 if key in ("h", "row") else 1.5), name=name,
                antialias=True)
        # one label for both lines, above the 1 px line at the right end: a label under the 0.5 px line was
        # cut by the axis, and one at the left end sat on the "Z min" label (issue 41)
        for value, style, label in ((1.0, Qt.PenStyle.DashLine, "1 px (dotted: 0.5 px)"),
                                    (0.5, Qt.PenStyle.DotLine, None)):
            line = pg.InfiniteLine(math.log10(value), angle=0, pen=pg.mkPen("#b00020", width=1, style=style),
                                   label=label, labelOpts={"position": 0.98, "color": "#b00020",
                                                           "anchors": [(1, 1), (1, 1)]})
            q.addItem(line)
            self.pixel_lines[value] = line
        self.zmin_line = pg.InfiniteLine(1.77, angle=90, pen=pg.mkPen(_COLORS["zmin"], width=1, style=Qt.PenStyle.DashDotLine),
                                         label="Z min {value:.2f} m",
                                         labelOpts={"position": 0.5, "color": _COLORS["zmin"], "rotateAxis": (1, 0)})
        q.addItem(self.zmin_line)

    def _room(self):
        """The room the panel is shown in: its dock's scroll area (which lays it out at no less than
        its minimum size, so the panel's own size would keep a side-by-side layout that does not fit)."""
        viewport = self.parentWidget()
        area = viewport.parentWidget() if viewport is not None else None
        if isinstance(area, QScrollArea) and area.widget() is self:
            return area.maximumViewportSize()
        return self.size()

    def resizeEvent(self, event) -> None:
        room = self._room()
        side_by_side_px = 2 * SIDE_BY_SIDE_PLOT_PX + self.plots_layout.spacing() + 8
        wide = room.width() > 1.4 * room.height() and room.width() >= side_by_side_px   # never scrolled sideways
        self.plots_layout.setDirection(QBoxLayout.Direction.LeftToRight if wide else QBoxLayout.Direction.TopToBottom)
        super().resizeEvent(event)

    def _schedule(self, plan) -> None:
        self._pending = plan
        self._timer.start()

    def draw(self, plan: ScenePlan | None) -> None:
        """Update every item for ``plan`` (None: empty plots and a hint)."""
        self._timer.stop()
        try:
            r = plan.derive() if plan is not None else None
        except InputError as exc:
            r = None
            self._set_note(str(exc))
        visible = r is not None
        for item in (self.scene_region, self.sharp_region, self.coc_line, self.pixels_line, self.focus_line,
                     self.disparity_scene, self.zmin_line):
            item.setVisible(visible)
        if plan is None or r is None:
            for curve in (self.blur_curve, self.airy_curve, *self.disparity_curves.values()):
                curve.setData([], [])
            if plan is None:
                self._set_note("No valid plan yet: fill in the Planner.")
            return

        f, pitch = plan.focal_length_mm, r.pixel_pitch_um
        near_mm, far_mm = plan.near_m * 1000, plan.far_m * 1000
        x_lo = max(0.5 * min(near_mm, r.min_distance_m * 1000), 4 * f + 1)
        x_hi = max(far_mm * 1.6, near_mm * 2)
        z_mm = np.geomspace(x_lo, x_hi, 600)
        z_m = z_mm / 1000.0

        # depth of field
        coc_um = plan.coc_mm * 1000
        y_top = max(3 * coc_um, r.airy_disk_um * 1.3)
        blur_um = optics.blur_diameter_mm(z_mm, r.focus_used_m * 1000, f, r.f_number_used) * 1000
        self.blur_curve.setData(z_m, np.minimum(blur_um, y_top * 2))
        self.airy_curve.setData([z_m[0], z_m[-1]], [r.airy_disk_um, r.airy_disk_um])
        self.scene_region.setRegion((plan.near_m, plan.far_m))
        self.sharp_region.setRegion((r.dof_near_m, min(r.dof_far_m, x_hi / 500.0)))
        self.coc_line.setValue(coc_um)
        self.pixels_line.setValue(2 * pitch)
        self.focus_line.setValue(r.focus_used_m)
        far_text = "∞" if math.isinf(r.dof_far_m) else f"{r.dof_far_m:.2f}"
        self._set_title(self.dof_plot, f"Depth of field at f/{r.f_number_used:.1f}: sharp {r.dof_near_m:.2f} – "
                                       f"{far_text} m")          # the scene: its shaded region
        self._set_range("dof", "x", x_lo / 1000, x_hi / 1000)
        self._set_range("dof", "y", -0.02 * y_top, 1.02 * y_top)

        # disparity against depth
        self.disparity_scene.setRegion((plan.near_m, plan.far_m))
        baselines = {"h": plan.spacing_mm[0], "v": plan.spacing_mm[1],
                     "row": r.baseline_mm["horizontal"], "col": r.baseline_mm["vertical"]}
        y_values = []
        for key, b in baselines.items():
            if b <= 0:
                self.disparity_curves[key].setData([], [])
                continue
            d = optics.disparity_px(b, z_mm, math.inf, f, pitch)
            y_values.append(d)
            self.disparity_curves[key].setData(z_m, d)
        self.zmin_line.setValue(r.min_distance_m)
        lo = min(0.2, float(min(v.min() for v in y_values)))
        hi = float(max(v.max() for v in y_values))
        self._set_range("disparity", "y", math.log10(lo), math.log10(hi * 1.5))
        self._set_range("disparity", "x", x_lo / 1000, x_hi / 1000)
        nd = r.neighbour_disparity_px
        self._set_note(
            f"Spacing {plan.spacing_mm[0]:g} × {plan.spacing_mm[1]:g} mm: neighbour disparity over the scene "
            f"{nd['horizontal']:.2f} px horizontal, {nd['vertical']:.2f} px vertical; row parallax "
            f"{r.row_parallax_px:.0f} px ({100 * r.row_parallax_fraction:.1f} % of the width) over "
            f"{r.baseline_mm['horizontal']:g} mm.")

    def _set_note(self, text: str) -> None:
        if self._texts.get("note") != text:
            self._texts["note"] = text
            self.note.setText(text)

    def _set_title(self, plot, text: str) -> None:
        key = plot.objectName()
        if self._texts.get(key) != text:
            self._texts[key] = text
            plot.setTitle(text, color="#30343a", size="10pt")

    def _set_range(self, plot: str, axis: str, lo: float, hi: float) -> None:
        """Show at least ``lo`` … ``hi`` on ``axis`` of ``plot`` ("dof" or "disparity"; the disparity
        plot's y in log10 units), keeping the current range when it still fits (:func:`sticky_range`)."""
        current = self.view_range(plot, axis)
        new = sticky_range(current, lo, hi)
        if new == current:
            return
        view = self._views[plot].getViewBox()
        if axis == "x":
            view.setXRange(*new, padding=0)
        else:
            view.setYRange(*new, padding=0)

    def view_range(self, plot: str, axis: str) -> tuple[float, float]:
        """The range ``axis`` of ``plot`` ("dof" or "disparity") shows now (after a mouse zoom too)."""
        x, y = self._views[plot].getViewBox().viewRange()
        lo, hi = x if axis == "x" else y
        return float(lo), float(hi)


#: a sticky range is kept while the wanted one fills at least this share of it
STICKY_FILL = 0.7


def sticky_range(current: tuple[float, float] | None, lo: float, hi: float) -> tuple[float, float]:
    """The range to show for data spanning ``lo`` … ``hi``: the ``current`` one while the data lies
    inside it and spans at least :data:`STICKY_FILL` of it, else exactly ``lo`` … ``hi``.

    Re-drawing an axis (new ticks, new labels) is most of what a plot update costs; keeping the range
    while the operator types small changes keeps the axes' cached pictures valid."""
    if hi <= lo:
        hi = lo + 1e-9
    if current is not None:
        c_lo, c_hi = current
        if c_lo <= lo and hi <= c_hi and (hi - lo) >= STICKY_FILL * (c_hi - c_lo):
            return current
    return (float(lo), float(hi))
