"""Dataset → Depth map of a view…: any view's disparity and depth in false colour, with a colour
bar in px and m, its confidence, and the computation of missing maps (one view, or every view of
the dataset on the local process pool) with progress, ETA and Cancel.

The maps are :mod:`lfstudio.depth.run`'s (``DATASET/depth/``); the picture is the quality check's
(:func:`lfstudio.quality.pictures.disparity_picture`: near = red). Reading and drawing run off the
GUI thread.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from PySide6.QtGui import QAction, QPixmap
from PySide6.QtWidgets import (QCheckBox, QDialog, QHBoxLayout, QLabel, QLineEdit, QPushButton, QVBoxLayout, QWidget)

from lfstudio.errors import LfError, window_message
from lfstudio.gui.bridge import JobRunner, run_off_gui
from lfstudio.gui.widgets import ColourBar, FitImageView, JobProgressWidget, add_stop_button, screen_fitted

#: pixels below this confidence are greyed out with "Hide unsure pixels"
UNSURE_BELOW = 0.1


def depth_picture(dataset, view: tuple[int, int], hide_unsure: bool = False) -> tuple[np.ndarray, dict[str, Any]]:
    """(BGR picture, figures) of a view's stored map: false-colour disparity over the rectified grey
    view, the colour bar in px and m (Qt-free; runs on a worker thread)."""
    import cv2

    from lfstudio.calibration.model import homography_for, load_calibration
    from lfstudio.dataset import images
    from lfstudio.depth.run import _processed_path, depth_from_disparity, read_disparity, zero_shear_px_per_mm
    from lfstudio.quality.pictures import colour_range, disparity_picture

    disp, conf, record = read_disparity(dataset, view)
    w, h = record["size_px"]
    cal = load_calibration(dataset) or {}
    path = _processed_path(dataset, view) if record["source"] == "processed" else dataset.path_of(dataset.view(*view))
    if path is None:        # processed again under another name, or its processed image deleted since
        from lfstudio.dataset.paths import view_stem

        raise LfError(f"{view_stem(*view)}: its depth map was computed from the processed image, which is no "
                      "longer there; compute the depth map again")
    grey, _, _ = images.read_grey(path, None)
    if grey.shape[::-1] != (w, h):
        grey = cv2.resize(grey, (w, h), interpolation=cv2.INTER_AREA)
    if record["source"] == "raw" and cal.get("homography"):
        grey = cv2.warpPerspective(grey, homography_for(cal, (w, h)), (w, h), flags=cv2.INTER_LINEAR,
                                   borderMode=cv2.BORDER_REPLICATE)
    shown = disp.copy()
    if hide_unsure:
        shown[conf < UNSURE_BELOW] = np.nan
    f_px = float(cal["focal_length_px"]) * w / float(cal["image_size_px"][0]) if cal.get("focal_length_px") \
        else dataset.focal_length_px(w)
    sx = float(dataset.grid.step_mm[0])
    shear = zero_shear_px_per_mm(dataset, w)
    scale = f_px * sx / 1000.0 if shear == 0.0 else None        # depth = scale / disparity (parallel views)
    picture = disparity_picture(shown, grey, depth_scale_m_px=scale, colour_bar=False)   # the window draws the bar
    fin = np.isfinite(disp)
    figures: dict[str, Any] = {"valid": float(fin.mean()), "confident": float((conf >= UNSURE_BELOW).mean()),
                               "source": record["source"], "size": (w, h), "colours_px": colour_range(shown),
                               "depth_scale_m_px": scale}
    from lfstudio.dataset.zero_plane import zero_plane

    figures["reference"] = zero_plane(dataset).disparity_reference()    # the maps are as the views are
    if fin.any():
        lo, hi = (float(v) for v in np.percentile(disp[fin], [1, 99]))   # as the check's map and the colours
        figures["disparity_px"] = (lo, hi)
        if shear is not None:
            z = depth_from_disparity(np.array([hi, lo]), f_px, sx, shear)
            figures["depth_m"] = tuple(float(v) for v in z)
    return picture, figures


def _compute_job(dataset, views, all_views: bool, disparity_range=None, *, progress, cancel):
    from lfstudio.depth.run import estimate_depth

    if not all_views:
        return estimate_depth(dataset, views, disparity_range_px=disparity_range, progress=progress, cancel=cancel)
    from lfstudio.processing.executors import open_executor

    with open_executor() as info:
        return estimate_depth(dataset, views, disparity_range_px=disparity_range, executor=info.executor,
                              workers=info.workers, progress=progress, cancel=cancel)


class DepthDialog(QDialog):
    """The depth/disparity view of any view of the open dataset (module docstring)."""

    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.dataset = state.dataset
        self.setObjectName("depthDialog")
        self.setWindowTitle("Depth map of a view")
        self.resize(screen_fitted(self, 1040, 820))
        views = self.dataset.captured_views()
        rows = sorted({r for r, _ in views})
        mid_row = rows[len(rows) // 2] if rows else 0
        cols = sorted(c for r, c in views if r == mid_row)
        self.view = (mid_row, cols[len(cols) // 2]) if cols else (0, 0)
        from lfstudio.dataset.paths import view_stem

        self.view_edit = QLineEdit(view_stem(*self.view))
        self.view_edit.setObjectName("depthViewEdit")
        self.view_edit.setToolTip("The view, by its name: r07_c042 is row 7, column 42")
        self.view_edit.setMaximumWidth(120)
        self.show_button = QPushButton("Show")
        self.show_button.setObjectName("depthShowButton")
        self.hide_check = QCheckBox("Hide unsure pixels")
        self.hide_check.setToolTip(f"Grey out pixels whose confidence is below {UNSURE_BELOW:g} (a flat or repeated "
                                   "texture, or seen from one side only)")
        self.compute_button = QPushButton("Compute this view")
        self.compute_button.setObjectName("depthComputeButton")
        self.compute_button.setToolTip("Estimate this view's disparity from the views around it "
                                       "(kept in the dataset's depth/ folder)")
        self.range_edit = QLineEdit("")
        self.range_edit.setObjectName("depthRangeEdit")
        self.range_edit.setPlaceholderText("automatic")
        self.range_edit.setMaximumWidth(110)
        self.range_edit.setToolTip("The disparities to search, in px between horizontal neighbours: MIN, MAX "
                                   "(e.g. -3.5, 3). Empty: the HCI folder's own range, the scene plan, else the "
                                   "tracks measured by the check or the import")
        self.compute_all_button = QPushButton("Compute every view")
        self.compute_all_button.setObjectName("depthComputeAllButton")
        self.compute_all_button.setToolTip("Every captured view on the local process pool (resumes: views done "
                                           "before are kept); for a cluster: lfstudio depth DATASET --cluster ADDR")
        top = QHBoxLayout()
        top.addWidget(QLabel("View"))
        top.addWidget(self.view_edit)
        top.addWidget(self.show_button)
        top.addWidget(self.hide_check)
        top.addStretch(1)
        top.addWidget(QLabel("Disparity range"))
        top.addWidget(self.range_edit)
        top.addWidget(self.compute_button)
        top.addWidget(self.compute_all_button)
        self.runner = JobRunner(self)
        self.progress = JobProgressWidget(self.runner)
        self.image = FitImageView("depthImage")     # whole by default, its colour bar in sight; Fit off: 1:1
        area = self.image
        self.fit_button = self.image.fit_button()
        top.insertWidget(top.indexOf(self.hide_check) + 1, self.fit_button)
        self.colour_bar = ColourBar("depthColourBar")     # at screen resolution, whatever the picture's scale
        self.caption = QLabel("")
        self.caption.setObjectName("depthCaption")
        self.caption.setWordWrap(True)
        lay = QVBoxLayout(self)
        lay.addLayout(top)
        lay.addWidget(self.progress)
        lay.addWidget(area, 1)
        lay.addWidget(self.colour_bar)
        lay.addWidget(self.caption)
        add_stop_button(self, lay)      # STOP in sight while this dialog covers the window's
        self.show_button.clicked.connect(self.show_view)
        self.view_edit.returnPressed.connect(self.show_view)
        self.hide_check.toggled.connect(self.show_view)
        self.compute_button.clicked.connect(lambda: self.compute(False))
        self.compute_all_button.clicked.connect(lambda: self.compute(True))
        self.runner.finished.connect(self._computed)
        self.runner.failed.connect(lambda message: self.caption.setText(f"Depth failed: {message}"))
        self.runner.cancelled.connect(lambda: self.caption.setText("Cancelled: the views finished so far are kept"))
        self._loader: JobRunner | None = None
        self.pictures_shown = 0
        self.range_text = ""                # the range the last computation searched, and its origin
        self.show_view()

    def _chosen(self) -> tuple[int, int] | None:
        from lfstudio.dataset.paths import parse_view_stem

        try:
            view = parse_view_stem(self.view_edit.text().strip())
        except (ValueError, LfError):
            self.caption.setText(f"{self.view_edit.text().strip()!r} is not a view name; write it like r01_c004")
            return None
        if view not in set(self.dataset.captured_views()):
            self.caption.setText(f"{self.view_edit.text().strip()} is not a captured view of this dataset")
            return None
        return view

    def show_view(self) -> None:
        from lfstudio.depth.run import has_disparity

        view = self._chosen()
        if view is None:
            return
        self.view = view
        if not has_disparity(self.dataset, view):
            self.image.clear()
            self.caption.setText(f"{self.view_edit.text().strip()} has no depth map yet: Compute this view "
                                 "(a few seconds) or every view")
            return
        self.caption.setText("Drawing…")
        hide = self.hide_check.isChecked()
        self._loader = run_off_gui(self, lambda: depth_picture(self.dataset, view, hide), self._show_picture,
                                   lambda message: self.caption.setText(f"Cannot show the map: {message}"))

    def _show_picture(self, result) -> None:
        from lfstudio.gui.imageutil import rgb_to_qimage

        picture, fig = result
        self.image.set_pixmap(QPixmap.fromImage(rgb_to_qimage(picture[..., ::-1].copy())))
        lo, hi = fig["colours_px"]
        reference = fig.get("reference", "from infinity")
        self.colour_bar.set_range(lo, hi, fig.get("depth_scale_m_px"),
                                  f"Disparity in px between horizontal neighbours, {reference} (near = red)")
        parts = [f"{self.view_edit.text().strip()}: disparity between horizontal neighbours, {reference} "
                 "(near = red)"]
        if "disparity_px" in fig:
            lo, hi = fig["disparity_px"]
            parts.append(f"{lo:+.2f} … {hi:+.2f} px (1st–99th percentile of the map)")
        if "depth_m" in fig:
            parts.append(f"depth {fig['depth_m'][0]:.2f} … {fig['depth_m'][1]:.2f} m")
        parts.append(f"{fig['confident']:.0%} of pixels sure (confidence ≥ {UNSURE_BELOW:g})")
        parts.append("from processed views" if fig["source"] == "processed" else "from the captures")
        if self.range_text:
            parts.append(self.range_text)
        self.caption.setText("; ".join(parts))
        self.pictures_shown += 1

    def compute(self, all_views: bool) -> None:
        if self.runner.running:
            return
        view = None if all_views else self._chosen()
        if not all_views and view is None:
            return
        stated = None
        if self.range_edit.text().strip():
            from lfstudio.depth.run import parse_disparity_range

            try:
                stated = parse_disparity_range("Disparity range", self.range_edit.text())
            except LfError as exc:
                self.caption.setText(window_message(exc))
                return
        self.caption.setText("Computing…")
        self.runner.start(_compute_job, self.dataset, None if all_views else [view], all_views, stated)

    def _computed(self, report) -> None:
        self.range_text = report.range_text.replace("the range stated", "the Disparity range field")
        self.caption.setText(f"{report.summary()}; {self.range_text}")
        self.show_view()

    def closeEvent(self, event) -> None:           # noqa: N802 - Qt's name
        self.runner.stop(5.0)
        super().closeEvent(event)


def install_menus(window) -> None:
    """Dataset → Depth map of a view… (greyed out until a dataset is open)."""
    state = window.state
    action = QAction("Depth map of a view…", window)
    action.setObjectName("actionDepthMap")
    action.setToolTip("A view's disparity and depth (colour bar in px and m) from its neighbours; computes missing maps")

    def open_dialog() -> None:
        if state.dataset is None:
            state.report_error("Depth map", "No dataset is open: open a dataset folder first (File → Open dataset…).")
            return
        dialog = getattr(window, "depth_dialog", None)
        if dialog is not None and dialog.isVisible() and dialog.dataset.root == state.dataset.root:
            dialog.raise_()
            return
        try:
            window.depth_dialog = DepthDialog(state, window)
        except LfError as exc:
            state.report_error("Depth map", window_message(exc))
            return
        window.depth_dialog.show()

    action.triggered.connect(open_dialog)
    state.datasetChanged.connect(lambda ds: action.setEnabled(ds is not None))
    action.setEnabled(state.dataset is not None)
    window.menu("Dataset").addAction(action)
