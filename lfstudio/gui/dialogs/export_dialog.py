"""File → Export dataset…: format, options, views, destination, a live size estimate, then the export.

The estimate (:func:`lfstudio.export.estimate_export`) and the export itself
(:func:`lfstudio.export.export_dataset`) run on worker threads through
:class:`lfstudio.gui.bridge.JobRunner`; the export shows progress, ETA and Cancel. An existing
destination is only replaced after the operator says so. The last format, destination folder and
options persist in QSettings.
"""

from __future__ import annotations

import html

from pathlib import Path
from typing import Any

from PySide6.QtCore import Qt, QTimer, QUrl, Signal
from PySide6.QtGui import QDesktopServices
from PySide6.QtWidgets import (QCheckBox, QComboBox, QDialog, QFileDialog, QFormLayout, QFrame, QGroupBox, QHBoxLayout,
                               QLabel, QLineEdit, QMessageBox, QPushButton, QScrollArea, QSizePolicy, QSpinBox,
                               QStackedWidget, QVBoxLayout, QWidget)

from lfstudio.dataset.paths import expand_path
from lfstudio.errors import LfError, window_message
from lfstudio.export import ExportOptions, estimate_export, export_dataset
from lfstudio.gui.bridge import JobRunner
from lfstudio.gui.path_field import expand_on_edit
from lfstudio.gui.preferences import EXPORT_KEY
from lfstudio.gui.settings import read_int, read_text, settings
from lfstudio.gui.widgets import GridPicker, JobProgressWidget, confirm_cancel_running, add_stop_button, screen_fitted
from lfstudio.jobs import format_duration

#: format key, menu text, what it is
FORMAT_INFO = (
    ("png", "PNG 16-bit — one file per view + manifest",
     "A folder of 16-bit RGB PNG files (rRR_cCCC.png) with manifest.json: grid, spacing, positions and "
     "calibration. Lossless, large (about 100 GB for 2121 full-size views)."),
    ("hevc", "HEVC 12-bit 4:4:4 — one video in meander order",
     "One x265 stream (12-bit 4:4:4, CRF 8 by default), views in meander order so neighbouring frames are "
     "neighbouring views, with a sidecar JSON mapping frames to views. About 1:100 of the PNG size; "
     "lfstudio import-hevc restores the views."),
    ("hci", "HCI benchmark — parameters.cfg + input_Cam*.png",
     "The HCI 4D light-field benchmark layout for a sub-array (e.g. 9 × 9): parameters.cfg with the real "
     "intrinsics and extrinsics and input_Cam000.png … in row-major order. Zero disparity lies at infinity "
     "(our views are parallel); disp_min/disp_max come from the plan or are measured from the views."),
    ("colmap", "COLMAP model — images/ + sparse/0 with the rig's poses",
     "A COLMAP text model (cameras.txt, images.txt, points3D.txt) beside images/: one pinhole camera at "
     "the exported size, every view's pose from its reported axis position and the calibrated rotation "
     "(rectified views: the rectified camera), in metres. For NeRF / Gaussian-splatting tools: no "
     "structure-from-motion needed."),
    ("nerfstudio", "nerfstudio — transforms.json with the rig's poses",
     "transforms.json (nerfstudio / instant-ngp: fl_x, fl_y, cx, cy, w, h, per-frame transform_matrix in the "
     "OpenGL convention) beside images/, the same poses as the COLMAP export, with views held out of training "
     "as ground-truth novel views."),
)
FORMAT_KEYS = tuple(k for k, _, _ in FORMAT_INFO)
SOURCES = (("auto", "Auto — processed views when every chosen view has one"),
           ("processed", "Processed views (processed/)"),
           ("raw", "Raw captures (developed, not processed)"),
           ("tonemap", "HDR tone map (a bracketed scan's merged frames, hdr/preview/)"),
           ("hdr", "HDR radiance, float (the merged frames as they are, hdr/; COLMAP and nerfstudio)"))
HEVC_SUFFIXES = (".mp4", ".mkv", ".hevc")


def format_bytes(n: float) -> str:
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{int(n)} B"


def default_name(dataset_name: str, fmt: str) -> str:
    return {"png": f"{dataset_name}_png", "hevc": f"{dataset_name}.mp4", "hci": f"{dataset_name}_hci",
            "colmap": f"{dataset_name}_colmap", "nerfstudio": f"{dataset_name}_nerfstudio"}[fmt]


def existing_outputs(fmt: str, out: Path) -> list[Path]:
    """What an export to ``out`` would replace: the folder or the video and its sidecar."""
    paths = [out]
    if fmt == "hevc":
        from lfstudio.export.hevc import sidecar_path

        paths.append(sidecar_path(out))
    return [p for p in paths if p.exists() or p.is_symlink()]


