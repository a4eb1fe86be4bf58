"""A small line-chart renderer with OpenCV (the core has no Qt and we do not ship matplotlib).

Used for the paper's Figure 3: residual after calibration against the principal-point shift.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from lfstudio.dataset.atomic import atomic_write_with

_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _nice_ticks(lo: float, hi: float, n: int = 6) -> list[float]:
    span = max(hi - lo, 1e-9)
    raw = span / n
    mag = 10 ** math.floor(math.log10(raw))
    step = min((m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw), default=mag * 10)
    start = math.ceil(lo / step - 1e-9) * step
    return [round(start + i * step, 10) for i in range(int((hi - start) / step + 1e-9) + 1)]


def line_chart(series: Sequence[dict], *, title: str, x_label: str, y_label: str,
               size_px: tuple[int, int] = (1000, 640), y_range: tuple[float, float] | None = None) -> np.ndarray:
    """Render ``series`` (dicts with ``x``, ``y``, ``label``, ``color`` (BGR), optional ``dashed``) to BGR."""
    w, h = size_px
    img = np.full((h, w, 3), 255, np.uint8)
    left, right, top, bottom = 90, 30, 60, 80
    xs = np.concatenate([np.asarray(s["x"], float) for s in series])
    ys = np.concatenate([np.asarray(s["y"], float) for s in series])
    x0, x1 = float(xs.min()), float(xs.max())
    if x1 <= x0:
        x0, x1 = x0 - 1, x1 + 1
    if y_range is None:
        pad = 0.08 * max(ys.max() - ys.min(), 1e-3)
        y0, y1 = float(ys.min() - pad), float(ys.max() + pad)
    else:
        y0, y1 = y_range

    def px(x, y):
        return (int(round(left + (x - x0) / (x1 - x0) * (w - left - right))),
                int(round(h - bottom - (y - y0) / (y1 - y0) * (h - top - bottom))))

    for t in _nice_ticks(y0, y1):
        p = px(x0, t)
        cv2.line(img, (left, p[1]), (w - right, p[1]), (230, 230, 230), 1)
        cv2.putText(img, f"{t:.2f}", (10, p[1] + 5), _FONT, 0.5, (60, 60, 60), 1, cv2.LINE_AA)
    for t in _nice_ticks(x0, x1):
        p = px(t, y0)
        cv2.line(img, (p[0], top), (p[0], h - bottom), (230, 230, 230), 1)
        cv2.putText(img, f"{t:g}", (p[0] - 10, h - bottom + 22), _FONT, 0.5, (60, 60, 60), 1, cv2.LINE_AA)
    cv2.rectangle(img, (left, top), (w - right, h - bottom), (0, 0, 0), 1)
    cv2.putText(img, title, (left, 35), _FONT, 0.7, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, x_label, (w // 2 - 120, h - 25), _FONT, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, y_label, (left + 5, top - 8), _FONT, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    for k, s in enumerate(series):
        pts = [px(x, y) for x, y in zip(s["x"], s["y"])]
        color = tuple(int(c) for c in s.get("color", (0, 0, 0)))
        for a, b in zip(pts, pts[1:]):
            if s.get("dashed"):
                n = max(2, int(np.hypot(b[0] - a[0], b[1] - a[1]) // 8))
                for i in range(0, n, 2):
                    p0 = (int(a[0] + (b[0] - a[0]) * i / n), int(a[1] + (b[1] - a[1]) * i / n))
                    p1 = (int(a[0] + (b[0] - a[0]) * (i + 1) / n), int(a[1] + (b[1] - a[1]) * (i + 1) / n))
                    cv2.line(img, p0, p1, color, 2, cv2.LINE_AA)
            else:
                cv2.line(img, a, b, color, 2, cv2.LINE_AA)
        for p in pts:
            cv2.circle(img, p, 3, color, -1, cv2.LINE_AA)
        ly = top + 20 + 22 * k
        cv2.line(img, (w - right - 330, ly - 5), (w - right - 300, ly - 5), color, 2, cv2.LINE_AA)
        cv2.putText(img, s["label"], (w - right - 292, ly), _FONT, 0.48, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def plot_sweep(results: Sequence[dict], path: str | Path) -> Path:
    """Figure 3 of the paper from :func:`lfstudio.calibration.simulate.sweep` results, as PNG."""
    r = [res["pp_shift_px"] for res in results]
    series = []
    key = "without_principal_point"
    if all(key in res for res in results):
        s = [res[key] for res in results]
        series += [
            {"x": r, "y": [x["residual_px"]["p99"] for x in s], "label": "residual p99", "color": (40, 40, 200)},
            {"x": r, "y": [x["residual_px"]["mean"] for x in s], "label": "residual mean", "color": (0, 0, 0)},
            {"x": r, "y": [x["residual_px"]["p1"] for x in s], "label": "residual p1", "color": (200, 80, 40)},
            {"x": r, "y": [x["true_residual_px"]["mean"] for x in s], "label": "true rectification error mean",
             "color": (40, 150, 40), "dashed": True},
        ]
    key = "with_principal_point"
    if all(key in res for res in results):
        s = [res[key] for res in results]
        series.append({"x": r, "y": [x["residual_px"]["mean"] for x in s], "label": "residual mean (PP auto)",
                       "color": (150, 60, 150), "dashed": True})
    top = max(max(s["y"]) for s in series)
    img = line_chart(series, y_range=(0.0, top * 1.35), title=f"Residual after self-calibration vs principal-point shift "
                                   f"({results[0]['trials']} trials per point)",
                     x_label="principal-point shift r [px]", y_label="RMS residual per trial [px]")
    path = Path(path)

    def write(tmp: Path) -> None:
        if not cv2.imwrite(str(tmp), img):
            raise OSError(f"{path}: the chart could not be written (cv2.imwrite failed; is the disk full?)")

    atomic_write_with(path, write)
    return path
