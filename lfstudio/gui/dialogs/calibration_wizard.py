"""The calibration wizard: choose views → detect and match (progress, ETA, cancel) → fit → results.

Results: the angles with their measured uncertainty (1σ per angle, and the rectification error it
allows at the image corners across the grid, 1σ/2σ — the same lines as the CLI report), the numbers,
residual histograms before/after (axes in px as they are: no SI scaling), the residuals binned per
image region over an image (mean vector and RMS per region: readable at tens of thousands of
matches, :func:`residual_field`), a per-view residual map over the
grid, epipolar-plane images before/after rectification and two neighbouring views with horizontal
guide lines. *Accept and save* writes ``calibration.json`` into the dataset. All image reading and
fitting runs on worker threads (:class:`lfstudio.gui.bridge.JobRunner`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtGui import QFont
from PySide6.QtWidgets import (QCheckBox, QComboBox, QDialog, QDoubleSpinBox, QFormLayout, QGraphicsGridLayout,
                               QGridLayout, QGroupBox,
                               QHBoxLayout, QLabel, QPlainTextEdit, QPushButton, QSlider, QSpinBox,
                               QStackedWidget, QTabWidget, QVBoxLayout, QWidget)

from lfstudio.calibration.calibrate import calibrate_dataset
from lfstudio.calibration.model import save_calibration
from lfstudio.calibration.epi import dataset_epis, load_preview, preview_homography, rectify_image
from lfstudio.calibration.features import DEFAULT_WORK_WIDTH_PX
from lfstudio.calibration.model import CalibrationUncertainty
from lfstudio.calibration.pairs import DEFAULT_PAIR_SET, DEFAULT_VIEWS, PAIR_SETS, make_pairs
from lfstudio.calibration.model import held_angles
from lfstudio.calibration.report import format_report, uncertainty_lines
from lfstudio.dataset.grid import View
from lfstudio.dataset.paths import view_stem
from lfstudio.errors import LfError
from lfstudio.gui.bridge import JobRunner
from lfstudio.gui.settings import read_int, settings
from lfstudio.gui.widgets import GridPicker, JobProgressWidget, calibration_warnings, add_stop_button, screen_fitted
from lfstudio.jobs import count

PAGE_VIEWS, PAGE_RUN, PAGE_RESULTS = range(3)

#: version of the wizard's saved choices (2: a choice equal to the default is not saved)
SETTINGS_VERSION = 2


def _calibration_job(dataset, views, *, preview_width_px: int = 900, progress, cancel, **kwargs) -> dict:
    run = calibrate_dataset(dataset, views, progress=progress, cancel=cancel, **kwargs)
    first = run.matches[0].view_a if run.matches else run.views[0]
    img, full = load_preview(dataset.path_of(dataset.view(*first)), preview_width_px)
    return {"run": run, "preview": img, "preview_view": first, "full_size": full}


def _inspection_job(dataset, document, row: int, column: int, y_frac: float, x_frac: float, *, progress,
                    cancel) -> dict:
    epis = dataset_epis(dataset, document, row=row, column=column, y_frac=y_frac, x_frac=x_frac, count=24,
                        width_px=800, progress=progress, cancel=cancel)
    neighbours = None
    hv = (epis.get("horizontal") or {}).get("views") or []
    if len(hv) >= 2:
        k = max(0, len(hv) // 2 - 1)
        a, b = hv[k], hv[k + 1]
        ia, full = load_preview(dataset.path_of(dataset.view(*a)), 800)
        ib, _ = load_preview(dataset.path_of(dataset.view(*b)), 800)
        H = preview_homography(np.asarray(document["homography"], float), full, ia)
        neighbours = {"views": (a, b), "before": (ia, ib), "after": (rectify_image(ia, H), rectify_image(ib, H))}
    return {"epis": epis, "neighbours": neighbours}


def plain_px_axis(axis: pg.AxisItem, label: str) -> None:
    """An axis in pixels, numbered as they are: pyqtgraph would otherwise read residuals of ±0.5 px
    as "±500 (x0.001)" (its SI-prefix scaling of values below 1; turning it off must come before
    any range is set, pyqtgraph issue 2899)."""
    if hasattr(axis, "setSIPrefixEnableRanges"):
        axis.setSIPrefixEnableRanges(())
    axis.enableAutoSIPrefix(False)
    axis.setLabel(label, units="px")


def residual_field(points_px: np.ndarray, residual_px: np.ndarray, vertical: np.ndarray, size_px: tuple[int, int],
                   cells: tuple[int, int] = (12, 8), min_count: int = 3) -> dict[str, np.ndarray]:
    """The residuals of many matches summarised per image region (``cells`` = columns, rows).

    ``points_px`` (n, 2) are the matches' x, y in an image of ``size_px`` (width, height);
    ``residual_px`` (n,) their residuals, measured vertically (``vertical``: row pairs) or horizontally
    (column pairs). Returns ``centres`` (m, 2) and ``mean`` (m, 2: mean horizontal, mean vertical
    residual) of the regions holding at least ``min_count`` matches, and ``rms`` (rows, columns) per
    region (NaN where too few), ``count`` likewise."""
    cols, rows = cells
    w, h = size_px
    pts = np.asarray(points_px, float).reshape(-1, 2)
    res = np.asarray(residual_px, float).ravel()
    vert = np.asarray(vertical, bool).ravel()
    ci = np.clip((pts[:, 0] / max(w, 1) * cols).astype(int), 0, cols - 1)
    ri = np.clip((pts[:, 1] / max(h, 1) * rows).astype(int), 0, rows - 1)
    flat = ri * cols + ci
    n = rows * cols
    count = np.bincount(flat, minlength=n).astype(float)
    sq = np.bincount(flat, res * res, minlength=n)
    sums, nums = [], []
    for sel in (~vert, vert):             # horizontal residuals (column pairs), vertical ones (row pairs)
        sums.append(np.bincount(flat[sel], res[sel], minlength=n))
        nums.append(np.bincount(flat[sel], minlength=n).astype(float))
    ok = count >= min_count
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.column_stack([np.where(k > 0, s / k, 0.0) for s, k in zip(sums, nums)])
        rms = np.where(ok, np.sqrt(sq / count), np.nan)
    idx = np.flatnonzero(ok)
    centres = np.column_stack([(idx % cols + 0.5) * w / cols, (idx // cols + 0.5) * h / rows])
    return {"centres": centres, "mean": mean[idx], "rms": rms.reshape(rows, cols),
            "count": count.reshape(rows, cols)}


def _colormap(name: str) -> pg.ColorMap:
    """One of the colour maps pyqtgraph ships (RuntimeError if this pyqtgraph lacks it)."""
    cmap = pg.colormap.get(name)
    if cmap is None:
        raise RuntimeError(f"pyqtgraph has no colour map {name!r}")
    return cmap


def _image_plot(title: str) -> tuple[pg.PlotItem, pg.ImageItem]:
    plot = pg.PlotItem(title=title)
    plot.getViewBox().invertY(True)
    plot.getViewBox().setAspectLocked(False)
    plot.hideButtons()
    item = pg.ImageItem(axisOrder="row-major")
    plot.addItem(item)
    return plot, item


def uncertainty_html(doc: dict) -> str:
    """The uncertainty lines of the CLI report (:func:`lfstudio.calibration.report.uncertainty_lines`)
    and the principal point's status, as rich text; red when the views cannot fix the rotation."""
    import html

    u = CalibrationUncertainty.from_document(doc)
    rows = [html.escape(line.strip()) for line in uncertainty_lines(doc)[1:]]
    rows.append("principal point " + html.escape(doc.get("principal_point_reason") or
                                                 ("estimated" if doc.get("principal_point_estimated")
                                                  else "at the image centre")))
    text = "<br>".join(rows)
    if u is not None and u.degenerate:
        text = ("<span style='color:#b00020'><b>These views cannot fix the rotation for this grid</b> "
                "(see the warnings in Numbers).</span><br>" + text)
    return text


