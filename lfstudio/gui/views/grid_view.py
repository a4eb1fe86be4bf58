"""The central thumbnail grid: every view of the open dataset laid out as on the rig (row x column).

One custom-painted scroll area (no widget per view: ``gui/views/grid_canvas.py``). At low zoom the
whole grid is drawn from one mosaic image (one small tile per view, filled in as thumbnails load);
zoomed in, only the visible views are drawn from their full thumbnails. Thumbnails are decoded off
the GUI thread (``gui/views/thumb_loader.py``: :func:`lfstudio.dataset.images.thumbnail_array`,
reduced-size JPEG decoding, visible views first) and cached (LRU). Cells are coloured by
state: pending, capturing, done, failed, skipped. Double-click opens a view full size; selected
views can be queued for re-capture (the Scan panel does it through ``AppState.recaptureRequested``).

Quality (:mod:`lfstudio.gui.views.quality`; painted over the canvas by ``gui/views/grid_quality.py``): the verdicts of the last ``Check dataset`` (or of the
scan-time check, view by view as the scan captures them) outline flagged views (yellow: warn, red:
fail) and can colour the grid as a heat map (sharpness, exposure, position error, residual);
clicking a flagged view shows it beside its neighbours.
"""

from __future__ import annotations

import html
import logging
from functools import partial
from pathlib import Path
from typing import Any

from PySide6.QtCore import QSize, Qt, QTimer
from PySide6.QtGui import (QAction, QFont, QFontMetrics, QImage, QKeySequence, QPixmap)
from PySide6.QtWidgets import (QDialog, QFileDialog, QHBoxLayout, QLabel, QMenu,
                               QPushButton, QScrollArea, QSizePolicy, QStackedWidget, QToolButton,
                               QVBoxLayout, QWidget)

from lfstudio.errors import window_message
from lfstudio.dataset import images
from lfstudio.dataset.manifest import is_done
from lfstudio.dataset.paths import view_label
from lfstudio.gui.bridge import run_off_gui
from lfstudio.gui.settings import read_text, settings
from lfstudio.gui.views.grid_canvas import (CAPTURING, DONE, FAILED, PENDING, SKIPPED, STATE_COLORS, STATE_NAMES,
                                            GridCanvas)
from lfstudio.gui.views.quality import (OVERLAY_KEY, DisparityDialog, LiveQuality, NeighboursDialog, QualityBar,
                                        run_check)
from lfstudio.gui.widgets import QuietLabel, WholeOrNothingLabel, screen_fitted
from lfstudio.jobs import count

log = logging.getLogger(__name__)

VERDICT_MS = 100                 # scan-time verdicts are shown in batches at most this often
MAX_RECENT = 8
TITLE_MIN_PX = 300     # the dataset name's title never needs more (the rest of the name elided)
TITLE_SHARE = 0.45               # of the view's width the dataset's name may take in the title bar


class ImageDialog(QDialog):
    """One view at full size (decoded off the GUI thread)."""

    def __init__(self, path: Path, title: str, parent: QWidget | None = None):
        super().__init__(parent)
        self.setWindowTitle(title)
        self.setObjectName("viewDialog")
        self.resize(screen_fitted(self, 1000, 700))
        self.label = QLabel("Loading…")
        self.label.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.info = QLabel(str(path))
        area = QScrollArea()
        area.setWidget(self.label)
        area.setWidgetResizable(True)
        lay = QVBoxLayout(self)
        lay.addWidget(area, 1)
        lay.addWidget(self.info)
        self._decoding = run_off_gui(self, partial(self._decode, path), lambda shown: self._show(*shown))

    @staticmethod
    def _decode(path: Path) -> tuple[QImage, str]:
        try:
            from lfstudio.gui.imageutil import rgb_to_qimage

            rgb = images.preview_rgb8(path, stretch=True)
            return rgb_to_qimage(rgb), f"{path.name}: {rgb.shape[1]} x {rgb.shape[0]} px"
        except Exception as exc:
            return QImage(), f"{path}: cannot be decoded ({exc})"

    def _show(self, image: QImage, text: str) -> None:
        self.info.setText(text)
        if image.isNull():
            self.label.setText(text)
            return
        self.label.setPixmap(QPixmap.fromImage(image))


