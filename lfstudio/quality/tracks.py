"""Feature tracks between neighbouring views: each view's corners followed into the views next to it.

A view's *star*: its corners (:mod:`lfstudio.quality.measure`) tracked with pyramidal Lucas–Kanade
(``cv2.calcOpticalFlowPyrLK``; a point whose matching error is far above the median is dropped and,
with :data:`BACK_CHECK` one that does not track back to where it started) into up to :data:`STAR_SIZE` neighbours that
are already known — the ones captured earlier during a scan, or earlier in row-major order for a
whole dataset — chosen from :data:`WINDOW` (the 8 around it and two steps along the row or column), nearest
first. Every corner found in at least one neighbour becomes a track of the position model
(:mod:`lfstudio.quality.positions`). The search starts where a point at ``guess_depth_m`` would
be, so large shifts (a skipped step) are found too.

Points are mapped into the rectified frame with the calibration's homography (scaled to the
working image) when the dataset has one; without it the captured frame is used, which the position
model tolerates (a shared orientation error only tilts the grid as a whole).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Sequence

import cv2
import numpy as np

from lfstudio.calibration.model import apply_homography
from lfstudio.quality.measure import ViewMeasures
from lfstudio.quality.positions import Observations

Cell = tuple[int, int]     # a grid cell (row, column); a dataset View is one

#: neighbour offsets (rows, columns) a star may use
WINDOW: tuple[Cell, ...] = tuple((dr, dc) for dr in (-2, -1, 0, 1, 2) for dc in (-2, -1, 0, 1, 2)
                                 if (dr, dc) != (0, 0) and (abs(dc) < 2 or dr == 0) and (abs(dr) < 2 or dc == 0))
STAR_SIZE = 3
ROUND_TRIP_PX = 0.15
#: track back as well (drop points that do not return): twice the cost; the position solve is robust anyway
BACK_CHECK = False
#: a forward-only track is kept when its Lucas–Kanade error is below this many times the median
LK_ERROR_FACTOR = 3.0


def _lk(image_a: np.ndarray, image_b: np.ndarray, pts: np.ndarray, guess: np.ndarray):
    """Pyramidal Lucas–Kanade from ``pts`` in ``image_a`` into ``image_b``, starting at ``guess``:
    (points, status, error) as OpenCV returns them."""
    return cv2.calcOpticalFlowPyrLK(image_a, image_b, pts, guess, winSize=(11, 11), maxLevel=3,
                                    criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 10, 0.03),
                                    flags=cv2.OPTFLOW_USE_INITIAL_FLOW)


def star_neighbours(cell: Cell, known: Callable[[Cell], bool], size: int = STAR_SIZE) -> list[Cell]:
    """Up to ``size`` cells of :data:`WINDOW` around ``cell`` for which ``known`` holds, nearest first
    (ties: the same row first)."""
    r, c = cell
    cands = sorted(WINDOW, key=lambda d: (d[0] * d[0] + d[1] * d[1], abs(d[0]), d[0], d[1]))
    return [(r + dr, c + dc) for dr, dc in cands if known((r + dr, c + dc))][:size]


@dataclass
class Star:
    """One view's corners and where they were found in its neighbours (NaN: lost)."""

    centre: Cell
    neighbours: list[Cell]
    xy: np.ndarray        # (1 + len(neighbours), n, 2) working-image pixels, captured frame

    @property
    def tracks(self) -> int:
        return int(np.count_nonzero(np.isfinite(self.xy[1:, :, 0]).any(axis=0))) if len(self.neighbours) else 0


def track_star(view: ViewMeasures, neighbours: Sequence[ViewMeasures], offsets_mm: Sequence[tuple[float, float]],
               focal_length_work_px: float, guess_depth_m: float, shear_work_px_per_mm: float = 0.0) -> Star:
    """Track ``view``'s corners into each neighbour (``offsets_mm``: neighbour position minus the
    view's, from the manifest; ``shear_work_px_per_mm``: the views' shear, :mod:`lfstudio.dataset.zero_plane`)."""
    pts = np.ascontiguousarray(view.corners, np.float32)
    out = np.full((1 + len(neighbours), len(pts), 2), np.nan, np.float32)
    out[0] = pts
    if len(pts) and view.grey8 is not None:
        for i, (nb, off) in enumerate(zip(neighbours, offsets_mm), start=1):
            if nb.grey8 is None or nb.grey8.shape != view.grey8.shape:
                continue
            shift = -(focal_length_work_px / (1000.0 * guess_depth_m) - shear_work_px_per_mm) \
                * np.asarray(off, np.float32)
            guess = pts + shift.astype(np.float32)
            fwd, st, err = _lk(view.grey8, nb.grey8, pts, guess.copy())
            h, w = view.grey8.shape
            ok = (st[:, 0] == 1) & (fwd[:, 0] >= 0) & (fwd[:, 1] >= 0) & (fwd[:, 0] <= w - 1) & (fwd[:, 1] <= h - 1)
            if BACK_CHECK:
                back, st2, _ = _lk(nb.grey8, view.grey8, fwd, pts.copy())
                ok &= (st2[:, 0] == 1) & (np.hypot(*(back - pts).T) < ROUND_TRIP_PX)
            else:
                e = err[:, 0]
                ok &= e < LK_ERROR_FACTOR * np.median(e[ok]) if ok.any() else ok
            out[i][ok] = fwd[ok]
    return Star(view.cell, [n.cell for n in neighbours], out)


def to_observations(stars: Iterable[Star], index: dict[Cell, int], homography: np.ndarray | None,
                    max_per_star: int | None = None) -> Observations:
    """The tracks of ``stars`` as :class:`lfstudio.quality.positions.Observations` over the views in
    ``index`` (cell → view number); ``homography`` maps working-image points to the rectified frame.
    ``max_per_star``: keep only that many tracks of each star, those seen in the most views first."""
    views, tracks, xys = [], [], []
    n_tracks = 0
    for star in stars:
        if star.centre not in index or not star.neighbours:
            continue
        cells = [star.centre] + star.neighbours
        present = np.array([c in index for c in cells])
        found = np.isfinite(star.xy[..., 0]) & present[:, None]
        keep = found[0] & found[1:].any(axis=0)
        if max_per_star is not None and keep.sum() > max_per_star:
            seen = np.where(keep, found.sum(axis=0), -1)
            best = np.argsort(-seen, kind="stable")[:max_per_star]
            keep = np.zeros_like(keep)
            keep[best] = True
        if not keep.any():
            continue
        sub = star.xy[:, keep]                      # (m, k, 2)
        m, k = sub.shape[:2]
        f = found[:, keep]
        tid = np.broadcast_to(np.arange(k)[None, :] + n_tracks, (m, k))
        vid = np.broadcast_to(np.array([index.get(c, -1) for c in cells])[:, None], (m, k))
        views.append(vid[f])
        tracks.append(tid[f])
        xys.append(sub[f].astype(np.float64))
        n_tracks += k
    if not views:
        return Observations(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)), len(index), 0)
    xy = np.concatenate(xys)
    if homography is not None:
        xy = apply_homography(homography, xy)
    return Observations(np.concatenate(views).astype(int), np.concatenate(tracks).astype(int), xy,
                        len(index), n_tracks)
