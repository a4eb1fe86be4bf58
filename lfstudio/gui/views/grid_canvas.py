"""The grid's canvas: every view of a dataset painted as on the rig (row x column) in one
custom-painted scroll area (no widget per view), coloured by state, with its thumbnail, zoom,
selection and double-click. At low zoom the whole grid is drawn from one mosaic image (one small
tile per view, filled in as thumbnails load: ``gui/views/thumb_loader.py``); zoomed in, only the
visible views from their full thumbnails (LRU cache). Changed cells repaint together once a frame
(FRAME_MS). The quality verdicts and heat map over it: ``gui/views/grid_quality.py``."""

from __future__ import annotations

import os
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import QPoint, QRect, QRectF, QSize, Qt, QTimer, Signal
from PySide6.QtGui import QColor, QImage, QPainter, QPen
from PySide6.QtWidgets import QAbstractScrollArea, QWidget

from lfstudio.dataset.manifest import is_done
from lfstudio.dataset.paths import view_label
from lfstudio.gui.views.grid_quality import QualityOverlay
from lfstudio.gui.views.thumb_loader import ThumbLoader

PENDING, CAPTURING, DONE, FAILED, SKIPPED = range(5)
STATUS_CODES = {"pending": PENDING, "done": DONE, "failed": FAILED, "skipped": SKIPPED}
STATE_NAMES = {PENDING: "pending", CAPTURING: "capturing", DONE: "done", FAILED: "failed", SKIPPED: "skipped"}
STATE_COLORS = {PENDING: QColor(70, 74, 82), CAPTURING: QColor(255, 176, 32), DONE: QColor(70, 180, 90),
                FAILED: QColor(220, 60, 60), SKIPPED: QColor(40, 42, 46)}
