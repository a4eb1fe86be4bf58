"""The central thumbnail grid: every view of the open dataset laid out as on the rig (row x column).

One custom-painted scroll area (no widget per view). At low zoom the whole grid is drawn from one
mosaic image (one small tile per view, filled in as thumbnails load); zoomed in, only the visible
views are drawn from their full thumbnails. Thumbnails are decoded off the GUI thread
(:func:`lfstudio.dataset.images.thumbnail_array`, reduced-size JPEG decoding, visible views first)
and cached (LRU). Cells are coloured by
state: pending, capturing, done, failed, skipped. Double-click opens a view full size; selected
views can be queued for re-capture (the Scan panel does it through ``AppState.recaptureRequested``).

Quality (:mod:`lfstudio.gui.views.quality`): the verdicts of the last ``Check dataset`` (or of the
scan-time check, view by view as the scan captures them) outline flagged views (yellow: warn, red:
fail) and can colour the grid as a heat map (sharpness, exposure, position error, residual);
clicking a flagged view shows it beside its neighbours.
"""

from __future__ import annotations

import atexit
import html
import logging
import os
import threading
import weakref
from collections import OrderedDict
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import QObject, QPoint, QRect, QRectF, QSize, Qt, QTimer, Signal
from PySide6.QtGui import (QAction, QColor, QFont, QFontMetrics, QImage, QKeySequence, QPainter, QPen,
                           QPixmap)
from PySide6.QtWidgets import (QAbstractScrollArea, QDialog, QFileDialog, QHBoxLayout, QLabel, QMenu,
                               QPushButton, QScrollArea, QSizePolicy, QStackedWidget, QToolButton,
                               QVBoxLayout, QWidget)

from lfstudio.dataset import images
from lfstudio.dataset.manifest import is_done
from lfstudio.dataset.paths import view_label
from lfstudio.gui.bridge import GuiInbox, run_off_gui
from lfstudio.gui.settings import settings
from lfstudio.gui.views.quality import (OVERLAY_KEY, DisparityDialog, LiveQuality, NeighboursDialog, QualityBar,
                                        run_check)
from lfstudio.gui.widgets import QuietLabel, WholeOrNothingLabel, screen_fitted
from lfstudio.jobs import count

log = logging.getLogger(__name__)

PENDING, CAPTURING, DONE, FAILED, SKIPPED = range(5)
STATUS_CODES = {"pending": PENDING, "done": DONE, "failed": FAILED, "skipped": SKIPPED}
STATE_NAMES = {PENDING: "pending", CAPTURING: "capturing", DONE: "done", FAILED: "failed", SKIPPED: "skipped"}
STATE_COLORS = {PENDING: QColor(70, 74, 82), CAPTURING: QColor(255, 176, 32), DONE: QColor(70, 180, 90),
                FAILED: QColor(220, 60, 60), SKIPPED: QColor(40, 42, 46)}
TILE_W, TILE_H = 48, 32          # mosaic tile (low zoom)
FULL_ZOOM_PX = 56                # from this cell width on, draw the full thumbnails
FLAG_COLORS = {"warn": QColor(255, 225, 0), "fail": QColor(230, 60, 60)}   # yellow: not the amber of "capturing"
FLAG_CODES = {"warn": 1, "fail": 2}       # GridCanvas._verdicts: 0 for a pass or no verdict
OVERLAY_ALPHA = 215
FRAME_MS = 40                    # the grid repaints what changed at most 25 times a second
VERDICT_MS = 100                 # scan-time verdicts are shown in batches at most this often
MAX_RECENT = 8
TITLE_MIN_PX = 300     # the dataset name's title never needs more (the rest of the name elided)
TITLE_SHARE = 0.45               # of the view's width the dataset's name may take in the title bar


def _file_thumbnail(path: str, width_px: int) -> QImage:
    """A view's stored thumbnail (``thumbs/``) decoded small, or a thumbnail made from the view's own
    file (RAW or 16-bit image) and cached in the dataset."""
    from lfstudio.dataset.thumbs import cached_thumbnail
    from lfstudio.gui.imageutil import rgb_to_qimage

    try:
        stored = "/thumbs/" in path.replace("\\", "/")
        bgr = images.thumbnail_array(path, width_px) if stored else cached_thumbnail(path, width_px)
    except Exception:  # an unreadable file stays a coloured cell; the dataset check reports it
        return QImage()
    return QImage() if bgr is None else rgb_to_qimage(np.ascontiguousarray(bgr[..., ::-1]))


