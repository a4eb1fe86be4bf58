"""Dataset → Process…: the processing profile editor, a before/after preview, and the run itself.

The editor is generated from the profile's dataclasses (one checkable group per step). The
preview renders one view with the current profile off the GUI thread (``JobRunner``) and shows it
split: the capture on the left of the divider, the processed view on the right. "Pick white" /
"Pick black" then a click on the preview set the colour step's points (full-resolution pixels of
the capture). Process runs :func:`lfstudio.processing.pipeline.process_dataset` on a local pool or
a Dask cluster with progress, ETA and Cancel; when it ends, ``state.datasetChanged`` is emitted.
"""

from __future__ import annotations

import dataclasses
import html
from typing import TYPE_CHECKING, Any

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt, Signal
from PySide6.QtGui import QColor, QImage, QPainter, QPen
from PySide6.QtWidgets import (QCheckBox, QComboBox, QDialog, QDialogButtonBox, QDoubleSpinBox, QFileDialog,
                               QFormLayout, QGroupBox, QHBoxLayout, QLabel, QLineEdit, QMessageBox, QPushButton,
                               QScrollArea, QSizePolicy, QSpinBox, QSplitter, QVBoxLayout, QWidget)

from lfstudio.errors import InputError, window_message
from lfstudio.gui.bridge import JobRunner
from lfstudio.gui.imageutil import rgb_to_qimage
from lfstudio.gui.settings import read_int, read_text, settings
from lfstudio.gui.widgets import JobProgressWidget, confirm_cancel_running, add_stop_button, screen_fitted
from lfstudio.dataset.manifest import processed_status
from lfstudio.dataset.profile import PARAMS, PROFILE_NAME, Profile

if TYPE_CHECKING:
    from lfstudio.processing.hdr import MergeReport
    from lfstudio.processing.pipeline import ProcessReport

STEP_TITLES = {
    "debayer": "1  Debayer (RAW → linear 16-bit)", "lens": "2  Lens distortion and lateral CA",
    "color": "3  Colour: black and white point", "shading": "4  Shading (flat field / vignetting)",
    "deflicker": "5  De-flicker (gain to the reference)", "rectify": "6  Rectification (calibration)",
    "resample": "7  Downsampling (area)", "reference": "Reference view", "output": "Output",
}
FLOAT_DECIMALS = 4
#: choices shown in operator words (the profile keeps its own values: processing.toml is unchanged)
CHOICE_WORDS = {
    ("deflicker", "statistic"): {"median_ratio": "median of per-pixel ratios (robust)",
                                 "median": "ratio of the medians"},
    ("debayer", "color_space"): {"srgb": "sRGB (the camera's colour matrix)", "raw": "camera RGB (no matrix)"},
}


def key_label(step: str, key: str) -> str:
    """A row's label: its description's (lfstudio.dataset.profile.PARAMS), e.g. "white output"."""
    param = PARAMS.get((step, key))
    return param.label if param is not None else key.replace("_", " ")


def field_label(step: str, key: str) -> str:
    """A setting as the dialog shows it: the step's title (without its number) › the row's label,
    e.g. "Colour: black and white point › white output" (used in every message about a field)."""
    return f"{STEP_TITLES.get(step, step).lstrip('0123456789 ')} › {key_label(step, key)}"


def _error_html(message: object) -> str:
    """A message in red for a rich-text label (escaped: "need low < high" must not start a tag)."""
    return f"<span style='color:#c00'>{html.escape(str(message))}</span>"


def to_display(img: np.ndarray) -> np.ndarray:
    """uint16 linear RGB -> uint8 with a 2.2 gamma (what the eye expects)."""
    f = np.clip(img.astype(np.float32) / 65535.0, 0.0, 1.0)
    return (np.power(f, 1 / 2.2) * 255.0 + 0.5).astype(np.uint8)