TILE_W, TILE_H = 48, 32          # mosaic tile (low zoom)
FULL_ZOOM_PX = 56                # from this cell width on, draw the full thumbnails
FRAME_MS = 40                    # the grid repaints what changed at most 25 times a second


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
        self.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
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
        self.loader = ThumbLoader(self, batch_ms=FRAME_MS // 2)
        self._dirty: list[tuple[int, int]] = []          # cells changed since the last frame
        self._frame_timer = QTimer(self)
        self._frame_timer.setSingleShot(True)
        self._frame_timer.setInterval(FRAME_MS)
        self._frame_timer.timeout.connect(self._frame)
        self.loader.ready.connect(self._thumbnails_ready, Qt.ConnectionType.QueuedConnection)
        self.setToolTip("Thumbnails as on the rig. Ctrl+wheel or +/- zooms, F fits; click or drag to select, "
                        "double-click opens a view full size")
        self._tip_cell: tuple[int, int] | None = None
        self.overlay = QualityOverlay()                    # the verdicts and the heat map

    # -- quality (gui/views/grid_quality.py) --------------------------------------------------------
    @property
    def quality(self) -> dict[tuple[int, int], dict]:
        """cell -> its quality.json view entry."""
        return self.overlay.quality

    @property
    def quality_doc(self) -> dict | None:
        """The quality document (thresholds etc. for the heat-map scales)."""
        return self.overlay.doc

    @property
    def overlay_key(self) -> str:
        return self.overlay.key

    def set_quality(self, doc: dict | None) -> None:
        """Show the verdicts of a quality document (``quality.json`` layout); None clears them."""
        self.overlay.set_document(doc)
        self.viewport().update()

    def update_quality(self, entry: dict, doc: dict | None = None) -> None:
        """One view's new verdict (scan-time check): that cell alone is recoloured and repainted."""
        self.update_quality_many([entry], doc)

    def update_quality_many(self, entries: list[dict], doc: dict | None = None) -> None:
        """New verdicts of some views (scan-time check, coalesced): only their cells change."""
        had = self.overlay.heat is not None
        for cell in self.overlay.update(entries, doc):
            self._mark_dirty(*cell)
        if self.overlay.heat is not None and not had:
            self.viewport().update()          # the heat map was coloured for the first time

    def set_overlay(self, key: str) -> None:
        self.overlay.set_key(key)
        self.viewport().update()

    def flagged(self) -> list[tuple[int, int]]:
        return self.overlay.flagged()

    # -- data --------------------------------------------------------------------------------------
    def set_dataset(self, dataset: Any) -> None:
        self.loader.clear()
        self._dirty = []
        self._cache.clear()
        self.selected.clear()
        self.overlay.reset(0, 0)
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
            self.overlay.reset(self.rows, self.columns)
            self.mosaic = QImage(self.columns * TILE_W, self.rows * TILE_H, QImage.Format.Format_RGB32)
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
                painter.fillRect(target, Qt.GlobalColor.black)
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
    def _paint_overview(self, p: QPainter, mosaic: QImage, r0: int, r1: int, c0: int, c1: int, px: float,
                        py: float, ox: float, oy: float, thin: bool) -> None:
        """Zoomed out: the thumbnail mosaic, then one status image over it (transparent where a
        thumbnail shows), gap lines and the few highlighted cells — a handful of calls, not one per cell."""
        src = QRectF(c0 * TILE_W, r0 * TILE_H, (c1 - c0) * TILE_W, (r1 - r0) * TILE_H)
        dst = QRectF(ox + c0 * px, oy + r0 * py, (c1 - c0) * px, (r1 - r0) * py)
        p.drawImage(dst, mosaic, src)
        block = self.status[r0:r1, c0:c1]
        has = self._mosaic_has[r0:r1, c0:c1]
        height, width = block.shape
        rgba = np.zeros((height, width, 4), np.uint8)
        for st, colour in STATE_COLORS.items():
            rgba[block == st] = (colour.red(), colour.green(), colour.blue(), 255)
        waiting = (block == DONE) & ~has
        dark = STATE_COLORS[DONE].darker(160)
        rgba[waiting] = (dark.red(), dark.green(), dark.blue(), 255)
        rgba[(block == DONE) & has, 3] = 0
        overlay = QImage(rgba.data, width, height, rgba.strides[0], QImage.Format.Format_RGBA8888)
        p.setRenderHint(QPainter.RenderHint.SmoothPixmapTransform, False)
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
                p.setBrush(Qt.BrushStyle.NoBrush)
                rect = QRectF(ox + (c0 + c) * px, oy + (r0 + r) * py, px - self.gap_px, py - self.gap_px)
                p.drawRect(rect.adjusted(1, 1, -1, -1))
        self._request_many([(r0 + int(r), c0 + int(c)) for r, c in np.argwhere(waiting)], full=False)

    def paintEvent(self, event) -> None:
        p = QPainter(self.viewport())
        p.fillRect(event.rect(), QColor(24, 25, 28))
        mosaic = self.mosaic
        if not self.rows or mosaic is None:
            p.end()
            return
        r0, r1, c0, c1 = self._visible_range(event.rect())
        if r1 <= r0 or c1 <= c0:
            p.end()
            return
        full = self.cell_px >= FULL_ZOOM_PX
        px, py = self._pitch()
        ox, oy = self._offset()
        p.setRenderHint(QPainter.RenderHint.SmoothPixmapTransform, self.cell_px < TILE_W)
        status = self.status
        thin = self.cell_px < 8
        if not full:
            self._paint_overview(p, mosaic, r0, r1, c0, c1, px, py, ox, oy, thin)
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
                                p.drawImage(rect, mosaic, QRectF(c * TILE_W, r * TILE_H, TILE_W, TILE_H))
                            self._request((r, c), full=True)
                    elif not self._mosaic_has[r, c]:
                        p.fillRect(rect, STATE_COLORS[DONE].darker(160))
                        self._request((r, c), full=False)
                else:
                    p.fillRect(rect, STATE_COLORS[st])
                if st != DONE and not thin and st != PENDING:
                    p.setPen(QPen(STATE_COLORS[st].lighter(130), 2))
                    p.drawRect(rect.adjusted(1, 1, -1, -1))
        if self.overlay.shown:
            self.overlay.paint(p, r0, r1, c0, c1, px, py, ox, oy, thin, self.gap_px)
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
            p.setPen(QPen(QColor(80, 160, 255), 1, Qt.PenStyle.DashLine))
            p.setBrush(Qt.BrushStyle.NoBrush)
            p.drawRect(QRectF(ox + ca * px, oy + ra * py, (cb - ca + 1) * px, (rb - ra + 1) * py))
        if full:
            p.setPen(QColor(230, 230, 230))
            font = p.font()
            font.setPointSizeF(max(6.0, min(9.0, self.cell_px / 14)))
            p.setFont(font)
            for r in range(r0, r1):
                for c in range(c0, c1):
                    rect = QRectF(ox + c * px + 3, oy + r * py + 2, px - 6, 14)
                    p.drawText(rect, Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignTop, view_label(r, c))
        p.end()

    # -- interaction -------------------------------------------------------------------------------
    def _band(self):
        if self._drag_from is None or self._drag_to is None:
            return None
        (ra, ca), (rb, cb) = self._drag_from, self._drag_to
        return (min(ra, rb), min(ca, cb)), (max(ra, rb), max(ca, cb))

    def mousePressEvent(self, event) -> None:
        if event.button() == Qt.MouseButton.LeftButton:
            cell = self.cell_at(event.position().toPoint())
            if not event.modifiers() & (Qt.KeyboardModifier.ControlModifier | Qt.KeyboardModifier.ShiftModifier):
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
                    if self.overlay.is_flagged(cell):
                        tip += "\n(click: compare with its neighbours)"
                self.setToolTip(tip)
        super().mouseMoveEvent(event)

    def mouseReleaseEvent(self, event) -> None:
        band = self._band()
        if event.button() == Qt.MouseButton.LeftButton and band is not None:
            (ra, ca), (rb, cb) = band
            cells = {(r, c) for r in range(ra, rb + 1) for c in range(ca, cb + 1)}
            if event.modifiers() & Qt.KeyboardModifier.ControlModifier and len(cells) == 1 and cells <= self.selected:
                self.selected -= cells
            else:
                self.selected |= cells
            self.selectionChanged.emit(len(self.selected))
            if len(cells) == 1 and not event.modifiers() & (Qt.KeyboardModifier.ControlModifier | Qt.KeyboardModifier.ShiftModifier):
                cell = next(iter(cells))
                if self.overlay.is_flagged(cell):
                    self.flaggedClicked.emit(*cell)
        self._drag_from = self._drag_to = None
        self.viewport().update()
        super().mouseReleaseEvent(event)

    def mouseDoubleClickEvent(self, event) -> None:
        cell = self.cell_at(event.position().toPoint())
        if cell is not None:
            self.viewActivated.emit(*cell)

    def wheelEvent(self, event) -> None:
        if event.modifiers() & Qt.KeyboardModifier.ControlModifier:
            steps = event.angleDelta().y() / 120.0
            self.set_zoom(self.cell_px * (1.25 ** steps), event.position().toPoint())
            event.accept()
            return
        super().wheelEvent(event)

    def keyPressEvent(self, event) -> None:
        key = event.key()
        if key in (Qt.Key.Key_Plus, Qt.Key.Key_Equal):
            self.zoom_by(1.25)
        elif key == Qt.Key.Key_Minus:
            self.zoom_by(0.8)
        elif key == Qt.Key.Key_F:
            self.fit()
        elif key == Qt.Key.Key_Escape:
            self.selected.clear()
            self.selectionChanged.emit(0)
            self.viewport().update()
        elif key == Qt.Key.Key_A and event.modifiers() & Qt.KeyboardModifier.ControlModifier:
            self.selected = {(r, c) for r in range(self.rows) for c in range(self.columns)}
            self.selectionChanged.emit(len(self.selected))
            self.viewport().update()
        else:
            super().keyPressEvent(event)

    def scrollContentsBy(self, dx: int, dy: int) -> None:
        self.viewport().update()

    def shutdown(self) -> None:
        self.loader.stop()