def _outlines(x: np.ndarray, y: np.ndarray, w: float, h: float):
    """One QPainterPath of the outlines of w x h rectangles at (x, y), built from numpy in one go
    (a painter call per flagged view would cost thousands of Python calls on a big grid)."""
    import pyqtgraph.functions as pgf

    xs = np.stack([x, x + w, x + w, x, x], axis=1).ravel().astype(float)
    ys = np.stack([y, y, y + h, y + h, y], axis=1).ravel().astype(float)
    connect = np.tile(np.array([1, 1, 1, 1, 0], dtype=np.int32), len(x))
    return pgf.arrayToQPath(xs, ys, connect=connect)


_LOADERS: "weakref.WeakSet[ThumbLoader]" = weakref.WeakSet()


@atexit.register
def _stop_loaders() -> None:
    """Let every loader finish its thumbnail before the interpreter ends: a daemon thread killed
    inside Qt's decoder aborts the process ("terminate called without an active exception")."""
    for loader in list(_LOADERS):
        try:
            loader.stop()
        except RuntimeError:        # its Qt object is gone already; so is the thread's work
            pass


class ThumbLoader(QObject):
    """Decodes thumbnails on one background thread; newest requests first.

    Decoded images reach the GUI thread in batches (:class:`~lfstudio.gui.bridge.GuiInbox`); ``ready``
    says some are waiting and the grid takes them all (:meth:`take`) once a frame: during a fast scan the
    GUI handles a batch, not one Python call (and one GIL hand-over) per thumbnail."""

    ready = Signal()

    def __init__(self, parent: QObject | None = None):
        super().__init__(parent)
        _LOADERS.add(self)
        self._stack: list[tuple[Any, str, QSize]] = []
        self._queued: set[Any] = set()
        self._cond = threading.Condition()
        self._stop = False
        self._generation = 0
        self._done: list[tuple[Any, QImage]] = []       # arrived on the GUI thread, not taken yet
        self._inbox = GuiInbox(self._arrived, self, every_ms=FRAME_MS // 2)   # the grid takes them once a frame
        self._thread = threading.Thread(target=self._run, name="thumb-loader", daemon=True)
        self._thread.start()

    def request(self, key: Any, path: str, size: QSize) -> None:
        self.request_many([(key, path, size)])

    def request_many(self, items: list[tuple[Any, str, QSize]]) -> None:
        """Queue several (key, path, size) at once (one lock, one wake-up)."""
        with self._cond:
            added = False
            for key, path, size in items:
                if key in self._queued:
                    continue
                self._queued.add(key)
                self._stack.append((key, path, size))
                added = True
            if added:
                self._cond.notify()

    def take(self) -> list[tuple[Any, QImage]]:
        """The thumbnails decoded since the last call (GUI thread), oldest first."""
        done, self._done = self._done, []
        return done

    def _arrived(self, items: list) -> None:
        """GUI thread (the inbox): keep the batch for :meth:`take` and say so once."""
        generation = self._generation
        self._done.extend((key, image) for g, key, image in items if g == generation)
        if self._done:
            self.ready.emit()

    def clear(self) -> None:
        with self._cond:
            self._stack.clear()
            self._queued.clear()
            self._generation += 1
        self._done.clear()

    def stop(self) -> None:
        with self._cond:
            self._stop = True
            self._stack.clear()
            self._cond.notify()
        self._thread.join(2)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._stop or self._stack)
                if self._stop:
                    return
                key, path, size = self._stack.pop()
                generation = self._generation
            image = _file_thumbnail(path, max(size.width(), 1))
            with self._cond:
                self._queued.discard(key)
                if generation != self._generation or image.isNull():
                    continue
            self._inbox.post((generation, key, image))