class SplitView(QWidget):
    """Before (left of the divider) / after (right) of one view; drag to move the divider.

    In pick mode a click emits ``picked(x, y)`` in image pixels instead of moving the divider.
    """

    picked = Signal(float, float)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.before: QImage | None = None
        self.after: QImage | None = None
        self.split = 0.5
        self.pick_mode: str | None = None
        self.marks: dict[str, tuple[float, float]] = {}
        self.setMinimumSize(420, 300)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.setMouseTracking(True)
        self.setToolTip("Left: capture, right: processed. Drag to move the divider.")

    def set_images(self, before: np.ndarray, after: np.ndarray) -> None:
        self.before, self.after = rgb_to_qimage(to_display(before)), rgb_to_qimage(to_display(after))
        self.update()

    def image_rect(self) -> QRectF:
        if self.after is None:
            return QRectF()
        w, h = self.after.width(), self.after.height()
        s = min(self.width() / w, self.height() / h)
        return QRectF((self.width() - w * s) / 2, (self.height() - h * s) / 2, w * s, h * s)

    def to_image(self, pos: QPointF) -> tuple[float, float] | None:
        r = self.image_rect()
        if self.after is None or r.isEmpty() or not r.contains(pos):
            return None
        s = r.width() / self.after.width()
        return (pos.x() - r.x()) / s - 0.5, (pos.y() - r.y()) / s - 0.5

    def paintEvent(self, event) -> None:
        p = QPainter(self)
        p.fillRect(self.rect(), QColor(32, 32, 32))
        if self.after is None or self.before is None:
            p.setPen(QColor(200, 200, 200))
            p.drawText(self.rect(), Qt.AlignmentFlag.AlignCenter, "Preview: choose a view and press Update preview")
            return
        r = self.image_rect()
        split = 1.0 if self.pick_mode else self.split
        sx = r.x() + r.width() * split
        p.save()
        p.setClipRect(QRectF(r.x(), r.y(), sx - r.x(), r.height()))
        p.drawImage(r, self.before)
        p.restore()
        p.save()
        p.setClipRect(QRectF(sx, r.y(), r.right() - sx, r.height()))
        p.drawImage(r, self.after)
        p.restore()
        p.setPen(QPen(QColor(255, 210, 0), 2))
        if not self.pick_mode:
            p.drawLine(QPointF(sx, r.y()), QPointF(sx, r.bottom()))
            p.drawText(QRectF(r.x() + 6, r.y() + 4, 200, 20), Qt.AlignmentFlag.AlignLeft, "capture")
            p.drawText(QRectF(r.right() - 206, r.y() + 4, 200, 20), Qt.AlignmentFlag.AlignRight, "processed")
        else:
            p.drawText(QRectF(r.x() + 6, r.y() + 4, 400, 20), Qt.AlignmentFlag.AlignLeft, f"click the {self.pick_mode} patch")
        s = r.width() / self.after.width()
        for name, (x, y) in self.marks.items():
            c = QPointF(r.x() + (x + 0.5) * s, r.y() + (y + 0.5) * s)
            p.setPen(QPen(QColor(255, 255, 255) if name == "black" else QColor(0, 0, 0), 2))
            p.drawEllipse(c, 7, 7)
            p.drawText(c + QPointF(9, -9), name)

    def mousePressEvent(self, event) -> None:
        pos = event.position()
        if self.pick_mode:
            xy = self.to_image(pos)
            if xy is not None:
                self.picked.emit(*xy)
            return
        self._drag(pos)

    def mouseMoveEvent(self, event) -> None:
        if event.buttons() & Qt.MouseButton.LeftButton and not self.pick_mode:
            self._drag(event.position())

    def _drag(self, pos: QPointF) -> None:
        r = self.image_rect()
        if r.width() > 0:
            self.split = float(np.clip((pos.x() - r.x()) / r.width(), 0.0, 1.0))
            self.update()


