"""File → Import images… and File → Import HEVC…: other rigs' images or an HEVC export → a dataset.

Both dialogs run the core importer (:func:`lfstudio.export.import_images.import_images`,
:func:`lfstudio.export.import_hevc`) on a :class:`JobRunner` with progress, ETA and Cancel, ask
before replacing an existing dataset (a non-modal question: the event loop keeps running), and
at the end offer to open the new dataset in the app (``AppState.set_dataset``). The images dialog
counts the matching files as the operator types ("found 42 images, grid needs 45").

The destination follows the rule of every new dataset (:func:`lfstudio.dataset.paths.check_new_dataset_folder`):
a new or empty folder is used at once; a dataset there is replaced only after the operator confirms;
a folder holding other files is never replaced: the Scan panel's offer of a new sub-folder is made
(:func:`lfstudio.gui.path_field.offer_sub_folder`); a folder a running scan holds (its ``dataset.lock``,
:func:`lfstudio.dataset.paths.check_not_in_use`) is refused at once, naming that scan, without a question.
"""

from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import Qt, QTimer
from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import (QCheckBox, QComboBox, QDialog, QDoubleSpinBox, QFileDialog, QFormLayout,
                               QHBoxLayout, QLabel, QLineEdit, QMessageBox, QPushButton, QSpinBox,
                               QStackedWidget, QVBoxLayout, QWidget)

from lfstudio.dataset.paths import (FOLDER_DATASET, FOLDER_FILE, FOLDER_OTHERS, check_not_in_use, dataset_folder_kind,
                                    expand_path, new_dataset_folder_problem)
from lfstudio.errors import InputError, LfError, for_window, window_message
from lfstudio.gui.bridge import JobRunner
from lfstudio.gui.path_field import expand_on_edit, field_path, offer_sub_folder
from lfstudio.gui.settings import read_float, read_int, read_text, settings
from lfstudio.gui.widgets import JobProgressWidget, QuietLabel, screen_fitted

OK_STYLE = "color: #1b7a1b;"
BAD_STYLE = "color: #b00020;"
INTRINSICS_MODES = ("From EXIF (if the files have it)", "Focal length (mm) + pixel pitch (µm)", "Focal length (px)")
POSITION_MODES = ("From the grid spacing", "Recorded in the file names (out_RR_CC_<a>_<b>)", "Recorded in a CSV file")
COUNT_LINES = 3        # the file count's message: lines reserved under the pattern (the whole text in its tooltip)
ZERO_MODES = ("Measure from the views", "Parallel views (not sheared)", "Sheared, zero-disparity plane at")


def _path_row(edit: QLineEdit, button: QPushButton) -> QWidget:
    w = QWidget()
    lay = QHBoxLayout(w)
    lay.setContentsMargins(0, 0, 0, 0)
    lay.addWidget(edit, 1)
    lay.addWidget(button)
    return w


def _pair(a: QWidget, b: QWidget, sep: str = "×") -> QWidget:
    w = QWidget()
    lay = QHBoxLayout(w)
    lay.setContentsMargins(0, 0, 0, 0)
    lay.addWidget(a)
    lay.addWidget(QLabel(sep))
    lay.addWidget(b)
    lay.addStretch(1)
    return w