class GridCanvas(QAbstractScrollArea):
    """Paints the grid; zoom with Ctrl+wheel or +/-; click/drag selects; double-click opens."""

    selectionChanged = Signal(int)
    viewActivated = Signal(int, int)       # row, column (double-click)
    flaggedClicked = Signal(int, int)      # row, column of a flagged view clicked alone
    zoomChanged = Signal(float)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.setObjectName("gridCanvas")
        self.viewport().setMouseTracking(True)
        self.setFocusPolicy(Qt.StrongFocus)
        self.rows = 0
        self.columns = 0
        self.root: Path | None = None
        self.status = np.zeros((0, 0), np.int8)
        self.thumbs: dict[tuple[int, int], str] = {}
        self.selected: set[tuple[int, int]] = set()
        self.cell_px = 24.0
        self.gap_px = 1.0
        self._fit = True
        self.mosaic: QImage | None = None
        self._mosaic_has: np.ndarray = np.zeros((0, 0), bool)
        self._cache: OrderedDict[tuple[int, int], QImage] = OrderedDict()
        self._cache_max = 400
        self._drag_from: tuple[int, int] | None = None
        self._drag_to: tuple[int, int] | None = None
        self.loader = ThumbLoader(self)
        self._dirty: list[tuple[int, int]] = []          # cells changed since the last frame
        self._frame_timer = QTimer(self)
        self._frame_timer.setSingleShot(True)
        self._frame_timer.setInterval(FRAME_MS)
        self._frame_timer.timeout.connect(self._frame)
        self.loader.ready.connect(self._thumbnails_ready, Qt.QueuedConnection)
        self.setToolTip("Thumbnails as on the rig. Ctrl+wheel or +/- zooms, F fits; click or drag to select, "
                        "double-click opens a view full size")
        self._tip_cell: tuple[int, int] | None = None
        self.quality: dict[tuple[int, int], dict] = {}     # cell -> quality.json view entry
        self.quality_doc: dict | None = None               # thresholds etc. for the heat-map scales
        self.overlay_key = ""
        self._overlay: np.ndarray | None = None            # rows x columns x 4 (RGBA) heat map
        self._verdicts = np.zeros((0, 0), np.int8)          # rows x columns FLAG_CODES, for painting

    # -- quality -----------------------------------------------------------------------------------
    def set_quality(self, doc: dict | None) -> None:
        """Show the verdicts of a quality document (``quality.json`` layout); None clears them."""
        self.quality_doc = doc
        self.quality = {(int(v["row"]), int(v["column"])): v for v in (doc or {}).get("views", [])
                        if v.get("checks")}
        self._verdicts = np.zeros((self.rows, self.columns), np.int8)
        for cell, entry in self.quality.items():
            self._set_verdict(cell, entry)
        self._rebuild_overlay()

    def update_quality(self, entry: dict, doc: dict | None = None) -> None:
        """One view's new verdict (scan-time check): that cell alone is recoloured and repainted."""
        self.update_quality_many([entry], doc)

    def update_quality_many(self, entries: list[dict], doc: dict | None = None) -> None:
        """New verdicts of some views (scan-time check, coalesced): only their cells change."""
        if doc is not None and self.quality_doc is None:
            self.quality_doc = doc
            if self.overlay_key:
                self._rebuild_overlay()
        for entry in entries:
            cell = (int(entry["row"]), int(entry["column"]))
            self.quality[cell] = entry
            self._set_verdict(cell, entry)
            if self._overlay is not None:
                self._colour_cell(cell, entry)
            self._mark_dirty(*cell)

    def _set_verdict(self, cell: tuple[int, int], entry: dict) -> None:
        r, c = cell
        if 0 <= r < self.rows and 0 <= c < self.columns and self._verdicts.shape == (self.rows, self.columns):
            self._verdicts[r, c] = FLAG_CODES.get(entry.get("verdict"), 0)

    def set_overlay(self, key: str) -> None:
        self.overlay_key = key or ""
        self._rebuild_overlay()

    def flagged(self) -> list[tuple[int, int]]:
        return sorted(c for c, e in self.quality.items() if e.get("verdict") in FLAG_COLORS)

    def _rebuild_overlay(self) -> None:
        self._overlay = None
        if self.overlay_key and self.quality_doc is not None and self.rows and self.columns:
            self._overlay = np.zeros((self.rows, self.columns, 4), np.uint8)
            for cell, entry in self.quality.items():
                self._colour_cell(cell, entry)
        self.viewport().update()

    def _colour_cell(self, cell: tuple[int, int], entry: dict) -> None:
        from lfstudio.quality.pictures import HEATMAPS, heatmap_colour

        r, c = cell
        if self._overlay is None or not (0 <= r < self.rows and 0 <= c < self.columns):
            return
        value = HEATMAPS[self.overlay_key].value(entry)
        if value is None:
            self._overlay[r, c] = 0
        else:
            self._overlay[r, c, :3] = heatmap_colour(self.quality_doc, self.overlay_key, value)
            self._overlay[r, c, 3] = OVERLAY_ALPHA

    def _paint_quality(self, p: QPainter, r0: int, r1: int, c0: int, c1: int, px: float, py: float,
                       ox: float, oy: float, thin: bool) -> None:
        if self._overlay is not None:
            block = np.ascontiguousarray(self._overlay[r0:r1, c0:c1])
            img = QImage(block.data, block.shape[1], block.shape[0], block.strides[0], QImage.Format_RGBA8888)
            p.setRenderHint(QPainter.SmoothPixmapTransform, False)
            p.drawImage(QRectF(ox + c0 * px, oy + r0 * py, (c1 - c0) * px, (r1 - r0) * py), img)
        p.setBrush(Qt.NoBrush)
        block = self._verdicts[r0:r1, c0:c1]       # only the cells being painted, found with numpy
        for code, colour in ((FLAG_CODES["warn"], FLAG_COLORS["warn"]), (FLAG_CODES["fail"], FLAG_COLORS["fail"])):
            cells = np.argwhere(block == code)
            if not len(cells):
                continue
            p.setPen(QPen(colour, 1 if thin else 3))
            inset = 0 if thin else 1
            p.drawPath(_outlines(ox + (c0 + cells[:, 1]) * px + inset, oy + (r0 + cells[:, 0]) * py + inset,
                                 px - self.gap_px - 2 * inset, py - self.gap_px - 2 * inset))

    # -- data --------------------------------------------------------------------------------------
    def set_dataset(self, dataset: Any) -> None:
        self.loader.clear()
        self._dirty = []
        self._cache.clear()
        self.selected.clear()
        self.quality, self.quality_doc, self._overlay = {}, None, None
        self._verdicts = np.zeros((0, 0), np.int8)
        if dataset is None:
            self.rows = self.columns = 0
            self.status = np.zeros((0, 0), np.int8)
            self.thumbs = {}
            self.mosaic = None
            self.root = None
        else:
            grid = dataset.grid
            self.rows, self.columns = grid.rows, grid.columns
            self.root = dataset.root
            self.status = np.zeros((self.rows, self.columns), np.int8)
            views = dataset.views      # a scan starts here with thousands of pending views: in numpy
            n = len(views)
            rows = np.fromiter((v["row"] for v in views), np.int64, n)
            cols = np.fromiter((v["column"] for v in views), np.int64, n)
            codes = np.fromiter((STATUS_CODES.get(v.get("status"), PENDING) for v in views), np.int8, n)
            inside = (rows >= 0) & (rows < self.rows) & (cols >= 0) & (cols < self.columns)
            self.status[rows[inside], cols[inside]] = codes[inside]
            self.thumbs = {(v["row"], v["column"]): v.get("thumb") or v["file"]
                           for i in np.flatnonzero(inside & (codes == DONE)) if is_done(v := views[i])}
            self._verdicts = np.zeros((self.rows, self.columns), np.int8)
            self.mosaic = QImage(self.columns * TILE_W, self.rows * TILE_H, QImage.Format_RGB32)
            self.mosaic.fill(QColor(0, 0, 0))
            self._mosaic_has = np.zeros((self.rows, self.columns), bool)
        self._fit = True
        self.selectionChanged.emit(0)
        self._relayout()

    def set_cell(self, row: int, column: int, state: int, thumb: str | None = None) -> None:
        if not (0 <= row < self.rows and 0 <= column < self.columns):
            return
        self.status[row, column] = state
        if thumb:
            self.thumbs[(row, column)] = thumb
            self._cache.pop((row, column), None)
            self._mosaic_has[row, column] = False
            self._request((row, column), full=False)
        self._mark_dirty(row, column)

    # -- geometry ----------------------------------------------------------------------------------
    def _pitch(self) -> tuple[float, float]:
        w = self.cell_px
        h = w * TILE_H / TILE_W
        return w + self.gap_px, h + self.gap_px

    def content_size(self) -> QSize:
        px, py = self._pitch()
        return QSize(int(self.columns * px) + 1, int(self.rows * py) + 1)

    def fit(self) -> None:
        self._fit = True
        self._relayout()

    def set_zoom(self, cell_px: float, anchor: QPoint | None = None) -> None:
        cell_px = float(min(max(cell_px, 2.0), 640.0))
        anchor = anchor or QPoint(self.viewport().width() // 2, self.viewport().height() // 2)
        px, py = self._pitch()
        fx = (self.horizontalScrollBar().value() + anchor.x()) / max(px, 1e-9)
        fy = (self.verticalScrollBar().value() + anchor.y()) / max(py, 1e-9)
        self._fit = False
        self.cell_px = cell_px
        self.gap_px = 1.0 if cell_px >= 8 else 0.0
        self._relayout()
        px, py = self._pitch()
        self.horizontalScrollBar().setValue(int(fx * px - anchor.x()))
        self.verticalScrollBar().setValue(int(fy * py - anchor.y()))

    def zoom_by(self, factor: float) -> None:
        self.set_zoom(self.cell_px * factor)

    def _relayout(self) -> None:
        vp = self.viewport().size()
        if self._fit and self.columns and self.rows:
            cw = (vp.width() - 2) / self.columns
            ch = (vp.height() - 2) / self.rows * TILE_W / TILE_H
            self.cell_px = max(2.0, min(cw, ch) - 1.0)
            self.gap_px = 1.0 if self.cell_px >= 8 else 0.0
        size = self.content_size()
        self.horizontalScrollBar().setRange(0, max(0, size.width() - vp.width()))
        self.verticalScrollBar().setRange(0, max(0, size.height() - vp.height()))
        self.horizontalScrollBar().setPageStep(vp.width())
        self.verticalScrollBar().setPageStep(vp.height())
        self.zoomChanged.emit(self.cell_px)
        self.viewport().update()

    def resizeEvent(self, event) -> None:
        super().resizeEvent(event)
        self._relayout()

    def _offset(self) -> tuple[float, float]:
        size = self.content_size()
        vp = self.viewport().size()
        ox = -self.horizontalScrollBar().value() + max(0, (vp.width() - size.width()) // 2)
        oy = -self.verticalScrollBar().value() + max(0, (vp.height() - size.height()) // 2)
        return ox, oy

    def _cell_rect(self, row: int, column: int) -> QRect:
        px, py = self._pitch()
        ox, oy = self._offset()
        return QRectF(ox + column * px, oy + row * py, px - self.gap_px, py - self.gap_px).toAlignedRect()

    def cell_at(self, pos: QPoint) -> tuple[int, int] | None:
        px, py = self._pitch()
        ox, oy = self._offset()
        c = int((pos.x() - ox) // px)
        r = int((pos.y() - oy) // py)
        if 0 <= r < self.rows and 0 <= c < self.columns:
            return r, c
        return None

    def _visible_range(self, rect: QRect | None = None) -> tuple[int, int, int, int]:
        """Rows r0..r1-1 and columns c0..c1-1 that touch ``rect`` (default: the whole viewport)."""
        px, py = self._pitch()
        ox, oy = self._offset()
        rect = rect if rect is not None else self.viewport().rect()
        c0 = max(0, int((rect.left() - ox) // px))
        c1 = min(self.columns, int((rect.right() + 1 - ox) // px) + 1)
        r0 = max(0, int((rect.top() - oy) // py))
        r1 = min(self.rows, int((rect.bottom() + 1 - oy) // py) + 1)
        return r0, r1, c0, c1

    # -- thumbnails ------------------------------------------------------------------------------
    def _request(self, cell: tuple[int, int], full: bool) -> None:
        self._request_many([cell], full)

    def _request_many(self, cells: list[tuple[int, int]], full: bool) -> None:
        if self.root is None or not cells:
            return
        size = QSize(160, 160) if full else QSize(TILE_W, TILE_H)
        root = str(self.root)              # os.path.join: 2121 pathlib joins cost ~20 ms on opening
        items = [((cell, full), os.path.join(root, self.thumbs[cell]), size) for cell in cells if cell in self.thumbs]
        self.loader.request_many(items)

    def _thumbnails_ready(self) -> None:
        if not self._frame_timer.isActive():
            self._frame_timer.start()

    def _take_loaded(self) -> None:
        """Put every thumbnail the loader has finished into the cache and the mosaic (one painter)."""
        painter = None
        for ((r, c), full), image in self.loader.take():
            if not (0 <= r < self.rows and 0 <= c < self.columns) or self.mosaic is None:
                continue
            if full:
                self._cache[(r, c)] = image
                self._cache.move_to_end((r, c))
                while len(self._cache) > self._cache_max:
                    self._cache.popitem(last=False)
            if not self._mosaic_has[r, c]:   # a full thumbnail fills the mosaic tile too
                if painter is None:
                    painter = QPainter(self.mosaic)
                target = QRect(c * TILE_W, r * TILE_H, TILE_W, TILE_H)
                painter.fillRect(target, Qt.black)
                painter.drawImage(target, image)   # stretched: no letterbox lines between tiles
                self._mosaic_has[r, c] = True
            self._dirty.append((r, c))
        if painter is not None:
            painter.end()

    # -- repainting: changed cells are collected and repainted together, once a frame ---------------
    def _mark_dirty(self, row: int, column: int) -> None:
        """Repaint the cell at the next frame (with every other cell changed until then)."""
        if 0 <= row < self.rows and 0 <= column < self.columns:
            self._dirty.append((row, column))
            if not self._frame_timer.isActive():
                self._frame_timer.start()

    def _frame(self) -> None:
        """Once a frame (FRAME_MS) while cells change: thumbnails that arrived go into the mosaic, then
        one repaint of the block holding every changed cell, however many scan events, verdicts and
        thumbnails came in meanwhile."""
        self._take_loaded()
        if not self._dirty:
            return
        cells = np.asarray(self._dirty)
        self._dirty = []
        (r0, c0), (r1, c1) = cells.min(axis=0), cells.max(axis=0)
        px, py = self._pitch()
        ox, oy = self._offset()
        rect = QRectF(ox + c0 * px, oy + r0 * py, (c1 - c0 + 1) * px, (r1 - r0 + 1) * py)
        self.viewport().update(rect.toAlignedRect().adjusted(-2, -2, 2, 2))

    # -- painting ----------------------------------------------------------------------------------
    def _paint_overview(self, p: QPainter, r0: int, r1: int, c0: int, c1: int, px: float, py: float,
                        ox: float, oy: float, thin: bool) -> None:
        """Zoomed out: the thumbnail mosaic, then one status image over it (transparent where a
        thumbnail shows), gap lines and the few highlighted cells — a handful of calls, not one per cell."""
        src = QRectF(c0 * TILE_W, r0 * TILE_H, (c1 - c0) * TILE_W, (r1 - r0) * TILE_H)
        dst = QRectF(ox + c0 * px, oy + r0 * py, (c1 - c0) * px, (r1 - r0) * py)
        p.drawImage(dst, self.mosaic, src)
        block = self.status[r0:r1, c0:c1]
        has = self._mosaic_has[r0:r1, c0:c1]
        rgba = np.zeros(block.shape + (4,), np.uint8)
        for st, colour in STATE_COLORS.items():
            rgba[block == st] = (colour.red(), colour.green(), colour.blue(), 255)
        waiting = (block == DONE) & ~has
        dark = STATE_COLORS[DONE].darker(160)
        rgba[waiting] = (dark.red(), dark.green(), dark.blue(), 255)
        rgba[(block == DONE) & has, 3] = 0
        overlay = QImage(rgba.data, rgba.shape[1], rgba.shape[0], rgba.strides[0], QImage.Format_RGBA8888)
        p.setRenderHint(QPainter.SmoothPixmapTransform, False)
        p.drawImage(dst, overlay)
        if self.gap_px:
            background = QColor(24, 25, 28)
            for c in range(c0, c1):
                p.fillRect(QRectF(ox + (c + 1) * px - self.gap_px, dst.top(), self.gap_px, dst.height()), background)
            for r in range(r0, r1):
                p.fillRect(QRectF(dst.left(), oy + (r + 1) * py - self.gap_px, dst.width(), self.gap_px), background)
        if not thin:
            for r, c in np.argwhere((block != PENDING) & (block != DONE)):
                st = int(block[r, c])
                p.setPen(QPen(STATE_COLORS[st].lighter(130), 2))
                p.setBrush(Qt.NoBrush)
                rect = QRectF(ox + (c0 + c) * px, oy + (r0 + r) * py, px - self.gap_px, py - self.gap_px)
                p.drawRect(rect.adjusted(1, 1, -1, -1))
        self._request_many([(r0 + int(r), c0 + int(c)) for r, c in np.argwhere(waiting)], full=False)

    def paintEvent(self, event) -> None:
        p = QPainter(self.viewport())
        p.fillRect(event.rect(), QColor(24, 25, 28))
        if not self.rows or self.mosaic is None:
            p.end()
            return
        r0, r1, c0, c1 = self._visible_range(event.rect())
        if r1 <= r0 or c1 <= c0:
            p.end()
            return
        full = self.cell_px >= FULL_ZOOM_PX
        px, py = self._pitch()
        ox, oy = self._offset()
        p.setRenderHint(QPainter.SmoothPixmapTransform, self.cell_px < TILE_W)
        status = self.status
        thin = self.cell_px < 8
        if not full:
            self._paint_overview(p, r0, r1, c0, c1, px, py, ox, oy, thin)
        rows_to_paint = range(r0, r1) if full else range(0)
        for r in rows_to_paint:
            row_status = status[r]
            for c in range(c0, c1):
                st = int(row_status[c])
                rect = QRectF(ox + c * px, oy + r * py, px - self.gap_px, py - self.gap_px)
                if st == DONE:
                    if full:
                        img = self._cache.get((r, c))
                        if img is not None:
                            self._cache.move_to_end((r, c))
                            p.drawImage(rect, img)
                        else:
                            if self._mosaic_has[r, c]:
                                p.drawImage(rect, self.mosaic, QRectF(c * TILE_W, r * TILE_H, TILE_W, TILE_H))
                            self._request((r, c), full=True)
                    elif not self._mosaic_has[r, c]:
                        p.fillRect(rect, STATE_COLORS[DONE].darker(160))
                        self._request((r, c), full=False)
                else:
                    p.fillRect(rect, STATE_COLORS[st])
                if st != DONE and not thin and st != PENDING:
                    p.setPen(QPen(STATE_COLORS[st].lighter(130), 2))
                    p.drawRect(rect.adjusted(1, 1, -1, -1))
        if self.quality or self._overlay is not None:
            self._paint_quality(p, r0, r1, c0, c1, px, py, ox, oy, thin)
        # selection and rubber band
        if self.selected:
            p.setPen(QPen(QColor(80, 160, 255), 2 if not thin else 1))
            p.setBrush(QColor(80, 160, 255, 60))
            for (r, c) in self.selected:
                if r0 <= r < r1 and c0 <= c < c1:
                    p.drawRect(QRectF(ox + c * px, oy + r * py, px - self.gap_px, py - self.gap_px))
        band = self._band()
        if band is not None:
            (ra, ca), (rb, cb) = band
            p.setPen(QPen(QColor(80, 160, 255), 1, Qt.DashLine))
            p.setBrush(Qt.NoBrush)
            p.drawRect(QRectF(ox + ca * px, oy + ra * py, (cb - ca + 1) * px, (rb - ra + 1) * py))
        if full:
            p.setPen(QColor(230, 230, 230))
            font = p.font()
            font.setPointSizeF(max(6.0, min(9.0, self.cell_px / 14)))
            p.setFont(font)
            for r in range(r0, r1):
                for c in range(c0, c1):
                    rect = QRectF(ox + c * px + 3, oy + r * py + 2, px - 6, 14)
                    p.drawText(rect, Qt.AlignLeft | Qt.AlignTop, view_label(r, c))
        p.end()

    # -- interaction -------------------------------------------------------------------------------
    def _band(self):
        if self._drag_from is None or self._drag_to is None:
            return None
        (ra, ca), (rb, cb) = self._drag_from, self._drag_to
        return (min(ra, rb), min(ca, cb)), (max(ra, rb), max(ca, cb))

    def mousePressEvent(self, event) -> None:
        if event.button() == Qt.LeftButton:
            cell = self.cell_at(event.position().toPoint())
            if not event.modifiers() & (Qt.ControlModifier | Qt.ShiftModifier):
                self.selected.clear()
            self._drag_from = self._drag_to = cell
            self.viewport().update()
        super().mousePressEvent(event)

    def mouseMoveEvent(self, event) -> None:
        cell = self.cell_at(event.position().toPoint())
        if self._drag_from is not None and cell is not None and cell != self._drag_to:
            self._drag_to = cell
            self.viewport().update()
        if cell != self._tip_cell:
            self._tip_cell = cell
            if cell is not None:
                r, c = cell
                tip = f"row {r}, column {c}: {STATE_NAMES[int(self.status[r, c])]}"
                entry = self.quality.get(cell)
                if entry is not None:
                    tip += f"\ncheck: {entry['verdict']}" + "".join(f"\n  {x}" for x in entry.get("reasons", []))
                    if entry.get("verdict") in FLAG_COLORS:
                        tip += "\n(click: compare with its neighbours)"
                self.setToolTip(tip)
        super().mouseMoveEvent(event)

    def mouseReleaseEvent(self, event) -> None:
        band = self._band()
        if event.button() == Qt.LeftButton and band is not None:
            (ra, ca), (rb, cb) = band
            cells = {(r, c) for r in range(ra, rb + 1) for c in range(ca, cb + 1)}
            if event.modifiers() & Qt.ControlModifier and len(cells) == 1 and cells <= self.selected:
                self.selected -= cells
            else:
                self.selected |= cells
            self.selectionChanged.emit(len(self.selected))
            if len(cells) == 1 and not event.modifiers() & (Qt.ControlModifier | Qt.ShiftModifier):
                cell = next(iter(cells))
                if (self.quality.get(cell) or {}).get("verdict") in FLAG_COLORS:
                    self.flaggedClicked.emit(*cell)
        self._drag_from = self._drag_to = None
        self.viewport().update()
        super().mouseReleaseEvent(event)

    def mouseDoubleClickEvent(self, event) -> None:
        cell = self.cell_at(event.position().toPoint())
        if cell is not None:
            self.viewActivated.emit(*cell)

    def wheelEvent(self, event) -> None:
        if event.modifiers() & Qt.ControlModifier:
            steps = event.angleDelta().y() / 120.0
            self.set_zoom(self.cell_px * (1.25 ** steps), event.position().toPoint())
            event.accept()
            return
        super().wheelEvent(event)

    def keyPressEvent(self, event) -> None:
        key = event.key()
        if key in (Qt.Key_Plus, Qt.Key_Equal):
            self.zoom_by(1.25)
        elif key == Qt.Key_Minus:
            self.zoom_by(0.8)
        elif key == Qt.Key_F:
            self.fit()
        elif key == Qt.Key_Escape:
            self.selected.clear()
            self.selectionChanged.emit(0)
            self.viewport().update()
        elif key == Qt.Key_A and event.modifiers() & Qt.ControlModifier:
            self.selected = {(r, c) for r in range(self.rows) for c in range(self.columns)}
            self.selectionChanged.emit(len(self.selected))
            self.viewport().update()
        else:
            super().keyPressEvent(event)

    def scrollContentsBy(self, dx: int, dy: int) -> None:
        self.viewport().update()

    def shutdown(self) -> None:
        self.loader.stop()


class ImageDialog(QDialog):
    """One view at full size (decoded off the GUI thread)."""

    def __init__(self, path: Path, title: str, parent: QWidget | None = None):
        super().__init__(parent)
        self.setWindowTitle(title)
        self.setObjectName("viewDialog")
        self.resize(screen_fitted(self, 1000, 700))
        self.label = QLabel("Loading…")
        self.label.setAlignment(Qt.AlignCenter)
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
        shown = fm_bold.elidedText(self._name, Qt.ElideMiddle, room)
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
        self.empty.setAlignment(Qt.AlignCenter)
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
        saved = settings().value(OVERLAY_KEY, "") or ""
        index = qb.overlay.findData(saved)
        if index > 0:
            qb.overlay.setCurrentIndex(index)
            self.canvas.set_overlay(saved)
        state.datasetChanged.connect(self.set_dataset)
        scan_events = getattr(state, "scanEvents", None)
        if scan_events is not None:
            scan_events.connect(self.on_scan_events)
        self._recent_menu: QMenu | None = None
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
        b.setSizePolicy(QSizePolicy.Fixed, QSizePolicy.Fixed)
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
            self.state.report_error("Open view", str(exc))
            return
        dlg = ImageDialog(path, f"View row {row}, column {column} — {view['file']}", self)
        dlg.setAttribute(Qt.WA_DeleteOnClose)
        dlg.show()
        self._last_dialog = dlg

    # -- menus -------------------------------------------------------------------------------------
    def install_menus(self, window) -> None:
        file_menu = window.menu("File")
        open_action = QAction("&Open dataset…", self)
        open_action.setShortcut(QKeySequence.Open)
        open_action.setToolTip("Open a dataset folder (the one holding dataset.json)")
        open_action.triggered.connect(self.choose_dataset)
        file_menu.addAction(open_action)
        self._recent_menu = file_menu.addMenu("Recent datasets")
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
        recap.setToolTip("Queue the views selected in the grid for capture again")
        recap.triggered.connect(self.request_recapture)
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
            self.state.report_error("Open dataset", str(exc))
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
            self.state.show_status(str(exc), 10000)
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
        dlg = DisparityDialog(Path(ds.root) / rel, doc.get("disparity_map"), self)
        dlg.setAttribute(Qt.WA_DeleteOnClose)
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
    if isinstance(value, str):
        value = [value]
    return [str(v) for v in (value or []) if v]


def add_recent_dataset(path: str) -> None:
    items = [p for p in recent_datasets() if p != path]
    items.insert(0, path)
    settings().setValue("datasets/recent", items[:MAX_RECENT])
