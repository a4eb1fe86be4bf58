"""The grid's quality overlay: the verdicts of a quality check (``quality.json`` layout, or the
scan-time check's, view by view) as outlines of flagged views (yellow: warn, red: fail) and, when a
heat map is chosen, one colour per view (sharpness, exposure, position error, residual). The grid
canvas (``gui/views/grid_canvas.py``) holds one :class:`QualityOverlay` and asks it to paint the
block of cells it repaints; the check itself and its dialogs are ``gui/views/quality.py``."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QRectF, Qt
from PySide6.QtGui import QColor, QImage, QPainter, QPen

FLAG_COLORS = {"warn": QColor(255, 225, 0), "fail": QColor(230, 60, 60)}   # yellow: not the amber of "capturing"
FLAG_CODES = {"warn": 1, "fail": 2}       # QualityOverlay.verdicts: 0 for a pass or no verdict
OVERLAY_ALPHA = 215


def _outlines(x: np.ndarray, y: np.ndarray, w: float, h: float):
    """One QPainterPath of the outlines of w x h rectangles at (x, y), built from numpy in one go
    (a painter call per flagged view would cost thousands of Python calls on a big grid)."""
    import pyqtgraph.functions as pgf

    xs = np.stack([x, x + w, x + w, x, x], axis=1).ravel().astype(float)
    ys = np.stack([y, y, y + h, y + h, y], axis=1).ravel().astype(float)
    connect = np.tile(np.array([1, 1, 1, 1, 0], dtype=np.int32), len(x))
    # connect: an array is documented ("1 connects to the next point"); pyqtgraph's "all" default types it str
    return pgf.arrayToQPath(xs, ys, connect=connect)  # pyright: ignore[reportArgumentType]


class QualityOverlay:
    """The verdicts and the heat map of a ``rows`` x ``columns`` grid (GUI thread).

    ``quality``: cell -> the view's quality entry (with checks); ``doc``: the whole document
    (thresholds for the heat-map scales); ``key``: the heat map shown ("": none); ``heat``: rows x
    columns x 4 RGBA or None; ``verdicts``: rows x columns :data:`FLAG_CODES`, for painting."""

    def __init__(self) -> None:
        self.rows = self.columns = 0
        self.quality: dict[tuple[int, int], dict] = {}
        self.doc: dict | None = None
        self.key = ""
        self.heat: np.ndarray | None = None
        self.verdicts = np.zeros((0, 0), np.int8)

    @property
    def shown(self) -> bool:
        """Anything to paint (verdicts or a heat map)."""
        return bool(self.quality) or self.heat is not None

    def reset(self, rows: int, columns: int) -> None:
        """A new grid: no verdicts, the heat map chosen stays chosen."""
        self.rows, self.columns = rows, columns
        self.quality, self.doc, self.heat = {}, None, None
        self.verdicts = np.zeros((rows, columns), np.int8)

    def set_document(self, doc: dict | None) -> None:
        """Show the verdicts of a quality document; None clears them."""
        self.doc = doc
        self.quality = {(int(v["row"]), int(v["column"])): v for v in (doc or {}).get("views", [])
                        if v.get("checks")}
        self.verdicts = np.zeros((self.rows, self.columns), np.int8)
        for cell, entry in self.quality.items():
            self._set_verdict(cell, entry)
        self._rebuild()

    def update(self, entries: list[dict], doc: dict | None = None) -> list[tuple[int, int]]:
        """New verdicts of some views (scan-time check, coalesced); returns their cells (to repaint).
        ``doc``: the live check's document, taken when there is none yet (the heat map's scales)."""
        if doc is not None and self.doc is None:
            self.doc = doc
            if self.key:
                self._rebuild()
        cells = []
        for entry in entries:
            cell = (int(entry["row"]), int(entry["column"]))
            self.quality[cell] = entry
            self._set_verdict(cell, entry)
            if self.heat is not None:
                self._colour_cell(cell, entry)
            cells.append(cell)
        return cells

    def set_key(self, key: str) -> None:
        self.key = key or ""
        self._rebuild()

    def flagged(self) -> list[tuple[int, int]]:
        return sorted(c for c, e in self.quality.items() if e.get("verdict") in FLAG_COLORS)

    def is_flagged(self, cell: tuple[int, int]) -> bool:
        return (self.quality.get(cell) or {}).get("verdict") in FLAG_COLORS

    def _set_verdict(self, cell: tuple[int, int], entry: dict) -> None:
        r, c = cell
        if 0 <= r < self.rows and 0 <= c < self.columns and self.verdicts.shape == (self.rows, self.columns):
            self.verdicts[r, c] = FLAG_CODES.get(str(entry.get("verdict")), 0)

    def _rebuild(self) -> None:
        self.heat = None
        if self.key and self.doc is not None and self.rows and self.columns:
            self.heat = np.zeros((self.rows, self.columns, 4), np.uint8)
            for cell, entry in self.quality.items():
                self._colour_cell(cell, entry)

    def _colour_cell(self, cell: tuple[int, int], entry: dict) -> None:
        from lfstudio.quality.pictures import HEATMAPS, heatmap_colour

        r, c = cell
        if self.heat is None or self.doc is None or not (0 <= r < self.rows and 0 <= c < self.columns):
            return
        value = HEATMAPS[self.key].value(entry)
        if value is None:
            self.heat[r, c] = 0
        else:
            self.heat[r, c, :3] = heatmap_colour(self.doc, self.key, value)
            self.heat[r, c, 3] = OVERLAY_ALPHA

    def paint(self, p: QPainter, r0: int, r1: int, c0: int, c1: int, px: float, py: float,
              ox: float, oy: float, thin: bool, gap_px: float) -> None:
        """Paint rows r0..r1-1, columns c0..c1-1 of cells at pitch (px, py) from (ox, oy)."""
        if self.heat is not None:
            block = np.ascontiguousarray(self.heat[r0:r1, c0:c1])
            img = QImage(block.data, block.shape[1], block.shape[0], block.strides[0], QImage.Format.Format_RGBA8888)
            p.setRenderHint(QPainter.RenderHint.SmoothPixmapTransform, False)
            p.drawImage(QRectF(ox + c0 * px, oy + r0 * py, (c1 - c0) * px, (r1 - r0) * py), img)
        p.setBrush(Qt.BrushStyle.NoBrush)
        block = self.verdicts[r0:r1, c0:c1]       # only the cells being painted, found with numpy
        for code, colour in ((FLAG_CODES["warn"], FLAG_COLORS["warn"]), (FLAG_CODES["fail"], FLAG_COLORS["fail"])):
            cells = np.argwhere(block == code)
            if not len(cells):
                continue
            p.setPen(QPen(colour, 1 if thin else 3))
            inset = 0 if thin else 1
            p.drawPath(_outlines(ox + (c0 + cells[:, 1]) * px + inset, oy + (r0 + cells[:, 0]) * py + inset,
                                 px - gap_px - 2 * inset, py - gap_px - 2 * inset))