class TitleLabel(QLabel):
    """The dataset's name (bold) and its grid, elided in the middle of the name to the label's own
    width (never cut off). It asks for the whole text up to ``share`` px (set by the view) and needs
    at most TITLE_MIN_PX: its minimum never follows the view's width (a wider view would then never
    shrink again, taking the docks' width for good)."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self._name, self._rest, self._share = "", "", 10 ** 6

    def _metrics(self) -> tuple[QFontMetrics, QFontMetrics]:
        bold = QFont(self.font())
        bold.setBold(True)
        return QFontMetrics(bold), self.fontMetrics()

    def _full_px(self) -> int:
        fm_bold, fm = self._metrics()
        return fm_bold.horizontalAdvance(self._name) + fm.horizontalAdvance(self._rest) + 12

    def set_parts(self, name: str, rest: str) -> None:
        self._name, self._rest = name, rest
        self._elide()
        self.updateGeometry()

    def set_share(self, share_px: int) -> None:
        if share_px != self._share:
            self._share = share_px
            self.updateGeometry()

    def sizeHint(self) -> QSize:   # noqa: N802 (Qt name)
        return QSize(max(60, min(self._full_px(), self._share)), super().sizeHint().height())

    def minimumSizeHint(self) -> QSize:   # noqa: N802 (Qt name)
        return QSize(min(self._full_px(), self._share, TITLE_MIN_PX), super().minimumSizeHint().height())

    def resizeEvent(self, event) -> None:   # noqa: N802 (Qt name)
        super().resizeEvent(event)
        self._elide()

    def _elide(self) -> None:
        fm_bold, fm = self._metrics()
        room = max(20, self.contentsRect().width() - fm.horizontalAdvance(self._rest) - 8)
        shown = fm_bold.elidedText(self._name, Qt.TextElideMode.ElideMiddle, room)
        self.setText(f"<b>{html.escape(shown)}</b>{html.escape(self._rest)}" if self._name else "")


class GridView(QWidget):
    """The central widget: a friendly empty state, or the grid of the open dataset with its toolbar."""

    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.setObjectName("gridView")
        self.stack = QStackedWidget()
        self.empty = QLabel(
            "<h2>No dataset open</h2>"
            "<p>Plan a scene in the <b>Planner</b>, then start a scan in the <b>Scan</b> panel:<br>"
            "its views appear here as they are captured, laid out as on the rig.</p>"
            "<p><b>File → Open dataset…</b> (Ctrl+O) shows an existing capture.</p>")
        self.empty.setObjectName("gridEmpty")
        self.empty.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.empty.setWordWrap(True)
        self.canvas = GridCanvas()
        page = QWidget()
        bar = QHBoxLayout()
        bar.setContentsMargins(4, 2, 4, 2)
        self.title = TitleLabel()
        self.title.setObjectName("gridTitle")
        self.counts = QuietLabel("", name="gridCounts",      # changes while a scan runs: no relayout
                                 hint_text="2121 done · 2121 to capture · 2121 failed · 2121 skipped")
        bar.addWidget(self.title)
        bar.addSpacing(12)
        bar.addWidget(self.counts)
        bar.addSpacing(16)
        bar.addStretch(1)
        legend = WholeOrNothingLabel("&nbsp;&nbsp;".join(
            f"<span style='color:{STATE_COLORS[code].name()}'>■</span>&nbsp;{STATE_NAMES[code]}"
            for code in (PENDING, CAPTURING, DONE, FAILED, SKIPPED)))
        legend.setObjectName("gridLegend")
        self.legend = legend
        legend.setToolTip("Colours of the views: pending, being captured, done, failed, skipped by the operator")
        # when the bar is narrow the legend gives way first, then the counts; the dataset's name keeps
        # its width (up to TITLE_SHARE of the view, beyond that elided in the middle): see _fit_title
        self._title_parts: tuple[str, str] | None = None
        bar.addWidget(legend)
        bar.addSpacing(12)
        self.fit_button = self._tool("Fit", "Show the whole grid (F)", self.canvas.fit)
        self.zoom_out_button = self._tool("−", "Zoom out (-)", lambda: self.canvas.zoom_by(0.8))
        self.zoom_in_button = self._tool("+", "Zoom in (+)", lambda: self.canvas.zoom_by(1.25))
        self.one_button = self._tool("1:1", "Thumbnails at their own size", lambda: self.canvas.set_zoom(160))
        self.recapture_button = QPushButton("Re-capture selected")
        self.recapture_button.setObjectName("recaptureButton")
        self.recapture_button.setToolTip("Queue the selected views for capture again (Scan panel)")
        self.recapture_button.setEnabled(False)
        self.recapture_button.clicked.connect(self.request_recapture)
        self.quality_bar = QualityBar()
        for b in (self.fit_button, self.zoom_out_button, self.zoom_in_button, self.one_button,
                  self.recapture_button):     # at the end of its second row: the title row keeps room
            self.quality_bar.line.addWidget(b)
        self.live: LiveQuality | None = None
        self._neighbours: NeighboursDialog | None = None
        lay = QVBoxLayout(page)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.setSpacing(0)
        lay.addLayout(bar)
        lay.addWidget(self.quality_bar)
        lay.addWidget(self.canvas, 1)
        self.stack.addWidget(self.empty)
        self.stack.addWidget(page)
        outer = QVBoxLayout(self)
        outer.setContentsMargins(0, 0, 0, 0)
        outer.addWidget(self.stack)
        self.canvas.selectionChanged.connect(self._on_selection)
        self.canvas.viewActivated.connect(self.open_view)
        self.canvas.flaggedClicked.connect(self.compare_with_neighbours)
        qb = self.quality_bar
        qb.check_button.clicked.connect(self.run_check)
        qb.runner.finished.connect(self._check_finished)
        qb.runner.failed.connect(self._check_failed)
        qb.runner.cancelled.connect(self._check_cancelled)
        qb.overlayChanged.connect(self._set_overlay)
        qb.selectFlagged.connect(self.select_flagged)
        qb.showDisparity.connect(self.show_disparity)
        saved = read_text(OVERLAY_KEY)
        index = qb.overlay.findData(saved)
        if index > 0:
            qb.overlay.setCurrentIndex(index)
            self.canvas.set_overlay(saved)
        state.datasetChanged.connect(self.set_dataset)
        scan_events = getattr(state, "scanEvents", None)
        if scan_events is not None:
            scan_events.connect(self.on_scan_events)
        self._recent_menu: QMenu | None = None
        self.recapture_action: QAction | None = None     # Dataset → Re-capture selected views (install_menus)
        self._counts_timer = QTimer(self)
        self._counts_timer.setSingleShot(True)
        self._counts_timer.setInterval(200)
        self._counts_timer.timeout.connect(self._update_counts)
        self._verdict_batch: list[dict] = []     # scan-time verdicts not shown yet
        self._verdict_timer = QTimer(self)
        self._verdict_timer.setSingleShot(True)
        self._verdict_timer.setInterval(VERDICT_MS)
        self._verdict_timer.timeout.connect(self._show_live_verdicts)
        self.set_dataset(state.dataset)

    def _tool(self, text: str, tip: str, slot) -> QToolButton:
        b = QToolButton()
        b.setText(text)
        b.setToolTip(tip)
        b.clicked.connect(slot)
        b.setSizePolicy(QSizePolicy.Policy.Fixed, QSizePolicy.Policy.Fixed)
        return b

    # -- state -------------------------------------------------------------------------------------
    def set_dataset(self, dataset: Any) -> None:
        self.canvas.set_dataset(dataset)
        self._stop_live()
        if dataset is None:
            self.quality_bar.set_available(False, False)
            self.stack.setCurrentWidget(self.empty)
            return
        self._load_quality(dataset)
        self.stack.setCurrentIndex(1)
        grid = dataset.grid
        self._title_parts = (dataset.root.name, f" — {grid.columns} × {grid.rows} {'view' if grid.columns * grid.rows == 1 else 'views'}")
        self.title.set_parts(*self._title_parts)
        self.title.setToolTip(str(dataset.root))
        self._fit_title()
        self._update_counts()
        add_recent_dataset(str(dataset.root))
        self._fill_recent()

    def resizeEvent(self, event) -> None:
        super().resizeEvent(event)
        self._fit_title()

    def _fit_title(self) -> None:
        """The title bar's dataset name asks for up to TITLE_SHARE of the view's width (see TitleLabel)."""
        self.title.set_share(int(self.width() * TITLE_SHARE))

    def _update_counts(self) -> None:
        st = self.canvas.status
        if st.size == 0:
            self.counts.setText("")
            return
        n = {k: int((st == k).sum()) for k in STATE_NAMES}
        self.counts.setText(f"{n[DONE]} done · {n[PENDING] + n[CAPTURING]} to capture · {n[FAILED]} failed"
                            + (f" · {n[SKIPPED]} skipped" if n[SKIPPED] else ""))

    def on_scan_events(self, events: list) -> None:
        for ev in events:
            self.on_scan_event(ev)

    def on_scan_event(self, ev: Any) -> None:
        kind = getattr(ev.kind, "value", ev.kind)
        if kind == "state" and getattr(ev.state, "value", ev.state) in ("paused", "finished") \
                and self.live is not None:
            self.live.checker.settle()     # every view checked so far located together
        if ev.row is None:
            return
        if kind == "view-done" and self.quality_bar.live_box.isChecked():
            self._live_checker().on_event(ev)
        if kind == "view-started":
            self.canvas.set_cell(ev.row, ev.column, CAPTURING)
        elif kind == "view-done":
            self.canvas.set_cell(ev.row, ev.column, DONE, ev.thumb)
        elif kind == "view-skipped":
            self.canvas.set_cell(ev.row, ev.column, FAILED if "failed" in ev.message else SKIPPED)
        elif kind in ("view-failed", "fault"):
            self.canvas.set_cell(ev.row, ev.column, FAILED if not ev.will_retry else CAPTURING)
        if not self._counts_timer.isActive():     # at most every 200 ms, also while views keep coming
            self._counts_timer.start()

    def _on_selection(self, n: int) -> None:
        self.recapture_button.setEnabled(n > 0)
        if self.recapture_action is not None:       # the Dataset menu's entry: nothing selected, nothing to do
            self.recapture_action.setEnabled(n > 0)
        self.recapture_button.setText(f"Re-capture {n} selected" if n else "Re-capture selected")

    def request_recapture(self) -> None:
        self.recapture(sorted(self.canvas.selected))

    def recapture(self, cells: list[tuple[int, int]]) -> None:
        """Queue ``cells`` for capture again (the Scan panel listens to ``AppState.recaptureRequested``)."""
        if not cells:
            return
        signal = getattr(self.state, "recaptureRequested", None)
        if signal is not None:
            signal.emit(cells)
        for r, c in cells:
            if self.canvas.status[r, c] != DONE:
                self.canvas.set_cell(r, c, PENDING)
        self.state.show_status(f"{count(len(cells), 'view')} queued for re-capture in the Scan panel")
        self.canvas.selected.clear()
        self._on_selection(0)
        self.canvas.viewport().update()

    def open_view(self, row: int, column: int) -> None:
        ds = self.state.dataset
        if ds is None:
            return
        try:
            view = ds.view(row, column)
        except KeyError:
            return
        if not is_done(view):
            self.state.show_status(f"row {row}, column {column} has not been captured yet")
            return
        try:
            path = ds.path_of(view)
        except Exception as exc:
            self.state.report_error("Open view", window_message(exc))
            return
        dlg = ImageDialog(path, f"View row {row}, column {column} — {view['file']}", self)
        dlg.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        dlg.show()
        self._last_dialog = dlg

    # -- menus -------------------------------------------------------------------------------------
    def install_menus(self, window) -> None:
        file_menu = window.menu("File")
        open_action = QAction("&Open dataset…", self)
        open_action.setShortcut(QKeySequence.StandardKey.Open)
        open_action.setToolTip("Open a dataset folder (the one holding dataset.json)")
        open_action.triggered.connect(self.choose_dataset)
        file_menu.addAction(open_action)
        self._recent_menu = QMenu("Recent datasets", file_menu)
        file_menu.addMenu(self._recent_menu)
        self._recent_menu.setToolTip("Datasets opened recently")
        self._fill_recent()
        view_menu = window.menu("View")
        for text, shortcut, slot in (("Zoom grid to fit", "Ctrl+0", self.canvas.fit),
                                     ("Zoom grid in", "Ctrl++", lambda: self.canvas.zoom_by(1.25)),
                                     ("Zoom grid out", "Ctrl+-", lambda: self.canvas.zoom_by(0.8))):
            a = QAction(text, self)
            a.setShortcut(QKeySequence(shortcut))
            a.triggered.connect(slot)
            view_menu.addAction(a)
        recap = QAction("Re-capture selected views", self)
        recap.setObjectName("recaptureAction")
        recap.setToolTip("Queue the views selected in the grid for capture again (select views in the grid first)")
        recap.triggered.connect(self.request_recapture)
        recap.setEnabled(bool(self.canvas.selected))
        self.recapture_action = recap
        window.menu("Dataset").addAction(recap)

    def choose_dataset(self) -> None:
        from lfstudio.gui.preferences import datasets_folder

        start = settings().value("datasets/last_dir", "") or str(datasets_folder())
        folder = QFileDialog.getExistingDirectory(self, "Open dataset folder", str(start or ""))
        if folder:
            settings().setValue("datasets/last_dir", str(Path(folder).parent))
            self.open_dataset(folder)

    def open_dataset(self, folder: str) -> bool:
        from lfstudio.dataset import Dataset
        from lfstudio.errors import LfError

        try:
            ds = Dataset.open(folder)
        except LfError as exc:
            self.state.report_error("Open dataset", window_message(exc))
            return False
        self.state.set_dataset(ds)
        self.state.show_status(f"Opened {folder}")
        return True

    def _fill_recent(self) -> None:
        if self._recent_menu is None:
            return
        self._recent_menu.clear()
        paths = recent_datasets()
        for path in paths:
            a = self._recent_menu.addAction(path)
            a.triggered.connect(lambda checked=False, p=path: self.open_dataset(p))
        self._recent_menu.setEnabled(bool(paths))

    # -- quality -----------------------------------------------------------------------------------
    def _load_quality(self, dataset: Any) -> None:
        from lfstudio.errors import LfError
        from lfstudio.quality import load_quality

        try:
            doc = load_quality(dataset)
        except LfError as exc:
            self.state.show_status(window_message(exc), 10000)
            doc = None
        self.canvas.set_quality(doc)
        self.quality_bar.legend.set_map(doc, self.canvas.overlay_key)
        has_map = bool(doc and (doc.get("pictures") or {}).get("disparity"))
        self.quality_bar.set_available(True, has_map)
        self.quality_bar.set_summary(self.canvas.quality, live=False)

    def run_check(self) -> None:
        ds = self.state.dataset
        runner = self.quality_bar.runner
        if ds is None or runner.running:
            return
        self.quality_bar.check_button.setEnabled(False)
        runner.start(run_check, str(ds.root))

    def _check_finished(self, doc: dict) -> None:
        ds = self.state.dataset
        self.quality_bar.check_button.setEnabled(ds is not None)
        if ds is None or str(ds.root) != doc.get("dataset"):
            return                     # another dataset was opened meanwhile
        self.canvas.set_quality(doc)
        self.quality_bar.legend.set_map(doc, self.canvas.overlay_key)
        self.quality_bar.set_available(True, bool((doc.get("pictures") or {}).get("disparity")))
        self.quality_bar.set_summary(self.canvas.quality, live=False)
        s = doc["summary"]
        self.state.show_status(f"Check: {doc['verdict']} — {s['pass']} pass, {s['warn']} warn, {s['fail']} fail; "
                               f"report in {Path(doc['dataset']) / 'quality' / 'report.html'}", 10000)

    def _check_failed(self, message: str) -> None:
        self.quality_bar.check_button.setEnabled(self.state.dataset is not None)
        self.state.report_error("Check dataset", message)

    def _check_cancelled(self) -> None:
        self.quality_bar.check_button.setEnabled(self.state.dataset is not None)
        self.state.show_status("Check cancelled; nothing was written")

    def _set_overlay(self, key: str) -> None:
        settings().setValue(OVERLAY_KEY, key)
        self.canvas.set_overlay(key)
        self.quality_bar.legend.set_map(self.canvas.quality_doc, key)

    def select_flagged(self) -> None:
        flagged = self.canvas.flagged()
        self.canvas.selected = set(flagged)
        self.canvas.selectionChanged.emit(len(flagged))
        self.canvas.viewport().update()
        self.state.show_status(f"{count(len(flagged), 'flagged view')} selected: Re-capture selected queues them")

    def show_disparity(self) -> None:
        doc = self.canvas.quality_doc or {}
        ds = self.state.dataset
        rel = (doc.get("pictures") or {}).get("disparity")
        if ds is None or not rel:
            self.state.show_status("No disparity map yet: run Check dataset")
            return
        dlg = DisparityDialog(Path(ds.root) / rel, doc.get("disparity_map"), self, doc.get("depth_range"))
        dlg.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        dlg.show()
        self._disparity_dialog = dlg

    def compare_with_neighbours(self, row: int, column: int) -> None:
        ds = self.state.dataset
        if ds is None:
            return
        if self._neighbours is None:
            self._neighbours = NeighboursDialog(self)
            self._neighbours.recaptureRequested.connect(self.recapture)
        self._neighbours.show_view(ds, (row, column), self.canvas.quality.get((row, column)))
        self._neighbours.show()
        self._neighbours.raise_()

    def _live_checker(self) -> LiveQuality:
        ds = self.state.dataset
        if self.live is None or self.live.root != Path(ds.root):
            self._stop_live()
            live = self.live = LiveQuality(ds, self)
            live.verdicts.connect(lambda entries, source=live: self._on_live_verdicts(source, entries))
        return self.live

    def _on_live_verdicts(self, source: LiveQuality, entries: list[dict]) -> None:
        if source is not self.live:
            return                      # late verdicts of a scan whose dataset is no longer shown
        self.state.liveVerdicts.emit(entries)       # notifications and the status page (Scan panel)
        self._verdict_batch.extend(entries)
        if not self._verdict_timer.isActive():   # verdicts are shown together, a few times a second
            self._verdict_timer.start()

    def _show_live_verdicts(self) -> None:
        entries, self._verdict_batch = self._verdict_batch, []
        if not entries or self.live is None:
            return
        self.canvas.update_quality_many(entries, self.live.document() if self.canvas.quality_doc is None else None)
        self.quality_bar.set_summary(self.canvas.quality, live=True)
        failed = [e for e in entries if e.get("verdict") == "fail"]
        if failed:
            entry = failed[-1]
            self.state.show_status(f"View {view_label(entry['row'], entry['column'])} failed the check: "
                                   + "; ".join(entry.get("reasons", [])), 10000)

    def _stop_live(self) -> None:
        self._verdict_timer.stop()
        self._verdict_batch = []
        if self.live is not None:
            self.live.shutdown()
            self.live = None

    def shutdown(self) -> None:
        self._stop_live()
        self.quality_bar.shutdown()
        self.canvas.shutdown()


def recent_datasets() -> list[str]:
    value = settings().value("datasets/recent", [])
    if isinstance(value, str):          # (the INI format gives one entry back as text)
        value = [value]
    return [str(v) for v in value if v] if isinstance(value, (list, tuple)) else []


def add_recent_dataset(path: str) -> None:
    items = [p for p in recent_datasets() if p != path]
    items.insert(0, path)
    settings().setValue("datasets/recent", items[:MAX_RECENT])