class _ImportDialogBase(QDialog):
    """Destination field, Import button, progress with Cancel, overwrite question, open-the-dataset."""

    settings_prefix = "import"
    action_text = "Import"

    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.result_root: Path | None = None
        self._confirm: QMessageBox | None = None
        self.out_edit = QLineEdit(str(settings().value(f"{self.settings_prefix}/out", "")))
        self.out_edit.setPlaceholderText("a new dataset folder")
        self.out_edit.setToolTip("The dataset folder to create: a new or empty folder (a dataset there is replaced "
                                 "only if you confirm; a folder of other files gets a new sub-folder)")
        expand_on_edit(self.out_edit, "Destination")
        self.out_button = QPushButton("Browse…")
        self.out_button.setToolTip("Choose where the new dataset goes")
        self.out_button.clicked.connect(self._browse_out)
        self.import_button = QPushButton(self.action_text)
        self.import_button.setObjectName("importButton")
        self.import_button.setDefault(True)
        self.open_button = QPushButton("Open dataset in lfstudio")
        self.open_button.setObjectName("openDatasetButton")
        self.open_button.setToolTip("Show the imported dataset in the grid view (then calibrate, process, export)")
        self.open_button.setEnabled(False)
        self.open_button.clicked.connect(self.open_result)
        self.close_button = QPushButton("Close")
        self.close_button.clicked.connect(self.close)
        self.runner = JobRunner(self)
        self.progress = JobProgressWidget(self.runner)
        self.message = QLabel("")
        self.message.setObjectName("importMessage")
        self.message.setWordWrap(True)
        self.message.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.import_button.clicked.connect(self.start_import)
        self.runner.finished.connect(self._done)
        self.runner.failed.connect(self._failed)
        self.runner.cancelled.connect(self._cancelled)

    def _lay_out(self, form: QFormLayout) -> None:
        """The dialog's fields, then progress, message and the buttons."""
        lay = QVBoxLayout(self)
        lay.addLayout(form)
        lay.addWidget(self.progress)
        lay.addWidget(self.message)
        lay.addStretch(1)
        buttons = QHBoxLayout()
        buttons.addStretch(1)
        for button in (self.open_button, self.import_button, self.close_button):
            buttons.addWidget(button)
        lay.addLayout(buttons)

    def _browse_out(self) -> None:
        start = self.out_edit.text() or str(settings().value("datasets/last_dir", ""))
        path, _ = QFileDialog.getSaveFileName(self, "New dataset folder", start, "Dataset folder (*)",
                                              options=QFileDialog.Option.ShowDirsOnly | QFileDialog.Option.DontConfirmOverwrite)
        if path:
            self.out_edit.setText(path)

    def show_message(self, text: str, ok: bool | None = None) -> None:
        self.message.setText(text)
        self.message.setStyleSheet("" if ok is None else OK_STYLE if ok else BAD_STYLE)

    # -- run ---------------------------------------------------------------------------------------
    def job(self, overwrite: bool):
        """(function, args) for :meth:`JobRunner.start`; raise InputError for a bad field."""
        raise NotImplementedError

    def save_settings(self) -> None:
        settings().setValue(f"{self.settings_prefix}/out", self.out_edit.text())

    def start_import(self) -> None:
        if self.runner.running:
            return
        out_text = self.out_edit.text().strip()
        if not out_text:
            self.show_message("Destination: choose a folder for the new dataset", ok=False)
            return
        try:
            out = field_path(self.out_edit, "Destination")
        except InputError as exc:
            self.show_message(window_message(exc), ok=False)
            return
        kind = dataset_folder_kind(out)
        if kind not in (FOLDER_FILE, FOLDER_OTHERS):
            try:
                check_not_in_use(out)         # a running scan's folder: not even a question
            except LfError as exc:
                self.show_message(f"Not imported: {exc}", ok=False)
                return
        if kind == FOLDER_OTHERS:            # the operator's files: never replaced; a sub-folder is offered
            self.show_message(f"Not imported yet: {new_dataset_folder_problem(out)}", ok=False)
            self._confirm = offer_sub_folder(self, out, stem="lfstudio-import", verb="Import",
                                             where="the Destination field", accepted=self._import_into)
            return
        if kind == FOLDER_FILE:
            self.show_message(f"Destination: {out} is a file; choose a folder name for the new dataset", ok=False)
            return
        if kind == FOLDER_DATASET:
            self._ask_overwrite(out)
            return
        self._start(overwrite=False)         # missing or empty

    def _import_into(self, sub: Path) -> None:
        self._confirm = None
        self.out_edit.setText(str(sub))
        self.start_import()

    def _ask_overwrite(self, out: Path) -> None:
        box = QMessageBox(QMessageBox.Icon.Question, "Replace dataset?",
                          f"{out} already holds a dataset.\n\nReplace it with the imported dataset? The whole "
                          "dataset there is deleted when the import has finished.",
                          QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.Cancel, self)
        box.setObjectName("confirmOverwrite")
        box.setDefaultButton(QMessageBox.StandardButton.Cancel)
        box.finished.connect(lambda result: self._overwrite_answer(result == QMessageBox.StandardButton.Yes))
        self._confirm = box
        box.open()   # non-modal: the event loop keeps running

    def _overwrite_answer(self, yes: bool) -> None:
        self._confirm = None
        if yes:
            self._start(overwrite=True)
        else:
            self.show_message("Not imported: the destination holds a dataset; choose another folder", ok=False)

    def _start(self, overwrite: bool) -> None:
        try:
            fn, args = self.job(overwrite)
        except InputError as exc:
            self.show_message(window_message(exc), ok=False)
            return
        self.save_settings()
        self.result_root = None
        self.open_button.setEnabled(False)
        self.import_button.setEnabled(False)
        self.show_message("Importing…")
        self.runner.start(fn, *args)

    def _done(self, root) -> None:
        self.import_button.setEnabled(True)
        self.result_root = Path(root)
        self.open_button.setEnabled(True)
        self.open_button.setFocus()
        self.show_message(self.summary(self.result_root), ok=True)
        self.state.show_status(f"Imported {root}")

    def summary(self, root: Path) -> str:
        from lfstudio.dataset import Dataset

        try:
            n = len(Dataset.open(root).done_views())
        except LfError:
            return f"Imported into {root}."
        return f"Imported {n} views into {root}."

    def _failed(self, message: str) -> None:
        self.import_button.setEnabled(True)
        self.show_message(message, ok=False)

    def _cancelled(self) -> None:
        self.import_button.setEnabled(True)
        self.show_message("Cancelled: nothing was written.", ok=None)

    def open_result(self) -> None:
        from lfstudio.dataset import Dataset

        if self.result_root is None:
            return
        try:
            ds = Dataset.open(self.result_root)
        except LfError as exc:
            self.show_message(window_message(exc), ok=False)
            return
        self.state.set_dataset(ds)
        self.state.show_status(f"Opened {self.result_root}")
        self.accept()

    def reject(self) -> None:   # also Close and the title bar's ×: closing cancels; the importer cleans up
        self.runner.stop(10.0)
        super().reject()


