"""The scan path preview: the grid's positions joined in capture order, done views filled, the
current one ringed (the Scan panel shows it under its grid settings; ``tests/gui/test_gui_stalls.py``
times it on a 2121-view grid)."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QBrush, QColor, QPainter, QPen, QPixmap, QPolygonF
from PySide6.QtWidgets import QSizePolicy, QWidget

from lfstudio.dataset.grid import grid_order
from lfstudio.scan.scan_plan import ScanPlan


class PathPreview(QWidget):
    """The scan path: grid positions joined in capture order; done views filled, the current one ringed.

    The path and the dots are drawn once into cached pixmaps (done dots are added one at a time), so
    repainting during a 2121-view scan costs two pixmap blits. Drawing them is a handful of painter
    calls whatever the grid's size: the positions are computed with numpy and handed to Qt as one
    polyline and one point set (:func:`_points`), never one call per view.
    """

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.setObjectName("pathPreview")
        self.setMinimumHeight(110)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.setAttribute(Qt.WidgetAttribute.WA_OpaquePaintEvent)      # paints every pixel: nothing under it is repainted
        self.plan: ScanPlan | None = None
        self.current: tuple[int, int] | None = None
        self.done: set[tuple[int, int]] = set()
        self._base: QPixmap | None = None
        self._overlay: QPixmap | None = None
        self._geom: tuple[float, float, float, float, float, float] | None = None
        self.rebuilds = 0               # how often the path was drawn anew (tests, benchmarks)
        self.setToolTip("Capture order: the camera visits the grid along this line, starting at the green dot")

    def set_plan(self, plan: ScanPlan | None) -> None:
        if plan == self.plan and self._base is not None:
            return                      # the same grid: keep the drawn path
        self.plan = plan
        self._base = None
        self.update()

    def set_done(self, cells) -> None:
        cells = set(cells)
        if cells == self.done:
            return
        if self.done <= cells and self._overlay is not None:   # only additions: paint just those
            new = cells - self.done
            self.done = cells
            self._paint_done(list(new))
        else:                           # some views are no longer done: a fresh overlay, same path
            self.done = cells
            if self._overlay is not None:
                self._overlay.fill(Qt.GlobalColor.transparent)
                self._paint_done(list(cells))
        self.update()

    def mark_done(self, row: int, column: int) -> None:
        self.done.add((row, column))
        self._paint_done([(row, column)])

    def _paint_done(self, cells) -> None:
        """Fill the dots of ``cells`` on the overlay, with one painter call for all of them."""
        if self._overlay is None or self._geom is None or not cells:
            return
        ox, oy, sx, sy, scale, dot = self._geom
        rc = np.asarray(cells, dtype=float).reshape(-1, 2)
        p = QPainter(self._overlay)
        _draw_dots(p, ox + rc[:, 1] * sx * scale, oy + rc[:, 0] * sy * scale, dot, QColor(70, 180, 90))
        p.end()

    def _rebuild(self) -> tuple[QPixmap, QPixmap]:
        """The path drawn anew at the widget's size: (the path, the overlay of views done)."""
        plan = self.plan
        self.rebuilds += 1
        self._base = base = QPixmap(self.size())
        base.fill(QColor(30, 32, 36))
        self._overlay = overlay = QPixmap(self.size())
        overlay.fill(Qt.GlobalColor.transparent)
        p = QPainter(base)
        p.setRenderHint(QPainter.RenderHint.Antialiasing)
        if plan is None:
            p.setPen(QColor(160, 160, 160))
            p.drawText(self.rect(), Qt.AlignmentFlag.AlignCenter, "no grid")
            p.end()
            self._geom = None
            return base, overlay
        margin = 12.0
        w, h = self.width() - 2 * margin, self.height() - 2 * margin - 14
        cols, rows = plan.columns, plan.rows
        sx, sy = plan.spacing_mm
        width_mm, height_mm = (cols - 1) * sx, (rows - 1) * sy
        scale = min(w / width_mm if width_mm > 0 else 1e9, h / height_mm if height_mm > 0 else 1e9)
        if scale > 1e8:
            scale = 1.0
        ox = margin + (w - width_mm * scale) / 2
        oy = margin + (h - height_mm * scale) / 2
        dot = max(1.5, min(4.0, sx * scale / 3))
        self._geom = (ox, oy, sx, sy, scale, dot)

        cells = grid_order(cols, rows, plan.order)
        if plan.subset is not None:
            cells = [rc for rc in cells if rc in plan.subset]
        rc = np.asarray(cells, dtype=float).reshape(-1, 2)
        x, y = ox + rc[:, 1] * sx * scale, oy + rc[:, 0] * sy * scale
        if len(rc):
            p.setPen(QPen(QColor(110, 150, 220), 1.2))
            p.drawPolyline(_points(x, y))
            _draw_dots(p, x, y, dot, QColor(140, 144, 152))
            p.setRenderHint(QPainter.RenderHint.Antialiasing)
            p.setPen(QPen(Qt.PenStyle.NoPen))
            p.setBrush(QBrush(QColor(60, 220, 90)))
            p.drawEllipse(QPointF(x[0], y[0]), dot + 2, dot + 2)
        x0, x1, y0, y1 = plan.extent_mm()
        p.setPen(QColor(190, 190, 190))
        p.drawText(QRectF(4, self.height() - 16, self.width() - 8, 14), Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignVCenter,
                   f"x {x0:.0f}…{x1:.0f} mm · y {y0:.0f}…{y1:.0f} mm · {plan.order}")
        p.end()
        self._paint_done(list(self.done))
        return base, overlay

    def resizeEvent(self, event) -> None:
        self._base = None
        super().resizeEvent(event)

    def paintEvent(self, event) -> None:
        base, overlay = self._base, self._overlay
        if base is None or overlay is None or base.size() != self.size():
            base, overlay = self._rebuild()
        p = QPainter(self)
        p.drawPixmap(0, 0, base)
        p.drawPixmap(0, 0, overlay)
        if self.current is not None and self._geom is not None:
            ox, oy, sx, sy, scale, dot = self._geom
            r, c = self.current
            p.setRenderHint(QPainter.RenderHint.Antialiasing)
            p.setPen(QPen(QColor(255, 176, 32), 2))
            p.setBrush(QBrush(Qt.BrushStyle.NoBrush))
            p.drawEllipse(QPointF(ox + c * sx * scale, oy + r * sy * scale), dot + 4, dot + 4)
        p.end()


def _points(x: np.ndarray, y: np.ndarray) -> QPolygonF:
    """A QPolygonF of the points (x, y), filled from numpy in one copy (no Python loop)."""
    import pyqtgraph.functions as pgf

    return pgf.arrayToQPolygonF(np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(y, dtype=float))


def _draw_dots(p: QPainter, x: np.ndarray, y: np.ndarray, radius: float, colour: QColor) -> None:
    """Dots of ``radius`` at (x, y) in one call: a wide pen's points, round and antialiased for a few
    hundred, plain squares for thousands (10x cheaper, and too small to tell apart)."""
    many = len(x) > 400
    pen = QPen(colour, 2 * radius)
    pen.setCapStyle(Qt.PenCapStyle.SquareCap if many else Qt.PenCapStyle.RoundCap)
    p.save()
    p.setRenderHint(QPainter.RenderHint.Antialiasing, not many)
    p.setPen(pen)
    p.drawPoints(_points(x, y))
    p.restore()
