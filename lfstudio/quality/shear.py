"""Measure, from matches between views, how an imported light field's views are sheared.

``measure_shear`` reads a block of views around the grid's centre (at most :data:`BLOCK` x
:data:`BLOCK`), tracks their corners into their neighbours with the check's own tracks
(:mod:`lfstudio.quality.tracks`) and solves the positions and every track's signed disparity per mm
(:mod:`lfstudio.quality.positions`). It reports

* the **signed disparity range** (full-size px per mm of baseline, 1st–99th percentile of the better
  measured tracks, each moved inwards by 1.5 of its standard errors as the check does);
* whether the views are **sheared**: a significantly negative disparity is impossible for parallel
  views, so it proves a shear of at least its size, and bounds the zero plane's depth from above
  (the farthest point at infinity); without one the views are read as parallel;
* whether the **rows run upwards**: the tracks' vertical and horizontal disparities must agree in
  sign for the grid as given; when they do only with the rows reversed (the Stanford archive numbers
  its rows from the bottom), the import reverses them (columns are taken as given: left to right).

The zero plane's depth is not observable from matches (see :mod:`lfstudio.dataset.zero_plane`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from lfstudio.jobs import CancelToken
from lfstudio.quality.measure import DEFAULT_WORK_WIDTH_PX, measure_view

Cell = tuple[int, int]     # a grid cell (row, column); a dataset View is one
BLOCK = 5
RANGE_SIGMAS = 1.5
#: a disparity this many standard errors below zero (and below NEGATIVE_FLOOR_PX per step) proves a shear
NEGATIVE_FLOOR_PX = 0.05


@dataclass
class ShearMeasurement:
    disparity_px_per_mm: tuple[float, float]      # signed (min, max), full-size px per mm of baseline
    step_disparity_px: tuple[float, float]         # the same per horizontal grid step
    sheared: bool
    rows_reversed: bool
    tracks: int
    views: int
    residual_px: float
    residual_px_rows_reversed: float
    shear_min_px_per_mm: float                     # the least shear the negative disparities prove
    depth_max_m: float | None                      # the zero plane is nearer than this (when sheared)

    def as_dict(self) -> dict:
        return {"disparity_px_per_mm": [round(v, 6) for v in self.disparity_px_per_mm],
                "step_disparity_px": [round(v, 4) for v in self.step_disparity_px],
                "sheared": self.sheared, "rows_reversed": self.rows_reversed, "tracks": self.tracks,
                "views": self.views, "residual_px": round(self.residual_px, 4),
                "residual_px_rows_reversed": round(self.residual_px_rows_reversed, 4),
                "shear_min_px_per_mm": round(self.shear_min_px_per_mm, 6),
                "depth_max_m": None if self.depth_max_m is None else round(self.depth_max_m, 4),
                "why": "tracks of a block of views around the centre: the signed disparity per mm of "
                       "baseline; a significantly negative one proves sheared views (the zero plane's "
                       "depth itself is not observable from matches)"}


def central_block(cells: list[Cell], block: int = BLOCK) -> list[Cell]:
    rows = sorted({c[0] for c in cells})
    cols = sorted({c[1] for c in cells})

    def middle(values: list[int]) -> set[int]:
        start = max(0, (len(values) - block) // 2)
        return set(values[start:start + block])

    keep_r, keep_c = middle(rows), middle(cols)
    return sorted(c for c in cells if c[0] in keep_r and c[1] in keep_c)


def measure_shear(files: dict[Cell, Path], positions_mm: dict[Cell, tuple[float, float]], spacing_mm: tuple[float, float],
                  focal_length_px: float | None = None, *, work_width_px: int = DEFAULT_WORK_WIDTH_PX,
                  cancel: CancelToken | None = None, progress: Callable[[int, int, str], None] | None = None
                  ) -> ShearMeasurement | None:
    """Measure the views ``files`` (cell → image) taken at ``positions_mm``; None with too few
    tracks (fewer than two views, a featureless scene). ``progress(done, total, message)``: after
    each view read and tracked, and before the solve (a few seconds for 25 views)."""
    from lfstudio.quality import verdicts
    from lfstudio.quality.check import Geometry, GridCheck

    cells = central_block(sorted(files))
    if len(cells) < 2:
        return None
    cols = max(c[1] for c in cells) + 1
    rows = max(c[0] for c in cells) + 1
    geometry = Geometry(cols, rows, (float(spacing_mm[0]), float(spacing_mm[1])),
                        {c: positions_mm[c] for c in cells}, None, None, None, None,
                        verdicts.DEFAULT_REPEATABILITY_UM)
    grid = GridCheck(geometry)
    done: set[Cell] = set()
    steps = len(cells) + 1
    for cell in cells:                       # row-major: each view tracks into those before it
        if cancel is not None:
            cancel.check()
        m = measure_view(files[cell], *cell, work_width_px=work_width_px)
        grid.add(m, known=lambda c: c in done)
        done.add(cell)
        if progress:
            # short: a progress line beside a bar shows ~30 characters (the rest in its tooltip)
            progress(len(done), steps, f"disparities: {len(done)} of {len(cells)} views ({files[cell].name})")
    if progress:
        progress(len(cells), steps, f"disparities: solving the tracks of {len(cells)} views")
    fit = grid.solve(cells)
    y_mid = np.mean([positions_mm[c][1] for c in cells])
    flipped = {c: (positions_mm[c][0], float(2 * y_mid - positions_mm[c][1])) for c in cells}
    fit_rev = grid.solve(cells, known_mm=flipped)
    reversed_rows = bool(np.isfinite(fit_rev.sigma_px) and fit_rev.sigma_px < 0.7 * fit.sigma_px)
    use = fit_rev if reversed_rows else fit
    m0 = grid.measures[cells[0]]
    s = use.s_px_per_mm * m0.work_scale                    # full-size px per mm
    sig = use.s_sigma * m0.work_scale
    good = np.isfinite(s) & np.isfinite(sig) & (use.track_views >= 3)
    if good.sum() < 20:
        return None
    if good.sum() > 100:
        good &= sig <= np.quantile(sig[good], 0.5)
    lo = float(np.percentile(s[good] + RANGE_SIGMAS * sig[good], 1.0))
    hi = float(np.percentile(s[good] - RANGE_SIGMAS * sig[good], 99.0))
    step = float(spacing_mm[0] or spacing_mm[1] or 1.0)
    sheared = lo * step < -NEGATIVE_FLOOR_PX
    shear_min = max(0.0, -lo) if sheared else 0.0
    depth_max = focal_length_px / (1000.0 * shear_min) if sheared and focal_length_px else None
    return ShearMeasurement((lo, hi), (lo * step, hi * step), bool(sheared), reversed_rows, int(good.sum()),
                            len(cells), float(fit.sigma_px * m0.work_scale),
                            float(fit_rev.sigma_px * m0.work_scale) if math.isfinite(fit_rev.sigma_px) else float("nan"),
                            shear_min, depth_max)