def _estimate_job(dataset, options: ExportOptions, *, progress, cancel):
    return estimate_export(dataset, options)


def _export_job(root: Path, options: ExportOptions, *, progress, cancel):
    from lfstudio.dataset import Dataset

    return export_dataset(Dataset.open(root), options, progress=progress, cancel=cancel)


class ExportDialog(QDialog):
    """Modeless dialog over ``state.dataset``; ``report`` holds the last finished export's report."""

    exportFinished = Signal(object)

    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.dataset = state.dataset
        self.setObjectName("exportDialog")
        self.setWindowTitle(f"Export dataset — {self.dataset.root.name}")
        self.resize(screen_fitted(self, 880, 760))
        self.estimate = None            # the last ExportEstimate for the current options
        self.estimate_error: str | None = None
        self.report = None
        self._estimate_dirty = False
        self._auto_name = ""
        self._pending_options: ExportOptions | None = None
        self._user_selection: set[tuple[int, int]] | None = None
        self.overwrite_box: QMessageBox | None = None
        self._running_out: Path | None = None

        self.runner = JobRunner(self)
        self.estimate_runner = JobRunner(self)
        self._estimate_timer = QTimer(self)
        self._estimate_timer.setSingleShot(True)
        self._estimate_timer.setInterval(150)
        self._estimate_timer.timeout.connect(self.update_estimate)

        lay = QVBoxLayout(self)
        lay.addWidget(self._build_format_box())
        lay.addWidget(self._build_views_box(), 1)
        lay.addWidget(self._build_destination_box())
        lay.addWidget(self._build_run_area())

        self.runner.finished.connect(self._export_done)
        self.runner.failed.connect(self._export_failed)
        self.runner.cancelled.connect(self._export_cancelled)
        self.estimate_runner.finished.connect(self._estimate_done)
        self.estimate_runner.failed.connect(self._estimate_failed)
        state.datasetChanged.connect(self._dataset_changed)

        self._restore_settings()
        self._format_changed()

    @property
    def exporting(self) -> bool:
        """From Export until the job's last signal (JobRunner.running is False in that signal's slots)."""
        return self.runner.running

    # -- construction --------------------------------------------------------------------------------
    def _build_format_box(self) -> QGroupBox:
        box = QGroupBox("Format and options")
        form = QFormLayout(box)
        self.format_combo = QComboBox()
        self.format_combo.setObjectName("formatCombo")
        for key, text, _ in FORMAT_INFO:
            self.format_combo.addItem(text, key)
        self.format_combo.setToolTip("What to write: a PNG tree, one HEVC video, the HCI benchmark layout, a COLMAP "
                                     "model or a nerfstudio transforms.json")
        self.format_info = QLabel()
        self.format_info.setWordWrap(True)
        self.format_info.setObjectName("formatInfo")
        self.source_combo = QComboBox()
        for key, text in SOURCES:
            self.source_combo.addItem(text, key)
        self.source_combo.setToolTip("Which images to export: the processed views (Dataset → Process…) or the "
                                     "raw captures")
        self.format_info.setStyleSheet("color: #555;")
        fmt_box = QVBoxLayout()
        fmt_box.setSpacing(2)
        fmt_box.addWidget(self.format_combo)
        fmt_box.addWidget(self.format_info)
        form.addRow("Format:", fmt_box)
        form.addRow("Source:", self.source_combo)

        self.options_stack = QStackedWidget()
        png_page = QLabel("none: every view as it is, 16-bit RGB")          # the row stays: no layout jump
        png_page.setStyleSheet("color: #555;")
        self.options_stack.addWidget(png_page)

        hevc = QWidget()
        hl = QHBoxLayout(hevc)
        hl.setContentsMargins(0, 0, 0, 0)
        self.crf_spin = QSpinBox()
        self.crf_spin.setRange(0, 51)
        self.crf_spin.setToolTip("x265 constant rate factor: lower = better quality and larger file "
                                 "(8 keeps PSNR above 45 dB)")
        self.bit_depth_combo = QComboBox()
        self.bit_depth_combo.addItem("12-bit", 12)
        self.bit_depth_combo.addItem("10-bit", 10)
        self.bit_depth_combo.setToolTip("Bits per sample of the 4:4:4 stream (12-bit keeps more of the 16-bit views)")
        hl.addWidget(QLabel("CRF"))
        hl.addWidget(self.crf_spin)
        hl.addSpacing(16)
        hl.addWidget(QLabel("Bit depth"))
        hl.addWidget(self.bit_depth_combo)
        hl.addStretch(1)
        self.options_stack.addWidget(hevc)

        hci = QWidget()
        hci_rows = QVBoxLayout(hci)
        hci_rows.setContentsMargins(0, 0, 0, 0)
        hci_rows.setSpacing(4)
        cl = QHBoxLayout()                      # the sub-array; below it the authors at full width
        hci_rows.addLayout(cl)
        grid = self.dataset.grid
        self.hci_columns, self.hci_rows = QSpinBox(), QSpinBox()
        self.hci_columns.setRange(1, grid.columns)
        self.hci_rows.setRange(1, grid.rows)
        self.hci_columns.setToolTip("Columns of the exported sub-array (num_cams_x)")
        self.hci_rows.setToolTip("Rows of the exported sub-array (num_cams_y)")
        self.hci_center_row, self.hci_center_column = QSpinBox(), QSpinBox()
        self.hci_center_row.setRange(0, grid.rows - 1)
        self.hci_center_column.setRange(0, grid.columns - 1)
        for s in (self.hci_center_row, self.hci_center_column):
            s.setToolTip("Grid view at the centre of the sub-array; or click a view on the grid below")
        cl.addWidget(QLabel("Sub-array"))
        cl.addWidget(self.hci_columns)
        cl.addWidget(QLabel("×"))
        cl.addWidget(self.hci_rows)
        cl.addWidget(QLabel("views (columns × rows)"))
        cl.addSpacing(16)
        cl.addWidget(QLabel("centre row"))
        cl.addWidget(self.hci_center_row)
        cl.addWidget(QLabel("column"))
        cl.addWidget(self.hci_center_column)
        cl.addStretch(1)
        cl = QHBoxLayout()
        hci_rows.addLayout(cl)
        cl.addWidget(QLabel("Authors"))
        self.hci_authors = QLineEdit()
        self.hci_authors.setObjectName("hciAuthors")
        self.hci_authors.setPlaceholderText("written to parameters.cfg [meta] (empty: the dataset's, if any)")
        self.hci_authors.setToolTip("The [meta] authors of parameters.cfg (empty: the dataset's, if any)")
        cl.addWidget(self.hci_authors, 1)
        cl.addSpacing(16)
        self.hci_depth_check = QCheckBox("Disparity maps")
        self.hci_depth_check.setObjectName("hciDepthCheck")
        self.hci_depth_check.setToolTip("Each view's estimated disparity (estimated_disp_CamNNN.pfm, px between "
                                        "neighbours) and its confidence; views without a depth map are computed "
                                        "first (Dataset → Depth map of a view…, 'lfstudio depth')")
        cl.addWidget(self.hci_depth_check)
        self.options_stack.addWidget(hci)

        self.image_depth_combos: list[QComboBox] = []
        self.points_checks: dict[str, QCheckBox] = {}
        for fmt in ("colmap", "nerfstudio"):
            page = QWidget()
            pl = QHBoxLayout(page)
            pl.setContentsMargins(0, 0, 0, 0)
            combo = QComboBox()
            combo.addItem("8-bit sRGB", 8)
            combo.addItem("16-bit linear", 16)
            combo.setToolTip("Images: 8-bit sRGB PNG (what view-synthesis tools expect) or linear 16-bit PNG")
            combo.currentIndexChanged.connect(self._image_depth_changed)
            self.image_depth_combos.append(combo)
            pl.addWidget(QLabel("Images"))
            pl.addWidget(combo)
            points = QCheckBox("Sparse points")
            points.setObjectName(f"{fmt}PointsCheck")
            points.setChecked(True)
            points.setToolTip("A coloured sparse point cloud triangulated from the views with the rig's known poses "
                              + ("(points3D.txt, points3D.ply)" if fmt == "colmap" else "(sparse_pc.ply, ply_file_path)"))
            self.points_checks[fmt] = points
            pl.addSpacing(16)
            pl.addWidget(points)
            if fmt == "nerfstudio":
                self.ns_depth_check = QCheckBox("Depth maps")
                self.ns_depth_check.setObjectName("nerfstudioDepthCheck")
                self.ns_depth_check.setToolTip("depth_file_path per frame (16-bit PNG in mm, float TIFF in m, "
                                               "confidence); views without a depth map are computed first")
                pl.addWidget(self.ns_depth_check)
            if fmt == "nerfstudio":
                pl.addSpacing(16)
                pl.addWidget(QLabel("Hold out"))
                self.holdout_combo = QComboBox()
                self.holdout_combo.setObjectName("holdoutCombo")
                self.holdout_combo.addItem("none (nerfstudio splits)", "none")
                self.holdout_combo.addItem("the centre view", "centre")
                for k in (2, 3, 4, 8):
                    self.holdout_combo.addItem(f"every {k}th row and column", f"every-{k}")
                self.holdout_combo.setToolTip("Views kept out of training as ground-truth novel views "
                                              "(val/test_filenames); each is surrounded by training views")
                pl.addWidget(self.holdout_combo)
            pl.addStretch(1)
            self.options_stack.addWidget(page)
        for i in range(self.options_stack.count()):      # one-row pages at the top of the two rows' room
            page = self.options_stack.widget(i)
            if isinstance(page, QLabel):
                page.setAlignment(Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignTop)
            elif page is not None and isinstance(layout := page.layout(), QHBoxLayout):
                layout.setAlignment(Qt.AlignmentFlag.AlignTop)
        form.addRow("Options:", self.options_stack)
        self._options_form = form

        self.format_combo.currentIndexChanged.connect(self._format_changed)
        self.source_combo.currentIndexChanged.connect(self._source_changed)
        for w in (self.source_combo, self.bit_depth_combo, self.holdout_combo):
            w.currentIndexChanged.connect(self._options_changed)
        self.hci_authors.textChanged.connect(self._options_changed)
        for check in (self.hci_depth_check, self.ns_depth_check, *self.points_checks.values()):
            check.toggled.connect(self._options_changed)
        for w in (self.crf_spin, self.hci_columns, self.hci_rows, self.hci_center_row, self.hci_center_column):
            w.valueChanged.connect(self._options_changed)
        return box

    def _build_views_box(self) -> QGroupBox:
        box = QGroupBox("Views")
        grid = self.dataset.grid
        self.available = set(self.dataset.captured_views())
        self.picker = GridPicker(grid.columns, grid.rows, self.available,
                                 tooltip="Click captured views (grey) to add them to or remove them from the "
                                         "export; blue = exported")
        self.picker.setObjectName("exportPicker")
        self.picker.selectionChanged.connect(self._selection_changed)
        self.picker.cellClicked.connect(self._cell_clicked)
        bar = QHBoxLayout()
        self.all_button = QPushButton("All captured")
        self.all_button.setToolTip("Export every captured view")
        self.all_button.clicked.connect(lambda: self.picker.set_selected(self.available))
        self.clear_button = QPushButton("Clear")
        self.clear_button.setToolTip("Deselect every view (then click the ones to export)")
        self.clear_button.clicked.connect(lambda: self.picker.set_selected(()))
        self.subset_edit = QLineEdit()
        self.subset_edit.setPlaceholderText("r0-8,c10-18")
        self.subset_edit.setToolTip("Select by rows and columns, e.g. 'r0-8,c10-18' or 'all' (Enter applies)")
        self.subset_button = QPushButton("Select")
        self.subset_button.setToolTip("Select the views the text on the left describes")
        self.subset_button.clicked.connect(self.apply_subset)
        self.subset_edit.returnPressed.connect(self.apply_subset)
        for w in (self.all_button, self.clear_button):
            bar.addWidget(w)
        bar.addSpacing(12)
        bar.addWidget(QLabel("Subset:"))
        bar.addWidget(self.subset_edit, 1)
        bar.addWidget(self.subset_button)
        self.views_label = QLabel()
        self.views_label.setObjectName("viewsLabel")
        self.views_label.setWordWrap(True)
        lay = QVBoxLayout(box)
        lay.addLayout(bar)
        lay.addWidget(self.picker, 1)
        lay.addWidget(self.views_label)
        return box

    def _build_destination_box(self) -> QGroupBox:
        box = QGroupBox("Destination")
        form = QFormLayout(box)
        row = QHBoxLayout()
        self.folder_edit = QLineEdit()
        self.folder_edit.setObjectName("folderEdit")
        self.folder_edit.setToolTip("The folder the export is written into (~ and $VARIABLES are expanded)")
        expand_on_edit(self.folder_edit, "Folder")
        self.browse_button = QPushButton("Browse…")
        self.browse_button.setToolTip("Choose the destination folder")
        self.browse_button.clicked.connect(self.choose_folder)
        row.addWidget(self.folder_edit, 1)
        row.addWidget(self.browse_button)
        self.name_edit = QLineEdit()
        self.name_edit.setObjectName("nameEdit")
        self.name_edit.setToolTip("PNG and HCI: a new folder of this name; HEVC: the video file (.mp4, .mkv or "
                                  ".hevc)")
        self.path_label = QLabel()
        self.path_label.setObjectName("pathLabel")
        self.path_label.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)   # a long path is clipped
        form.addRow("Folder:", row)
        form.addRow("Name:", self.name_edit)
        form.addRow("", self.path_label)
        self.folder_edit.textChanged.connect(self._destination_changed)
        self.name_edit.textChanged.connect(self._destination_changed)
        return box

    def _build_run_area(self) -> QWidget:
        area = QWidget()
        self.estimate_label = QLabel("Estimating…")
        self.estimate_label.setObjectName("estimateLabel")
        self.estimate_label.setWordWrap(True)
        self.warnings_label = QLabel()
        self.warnings_label.setObjectName("warningsLabel")
        self.warnings_label.setWordWrap(True)
        self.warnings_label.setStyleSheet("color: #b35900;")
        self.progress = JobProgressWidget(self.runner)
        self.result_label = QLabel()
        self.result_label.setObjectName("exportResult")
        self.result_label.setWordWrap(True)
        self.result_label.setTextInteractionFlags(self.result_label.textInteractionFlags())
        self.export_button = QPushButton("Export")
        self.export_button.setDefault(True)
        self.export_button.setToolTip("Write the export (asks before replacing an existing destination)")
        self.export_button.clicked.connect(self.start_export)
        self.open_folder_button = QPushButton("Open folder")
        self.open_folder_button.setToolTip("Show the exported files in the file manager")
        self.open_folder_button.setEnabled(False)
        self.open_folder_button.clicked.connect(self.open_folder)
        self.close_button = QPushButton("Close")
        self.close_button.setToolTip("Close the dialog (a running export is cancelled after asking)")
        self.close_button.clicked.connect(self.close)
        buttons = QHBoxLayout()                      # the result beside the buttons: fits a 768 px screen
        buttons.addWidget(self.result_label, 1)
        for b in (self.open_folder_button, self.export_button, self.close_button):
            buttons.addWidget(b)
        add_stop_button(self, buttons)     # STOP in sight while this dialog covers the window's (no row of its own:
        #                                    the dialog fits a 768 px screen)
        # every line keeps its room whether it has text or not, so the dialog never jumps between states
        lines = self.fontMetrics().lineSpacing()
        for label in (self.estimate_label, self.warnings_label, self.result_label):
            label.setMinimumHeight(2 * lines + 4)
            label.setAlignment(Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignTop)
        self.result_label.setMinimumHeight(3 * lines + 4)      # a report beside the buttons takes up to 3 lines
        self.warnings_area = QScrollArea()           # however many warnings: the same room (scrolls)
        self.warnings_area.setObjectName("warningsArea")
        self.warnings_area.setWidget(self.warnings_label)
        self.warnings_area.setWidgetResizable(True)
        self.warnings_area.setFrameShape(QFrame.Shape.NoFrame)
        self.warnings_area.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.warnings_area.setFixedHeight(3 * lines + 6)
        self.format_info.setMinimumHeight(3 * lines + 4)          # the longest (HCI) is 3 lines wide
        self.format_info.setAlignment(Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignTop)
        lay = QVBoxLayout(area)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.estimate_label)
        lay.addWidget(self.warnings_area)
        lay.addWidget(self.progress)
        lay.addLayout(buttons)
        return area

    # -- options -------------------------------------------------------------------------------------
    @property
    def format(self) -> str:
        return str(self.format_combo.currentData())

    def out_path(self) -> Path:
        """The destination: the folder as typed (``~`` and ``$VARIABLES`` expanded, absolute) and the
        name; InputError naming "Folder" when the folder names no path."""
        return expand_path(self.folder_edit.text(), "Folder", absolute=True) / self.name_edit.text().strip()

    def selected_views(self) -> list[tuple[int, int]] | None:
        """The picked views (None when every captured view is picked)."""
        if self.picker.selected == self.available:
            return None
        return sorted(self.picker.selected)

    def options(self, overwrite: bool = False) -> ExportOptions:
        fmt = self.format
        kwargs: dict[str, Any] = {}
        if fmt == "hevc":
            kwargs.update(crf=self.crf_spin.value(), bit_depth=int(self.bit_depth_combo.currentData()))
        if fmt == "hci":
            kwargs.update(hci_size=(self.hci_columns.value(), self.hci_rows.value()),
                          hci_center=(self.hci_center_row.value(), self.hci_center_column.value()))
            kwargs.update(authors=self.hci_authors.text().strip())
            views = None
        else:
            views = self.selected_views()
        if fmt in ("colmap", "nerfstudio"):
            kwargs.update(image_bit_depth=int(self.image_depth_combos[0].currentData()))
        if fmt == "nerfstudio":
            kwargs.update(holdout=str(self.holdout_combo.currentData()))
        if fmt in self.points_checks:
            kwargs.update(points=self.points_checks[fmt].isChecked())
        if fmt in ("nerfstudio", "hci"):
            kwargs.update(depth=(self.ns_depth_check if fmt == "nerfstudio" else self.hci_depth_check).isChecked())
        return ExportOptions(format=fmt, out=self.out_path(), views=views,
                             source=str(self.source_combo.currentData()), overwrite=overwrite, **kwargs)

    def apply_subset(self) -> None:
        try:
            views = self.dataset.select(self.subset_edit.text().strip() or "all")
        except LfError as exc:
            self.views_label.setText(f"<span style='color:#b00020'>{exc}</span>")
            return
        if self.format == "hci":
            self.format_combo.setCurrentIndex(FORMAT_KEYS.index("png"))
        self.picker.set_selected(views)

    def _cell_clicked(self, row: int, column: int) -> None:
        """HCI: a click centres the sub-array on that view (moved inside the grid near its edges)."""
        if self.format != "hci":
            return
        grid = self.dataset.grid
        for spin, value, size, n in ((self.hci_center_row, row, self.hci_rows.value(), grid.rows),
                                     (self.hci_center_column, column, self.hci_columns.value(),
                                      grid.columns)):
            lo, hi = (size - 1) // 2, n - 1 - size // 2
            spin.setValue(min(max(value, lo), hi) if lo <= hi else value)

    def _format_changed(self) -> None:
        fmt = self.format
        self.format_info.setText(FORMAT_INFO[FORMAT_KEYS.index(fmt)][2])
        self.options_stack.setCurrentIndex(FORMAT_KEYS.index(fmt))
        hci = fmt == "hci"
        self.picker.toggle_on_click = not hci
        for w in (self.all_button, self.clear_button):
            w.setEnabled(not hci)
        if hci:
            self._user_selection = set(self.picker.selected)
        elif self._user_selection is not None:
            self.picker.set_selected(self._user_selection)
            self._user_selection = None
        self.picker.marked = (self.hci_center_row.value(), self.hci_center_column.value()) if hci else None
        name = self.name_edit.text().strip()
        if not name or name == self._auto_name:
            self._auto_name = default_name(self.dataset.root.name, fmt)
            self.name_edit.setText(self._auto_name)
        elif fmt == "hevc" and Path(name).suffix.lower() not in HEVC_SUFFIXES:
            self.name_edit.setText(name + ".mp4")
        self._options_changed()

    def _image_depth_changed(self, index: int) -> None:
        """COLMAP and nerfstudio share one image bit depth: both combos follow the last change."""
        for combo in self.image_depth_combos:
            if combo.currentIndex() != index:
                combo.setCurrentIndex(index)
        self._options_changed()

    def _selection_changed(self) -> None:
        if self.format != "hci":           # in HCI mode the picker only shows the sub-array
            self._options_changed()

    def _options_changed(self, *args) -> None:
        if self.format == "hci":
            self.picker.marked = (self.hci_center_row.value(), self.hci_center_column.value())
            self.picker.update()
        self.estimate = None
        self.estimate_error = None
        self.estimate_label.setText("Estimating…")
        if not self.exporting:              # the last export's line was about other options
            self.result_label.setText("")
        self._update_export_button()
        self._estimate_timer.start()

    def _destination_changed(self) -> None:
        try:
            out = self.out_path()
        except LfError as exc:
            self.path_label.setText(f"<span style='color:#b00020'>{exc}</span>")
            self.path_label.setToolTip(window_message(exc))
            self._update_export_button()
            return
        exists = " <span style='color:#b35900'>(exists: you will be asked before it is replaced)</span>" \
            if existing_outputs(self.format, out) else ""
        self.path_label.setText(f"→ {out}{exists}")
        self.path_label.setToolTip(str(out))
        self._update_export_button()

    def _source_changed(self) -> None:
        """HDR radiance is copied as the merge wrote it (float): the Images choice does not apply."""
        hdr = self.source_combo.currentData() == "hdr"
        for combo in self.image_depth_combos:
            combo.setEnabled(not hdr)
            combo.setToolTip("HDR radiance is exported as the merge wrote it (float EXR or TIFF)" if hdr else
                             "Images: 8-bit sRGB PNG (what view-synthesis tools expect) or linear 16-bit PNG")

    def _update_export_button(self) -> None:
        ok = (self.estimate is not None and not self.exporting and bool(self.folder_edit.text().strip())
              and bool(self.name_edit.text().strip()))
        self.export_button.setEnabled(ok)

    def choose_folder(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "Export into folder", self.folder_edit.text())
        if folder:
            self.folder_edit.setText(folder)

    # -- estimate ------------------------------------------------------------------------------------
    def update_estimate(self) -> None:
        """Recompute the size estimate off the GUI thread (one at a time; the latest options win)."""
        if self.estimate_runner.running:
            self._estimate_dirty = True
            return
        self._estimate_dirty = False
        try:
            options = self.options()
        except LfError as exc:
            self._estimate_failed(window_message(exc))
            return
        self.estimate_runner.start(_estimate_job, self.dataset, options)

    def _estimate_done(self, est) -> None:
        if self._estimate_dirty:
            self.update_estimate()
            return
        self.estimate = est
        self.estimate_error = None
        w, h = est.image_size_px
        self.estimate_label.setText(
            f"<b>{len(est.views)} views</b> · {w} × {h} px · from the {est.source} views · "
            f"about <b>{format_bytes(est.bytes_estimate)}</b>")
        self.warnings_label.setText("<br>".join(f"⚠ {w}" for w in est.warnings))
        if self.format == "hci":            # show exactly the sub-array that will be written
            self.picker.set_selected(est.views)
        self._update_views_label(len(est.views))
        self._destination_changed()         # the destination may have appeared or gone meanwhile

    def _estimate_failed(self, message: str) -> None:
        if self._estimate_dirty:
            self.update_estimate()
            return
        self.estimate = None
        self.estimate_error = message
        self.estimate_label.setText(f"<span style='color:#b00020'>{message}</span>")
        self.warnings_label.setText("")
        self._update_export_button()

    def _update_views_label(self, count: int) -> None:
        if self.format == "hci":
            text = (f"{count} views of the {self.hci_columns.value()} × {self.hci_rows.value()} sub-array "
                    f"around row {self.hci_center_row.value()}, column {self.hci_center_column.value()} "
                    "(click a view to centre the sub-array there)")
        else:
            text = f"{len(self.picker.selected)} of {len(self.available)} captured views selected"
            if self.format == "hevc":
                text += " (written in meander order)"
        self.views_label.setText(text)

    # -- export --------------------------------------------------------------------------------------
    def start_export(self) -> None:
        if self.exporting:
            return
        try:
            options = self.options()
        except LfError as exc:
            self.result_label.setText(f"<span style='color:#b00020'>{exc}</span>")
            return
        existing = existing_outputs(options.format, options.out)
        if existing:
            self._pending_options = options
            names = "\n".join(str(p) for p in existing)
            box = QMessageBox(QMessageBox.Icon.Question, "Replace the existing export?",
                              f"Already there:\n{names}\n\nReplace with this export? The old files are deleted "
                              "only when the new export is complete.", QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.No, self)
            box.setObjectName("overwriteBox")
            box.setDefaultButton(QMessageBox.StandardButton.No)
            box.finished.connect(lambda result, b=box: self._overwrite_answer(b, result))
            self.overwrite_box = box
            box.open()                      # window-modal, never blocks the event loop
            return
        self._run(options)

    def _overwrite_answer(self, box: QMessageBox, result: int) -> None:
        options, self._pending_options = self._pending_options, None
        box.deleteLater()
        self.overwrite_box = None
        if options is None:
            return
        if result == QMessageBox.StandardButton.Yes:
            options.overwrite = True
            self._run(options)
        else:
            self.result_label.setText("Not exported: choose another name or folder, or confirm replacing it.")

    def _run(self, options: ExportOptions) -> None:
        self._save_settings()
        self.report = None
        self.open_folder_button.setEnabled(False)
        self._running_out = options.out
        self.result_label.setText(f"Exporting to {options.out}…")
        self.runner.start(_export_job, self.dataset.root, options)
        self._update_export_button()
        self.format_combo.setEnabled(False)

    def _export_done(self, report) -> None:
        self.report = report
        self.format_combo.setEnabled(True)
        self._update_export_button()
        self.open_folder_button.setEnabled(True)
        self.result_label.setText(self.report_text(report))
        self._destination_changed()
        self.state.show_status(f"Exported {report.views} views to {report.out}", 8000)
        self.exportFinished.emit(report)

    @staticmethod
    def report_text(report) -> str:
        parts = [f"<b>Exported {report.views} views</b> to {report.out}: {format_bytes(report.bytes_written)} "
                 f"in {format_duration(report.seconds)}."]
        ratio = getattr(report, "compression_ratio_vs_png", None)
        if ratio:
            parts.append(f"{ratio:.0f}× smaller than 16-bit PNG.")
        psnr = getattr(report, "psnr_db", None)
        if psnr is not None:
            parts.append(f"PSNR {psnr:.1f} dB against the source views.")
        cloud = (getattr(report, "details", None) or {}).get("point_cloud")
        if isinstance(cloud, dict):      # how many sparse points, and why the other tracks were dropped
            from lfstudio.export import describe_points
            parts.append("<br>" + html.escape(describe_points(cloud)[:1].upper() + describe_points(cloud)[1:]) + ".")
        return " ".join(parts)

    def _export_failed(self, message: str) -> None:
        self.format_combo.setEnabled(True)
        self._update_export_button()
        self.result_label.setText(f"<span style='color:#b00020'>Export failed: {message}</span>")

    def _export_cancelled(self) -> None:
        self.format_combo.setEnabled(True)
        self._update_export_button()
        self.result_label.setText(f"Cancelled: nothing was written to {self._running_out}.")

    def export_folder(self) -> Path | None:
        if self.report is None:
            return None
        out = Path(self.report.out)
        return out if out.is_dir() else out.parent

    def open_folder(self) -> None:
        folder = self.export_folder()
        if folder is not None and not QDesktopServices.openUrl(QUrl.fromLocalFile(str(folder))):
            self.state.report_error("Open folder", f"No file manager could open {folder}; open it by hand.")

    # -- dataset, settings, closing --------------------------------------------------------------------
    def _dataset_changed(self, dataset) -> None:
        if dataset is None or self.runner.running:
            return
        if Path(dataset.root) != Path(self.dataset.root):
            return                          # the dialog stays on the dataset it was opened for
        self.dataset = dataset
        old = self.available
        self.available = set(dataset.captured_views())
        self.picker.available = self.available
        keep = self.picker.selected | (self.available - old) if self.picker.selected == old else self.picker.selected
        self.picker.set_selected(keep)

    def _restore_settings(self) -> None:
        s = settings()
        fmt = read_text("export/format", "png", s)
        self.format_combo.setCurrentIndex(FORMAT_KEYS.index(fmt) if fmt in FORMAT_KEYS else 0)
        source = read_text("export/source", "auto", s)
        keys = [k for k, _ in SOURCES]
        self.source_combo.setCurrentIndex(keys.index(source) if source in keys else 0)
        self.crf_spin.setValue(read_int("export/crf", 8, s))
        self.bit_depth_combo.setCurrentIndex(0 if read_int("export/bit_depth", 12, s) == 12 else 1)
        grid = self.dataset.grid
        self.hci_columns.setValue(read_int("export/hci_columns", 9, s))
        self.hci_rows.setValue(read_int("export/hci_rows", 9, s))
        self.hci_authors.setText(str(s.value("export/hci_authors", "") or ""))
        self.image_depth_combos[0].setCurrentIndex(1 if read_int("export/image_bit_depth", 8, s) == 16 else 0)
        holdout = read_text("export/holdout", "none", s)
        self.holdout_combo.setCurrentIndex(max(0, self.holdout_combo.findData(holdout)))
        self.hci_center_row.setValue(grid.rows // 2)
        self.hci_center_column.setValue(grid.columns // 2)
        folder = str(s.value(EXPORT_KEY, "") or self.dataset.root.parent)
        self.folder_edit.setText(folder)
        self.picker.set_selected(self.available)

    def _save_settings(self) -> None:
        s = settings()
        s.setValue("export/format", self.format)
        s.setValue("export/source", str(self.source_combo.currentData()))
        s.setValue("export/crf", self.crf_spin.value())
        s.setValue("export/bit_depth", int(self.bit_depth_combo.currentData()))
        s.setValue("export/hci_columns", self.hci_columns.value())
        s.setValue("export/hci_rows", self.hci_rows.value())
        s.setValue("export/hci_authors", self.hci_authors.text().strip())
        s.setValue("export/image_bit_depth", int(self.image_depth_combos[0].currentData()))
        s.setValue("export/holdout", str(self.holdout_combo.currentData()))
        if self.folder_edit.text().strip():
            s.setValue(EXPORT_KEY, self.folder_edit.text().strip())

    def done(self, result: int) -> None:
        if not confirm_cancel_running(self, self.runner, "Export", "The export is running. Cancel it and close? "
                                      "Nothing is left under the destination name."):
            return
        self._save_settings()
        super().done(result)

    def shutdown(self) -> None:
        for r in (self.runner, self.estimate_runner):
            r.stop(30)