class StepEditor(QGroupBox):
    """One profile section: a checkable group (when the step has ``enabled``) with a field per setting."""

    def __init__(self, name: str, step: Any, parent: QWidget | None = None):
        super().__init__(STEP_TITLES.get(name, name), parent)
        self.name = name
        self.setObjectName(f"step_{name}")
        self.fields: dict[str, QWidget] = {}
        form = QFormLayout(self)
        self.form = form
        form.setFieldGrowthPolicy(QFormLayout.FieldGrowthPolicy.AllNonFixedFieldsGrow)
        for f in dataclasses.fields(step):
            value = getattr(step, f.name)
            if f.name == "enabled":
                self.setCheckable(True)
                self.setChecked(bool(value))
                continue
            widget = self._widget(f.name, value)
            param = PARAMS[(name, f.name)]
            widget.setToolTip(f"{param.tip} (valid: {param.valid()})" if param.number is not None else param.tip)
            self.fields[f.name] = widget
            form.addRow(key_label(name, f.name), widget)
        if self.isCheckable():  # a switched-off step folds away
            self.toggled.connect(self._fold)
            self._fold(self.isChecked())

    def _fold(self, on: bool) -> None:
        for row in range(self.form.rowCount()):
            self.form.setRowVisible(row, on)

    def _widget(self, key: str, value: Any) -> QWidget:
        """The editor of one setting, made from its description: choices -> a list, true/false -> a
        check box, a whole number -> a spin box, a number -> a decimal spin box (each holding exactly
        the described range), a list of numbers or text -> a line."""
        param = PARAMS[(self.name, key)]
        number = param.number
        if param.choices:
            w = QComboBox()
            words = CHOICE_WORDS.get((self.name, key), {})
            for choice in param.choices:
                w.addItem(words.get(str(choice), str(choice)), choice)
            w.setCurrentIndex(max(0, w.findData(str(value))))
        elif param.flag:
            w = QCheckBox()
            w.setChecked(value)
        elif number is not None and not param.lengths and number.integer:
            w = QSpinBox()
            low, high = self._range(key, -1_000_000_000, 1_000_000_000, 1)
            w.setRange(int(low), int(high))
            if number.unit:
                w.setSuffix(f" {number.unit}")
            w.setValue(value)
        elif number is not None and not param.lengths:
            w = QDoubleSpinBox()
            w.setDecimals(FLOAT_DECIMALS)
            low, high = self._range(key, -1e9, 1e9, 10.0 ** -FLOAT_DECIMALS)
            w.setRange(low, high)
            if number.unit:
                w.setSuffix(f" {number.unit}")
            w.setValue(value)
        elif param.lengths:
            w = QLineEdit(param.to_text(value))
        else:
            w = QLineEdit(str(value))
        return w

    def _range(self, key: str, low: float, high: float, step: float) -> tuple[float, float]:
        """The spin box's range: the described range of this setting (an open bound moved in by one
        step), each end within [low, high]; so the widget never holds a value the profile refuses."""
        limits = PARAMS[(self.name, key)].number
        if limits is None:
            return low, high
        if limits.low is not None:
            low = max(low, limits.low + step if limits.low_open else limits.low)
        if limits.high is not None:
            high = min(high, limits.high)
        return low, high

    def set_value(self, key: str, value: Any) -> None:
        w = self.fields[key]
        if isinstance(w, QComboBox):
            if w.findData(str(value)) >= 0:
                w.setCurrentIndex(w.findData(str(value)))
        elif isinstance(w, QCheckBox):
            w.setChecked(bool(value))
        elif isinstance(w, (QSpinBox, QDoubleSpinBox)):
            w.setValue(value)
        elif isinstance(w, QLineEdit):
            w.setText(" ".join(f"{v:g}" for v in value) if isinstance(value, list) else str(value))

    def values(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.isCheckable():
            out["enabled"] = self.isChecked()
        for key, w in self.fields.items():
            if isinstance(w, QComboBox):
                out[key] = w.currentData()
            elif isinstance(w, QCheckBox):
                out[key] = w.isChecked()
            elif isinstance(w, QSpinBox):
                out[key] = int(w.value())
            elif isinstance(w, QDoubleSpinBox):
                out[key] = float(w.value())
            elif isinstance(w, QLineEdit):
                text = w.text().strip()
                if PARAMS[(self.name, key)].lengths:
                    try:
                        out[key] = [float(t) for t in text.replace(",", " ").split()]
                    except ValueError:
                        raise InputError(field_label(self.name, key), f"{text!r} is not a list of numbers",
                                         "numbers separated by spaces")
                else:
                    out[key] = text
        return out


def _preview_job(root: str, profile: Profile, row: int, column: int, *, progress, cancel):
    from lfstudio.processing.pipeline import preview

    progress(0, 1, "rendering preview")
    result = preview(root, profile, row, column)
    progress(1, 1, "preview ready")
    return result


def _process_job(root: str, profile: Profile, workers: int | None, cluster: str | None, force: bool, *,
                 progress, cancel) -> tuple[ProcessReport, MergeReport | None]:
    """The views processed, and a bracketed scan's frames merged to linear HDR too: both reports
    (the merge's None for a scan without brackets)."""
    from lfstudio.dataset import Dataset
    from lfstudio.processing.pipeline import process_dataset

    bracketed = bool(Dataset.open(root).manifest.get("bracket"))

    def half(second: bool):
        """A bracketed scan's two passes (the views, then their merge) as the two halves of one bar."""
        def report(done: int, total: int, message: str = "") -> None:
            progress(done + (total if second else 0), 2 * total, message)
        return report if bracketed else progress

    report = process_dataset(root, profile, workers=workers, cluster=cluster, force=force,
                             progress=half(False), cancel=cancel)
    if not bracketed:
        return report, None
    from lfstudio.processing.hdr import merge_dataset

    return report, merge_dataset(root, profile=profile, workers=workers, cluster=cluster, force=force,
                                 progress=half(True), cancel=cancel)


class ProcessDialog(QDialog):
    """Profile editor + before/after preview + run with progress, ETA and Cancel."""

    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.setObjectName("processDialog")
        self.setWindowTitle("Process views")
        self.resize(screen_fitted(self, 1250, 800))
        ds = state.dataset
        self.root = str(ds.root)
        try:
            profile = Profile.for_dataset(self.root)
        except InputError as exc:  # a hand-edited processing.toml with a mistake: say so, start from defaults
            state.report_error("Processing profile", f"{exc}\n\nThe dialog starts from the defaults; "
                                                     "saving or processing replaces the file.")
            profile = Profile()
        self.preview_scale = 1.0  # preview pixels per full-resolution pixel

        # -- profile editor (left) --
        self.editors: dict[str, StepEditor] = {}
        editor_box = QWidget()
        ed_lay = QVBoxLayout(editor_box)
        for name in ("debayer", "lens", "color", "shading", "deflicker", "rectify", "resample", "reference",
                     "output"):
            ed = StepEditor(name, getattr(profile, name))
            self.editors[name] = ed
            ed_lay.addWidget(ed)
        ed_lay.addStretch(1)
        scroll = QScrollArea()
        scroll.setWidget(editor_box)
        scroll.setWidgetResizable(True)
        scroll.setMinimumWidth(400)
        profile_buttons = QHBoxLayout()
        for text, tip, slot in (("Load…", "Load a processing profile (TOML)", self.load_profile),
                                ("Save as…", "Save this profile to a TOML file", self.save_profile),
                                ("Defaults", "Reset every step to the built-in defaults", self.reset_profile)):
            b = QPushButton(text)
            b.setToolTip(tip)
            b.clicked.connect(slot)
            profile_buttons.addWidget(b)
        left = QWidget()
        l_lay = QVBoxLayout(left)
        l_lay.setContentsMargins(0, 0, 0, 0)
        l_lay.addWidget(QLabel(f"<b>Profile</b> (saved as {PROFILE_NAME} in the dataset)"))
        l_lay.addWidget(scroll, 1)
        l_lay.addLayout(profile_buttons)

        # -- preview (right) --
        self.split_view = SplitView()
        self.split_view.picked.connect(self._picked)
        self.row_spin, self.col_spin = QSpinBox(), QSpinBox()
        self.row_spin.setRange(0, max(0, ds.grid.rows - 1))
        self.col_spin.setRange(0, max(0, ds.grid.columns - 1))
        self.row_spin.setValue(ds.grid.rows // 2)
        self.col_spin.setValue(ds.grid.columns // 2)
        self.row_spin.setToolTip("Row of the view to preview")
        self.col_spin.setToolTip("Column of the view to preview")
        self.preview_button = QPushButton("Update preview")
        self.preview_button.setToolTip("Process the chosen view with this profile (nothing is written)")
        self.preview_button.setShortcut("F5")
        self.preview_button.clicked.connect(self.update_preview)
        self.pick_white = QPushButton("Pick white")
        self.pick_white.setToolTip("Then click a white patch in the preview: sets the colour step's white point")
        self.pick_black = QPushButton("Pick black")
        self.pick_black.setToolTip("Then click a black patch in the preview: sets the colour step's black point")
        for b, name in ((self.pick_white, "white"), (self.pick_black, "black")):
            b.setCheckable(True)
            b.setEnabled(False)
            b.toggled.connect(lambda on, n=name: self._pick_mode(n, on))
        self.preview_info = QLabel("")
        self.preview_info.setWordWrap(True)
        pv_bar = QHBoxLayout()
        pv_bar.addWidget(QLabel("Row"))
        pv_bar.addWidget(self.row_spin)
        pv_bar.addWidget(QLabel("Column"))
        pv_bar.addWidget(self.col_spin)
        pv_bar.addWidget(self.preview_button)
        pv_bar.addStretch(1)
        pv_bar.addWidget(self.pick_white)
        pv_bar.addWidget(self.pick_black)
        right = QWidget()
        r_lay = QVBoxLayout(right)
        r_lay.setContentsMargins(0, 0, 0, 0)
        r_lay.addLayout(pv_bar)
        r_lay.addWidget(self.split_view, 1)
        r_lay.addWidget(self.preview_info)
        self.hdr_box = self._hdr_section(ds)       # a bracketed scan: what Process will merge, and a look at it
        if self.hdr_box is not None:
            r_lay.addWidget(self.hdr_box)

        splitter = QSplitter()
        splitter.addWidget(left)
        splitter.addWidget(right)
        splitter.setStretchFactor(1, 1)
        splitter.setSizes([430, 820])

        # -- run (bottom) --
        s = settings()
        self.workers_spin = QSpinBox()
        self.workers_spin.setRange(0, 256)
        self.workers_spin.setSpecialValueText("in this process")
        from lfstudio.processing.executors import default_workers
        self.workers_spin.setValue(read_int("process/workers", default_workers(), s))
        self.workers_spin.setToolTip("Local worker processes (one per core is fastest)")
        self.cluster_edit = QLineEdit(read_text("process/cluster", "", s))
        self.cluster_edit.setPlaceholderText("tcp://HOST:8786 (empty: this computer)")
        self.cluster_edit.setToolTip("Address of a Dask scheduler; its workers must see the dataset at the same path")
        self.force_check = QCheckBox("Redo finished views")
        self.force_check.setToolTip("Process every view again, even those already done with this profile")
        self.process_button = QPushButton("Process")
        self.process_button.setDefault(True)
        self.process_button.setToolTip("Process every captured view into the dataset's processed/ folder")
        self.process_button.clicked.connect(self.start_processing)
        run_bar = QHBoxLayout()
        run_bar.addWidget(QLabel("Workers"))
        run_bar.addWidget(self.workers_spin)
        run_bar.addWidget(QLabel("Cluster"))
        run_bar.addWidget(self.cluster_edit, 1)
        run_bar.addWidget(self.force_check)
        run_bar.addWidget(self.process_button)
        close_box = QDialogButtonBox(QDialogButtonBox.StandardButton.Close)
        self.close_button = close_box.button(QDialogButtonBox.StandardButton.Close)
        self.close_button.setToolTip("Close the dialog (while processing runs, asks whether to cancel it)")
        close_box.rejected.connect(self.reject)
        run_bar.addWidget(close_box)
        self.runner = JobRunner(self)
        self.progress = JobProgressWidget(self.runner)
        self.result_label = QLabel(self._status_text())
        self.result_label.setWordWrap(True)
        self.result_label.setObjectName("processResult")

        lay = QVBoxLayout(self)
        lay.addWidget(splitter, 1)
        lay.addLayout(run_bar)
        lay.addWidget(self.progress)
        lay.addWidget(self.result_label)
        add_stop_button(self, lay)      # STOP in sight while this dialog covers the window's

        self.preview_runner = JobRunner(self)
        self.preview_runner.finished.connect(self._preview_done)
        self.preview_runner.failed.connect(self._preview_failed)
        self.runner.finished.connect(self._process_done)
        self.runner.failed.connect(self._process_failed)
        self.runner.cancelled.connect(self._process_cancelled)
        self._set_marks()

    # -- profile -----------------------------------------------------------------------------------
    def profile(self) -> Profile:
        """The profile in the editor; raises InputError naming the field."""
        return Profile.from_dict({name: ed.values() for name, ed in self.editors.items()}, "Process dialog",
                                 field=field_label)

    def set_profile(self, profile: Profile) -> None:
        for name, ed in self.editors.items():
            step = getattr(profile, name)
            if ed.isCheckable():
                ed.setChecked(step.enabled)
            for key in ed.fields:
                ed.set_value(key, getattr(step, key))
        self._set_marks()

    def load_profile(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Load processing profile", self.root, "TOML (*.toml)")
        if path:
            try:
                self.set_profile(Profile.load(path))
            except InputError as exc:
                QMessageBox.warning(self, "Load profile", str(exc))

    def save_profile(self) -> None:
        try:
            profile = self.profile()
        except InputError as exc:
            QMessageBox.warning(self, "Save profile", str(exc))
            return
        path, _ = QFileDialog.getSaveFileName(self, "Save processing profile", self.root, "TOML (*.toml)")
        if path:
            profile.save(path)

    def reset_profile(self) -> None:
        self.set_profile(Profile())

    # -- preview -----------------------------------------------------------------------------------
    def update_preview(self) -> None:
        if self.preview_runner.running:
            return
        try:
            profile = self.profile()
        except InputError as exc:
            self.preview_info.setText(_error_html(exc))
            return
        self.preview_button.setEnabled(False)
        self.preview_info.setText("Rendering the preview…")
        self.preview_runner.start(_preview_job, self.root, profile, self.row_spin.value(), self.col_spin.value())

    def _preview_done(self, result) -> None:
        before, after, info = result
        self.preview_button.setEnabled(True)
        profile = self.profile()
        self.preview_scale = profile.resample.scale if profile.resample.enabled else 1.0
        self.split_view.set_images(before, after)
        self._set_marks()
        for b in (self.pick_white, self.pick_black):
            b.setEnabled(True)
        t = info["timings_s"]
        self.preview_info.setText(
            f"View row {info['row']}, column {info['column']}: {after.shape[1]} × {after.shape[0]} px, "
            f"de-flicker gain {info['gain']:.4f}; decode {t['decode']:.2f} s, steps {t['process']:.2f} s")

    def _preview_failed(self, message: str) -> None:
        self.preview_button.setEnabled(True)
        self.preview_info.setText(_error_html(message))

    def _pick_mode(self, name: str, on: bool) -> None:
        other = self.pick_black if name == "white" else self.pick_white
        if on:
            other.setChecked(False)
            self.split_view.pick_mode = name
        elif self.split_view.pick_mode == name:
            self.split_view.pick_mode = None
        self.split_view.update()

    def _picked(self, x: float, y: float) -> None:
        name = self.split_view.pick_mode
        s = self.preview_scale
        full = [round((x + 0.5) / s - 0.5, 1), round((y + 0.5) / s - 0.5, 1)]
        color = self.editors["color"]
        color.setChecked(True)
        color.set_value("mode", "points")
        color.set_value(f"{name}_point_px", full)
        (self.pick_white if name == "white" else self.pick_black).setChecked(False)
        self._set_marks()
        self.state.show_status(f"{name} point set to x {full[0]:g}, y {full[1]:g} (full-resolution pixels)")

    def _set_marks(self) -> None:
        marks = {}
        try:
            values = self.editors["color"].values()
        except InputError:
            values = {}
        if values.get("mode") == "points":
            s = self.preview_scale
            for name in ("white", "black"):
                x, y = values[f"{name}_point_px"]
                marks[name] = ((x + 0.5) * s - 0.5, (y + 0.5) * s - 0.5)
        self.split_view.marks = marks
        self.split_view.update()

    # -- run ---------------------------------------------------------------------------------------
    def _status_text(self) -> str:
        ds = self.state.dataset
        views = ds.done_views()
        done = sum(1 for v in views if processed_status(v) == "done")
        failed = sum(1 for v in views if processed_status(v) == "failed")
        text = f"{len(views)} captured views: {done} processed"
        if failed:
            text += f", {failed} failed"
        return text + "."

    def start_processing(self) -> None:
        if self.runner.running:
            return
        try:
            profile = self.profile()
        except InputError as exc:
            self.result_label.setText(_error_html(exc))
            return
        cluster = self.cluster_edit.text().strip() or None
        workers = None if cluster else self.workers_spin.value()
        s = settings()
        s.setValue("process/workers", self.workers_spin.value())
        s.setValue("process/cluster", self.cluster_edit.text().strip())
        self.process_button.setEnabled(False)
        self.result_label.setText("Processing…")
        self.runner.start(_process_job, self.root, profile, workers, cluster, self.force_check.isChecked())

    def _hdr_section(self, ds) -> QGroupBox | None:
        """"HDR merge" for a dataset scanned with an exposure bracket (None without one): the frames a
        view has, what Process writes from them, how many views are merged, and View radiance…"""
        from lfstudio.dataset.bracket import Bracket
        from lfstudio.processing.hdr import MergeOptions

        recorded = ds.manifest.get("bracket")
        if not recorded:
            return None
        try:
            bracket = Bracket.from_manifest(recorded)
        except InputError:
            return None
        box = QGroupBox("HDR merge (this scan is bracketed)")
        box.setObjectName("hdrSection")
        options = MergeOptions()
        self.hdr_label = QLabel("")
        self.hdr_label.setObjectName("hdrHint")
        self.hdr_label.setWordWrap(True)
        self.hdr_label.setText(
            f"Each view has {bracket.frames} frames ({html.escape(bracket.describe())}). After the views, Process "
            f"merges each view's frames into one linear radiance image: <code>{options.folder}/rRR_cCCC"
            f"{options.suffix}</code> (32-bit float {'OpenEXR' if options.format == 'exr' else 'TIFF'}, the steps "
            "above applied to its geometry) with a tone-mapped 16-bit PNG in "
            f"<code>{options.folder}/preview/</code>. {self._hdr_count_text(ds)}")
        self.radiance_button = QPushButton("View radiance…")
        self.radiance_button.setObjectName("viewRadianceButton")
        self.radiance_button.setToolTip("The merged radiance of the preview's view under an exposure slider "
                                        "(also Dataset → HDR radiance of a view…)")
        self.radiance_button.clicked.connect(self.view_radiance)
        lay = QVBoxLayout(box)
        lay.addWidget(self.hdr_label)
        row = QHBoxLayout()
        row.addStretch(1)
        row.addWidget(self.radiance_button)
        lay.addLayout(row)
        self._refresh_hdr()
        return box

    @staticmethod
    def _hdr_count_text(ds) -> str:
        from lfstudio.gui.views.radiance import merged_views

        if ds is None:              # the dataset could not be read: the section only informs
            return ""
        merged, total = len(merged_views(ds)), len(ds.done_views())
        return f"Merged so far: {merged} of {total} views." if merged else "No view merged yet."

    def _refresh_hdr(self) -> None:
        if getattr(self, "radiance_button", None) is None:
            return
        from lfstudio.dataset import Dataset
        from lfstudio.gui.views.radiance import merged_views

        try:                        # read once: the button and the count from the same manifest
            ds = Dataset.open(self.root)
        except Exception:  # noqa: BLE001 - the section only informs
            ds = None
        self.radiance_button.setEnabled(ds is not None and bool(merged_views(ds)))
        text = self.hdr_label.text()
        head = text.rsplit(" Merged so far:", 1)[0].rsplit(" No view merged yet.", 1)[0]
        self.hdr_label.setText(f"{head} {self._hdr_count_text(ds)}")

    def view_radiance(self) -> None:
        from lfstudio.gui.views.radiance import RadianceDialog, merged_views

        view = (self.row_spin.value(), self.col_spin.value())
        merged = merged_views(self.state.dataset) if self.state.dataset is not None else []
        if merged and view not in merged:
            view = merged[len(merged) // 2]
        self.radiance_dialog = RadianceDialog(self.state, self, view)
        self.radiance_dialog.show()

    def _reload_dataset(self) -> None:
        from lfstudio.dataset import Dataset
        from lfstudio.errors import LfError

        try:
            self.state.set_dataset(Dataset.open(self.root))
        except LfError as exc:
            self.state.report_error("Process", window_message(exc))

    def _process_done(self, outcome: tuple[ProcessReport, MergeReport | None]) -> None:
        report, merged = outcome
        self.process_button.setEnabled(True)
        self._reload_dataset()
        self._refresh_hdr()
        text = report.summary().replace("\n", "<br>")
        if merged is not None:
            text += "<br>" + html.escape(merged.summary()).replace("\n", "<br>")
            if merged.failed:
                text += "<br><span style='color:#c00'>HDR merge failed:<br>" + "<br>".join(
                    f"row {r}, column {c}: {html.escape(msg)}" for r, c, msg in merged.failed[:10]) + "</span>"
        if report.failed:
            text += "<br><span style='color:#c00'>Failed views:<br>" + "<br>".join(
                f"row {r}, column {c}: {html.escape(msg)}" for r, c, msg in report.failed[:10]) + "</span>"
        self.result_label.setText(text)
        self.state.show_status(f"Processing done: {report.processed} processed, {len(report.failed)} failed")

    def _process_failed(self, message: str) -> None:
        self.process_button.setEnabled(True)
        self.result_label.setText(_error_html(message))

    def _process_cancelled(self) -> None:
        self.process_button.setEnabled(True)
        self._reload_dataset()
        self.result_label.setText("Cancelled. " + self._status_text() + " Process again to resume.")

    def done(self, result: int) -> None:
        if not confirm_cancel_running(self, self.runner, "Process", "Processing is running. Cancel it and close?"):
            return
        super().done(result)