def _knows_focal_length(dataset) -> bool:
    """Whether the dataset's camera and lens give the focal length in pixels (imported images without
    EXIF do not: the wizard's Focal length field must)."""
    from lfstudio.errors import LfError

    try:
        return dataset is not None and dataset.focal_length_px() > 0
    except (LfError, ValueError, TypeError):
        return False


class CalibrationWizard(QDialog):
    """Modeless wizard over ``state.dataset``; ``accepted_document`` is set when saved."""

    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.dataset = state.dataset
        self.setWindowTitle("Calibrate — self-calibration of the camera orientation")
        self.setObjectName("calibrationWizard")
        self.resize(screen_fitted(self, 1150, 800))
        self.result: dict | None = None
        self.accepted_document: dict | None = None
        self.runner = JobRunner(self)
        self.inspect_runner = JobRunner(self)

        grid = self.dataset.grid
        self.available = set(self.dataset.captured_views())
        self.stack = QStackedWidget()
        self.stack.addWidget(self._build_views_page(grid.columns, grid.rows))
        self.stack.addWidget(self._build_run_page())
        self.stack.addWidget(self._build_results_page())

        self.back_button = QPushButton("< Back")
        self.back_button.setToolTip("Return to the choice of views")
        self.next_button = QPushButton("Detect, match and fit >")
        self.next_button.setToolTip("Detect SIFT features in the chosen views, match them and fit the orientation")
        self.next_button.setDefault(True)
        self.accept_button = QPushButton("Accept and save")
        self.accept_button.setToolTip("Write calibration.json into the dataset (processing will rectify with it)")
        self.close_button = QPushButton("Close")
        self.close_button.setToolTip("Close without saving (a running job is cancelled)")
        self.step_label = QLabel()
        self.step_label.setObjectName("stepLabel")
        buttons = QHBoxLayout()
        buttons.addWidget(self.step_label, 1)
        for b in (self.back_button, self.next_button, self.accept_button, self.close_button):
            buttons.addWidget(b)
        lay = QVBoxLayout(self)
        lay.addWidget(self.stack, 1)
        lay.addLayout(buttons)
        add_stop_button(self, lay)      # STOP in sight while this dialog covers the window's

        self.back_button.clicked.connect(self.go_back)
        self.next_button.clicked.connect(self.start_calibration)
        self.accept_button.clicked.connect(self.accept_and_save)
        self.close_button.clicked.connect(self.close)
        self.runner.progress.connect(self._on_progress)
        self.runner.finished.connect(self._on_finished)
        self.runner.failed.connect(self._on_failed)
        self.runner.cancelled.connect(self._on_cancelled)
        self.inspect_runner.finished.connect(self._show_inspection)
        self.inspect_runner.failed.connect(lambda msg: self.inspect_status.setText(f"Could not build the EPIs: {msg}"))
        self.inspect_runner.progress.connect(
            lambda d, t, m, e: self.inspect_status.setText(f"{m} ({d}/{t})"))
        self._restore_settings()
        self._set_page(PAGE_VIEWS)

    # -- page 1: views ------------------------------------------------------------------------------
    def _build_views_page(self, columns: int, rows: int) -> QWidget:
        page = QWidget()
        self.picker = GridPicker(columns, rows, self.available)
        self.picker.selectionChanged.connect(self._update_selection_label)
        presets = QHBoxLayout()
        for text, tip, spec in (("Default", "The default views: ten rows spread over the grid × the first two and "
                                 "last two columns (capped by its size): the rig's position errors average out over "
                                 "many views far apart", "default"),
                                ("2 × 3 (paper)", "First and last row; first, middle and last column", (2, 3)),
                                ("3 × 5", "A denser array: 3 rows × 5 columns spread over the grid", (3, 5)),
                                ("All captured", "Every captured view (slow on a full grid)", "all"),
                                ("Clear", "Deselect every view", "none")):
            b = QPushButton(text)
            b.setToolTip(tip)
            b.clicked.connect(lambda _=False, s=spec: self.apply_preset(s))
            presets.addWidget(b)
        presets.addStretch(1)
        self.selection_label = QLabel()
        self.selection_label.setObjectName("selectionLabel")

        opts = QGroupBox("Options")
        form = QFormLayout(opts)
        self.estimate_pp = QCheckBox("Estimate the principal point where the views determine it")
        self.estimate_pp.setToolTip("A translating rig barely sees the principal point: it is estimated only when "
                                    "the fit determines it to 10 px, otherwise held at the image centre (the result "
                                    "says which and why). Off: always at the centre.")
        self.pair_set = QComboBox()
        for key, text in (("all", "every pair in each row and column"),
                          ("spanning", "neighbours and every pair with an end view"),
                          ("neighbours", "adjacent views only (short baselines)")):
            self.pair_set.addItem(text, key)
        self.pair_set.setToolTip("Which pairs of the chosen views are matched. Long baselines fix pan and tilt for "
                                 "the whole grid; adjacent views alone are warned about on a wide grid.")
        self.focal_px = QDoubleSpinBox()
        self.focal_px.setRange(0.0, 1e6)
        self.focal_px.setDecimals(1)
        self.focal_px.setSuffix(" px")
        self.focal_px.setSpecialValueText("from camera and lens")
        self.focal_px.setToolTip("Focal length in full-resolution pixels; 0 = computed from the dataset's "
                                 "camera (pixel pitch) and lens (focal length)")
        self.work_width = QSpinBox()
        self.work_width.setRange(400, 20000)
        self.work_width.setSingleStep(200)
        self.work_width.setSuffix(" px")
        self.work_width.setToolTip("Features are detected on images downscaled to this width")
        form.addRow(self.estimate_pp)
        form.addRow("Pairs:", self.pair_set)
        form.addRow("Focal length:", self.focal_px)
        self.focal_known = _knows_focal_length(self.dataset)
        self.focal_note = QLabel("")
        self.focal_note.setObjectName("focalLengthNote")
        self.focal_note.setWordWrap(True)
        self.focal_note.setProperty("role", "warning")
        if not self.focal_known:          # e.g. imported images without EXIF: say so before any work
            self.focal_px.setSpecialValueText("unknown: enter it")
            self.focal_note.setText("This dataset does not record its focal length (its images carry no EXIF "
                                    "focal length): enter it in pixels in the Focal length field above "
                                    "(focal length in mm ÷ pixel pitch in mm, e.g. 50 ÷ 0.0045 = 11111 px).")
            self.focal_note.setStyleSheet("color: #b35900;")
            form.addRow(self.focal_note)
        form.addRow("Detection width:", self.work_width)
        self.pair_set.currentIndexChanged.connect(self._update_selection_label)

        lay = QVBoxLayout(page)
        lay.addWidget(QLabel("<b>1. Choose the views.</b> Pairs are formed within each row (rows must line "
                             "up) and each column (columns must line up)."))
        lay.addLayout(presets)
        lay.addWidget(self.picker, 1)
        lay.addWidget(self.selection_label)
        lay.addWidget(opts)
        return page

    def apply_preset(self, spec) -> None:
        grid = self.dataset.grid
        if spec == "all":
            views = self.available
        elif spec == "none":
            views = set()
        elif spec == "default":
            views = grid.select(DEFAULT_VIEWS, self.available)
        else:
            views = grid.spread(spec[0], spec[1], self.available)
        self.picker.set_selected(views)

    def selected_pairs(self):
        return make_pairs([View(r, c) for r, c in self.picker.selected], self.dataset.grid.step_mm,
                          pair_set=self.pair_set.currentData())

    def _update_selection_label(self) -> None:
        pairs = self.selected_pairs()
        nh = sum(p.direction == "h" for p in pairs)
        nv = len(pairs) - nh
        text = f"{len(self.picker.selected)} views · {nh} horizontal + {nv} vertical pairs"
        if nh == 0 and nv == 0:
            text += " — choose at least two views in one row or in one column"
        elif nv == 0:
            text += (" — rows only: pan and roll are determined, tilt is held at 0° (rows will line up; add views "
                     "in a second row to determine the tilt)")
        elif nh == 0:
            text += (" — columns only: tilt and roll are determined, pan is held at 0° (columns will line up; add "
                     "views in a second column to determine the pan)")
        self.selection_label.setText(text)
        if self.stack.currentIndex() == PAGE_VIEWS:
            self.next_button.setEnabled((nh > 0 or nv > 0) and not self.runner.running)

    # -- page 2: run ---------------------------------------------------------------------------------
    def _build_run_page(self) -> QWidget:
        page = QWidget()
        self.job_widget = JobProgressWidget(self.runner)
        self.log = QPlainTextEdit()
        self.log.setReadOnly(True)
        self.log.setObjectName("calibrationLog")
        self.error_label = QLabel()
        self.error_label.setWordWrap(True)
        self.error_label.setStyleSheet("color: #b00020;")
        self.error_label.setObjectName("errorLabel")
        lay = QVBoxLayout(page)
        lay.addWidget(QLabel("<b>2. Detect and match features, fit the orientation.</b> Features are cached in "
                             "the dataset (cache/features), so a second run is fast."))
        lay.addWidget(self.job_widget)
        lay.addWidget(self.error_label)
        lay.addWidget(self.log, 1)
        return page

    def start_calibration(self) -> None:
        if self.runner.running:
            return
        views = sorted(self.picker.selected)
        if not self.focal_known and self.focal_px.value() <= 0:
            self.focal_note.setText("Enter the focal length in pixels in the Focal length field first: this "
                                    "dataset does not record it (no EXIF focal length in its images).")
            self.focal_note.setStyleSheet("color: #b00020; font-weight: 600;")
            self.focal_px.setFocus()
            return
        self._save_settings()
        self.error_label.setText("")
        self.log.clear()
        self._set_page(PAGE_RUN)
        kwargs: dict[str, Any] = {"principal_point": "auto" if self.estimate_pp.isChecked() else "centre",
                                  "pair_set": self.pair_set.currentData(),
                                  "max_width_px": self.work_width.value()}
        if self.focal_px.value() > 0:
            kwargs["focal_length_px"] = self.focal_px.value()
        self.log.appendPlainText(f"views: {', '.join(view_stem(*v) for v in views)}")
        self.runner.start(_calibration_job, self.dataset, views, **kwargs)

    def _on_progress(self, done: int, total: int, message: str, eta: float) -> None:
        if message:
            self.log.appendPlainText(message)

    def _on_failed(self, message: str) -> None:
        self.error_label.setText(message)
        self.log.appendPlainText("failed: " + message)
        self._update_buttons()

    def _on_cancelled(self) -> None:
        self.error_label.setText("Cancelled. Go back to change the views or start again.")
        self._update_buttons()

    def _on_finished(self, result: dict) -> None:
        self.result = result
        self._fill_results(result)
        self._set_page(PAGE_RESULTS)

    # -- page 3: results -------------------------------------------------------------------------------
    def _build_results_page(self) -> QWidget:
        page = QWidget()
        self.headline = QLabel()
        self.headline.setObjectName("headline")
        self.headline.setWordWrap(True)
        self.uncertainty_label = QLabel()
        self.uncertainty_label.setObjectName("uncertaintyLabel")
        self.uncertainty_label.setWordWrap(True)
        self.uncertainty_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.uncertainty_label.setToolTip("Measured: the fit's covariance with every view's position error in the "
                                          "model and the residuals' observed spread; 1σ covers the truth 68 % of "
                                          "the time, 2σ 95 % (checked by lfstudio simulate-calibration)")
        self.tabs = QTabWidget()
        self.tabs.setObjectName("resultTabs")

        self.report_text = QPlainTextEdit()
        self.report_text.setReadOnly(True)
        self.report_text.setFont(QFont("monospace"))
        self.report_text.setLineWrapMode(QPlainTextEdit.LineWrapMode.WidgetWidth)    # long warnings wrap, never cut off
        self.tabs.addTab(self.report_text, "Numbers")

        res = QWidget()
        self.res_plots = pg.GraphicsLayoutWidget()
        self.hist_before = self.res_plots.ci.addPlot(0, 0, title="Residuals before (px)")
        self.hist_after = self.res_plots.ci.addPlot(0, 1, title="Residuals after (px)")
        for plot in (self.hist_before, self.hist_after):
            plain_px_axis(plot.getAxis("bottom"), "v-difference (row pairs) / u-difference (column pairs)")
        self.heat = self.res_plots.ci.addPlot(1, 0, title="RMS after per view (px)")
        self.heat.getViewBox().invertY(True)
        self.heat.setLabel("bottom", "column")
        self.heat.setLabel("left", "row")
        # the colour scales as bars beside the plots (the axis labels also name the range)
        self.heat_bar = pg.ColorBarItem(values=(0.0, 1.0), colorMap=_colormap("viridis"), width=14,
                                        label="RMS after (px)", interactive=False, colorMapMenu=False)
        # PlotItem's grid, an attribute pyqtgraph names like the QGraphicsWidget.layout() method it hides
        heat_grid: QGraphicsGridLayout = self.heat.layout  # pyright: ignore[reportAssignmentType]
        heat_grid.addItem(self.heat_bar, 2, 5)              # where ColorBarItem puts itself in a plot
        heat_grid.setColumnFixedWidth(4, 5)
        self.vectors = self.res_plots.ci.addPlot(1, 1, title="Residual vectors")
        self.vectors.getViewBox().invertY(True)
        self.vectors.getViewBox().setAspectLocked(True)
        self.vector_image = pg.ImageItem(axisOrder="row-major")
        self.vectors.addItem(self.vector_image)
        self.region_rms = pg.ImageItem(axisOrder="row-major")      # RMS per region, over the image
        self.region_rms.setOpacity(0.45)
        self.vectors.addItem(self.region_rms)
        self.region_bar = pg.ColorBarItem(values=(0.0, 1.0), colorMap=_colormap("inferno"), width=14,
                                          label="region RMS (px)", interactive=False, colorMapMenu=False)
        self.region_bar.setImageItem(self.region_rms, insert_in=self.vectors)
        self.vectors.setLabel("bottom", "x (preview px)")
        self.vectors.setLabel("left", "y (preview px)")
        self.vector_lines = pg.PlotDataItem(connect="pairs", pen=pg.mkPen((0, 200, 60), width=2.5))
        self.vectors.addItem(self.vector_lines)
        self.vector_roots = pg.ScatterPlotItem(size=5, pen=None, brush=pg.mkBrush(255, 255, 255, 220))
        self.vectors.addItem(self.vector_roots)
        self.field: dict | None = None
        self.vector_mode = QComboBox()
        self.vector_mode.addItems(["after calibration", "before calibration"])
        self.vector_mode.setToolTip("Which residuals to draw as vectors")
        self.vector_gain = QSpinBox()
        self.vector_gain.setRange(1, 100_000)      # a good calibration leaves residuals of hundredths of a px
        self.vector_gain.setValue(50)
        self.vector_gain.setPrefix("× ")
        self.vector_gain.setToolTip("Arrow length = mean residual of the region × this factor (preview pixels); "
                                    "set so the longest arrow fills most of its region")
        self.vector_mode.currentIndexChanged.connect(self._draw_vectors)
        self.vector_gain.valueChanged.connect(self._draw_vectors)
        row = QHBoxLayout()
        row.addWidget(QLabel("Vectors:"))
        row.addWidget(self.vector_mode)
        row.addWidget(self.vector_gain)
        row.addStretch(1)
        rl = QVBoxLayout(res)
        rl.addLayout(row)
        rl.addWidget(self.res_plots, 1)
        self.tabs.addTab(res, "Residuals")

        insp = QWidget()
        controls = QGridLayout()
        self.epi_row = QSpinBox()
        self.epi_row.setToolTip("Grid row whose views form the horizontal EPI")
        self.epi_column = QSpinBox()
        self.epi_column.setToolTip("Grid column whose views form the vertical EPI")
        self.epi_y = QSlider(Qt.Orientation.Horizontal)
        self.epi_y.setRange(0, 100)
        self.epi_y.setValue(50)
        self.epi_y.setToolTip("Image row of the horizontal EPI (0 = top, 100 = bottom)")
        self.epi_x = QSlider(Qt.Orientation.Horizontal)
        self.epi_x.setRange(0, 100)
        self.epi_x.setValue(50)
        self.epi_x.setToolTip("Image column of the vertical EPI (0 = left, 100 = right)")
        self.epi_button = QPushButton("Update")
        self.epi_button.setToolTip("Read the views and build the EPIs and the neighbouring-view check")
        self.epi_button.clicked.connect(self.start_inspection)
        self.inspect_status = QLabel()
        controls.addWidget(QLabel("Grid row:"), 0, 0)
        controls.addWidget(self.epi_row, 0, 1)
        controls.addWidget(QLabel("image row %:"), 0, 2)
        controls.addWidget(self.epi_y, 0, 3)
        controls.addWidget(QLabel("Grid column:"), 1, 0)
        controls.addWidget(self.epi_column, 1, 1)
        controls.addWidget(QLabel("image column %:"), 1, 2)
        controls.addWidget(self.epi_x, 1, 3)
        controls.addWidget(self.epi_button, 0, 4, 2, 1)
        controls.setColumnStretch(3, 1)
        self.epi_plots = pg.GraphicsLayoutWidget()
        self.epi_items = {}
        for i, (key, title) in enumerate((("h_before", "Horizontal EPI before"), ("h_after", "Horizontal EPI after"))):
            plot, item = _image_plot(title)
            self.epi_plots.addItem(plot, i, 0, 1, 2)
            self.epi_items[key] = item
        for j, (key, title) in enumerate((("v_before", "Vertical EPI before"), ("v_after", "Vertical EPI after"))):
            plot, item = _image_plot(title)
            self.epi_plots.addItem(plot, 2, j)
            self.epi_items[key] = item
        il = QVBoxLayout(insp)
        il.addLayout(controls)
        il.addWidget(self.inspect_status)
        il.addWidget(self.epi_plots, 1)
        self.tabs.addTab(insp, "EPIs")

        nb = QWidget()
        self.pair_rectified = QCheckBox("Rectified")
        self.pair_rectified.setChecked(True)
        self.pair_rectified.setToolTip("Show the two views rectified with the result (off: as captured)")
        self.pair_rectified.toggled.connect(self._draw_neighbours)
        self.pair_label = QLabel()
        self.pair_plots = pg.GraphicsLayoutWidget()
        self.pair_items = []
        self.pair_plot_items = []
        for k in range(2):
            plot, item = _image_plot("")
            plot.getViewBox().setAspectLocked(True)
            self.pair_plots.addItem(plot, 0, k)
            self.pair_items.append(item)
            self.pair_plot_items.append(plot)
        self.pair_plot_items[1].setXLink(self.pair_plot_items[0])
        self.pair_plot_items[1].setYLink(self.pair_plot_items[0])
        nl = QVBoxLayout(nb)
        top = QHBoxLayout()
        top.addWidget(self.pair_rectified)
        top.addWidget(self.pair_label, 1)
        nl.addLayout(top)
        nl.addWidget(self.pair_plots, 1)
        self.tabs.addTab(nb, "Neighbouring views")

        lay = QVBoxLayout(page)
        lay.addWidget(self.headline)
        lay.addWidget(self.uncertainty_label)
        lay.addWidget(self.tabs, 1)
        return page

    def _fill_results(self, result: dict) -> None:
        doc = result["run"].document
        fit = result["run"].fit
        rx, ry, rz = doc["rotation_deg"]
        before, after = doc["residual_px"]["before"], doc["residual_px"]["after"]
        warnings, notes = calibration_warnings(doc)        # a held angle is a note, not a red warning
        warn = "".join(f" <span style='color:{colour}'>{count(len(items), word)} — see Numbers.</span>"
                       for items, word, colour in ((warnings, "warning", "#b00020"), (notes, "note", "#5b6470"))
                       if items)
        u = CalibrationUncertainty.from_document(doc)
        std = u.rotation_std_deg if u else (float("nan"),) * 3
        held = held_angles(doc)
        angles = ", ".join(f"{key} {value:+.3f}° (held: not determined)" if key in held
                           else f"{key} {value:+.3f}° ± {sd:.3f}°"
                           for key, value, sd in zip(("rx", "ry", "rz"), (rx, ry, rz), std))
        self.headline.setText(
            f"<b>3. Result.</b> {angles} (1σ) · residual RMS "
            f"<b>{before['rms']:.2f} → {after['rms']:.2f} px</b> over {after['count']} matches.{warn}")
        self.uncertainty_label.setText(uncertainty_html(doc))
        self.report_text.setPlainText(format_report(doc))

        inl = fit.inlier
        for plot, data, color in ((self.hist_before, fit.residual_before_px[inl], (200, 60, 60)),
                                  (self.hist_after, fit.residual_after_px[inl], (40, 160, 70))):
            plot.clear()
            if data.size:
                lim = float(np.percentile(np.abs(data), 99.5)) or 1.0
                counts, edges = np.histogram(np.clip(data, -lim, lim), bins=41, range=(-lim, lim))
                plot.addItem(pg.BarGraphItem(x0=edges[:-1], x1=edges[1:], height=counts, brush=color))
            plot.setLabel("left", "matches")

        self.heat.clear()
        views = [v for v in doc["views"] if v["residual_px"]["after"]["rms"] is not None]
        if views:
            values = np.array([v["residual_px"]["after"]["rms"] for v in views])
            cmap = _colormap("viridis")
            top = max(float(values.max()), 1.0)   # colour scale 0 … max(1 px, worst view)
            brushes = [pg.mkBrush(cmap.mapToQColor(val / top)) for val in values]
            scatter = pg.ScatterPlotItem(x=[v["column"] for v in views], y=[v["row"] for v in views], symbol="s",
                                         size=34, brush=brushes, pen=pg.mkPen("k"))
            self.heat.addItem(scatter)
            for v, val in zip(views, values):
                t = pg.TextItem(f"{val:.2f}", color="w" if val / top < 0.6 else "k", anchor=(0.5, 0.5))
                t.setPos(v["column"], v["row"])
                self.heat.addItem(t)
            grid = self.dataset.grid
            self.heat.setLabel("bottom", f"column · colour: RMS 0 (dark) … {top:.2f} px (yellow)")
            self.heat_bar.setLevels((0.0, top))
            self.heat.getViewBox().setXRange(-1, grid.columns, padding=0.05)
            self.heat.getViewBox().setYRange(-1, grid.rows, padding=0.1)
        self.vector_image.setImage(result["preview"], autoLevels=True)
        self.vectors.setTitle(f"Mean residual per region, {view_stem(*result['preview_view'])}")
        self.field = None
        self._draw_vectors(auto_gain=True)

        grid = self.dataset.grid
        self.epi_row.setRange(0, grid.rows - 1)
        self.epi_column.setRange(0, grid.columns - 1)
        rows = sorted({r for r, _ in self.available})
        cols = sorted({c for _, c in self.available})
        self.epi_row.setValue(rows[len(rows) // 2] if rows else 0)
        self.epi_column.setValue(cols[len(cols) // 2] if cols else 0)
        self.start_inspection()

    def _draw_vectors(self, *args, auto_gain: bool = False) -> None:
        """The chosen residuals (after / before) binned per image region (:func:`residual_field`): an
        arrow per region from its centre, its mean residual × the gain, over the region's RMS."""
        if not self.result:
            return
        run = self.result["run"]
        fit = run.fit
        img = self.result["preview"]
        s = img.shape[1] / self.result["full_size"][0]
        use_after = self.vector_mode.currentIndex() == 0
        r_all = fit.residual_after_px if use_after else fit.residual_before_px
        points, residuals, vertical = [], [], []
        for m, sl in zip(run.matches, fit.pair_slices):
            keep = fit.inlier[sl]
            points.append((m.xy_a[keep] + 0.5) * s - 0.5)
            residuals.append(r_all[sl][keep])
            vertical.append(np.full(int(keep.sum()), m.direction == "h"))
        h, w = img.shape[:2]
        if not points:
            self.vector_lines.setData([], [])
            self.vector_roots.setData([], [])
            return
        field = self.field = residual_field(np.concatenate(points), np.concatenate(residuals),
                                            np.concatenate(vertical), (w, h))
        rows, cols = field["rms"].shape
        if auto_gain and len(field["mean"]):
            longest = float(np.max(np.hypot(field["mean"][:, 0], field["mean"][:, 1]))) or 1.0
            self.vector_gain.blockSignals(True)      # the longest arrow about 0.9 of a region
            self.vector_gain.setValue(int(np.clip(0.9 * min(w / cols, h / rows) / longest, 1, 100_000)))
            self.vector_gain.blockSignals(False)
        gain = self.vector_gain.value()
        rms = field["rms"]
        top = float(np.nanmax(rms)) if np.isfinite(rms).any() else 1.0
        self.region_rms.setImage(np.nan_to_num(rms, nan=0.0), levels=(0.0, max(top, 1e-6)))
        self.region_bar.setLevels((0.0, max(top, 1e-6)))
        self.vectors.setLabel("bottom", f"x (preview px) · colour: RMS 0 … {top:.2f} px")
        self.region_rms.setRect(0, 0, w, h)
        c, v = field["centres"], field["mean"]
        end = c + gain * v
        color = (0, 220, 70) if use_after else (240, 70, 70)
        self.vector_lines.setPen(pg.mkPen(color, width=2.5))
        self.vector_lines.setData(np.column_stack([c[:, 0], end[:, 0]]).ravel(),
                                  np.column_stack([c[:, 1], end[:, 1]]).ravel())
        self.vector_roots.setData(c[:, 0], c[:, 1])

    def start_inspection(self) -> None:
        if not self.result or self.inspect_runner.running:
            return
        self.inspect_status.setText("Reading views…")
        self.inspect_runner.start(_inspection_job, self.dataset, self.result["run"].document, self.epi_row.value(),
                                  self.epi_column.value(), self.epi_y.value() / 100.0, self.epi_x.value() / 100.0)

    def _show_inspection(self, out: dict) -> None:
        self.inspection = out
        epis = out["epis"]
        notes = []
        for key, prefix in (("horizontal", "h"), ("vertical", "v")):
            e = epis.get(key)
            for when in ("before", "after"):
                item = self.epi_items[f"{prefix}_{when}"]
                if e is None or e.get(when) is None:
                    item.clear()
                    continue
                item.setImage(e[when], autoLevels=True)
                item.getViewBox().setRange(xRange=(0, e[when].shape[1]), yRange=(0, e[when].shape[0]), padding=0.02)
            if e is None:
                notes.append(f"no {key} EPI: fewer than two captured views in that grid "
                             f"{'row' if key == 'horizontal' else 'column'}")
            else:
                notes.append(f"{key}: {len(e['views'])} views {view_stem(*e['views'][0])} … {view_stem(*e['views'][-1])}")
        self.inspect_status.setText("Straight, unbroken lines after rectification mean a good calibration. "
                                    + "; ".join(notes))
        self._draw_neighbours()

    def _draw_neighbours(self) -> None:
        nb = getattr(self, "inspection", {}).get("neighbours") if hasattr(self, "inspection") else None
        if not nb:
            self.pair_label.setText("Needs two captured views next to each other in the chosen grid row.")
            return
        imgs = nb["after" if self.pair_rectified.isChecked() else "before"]
        h, w = imgs[0].shape
        for plot, item, img, v in zip(self.pair_plot_items, self.pair_items, imgs, nb["views"]):
            item.setImage(img, autoLevels=True)
            plot.setTitle(view_stem(*v) + (" rectified" if self.pair_rectified.isChecked() else " as captured"))
            plot.setRange(xRange=(0, w), yRange=(0, h), padding=0.02)
            for line in [i for i in plot.items if isinstance(i, pg.InfiniteLine)]:
                plot.removeItem(line)
            for y in np.linspace(h * 0.08, h * 0.92, 12):
                plot.addItem(pg.InfiniteLine(pos=float(y), angle=0, pen=pg.mkPen((255, 60, 60, 170), width=1)))
        self.pair_label.setText("Horizontal guide lines: the same scene detail should touch the same line in both "
                                "views after rectification.")

    # -- navigation and saving -----------------------------------------------------------------------------
    def _set_page(self, index: int) -> None:
        self.stack.setCurrentIndex(index)
        self.step_label.setText(("Step 1 of 3: views", "Step 2 of 3: detect, match, fit",
                                 "Step 3 of 3: inspect and accept")[index])
        self._update_buttons()

    def _update_buttons(self) -> None:
        index = self.stack.currentIndex()
        running = self.runner.running
        self.back_button.setEnabled(index > PAGE_VIEWS and not running)
        self.next_button.setVisible(index == PAGE_VIEWS)
        self.accept_button.setEnabled(index == PAGE_RESULTS and self.result is not None)
        if index == PAGE_VIEWS:
            self._update_selection_label()

    def go_back(self) -> None:
        if not self.runner.running:
            self._set_page(PAGE_VIEWS)

    def accept_and_save(self) -> None:
        if not self.result:
            return
        doc = self.result["run"].document
        try:
            path = save_calibration(self.dataset, doc)
        except (LfError, OSError) as exc:
            self.state.report_error("Save calibration", f"{exc}\nCheck that the dataset folder is writable.")
            return
        self.accepted_document = doc
        self.state.show_status(f"Calibration saved to {path}", 8000)
        self.state.set_dataset(self.dataset)
        self.accept()

    def reject(self) -> None:   # also the title bar's × (QDialog.closeEvent calls reject)
        self.shutdown()
        super().reject()

    def shutdown(self) -> None:
        self._save_settings()
        for r in (self.runner, self.inspect_runner):
            r.stop(10.0)

    # -- settings --------------------------------------------------------------------------------------
    def _restore_settings(self) -> None:
        s = settings()
        self.estimate_pp.setChecked(s.value("calibration/principal_point", "auto") == "auto")
        if read_int("calibration/settings_version", 1, s) < SETTINGS_VERSION:
            # saved before choices equal to the defaults were left unsaved: what was saved then was the
            # old default (all pairs, 2000 px) as often as a choice, so the current defaults apply
            s.remove("calibration/pair_set")
            s.remove("calibration/work_width_px")
        pair_set = s.value("calibration/pair_set", DEFAULT_PAIR_SET)
        self.pair_set.setCurrentIndex(PAIR_SETS.index(pair_set) if pair_set in PAIR_SETS else 0)
        self.work_width.setValue(read_int("calibration/work_width_px", DEFAULT_WORK_WIDTH_PX, s))
        self.focal_px.setValue(0.0)
        self.apply_preset("default")

    def _save_settings(self) -> None:
        s = settings()
        s.setValue("calibration/principal_point", "auto" if self.estimate_pp.isChecked() else "centre")
        # a choice equal to the default is not saved, so it follows the defaults when they improve
        s.setValue("calibration/settings_version", SETTINGS_VERSION)
        for key, value, default in (("calibration/pair_set", self.pair_set.currentData(), DEFAULT_PAIR_SET),
                                    ("calibration/work_width_px", self.work_width.value(), DEFAULT_WORK_WIDTH_PX)):
            if value == default:
                s.remove(key)
            else:
                s.setValue(key, value)