class ImportImagesDialog(_ImportDialogBase):
    """Folder, grid, spacing, order, pattern, intrinsics, destination; live file count; run."""

    settings_prefix = "import_images"

    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(state, parent)
        self.setObjectName("importImagesDialog")
        self.setWindowTitle("Import images from another rig")
        s = settings()
        p = self.settings_prefix
        self.folder_edit = QLineEdit(read_text(f"{p}/folder", "", s))
        self.folder_edit.setPlaceholderText("folder holding one image per view")
        self.folder_edit.setToolTip("The other rig's images: PNG, TIFF, JPEG or camera RAW, one file per view")
        expand_on_edit(self.folder_edit, "Image folder")
        self.folder_button = QPushButton("Browse…")
        self.folder_button.setToolTip("Choose the folder of images")
        self.folder_button.clicked.connect(self._browse_folder)
        self.pattern_edit = QLineEdit(read_text(f"{p}/pattern", "", s))
        self.pattern_edit.setPlaceholderText("every PNG, TIFF, JPEG and RAW file")
        self.pattern_edit.setToolTip("Which files to take, e.g. *.png or cam_*.tif; sorted naturally (img2 < img10)")
        self.columns_spin, self.rows_spin = QSpinBox(), QSpinBox()
        for spin, key, default, tip in ((self.columns_spin, "columns", 9, "Views per row"),
                                        (self.rows_spin, "rows", 5, "Rows of views")):
            spin.setRange(1, 10000)
            spin.setValue(read_int(f"{p}/{key}", default, s))
            spin.setToolTip(tip)
        self.spacing_h, self.spacing_v = QDoubleSpinBox(), QDoubleSpinBox()
        for spin, key, default, tip in ((self.spacing_h, "spacing_h_mm", 4.0, "Horizontal distance between views"),
                                        (self.spacing_v, "spacing_v_mm", 6.0, "Vertical distance between rows")):
            spin.setRange(0.0, 100000.0)
            spin.setDecimals(3)
            spin.setSuffix(" mm")
            spin.setValue(read_float(f"{p}/{key}", default, s))
            spin.setToolTip(tip)
        self.order_combo = QComboBox()
        self.order_combo.addItems(["row-major", "meander"])
        self.order_combo.setCurrentText(read_text(f"{p}/order", "row-major", s))
        self.order_combo.setToolTip("row-major: every row left to right; meander: odd rows right to left "
                                    "(as a gantry scans). Row 0 is the top row.")
        self.intrinsics_combo = QComboBox()
        self.intrinsics_combo.addItems(list(INTRINSICS_MODES))
        self.intrinsics_combo.setCurrentIndex(read_int(f"{p}/intrinsics", 0, s))
        self.intrinsics_combo.setToolTip("Where the focal length comes from (calibration needs it in pixels)")
        self.focal_mm = QDoubleSpinBox()
        self.focal_mm.setRange(0.1, 5000.0)
        self.focal_mm.setSuffix(" mm")
        self.focal_mm.setValue(read_float(f"{p}/focal_length_mm", 50.0, s))
        self.focal_mm.setToolTip("Lens focal length")
        self.pitch_um = QDoubleSpinBox()
        self.pitch_um.setRange(0.1, 1000.0)
        self.pitch_um.setDecimals(3)
        self.pitch_um.setSuffix(" µm")
        self.pitch_um.setValue(read_float(f"{p}/pixel_pitch_um", 4.5, s))
        self.pitch_um.setToolTip("Sensor pixel size (pitch) of these images")
        self.focal_px = QDoubleSpinBox()
        self.focal_px.setRange(1.0, 1e6)
        self.focal_px.setDecimals(1)
        self.focal_px.setSuffix(" px")
        self.focal_px.setValue(read_float(f"{p}/focal_length_px", 5000.0, s))
        self.focal_px.setToolTip("Focal length in pixels of these images (full size)")
        self.intrinsics_stack = QStackedWidget()
        exif_page = QLabel("Read from the first image's EXIF; if it has none, calibration will ask for one.")
        exif_page.setWordWrap(True)
        self.intrinsics_stack.addWidget(exif_page)
        self.intrinsics_stack.addWidget(_pair(self.focal_mm, self.pitch_um, "with"))
        self.intrinsics_stack.addWidget(_pair(self.focal_px, QLabel(""), ""))
        self.intrinsics_combo.currentIndexChanged.connect(self.intrinsics_stack.setCurrentIndex)
        self.intrinsics_stack.setCurrentIndex(self.intrinsics_combo.currentIndex())
        self.positions_combo = QComboBox()
        self.positions_combo.addItems(list(POSITION_MODES))
        self.positions_combo.setCurrentIndex(read_int(f"{p}/positions", 0, s))
        self.positions_combo.setToolTip("Where each view's position comes from: the grid spacing, the rig's "
                                        "recorded positions in the file names (Stanford archive: "
                                        "out_RR_CC_<a>_<b>) or a CSV file (file,x_mm,y_mm); check then "
                                        "measures each view against the record")
        self.positions_csv = QLineEdit(read_text(f"{p}/positions_csv", "", s))
        self.positions_csv.setPlaceholderText("CSV with the columns file,x_mm,y_mm")
        self.positions_csv.setToolTip("One row per image: its file name and the recorded position in mm")
        self.positions_csv_button = QPushButton("Browse…")
        self.positions_csv_button.setToolTip("Choose the CSV of recorded positions")
        self.positions_csv_button.clicked.connect(self._browse_csv)
        self.positions_csv_row = _path_row(self.positions_csv, self.positions_csv_button)
        self.positions_combo.currentIndexChanged.connect(self._positions_changed)
        self.zero_combo = QComboBox()
        self.zero_combo.addItems(list(ZERO_MODES))
        self.zero_combo.setCurrentIndex(read_int(f"{p}/zero_plane", 0, s))
        self.zero_combo.setToolTip("Archive light fields are published sheared (a plane inside the scene has zero "
                                   "disparity). Measuring tells whether the views are sheared, not at which depth: "
                                   "state the depth for depths and posed exports")
        self.zero_depth = QDoubleSpinBox()
        self.zero_depth.setRange(0.01, 100000.0)
        self.zero_depth.setDecimals(3)
        self.zero_depth.setSuffix(" m")
        self.zero_depth.setValue(read_float(f"{p}/zero_depth_m", 3.0, s))
        self.zero_depth.setToolTip("Depth of the plane with zero disparity (needs the focal length)")
        self.zero_combo.currentIndexChanged.connect(self._zero_changed)
        self.copy_check = QCheckBox("Always copy the files (default: hard-link them when on the same disk)")
        self.copy_check.setChecked(s.value(f"{p}/copy", "false") in (True, "true"))
        self.copy_check.setToolTip("Hard links take no extra space; copies are independent of the originals")
        # the live count's message takes 1 to 3 lines as the operator types: its height is reserved, so the
        # fields under it never move (a click meant for Focal length opened File order)
        self.count_label = QuietLabel("", name="countLabel", lines=COUNT_LINES,
                                      hint_text="Found 2121 images (.dng, .tif), grid needs 2121 ✓")
        self.import_button.setToolTip("Build the dataset (files are checked first; nothing is left on Cancel)")

        form = QFormLayout()
        form.setFieldGrowthPolicy(QFormLayout.FieldGrowthPolicy.AllNonFixedFieldsGrow)
        form.addRow("Image folder", _path_row(self.folder_edit, self.folder_button))
        form.addRow("Files (pattern)", self.pattern_edit)
        form.addRow("", self.count_label)
        form.addRow("Grid (columns × rows)", _pair(self.columns_spin, self.rows_spin))
        form.addRow("Spacing (horizontal × vertical)", _pair(self.spacing_h, self.spacing_v))
        form.addRow("File order", self.order_combo)
        form.addRow("Focal length", self.intrinsics_combo)
        form.addRow("", self.intrinsics_stack)
        form.addRow("Positions", self.positions_combo)
        form.addRow("", self.positions_csv_row)
        form.addRow("Zero disparity", _pair(self.zero_combo, self.zero_depth, ""))
        form.addRow("Destination", _path_row(self.out_edit, self.out_button))
        form.addRow("", self.copy_check)
        self._lay_out(form)
        self.resize(screen_fitted(self, 720, 560))
        self._positions_changed()
        self._zero_changed()

        self._recount_timer = QTimer(self)
        self._recount_timer.setSingleShot(True)
        self._recount_timer.setInterval(250)
        self._recount_timer.timeout.connect(self.recount)
        for sig in (self.folder_edit.textChanged, self.pattern_edit.textChanged, self.columns_spin.valueChanged,
                    self.rows_spin.valueChanged):
            sig.connect(self._recount_timer.start)
        self.recount()

    def _positions_changed(self) -> None:
        self.positions_csv_row.setEnabled(self.positions_combo.currentIndex() == 2)   # shown: no fields move
        self.spacing_h.setEnabled(self.positions_combo.currentIndex() == 0)
        self.spacing_v.setEnabled(self.positions_combo.currentIndex() == 0)

    def _zero_changed(self) -> None:
        self.zero_depth.setEnabled(self.zero_combo.currentIndex() == 2)

    def _browse_csv(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Recorded positions", self.positions_csv.text(), "CSV (*.csv);;All files (*)")
        if path:
            self.positions_csv.setText(path)

    def _browse_folder(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "Folder of images", self.folder_edit.text())
        if folder:
            self.folder_edit.setText(folder)
            if not self.out_edit.text().strip():
                self.out_edit.setText(str(Path(folder).parent / f"{Path(folder).name}_dataset"))

    def recount(self) -> int | None:
        """List the matching files now and say whether they fill the grid; the count (None: no folder)."""
        from lfstudio.export.import_images import find_images

        self._recount_timer.stop()
        text = self.folder_edit.text().strip()
        need = self.columns_spin.value() * self.rows_spin.value()
        if not text:
            self._say_count(f"Choose a folder; the grid needs {need} images", "")
            return None
        try:
            files = find_images(expand_path(text, "Image folder", absolute=True), self.pattern_edit.text().strip() or None)
        except InputError as exc:
            self._say_count(window_message(exc).split(": ", 1)[-1], BAD_STYLE)
            return None
        n = len(files)
        kinds = sorted({p.suffix.lower() for p in files})
        text = f"Found {n} image{'s' if n != 1 else ''}" + (f" ({', '.join(kinds)})" if kinds else "") + \
            f", grid needs {need}"
        if n == need:
            self._say_count(text + f" ✓  ({files[0].name} … {files[-1].name})", OK_STYLE)
        else:
            hint = "; choose one kind with the pattern, e.g. *" + kinds[0] if len(kinds) > 1 else ""
            self._say_count(text + hint, BAD_STYLE)
        return n

    def _say_count(self, text: str, style: str) -> None:
        """The count's message in its reserved lines (and whole in its tooltip)."""
        self.count_label.setText(text)
        self.count_label.label.setStyleSheet(style)
        self.count_label.setToolTip(text)

    def options(self, overwrite: bool = False):
        from lfstudio.export.import_images import POSITIONS_FROM_NAMES, ImportOptions
        from lfstudio.quality.shear import measure_shear

        mode = self.intrinsics_combo.currentIndex()
        where = self.positions_combo.currentIndex()
        if where == 2 and not self.positions_csv.text().strip():
            raise InputError("Positions", "choose the CSV file of recorded positions (file,x_mm,y_mm)")
        zero = self.zero_combo.currentIndex()
        return ImportOptions(
            folder=field_path(self.folder_edit, "Image folder"),
            out=field_path(self.out_edit, "Destination"),
            grid=(self.columns_spin.value(), self.rows_spin.value()),
            spacing_mm=(self.spacing_h.value(), self.spacing_v.value()) if where == 0 else None,
            positions=None if where == 0 else POSITIONS_FROM_NAMES if where == 1 else
            str(field_path(self.positions_csv, "Positions")),
            parallel_views=zero == 1, zero_disparity_depth_m=self.zero_depth.value() if zero == 2 else None,
            measure=measure_shear,
            order=self.order_combo.currentText(), pattern=self.pattern_edit.text().strip() or None,
            focal_length_mm=self.focal_mm.value() if mode == 1 else None,
            pixel_pitch_um=self.pitch_um.value() if mode == 1 else None,
            focal_length_px=self.focal_px.value() if mode == 2 else None,
            overwrite=overwrite, link=not self.copy_check.isChecked())

    def job(self, overwrite: bool):
        from lfstudio.export.import_images import check_options, import_images

        if not self.folder_edit.text().strip():
            raise InputError("Image folder", "choose the folder of images")
        options = self.options(overwrite)
        check_options(options)
        return import_images, (options,)

    def save_settings(self) -> None:
        super().save_settings()
        s, p = settings(), self.settings_prefix
        for key, value in (("folder", self.folder_edit.text()), ("pattern", self.pattern_edit.text()),
                           ("columns", self.columns_spin.value()), ("rows", self.rows_spin.value()),
                           ("spacing_h_mm", self.spacing_h.value()), ("spacing_v_mm", self.spacing_v.value()),
                           ("order", self.order_combo.currentText()),
                           ("intrinsics", self.intrinsics_combo.currentIndex()),
                           ("focal_length_mm", self.focal_mm.value()), ("pixel_pitch_um", self.pitch_um.value()),
                           ("focal_length_px", self.focal_px.value()), ("copy", self.copy_check.isChecked()),
                           ("positions", self.positions_combo.currentIndex()),
                           ("positions_csv", self.positions_csv.text()),
                           ("zero_plane", self.zero_combo.currentIndex()), ("zero_depth_m", self.zero_depth.value())):
            s.setValue(f"{p}/{key}", value)

    def summary(self, root: Path) -> str:
        from lfstudio.dataset import Dataset

        try:
            ds = Dataset.open(root)
        except LfError:
            return super().summary(root)
        record = ds.manifest.get("import", {})
        w, h = ds.camera.get("sensor_px", ["?", "?"])
        text = (f"Imported {len(ds.views)} views ({ds.grid.columns} × {ds.grid.rows}, {w} × {h} px) into "
                f"{root}; {record.get('linked', 0)} hard-linked. ")
        source = record.get("intrinsics", "none")
        # the record names the command line's options: the window names its own fields
        source = {"--focal-length-px": "the Focal length (px) field",
                  "--focal-length-mm and --pixel-pitch-um": "the Focal length (mm) and pixel pitch fields"}.get(source,
                                                                                                             source)
        text += ("Focal length: not known; calibration will need one (Dataset → Calibrate…: Focal length), or "
                 "import again with the Focal length set." if source == "none" else f"Focal length from {source}.")
        from lfstudio.export.import_images import NO_FOCAL_LENGTH_WARNING, import_summary

        text += "\n" + "\n".join(line.replace("  ", "").replace(" :", ":")
                                  for line in for_window(import_summary(ds)).splitlines())
        for warning in record.get("warnings", []):
            if not warning.startswith(NO_FOCAL_LENGTH_WARNING):     # said above in the window's words
                text += f"\nNote: {warning}"
        return text


class ImportHevcDialog(_ImportDialogBase):
    """An HEVC export (``lfstudio export --format hevc``) back to a dataset of 16-bit PNG views."""

    settings_prefix = "import_hevc"

    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(state, parent)
        self.setObjectName("importHevcDialog")
        self.setWindowTitle("Import an HEVC light-field export")
        self.file_edit = QLineEdit(str(settings().value(f"{self.settings_prefix}/file", "")))
        self.file_edit.setPlaceholderText("an .mp4/.mkv/.hevc exported by lfstudio (with its .json sidecar)")
        self.file_edit.setToolTip("The HEVC stream; its sidecar JSON maps frames to views")
        expand_on_edit(self.file_edit, "HEVC file")
        self.file_button = QPushButton("Browse…")
        self.file_button.clicked.connect(self._browse_file)
        self.import_button.setToolTip("Decode every frame into a new dataset of 16-bit PNG views")
        form = QFormLayout()
        form.setFieldGrowthPolicy(QFormLayout.FieldGrowthPolicy.AllNonFixedFieldsGrow)
        form.addRow("HEVC file", _path_row(self.file_edit, self.file_button))
        form.addRow("Destination", _path_row(self.out_edit, self.out_button))
        self._lay_out(form)
        self.resize(680, 240)

    def _browse_file(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "HEVC export", self.file_edit.text(),
                                              "HEVC video (*.mp4 *.mkv *.hevc *.mov);;All files (*)")
        if path:
            self.file_edit.setText(path)
            if not self.out_edit.text().strip():
                self.out_edit.setText(str(Path(path).with_suffix("")) + "_dataset")

    def job(self, overwrite: bool):
        if not self.file_edit.text().strip():
            raise InputError("HEVC file", "choose the exported .mp4/.mkv/.hevc file")
        file = field_path(self.file_edit, "HEVC file")
        if not file.is_file():
            raise InputError("HEVC file", f"{file} is not a file" if self.file_edit.text().strip() else
                             "choose the exported .mp4/.mkv/.hevc file")
        fn = hevc_importer()
        if fn is None:
            raise InputError("HEVC file", "HEVC import is not available in this lfstudio build "
                             "(lfstudio.export.import_hevc is missing); update lfstudio")
        out = field_path(self.out_edit, "Destination")

        def run(*, progress, cancel):
            return fn(file, out, progress=progress, cancel=cancel, overwrite=overwrite)

        run.__name__ = "import_hevc"
        return run, ()

    def save_settings(self) -> None:
        super().save_settings()
        settings().setValue(f"{self.settings_prefix}/file", self.file_edit.text())


def hevc_importer():
    """``lfstudio.export.import_hevc`` when this build has it, else None."""
    try:
        from lfstudio import export
    except ImportError:
        return None
    fn = getattr(export, "import_hevc", None)
    return fn if callable(fn) else None


def install_menus(window) -> None:
    """File → Import images… and File → Import HEVC… (one dialog of each, kept on the window)."""
    state = window.state
    menu = window.menu("File")
    menu.addSeparator()

    def show(cls, attr: str) -> None:
        dialog = getattr(window, attr, None)
        if dialog is None:
            dialog = cls(state, window)
            setattr(window, attr, dialog)
        dialog.show()
        dialog.raise_()
        dialog.activateWindow()

    images = QAction("Import images…", window)
    images.setObjectName("actionImportImages")
    images.setShortcut(QKeySequence("Ctrl+I"))
    images.setToolTip("Build a dataset from another rig's folder of images (PNG, TIFF, JPEG, RAW)")
    images.triggered.connect(lambda: show(ImportImagesDialog, "import_images_dialog"))
    menu.addAction(images)
    hevc = QAction("Import HEVC…", window)
    hevc.setObjectName("actionImportHevc")
    hevc.setToolTip("Restore a dataset of 16-bit PNG views from an HEVC export (with its sidecar JSON)")
    hevc.triggered.connect(lambda: show(ImportHevcDialog, "import_hevc_dialog"))
    menu.addAction(hevc)
