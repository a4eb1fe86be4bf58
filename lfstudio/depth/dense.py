"""Dense per-view disparity from the light field: a plane sweep over the view's 2-D neighbourhood
(near and far baselines, every direction), occlusion-aware half-plane costs, semi-global
aggregation, sub-pixel refinement, depth edges snapped to the surface each pixel matches, and a
confidence map; and OpenCV's single-pair semi-global matcher, the baseline it is measured against
(``benchmarks/depth_points.py``, ``benchmarks/hci_depth.py``).

**Unit**: disparity in **pixels between horizontal neighbours** of the (rectified) views at the
reference image's size — the HCI convention: a point at depth Z has ``d = f · spacing_x / (1000 · Z)``
(zero at infinity; a sheared archive's views add their zero-disparity plane, see
:func:`lfstudio.depth.run.depth_from_disparity`).

**Cost** (the multi-baseline sum of Okutomi & Kanade over inverse depth, with the occlusion handling
of Kang, Szeliski & Chai): the grey images are contrast-normalised (:func:`_normalised`: dark and
faint texture weighs like bright texture). For each candidate ``d`` every neighbour at grid offset
``(dx, dy)`` (in horizontal spacings: a neighbour 6 mm below with 4 mm columns is dy = 1.5) is
sampled where a point of disparity ``d`` lies, ``(u − d·dx, v − d·dy)`` (the camera moving right
moves the image left); the absolute differences, truncated at :data:`TRUNCATE`, are averaged over a
small window per **half-plane** of views (left, right, up, down: a diagonal view counts in two)
and per **line** (the views of its row, of its column; a view whose recorded or measured position
misses the line by up to :data:`LINE_TOLERANCE` spacings is on it), counting only samples inside the neighbour.
A point hidden from one side is seen from the others, so the cost is the mean of the best
:data:`BEST_OF` half-planes' (two of four: one occluded side is left out, and the noise of a single
side is halved), or a line's where that is lower (:data:`LINE_WEIGHT`): a gap or strip a few pixels
wide along a row is hidden from every half-plane's diagonal and vertical views but seen by the row.
An edge or corner view simply has fewer half-planes; a pixel no view of a half-plane sees leaves it out.

**Semi-global aggregation** (Hirschmüller 2008) along the four horizontal and vertical paths: a change
by one candidate costs :data:`P1`, a larger jump :data:`P2`, lowered across an image edge. The best
candidate is refined to sub-pixel: the equiangular fit through the matching costs around it where
they have a sharp minimum there that agrees with the aggregated costs, else a parabola fitted to
the aggregated costs of five candidates around it; last, a plane fitted to the disparities around
each pixel that lie within :data:`PLANE_INLIER_PX` of its own gives its value (:func:`fit_planes`).
Candidates are spaced so that the farthest neighbour moves by at most :data:`SWEEP_STEP_PX` between
them. **Depth edges**: where a pixel's surroundings span more than :data:`EDGE_JUMP_PX`, a pixel given
the nearer surface takes the farther one unless its own grey value matches the nearer clearly better
in the views (a window straddling the edge fattens the nearer surface otherwise); then, given the
view in colour, each such pixel takes the surface of the pixels around it whose colour is nearest
its own (:func:`colour_edges`: an anti-aliased silhouette pixel mostly showing the background).

**Memory**: the cost volume is built and aggregated in strips of rows (at most
:data:`VOLUME_CELLS` cells at once, each strip reading :data:`STRIP_OVERLAP` rows beyond its own), so a
4000 px view needs no more than a 512 px one.

**Confidence** in [0, 1]: ``1 − c_best / c_far``, the matching cost at the answer against the best
cost three or more candidates away (a unique, sharp minimum → near 1; a flat or repeated texture →
near 0); 0 at the end of the searched range. A ranking within one map, not a probability: the same
value means a different share of wrong pixels on different scenes (measured: pixels of 0.3–0.5 are
0.4–1.6 % more than 0.07 px off on three HCI scenes, 5 % on the virtual studio; an expected error
from the cost curve's curvature, ``step · c / rise`` of the aggregated cost, agrees no better).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

#: the farthest neighbour moves by at most this many pixels between two candidate disparities
SWEEP_STEP_PX = 0.25
#: ... and candidates lie at most this far apart (px between horizontal neighbours)
MAX_CANDIDATE_STEP_PX = 0.0625
#: absolute grey differences are truncated here (a pixel hidden from one view costs at most this)
TRUNCATE = 0.3
#: the cost window (box, px) over which each half-plane's differences are averaged
WINDOW_PX = 3
#: semi-global smoothness: a change by one candidate costs P1, a larger jump P2 (lowered across an
#: image edge: P2 / (1 + EDGE_GAIN · |grey step|)); in units of the truncated mean difference
P1 = 0.002
P2 = 0.03
EDGE_GAIN = 30.0
#: cost-volume cells (rows x columns x candidates) held at once: the view is done in strips of rows
VOLUME_CELLS = 24_000_000
#: rows a strip reads below its own (the upward paths settle; the downward ones carry on from the
#: strip above)
STRIP_OVERLAP = 16
#: local contrast normalisation before matching (window, px, and the variance floor): dark and
#: low-contrast texture weighs like bright texture
LCN_WINDOW_PX = 5
LCN_EPS = 0.0004
LCN_SCALE = 0.05
#: depth edges: a pixel whose neighbourhood (this window) spans more than EDGE_JUMP_PX and that was
#: given the nearer surface takes the farther one (the window's minimum) unless its own pixel matches
#: the nearer better by FAR_BIAS across the views (the farther never goes nearer: that only made
#: thin near strips wider, HCI backgammon)
SNAP_WINDOW_PX = 5
SNAP_PASSES = 2
EDGE_JUMP_PX = 1.0
FAR_BIAS = 0.7
#: ... then each pixel of such an edge takes the surface (the window's minimum or maximum) of the
#: pixels within COLOUR_RADIUS_PX whose colour is nearest its own (an anti-aliased pixel of a
#: silhouette belongs to the surface it mostly shows; matching alone gives it the nearer one)
COLOUR_RADIUS_PX = 2
COLOUR_PASSES = 2
#: sub-pixel: where the matching cost (averaged over REFINE_WINDOW_PX) has its minimum at the
#: answer, its neighbours exceeding it by more than REFINE_SHARP of it, and the equiangular fit
#: through it lies within REFINE_AGREE candidates of the parabola fitted to the aggregated costs of
#: five candidates around the answer, that fit; else the parabola (1/4 candidate: the virtual studio's
#: median relative depth error 0.50 %, 1/2: 0.43 %, the HCI scenes alike)
REFINE_SHARP = 0.0
REFINE_AGREE = 0.5
REFINE_WINDOW_PX = 7
#: last, each pixel's disparity is the value at its centre of the plane fitted (least squares) to
#: the disparities within PLANE_WINDOW_PX that lie within PLANE_INLIER_PX of its own: the sub-pixel
#: fits' noise averaged along the surface, slopes kept (no fronto-parallel bias), edges and steps
#: larger than that left alone
PLANE_WINDOW_PX = 5
PLANE_INLIER_PX = 0.05
#: the cost: the mean of the lowest this many half-plane costs, each weighted by (the farthest
#: reach of any half-plane / its own) ^ PLANE_WEIGHT_POWER
BEST_OF = 2
PLANE_WEIGHT_POWER = 0.5
#: half-planes of the 2-D neighbourhood; a view belongs to each side its offset points to
HALF_PLANES = ("left", "right", "up", "down")
#: ... and the lines of views through it (both sides): a thin gap or strip along a row is seen whole
#: by the views of that row and hidden from most others (HCI backgammon)
LINES = ("row", "column")
#: a line's cost counts where it is below the half-planes' times this (fewer views: noisier)
LINE_WEIGHT = 1.15
#: a neighbour lies on the reference's row (column) when its vertical (horizontal) offset is within
#: this many spacings of it: measured or recorded positions miss the grid by a little (the rig's
#: repeatability), which moves no view off its line or into another half-plane
LINE_TOLERANCE = 0.25


@dataclass(frozen=True)
class Neighbour:
    image: np.ndarray                 # grey float32 (as :func:`prepare`), the reference's size
    dx: float                         # its offset from the reference, in horizontal spacings (right +)
    dy: float                         # ... (down +)


@dataclass
class DenseResult:
    disparity_px: np.ndarray          # (h, w) float32, px between horizontal neighbours
    confidence: np.ndarray            # (h, w) float32 in [0, 1]
    candidates: int                   # disparities swept
    neighbours: int


def prepare(rgb: np.ndarray) -> np.ndarray:
    """Grey float32 in [0, 1] of a linear 16-bit (or 8-bit sRGB) RGB view, gamma-encoded so that
    dark and bright texture weigh alike."""
    if rgb.ndim == 3:
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    else:
        grey = rgb
    if grey.dtype == np.uint16:
        return np.sqrt(grey.astype(np.float32) * np.float32(1.0 / 65535.0))
    return grey.astype(np.float32) * np.float32(1.0 / 255.0)


def prepare_colour(rgb: np.ndarray) -> np.ndarray:
    """RGB float32 in [0, 1] (h, w, 3) of a linear 16-bit (or 8-bit sRGB) view, gamma-encoded as
    :func:`prepare` (grey views: one channel)."""
    img = rgb if rgb.ndim == 3 else rgb[:, :, None]
    if img.dtype == np.uint16:
        return np.sqrt(img.astype(np.float32) * np.float32(1.0 / 65535.0))
    return img.astype(np.float32) * np.float32(1.0 / 255.0)


def disparity_candidates(d_min_px: float, d_max_px: float, max_offset: float, step_px: float) -> np.ndarray:
    """Evenly spaced disparities covering [d_min, d_max] so that a neighbour ``max_offset``
    spacings away moves by at most ``step_px`` between two of them."""
    span = max(float(d_max_px) - float(d_min_px), 1e-6)
    n = int(np.ceil(span * max(max_offset, 1e-6) / step_px)) + 1
    return np.linspace(float(d_min_px), float(d_max_px), max(n, 3))


def sgbm_disparity(left: np.ndarray, right: np.ndarray, max_disparity_px: float, block: int = 5,
                   min_disparity_px: float = 0.0) -> np.ndarray:
    """OpenCV's semi-global matcher (3-way) on one rectified pair, ``right`` the view to the right
    of ``left`` (uint8 grey): the disparity of ``left`` in pixels of this pair (float32, NaN where
    it found none or no partner pixel lies that far left); ``min_disparity_px`` < 0 for sheared views."""
    lo = int(np.floor(min(0.0, min_disparity_px * 1.25 - 2)))
    n = int(np.ceil(max(16.0, max_disparity_px * 1.25 + 4 - lo) / 16.0) * 16)
    matcher = cv2.StereoSGBM.create(minDisparity=lo, numDisparities=n, blockSize=block, P1=8 * block * block,
                                    P2=32 * block * block, disp12MaxDiff=1, uniquenessRatio=10,
                                    speckleWindowSize=100, speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    raw = matcher.compute(np.ascontiguousarray(left), np.ascontiguousarray(right)).astype(np.float32) / 16.0
    raw[raw < lo] = np.nan
    raw[:, :max(0, n + lo)] = np.nan
    return raw


def to_uint8(grey: np.ndarray) -> np.ndarray:
    """A :func:`prepare` image as uint8 (what the semi-global matcher takes)."""
    return np.clip(np.rint(grey * 255.0), 0, 255).astype(np.uint8)


def _half_planes(dx: float, dy: float) -> tuple[int, ...]:
    """The subsets of views a neighbour at offset (dx, dy) belongs to: the half-planes
    (:data:`HALF_PLANES`: 0 left, 1 right, 2 up, 3 down) its offset points to, and the line through
    the reference it lies on (:data:`LINES`: 4 the row, 5 the column)."""
    t = LINE_TOLERANCE
    out = []
    if dx < -t:
        out.append(0)
    if dx > t:
        out.append(1)
    if dy < -t:
        out.append(2)
    if dy > t:
        out.append(3)
    if abs(dy) <= t:
        out.append(4)
    if abs(dx) <= t:
        out.append(5)
    return tuple(out)


def _plane_weights(neighbours: Sequence[Neighbour], planes: Sequence[tuple[int, ...]]) -> dict[int, float]:
    """Each half-plane's cost weight: (the farthest reach of any half-plane / its own) ^
    :data:`PLANE_WEIGHT_POWER`. A half-plane of few, near views (beside an edge of the grid) has a
    flat, noisy cost: it counts when the far-reaching ones are clearly worse (occluded)."""
    reach: dict[int, float] = {}
    for n, ps in zip(neighbours, planes):
        for p in ps:
            reach[p] = max(reach.get(p, 0.0), float(np.hypot(n.dx, n.dy)))
    top = max(reach.values(), default=1.0)
    return {p: float((top / max(r, 1e-9)) ** PLANE_WEIGHT_POWER) for p, r in reach.items()}


def _valid_span(n: int, shift: float) -> tuple[int, int]:
    """Output indices i (0 ≤ i < n) whose sample i + shift lies inside [0, n − 1]."""
    lo = max(0, int(np.ceil(-shift - 1e-6)))
    hi = min(n, int(np.floor(n - 1 - shift + 1e-6)) + 1)
    return lo, max(lo, hi)


def sgm_aggregate(cost: np.ndarray, grey: np.ndarray, p1: float | None = None, p2: float | None = None,
                  edge_gain: float | None = None, carry: np.ndarray | None = None,
                  keep_row: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Semi-global aggregation (Hirschmüller 2008) of a cost volume ``(h, w, D)`` along the four
    horizontal and vertical paths; the large-jump penalty is lowered across image edges of ``grey``.
    Returns the summed path costs (same shape) and the downward path's costs at row ``keep_row``
    (``carry`` continues that path from the row above the volume: strips of one image)."""
    p1 = P1 if p1 is None else p1
    p2 = P2 if p2 is None else p2
    edge_gain = EDGE_GAIN if edge_gain is None else edge_gain
    h, w, D = cost.shape
    total = np.zeros_like(cost)
    p1f = np.float32(p1)

    kept: list[np.ndarray] = []

    def run(get, put, steps: int, edges: np.ndarray, start: np.ndarray | None = None) -> None:
        if start is None:
            prev = get(0).copy()
            put(0, prev)
            first = 1
        else:
            prev, first = start, 0
        for k in range(first, steps):
            c = get(k)
            m = prev.min(axis=1, keepdims=True)
            jump = m + edges[k][:, None]
            nxt = np.minimum(prev, jump)
            np.minimum(nxt[:, 1:], prev[:, :-1] + p1f, out=nxt[:, 1:])
            np.minimum(nxt[:, :-1], prev[:, 1:] + p1f, out=nxt[:, :-1])
            nxt -= m
            nxt += c
            put(k, nxt)
            prev = nxt

    gx = np.abs(np.diff(grey, axis=1, prepend=grey[:, :1]))            # (h, w): step into column x
    gy = np.abs(np.diff(grey, axis=0, prepend=grey[:1, :]))            # step into row y
    pen_x = np.maximum(np.float32(p2) / (1.0 + np.float32(edge_gain) * gx), p1f * 1.5).astype(np.float32)
    pen_y = np.maximum(np.float32(p2) / (1.0 + np.float32(edge_gain) * gy), p1f * 1.5).astype(np.float32)
    px_t = np.ascontiguousarray(pen_x.T)                                 # (w, h): per column
    px_rev = np.ascontiguousarray(np.roll(pen_x, -1, axis=1)[:, ::-1].T)  # right to left: step from x+1 to x
    py_rev = np.ascontiguousarray(np.roll(pen_y, -1, axis=0)[::-1])

    def add_col(k, v):
        total[:, k, :] += v

    def add_col_rev(k, v):
        total[:, w - 1 - k, :] += v

    def add_row(k, v):
        total[k] += v
        if k == keep_row:
            kept.append(v.copy())

    def add_row_rev(k, v):
        total[h - 1 - k] += v

    run(lambda k: cost[:, k, :], add_col, w, px_t)
    run(lambda k: cost[:, w - 1 - k, :], add_col_rev, w, px_rev)
    run(lambda k: cost[k], add_row, h, pen_y, carry)
    run(lambda k: cost[h - 1 - k], add_row_rev, h, py_rev)
    return total, (kept[0] if kept else None)


def _strip_cost(reference: np.ndarray, neighbours: Sequence[Neighbour], ds: np.ndarray, a: int, b: int,
                window_px: int, check=None) -> np.ndarray:
    """The occlusion-aware matching cost of rows [a, b) of ``reference`` at every candidate:
    ``(b − a, w, D)`` float32 (module docstring)."""
    h, w = reference.shape
    rows = b - a
    ref = np.ascontiguousarray(reference[a:b])
    out = np.empty((rows, w, len(ds)), np.float32)
    planes = [_half_planes(n.dx, n.dy) for n in neighbours]
    used = sorted({p for ps in planes for p in ps})
    weight = _plane_weights(neighbours, planes)
    ksize = (int(window_px), int(window_px))
    area = float(ksize[0] * ksize[1])
    tau = float(TRUNCATE)
    for i, d in enumerate(ds):
        if check is not None:
            check()
        sums: dict[int, np.ndarray] = {}
        # each neighbour counts where its sample lies inside it: a rectangle, summed through corners
        # (by columns alone while every neighbour covers the strip's rows: the usual case)
        spans: dict[int, list[tuple[int, int, int, int]]] = {p: [] for p in used}
        for n, ps in zip(neighbours, planes):
            sx, sy = -float(d) * n.dx, -float(d) * n.dy
            M = np.array([[1.0, 0.0, sx], [0.0, 1.0, sy + a]], np.float64)
            warped = cv2.warpAffine(n.image, M, (w, rows), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                    borderMode=cv2.BORDER_REPLICATE)
            ad = cv2.absdiff(ref, warped)
            np.minimum(ad, np.float32(tau), out=ad)
            x0, x1 = _valid_span(w, sx)
            y0, y1 = _valid_span(h, sy)
            y0, y1 = min(rows, max(0, y0 - a)), max(0, min(rows, y1 - a))
            if x0 > 0 or x1 < w or y0 > 0 or y1 < rows:     # outside the neighbour: no sample
                ad[:y0] = 0.0
                ad[y1:] = 0.0
                ad[:, :x0] = 0.0
                ad[:, x1:] = 0.0
            for p in ps:
                sums[p] = ad if p not in sums else cv2.add(sums[p], ad)
                if y1 > y0 and x1 > x0:
                    spans[p].append((y0, y1, x0, x1))
        # the mean of the best BEST_OF half-planes' costs (a point hidden from one side is seen from
        # the others)
        costs = []
        for p in used:
            den = _window_count(spans[p], rows, w, ksize)
            num = cv2.boxFilter(sums[p], -1, ksize, normalize=False, borderType=cv2.BORDER_REFLECT)
            # where a half-plane saw the pixel through too few samples its cost is the truncation
            cost = num / np.maximum(den, np.float32(1e-6))
            np.copyto(cost, np.float32(tau), where=den <= 0.5 * area)
            costs.append(cost if weight[p] == 1.0 else cost * np.float32(weight[p]))
        half = [c for p, c in zip(used, costs) if p < len(HALF_PLANES)]
        best = _best_of(half, BEST_OF) if half else np.full((rows, w), tau, np.float32)
        for p, c in zip(used, costs):
            if p >= len(HALF_PLANES):           # a line where it matches better
                best = cv2.min(best, c * np.float32(LINE_WEIGHT))
        out[:, :, i] = best
    return out


def _window_count(spans: list[tuple[int, int, int, int]], rows: int, w: int, ksize: tuple[int, int]) -> np.ndarray:
    """How many samples of the rectangles ``spans`` (y0, y1, x0, x1) fall in each pixel's window:
    ``(rows, w)``, or ``(1, w)`` (broadcasts) when every rectangle covers all rows."""
    if all(y0 == 0 and y1 == rows for y0, y1, _, _ in spans):
        line = np.zeros(w + 1, np.float32)
        for _, _, x0, x1 in spans:
            line[x0] += 1.0
            line[x1] -= 1.0
        count = np.cumsum(line)[:w].astype(np.float32)[None, :]
        return cv2.boxFilter(np.repeat(count, ksize[1], axis=0), -1, ksize, normalize=False,
                             borderType=cv2.BORDER_REFLECT)[:1]
    corners = np.zeros((rows + 1, w + 1), np.float32)
    for y0, y1, x0, x1 in spans:
        corners[y0, x0] += 1.0
        corners[y0, x1] -= 1.0
        corners[y1, x0] -= 1.0
        corners[y1, x1] += 1.0
    count = np.cumsum(np.cumsum(corners, axis=0), axis=1)[:rows, :w].astype(np.float32)
    return cv2.boxFilter(count, -1, ksize, normalize=False, borderType=cv2.BORDER_REFLECT)


def _best_of(costs: list[np.ndarray], k: int) -> np.ndarray:
    """Per pixel, the mean of the ``k`` lowest of ``costs`` (all when there are no more)."""
    if len(costs) <= k:
        return sum(costs[1:], costs[0]) * np.float32(1.0 / len(costs))
    if k == 1:
        out = costs[0]
        for c in costs[1:]:
            out = cv2.min(out, c)
        return out
    if k == 2:                      # the lowest two, kept as they come (no sort)
        first, second = cv2.min(costs[0], costs[1]), cv2.max(costs[0], costs[1])
        for c in costs[2:]:
            second = cv2.min(second, cv2.max(first, c))
            first = cv2.min(first, c)
        return (first + second) * np.float32(0.5)
    stack = np.sort(np.stack(costs), axis=0)
    return stack[:k].mean(axis=0)


def light_field_disparity(reference: np.ndarray, neighbours: Sequence[Neighbour], d_min_px: float,
                          d_max_px: float, *, window_px: int | None = None, step_px: float | None = None,
                          volume_cells: int | None = None, check=None,
                          colour: np.ndarray | None = None) -> DenseResult:
    """Disparity and confidence of ``reference`` (grey float32 from :func:`prepare`) from its
    ``neighbours`` anywhere in the grid (module docstring); the search covers [d_min_px, d_max_px]
    with a margin of one candidate. Memory: at most ``volume_cells`` cost cells (strips of rows).
    ``check()`` is called between candidates (cancel). ``colour``: the reference in colour
    (:func:`prepare_colour`), for the pixels of depth edges (:func:`colour_edges`)."""
    if not neighbours:
        raise ValueError("no neighbour view to compare the reference with")
    window_px = int(window_px or WINDOW_PX)
    step_px = float(step_px or SWEEP_STEP_PX)
    volume_cells = int(volume_cells or VOLUME_CELLS)
    h, w = reference.shape
    max_offset = max(float(np.hypot(n.dx, n.dy)) for n in neighbours)
    # the farthest neighbour moves by at most step_px between candidates, and no two candidates lie
    # more than MAX_CANDIDATE_STEP_PX apart (sub-pixel precision for a small neighbourhood)
    ds = disparity_candidates(d_min_px, d_max_px, max(max_offset, step_px / MAX_CANDIDATE_STEP_PX), step_px)
    pad = ds[1] - ds[0]
    ds = np.concatenate([[ds[0] - pad], ds, [ds[-1] + pad]]).astype(np.float64)
    D = len(ds)
    raw_ref, raw_nbs = reference, neighbours
    reference = _normalised(reference)
    neighbours = [Neighbour(_normalised(n.image), n.dx, n.dy) for n in neighbours]
    top = window_px // 2 + 1            # rows above a strip: its cost window; the downward path carries on
    core = max(8, int(volume_cells // max(1, w * D)) - top - STRIP_OVERLAP)
    disp = np.full((h, w), np.nan, np.float32)
    conf = np.zeros((h, w), np.float32)
    step = np.float32(ds[1] - ds[0])
    carry = None
    y = 0
    while y < h:
        y1 = min(h, y + core)
        a, b = max(0, y - top), min(h, y1 + STRIP_OVERLAP)
        cost = _strip_cost(reference, neighbours, ds, a, b, window_px, check)
        next_a = max(0, y1 - top)
        total, carry = sgm_aggregate(cost, reference[a:b], carry=carry, keep_row=next_a - 1 - a if y1 < h else None)
        best = np.argmin(total, axis=2)
        r_, c_ = np.indices(best.shape)
        ii = np.clip(best, 1, D - 2)
        off = _subpixel(total, cost, ii)
        d_map = (ds[0] + (ii.astype(np.float32) + off) * step).astype(np.float32)
        # confidence: the matching cost at the answer against the best one at least 2 candidates away
        # (the lowest cost below and above that gap: running minima from either end)
        c_best = cost[r_, c_, ii]
        below = np.minimum.accumulate(cost, axis=2, out=total)          # total is not needed any more
        lo_i = ii - 3
        c_far = np.where(lo_i >= 0, below[r_, c_, np.maximum(lo_i, 0)], np.inf)
        above = np.minimum.accumulate(cost[:, :, ::-1], axis=2)[:, :, ::-1]
        hi_i = ii + 3
        c_far = np.minimum(c_far, np.where(hi_i < D, above[r_, c_, np.minimum(hi_i, D - 1)], np.inf))
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.where(c_far > 0, 1.0 - c_best / c_far, 0.0)
        q = np.clip(np.nan_to_num(q, nan=0.0, posinf=0.0, neginf=0.0), 0.0, 1.0).astype(np.float32)
        q[(best == 0) | (best == D - 1)] = 0.0       # at the end of the range: not a minimum
        disp[y:y1] = d_map[y - a:y1 - a]
        conf[y:y1] = q[y - a:y1 - a]
        y = y1
    for _ in range(SNAP_PASSES):
        disp = snap_edges(raw_ref, raw_nbs, disp)
    if colour is not None and COLOUR_RADIUS_PX > 0:
        for _ in range(COLOUR_PASSES):
            disp = colour_edges(disp, colour)
    if PLANE_WINDOW_PX > 1:
        disp = fit_planes(disp)
    return DenseResult(disp, conf, D, len(neighbours))


def _subpixel(total: np.ndarray, cost: np.ndarray, ii: np.ndarray) -> np.ndarray:
    """Sub-pixel offset (in candidates) of the answer ``ii`` (see :data:`REFINE_SHARP`)."""
    D = total.shape[2]
    r_, c_ = np.indices(ii.shape)
    jj = np.clip(ii, 2, D - 3)
    y0, y1, y2, y3, y4 = (total[r_, c_, jj + k] for k in (-2, -1, 0, 1, 2))
    slope = (-2 * y0 - y1 + y3 + 2 * y4) / 10.0                  # least squares over the five
    curve = (2 * y0 - y1 - 2 * y2 - y3 + 2 * y4) / 14.0
    with np.errstate(divide="ignore", invalid="ignore"):
        vertex = np.where(curve > 1e-12, -slope / (2 * np.maximum(curve, 1e-12)), 0.0)
    off = np.clip(np.nan_to_num(vertex), -1.0, 1.0) + (jj - ii)
    c0, c1, c2 = (cost[r_, c_, ii + k] for k in (-1, 0, 1))
    if REFINE_WINDOW_PX > 1:
        kw = (REFINE_WINDOW_PX, REFINE_WINDOW_PX)
        c0, c1, c2 = (cv2.boxFilter(np.ascontiguousarray(c, dtype=np.float32), -1, kw, borderType=cv2.BORDER_REFLECT)
                      for c in (c0, c1, c2))
    sharp = (c1 <= c0) & (c1 <= c2) & (np.minimum(c0, c2) - c1 > REFINE_SHARP * c1)
    fine = _equiangular(c0, c1, c2)
    off = np.where(sharp & (np.abs(fine - off) < REFINE_AGREE), fine, off)
    return off.astype(np.float32)


def _equiangular(c0: np.ndarray, c1: np.ndarray, c2: np.ndarray) -> np.ndarray:
    """Offset of the minimum from the middle of three equally spaced costs, V-shaped fit (suits
    absolute differences better than a parabola: less pixel-locking)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        off = 0.5 * (c0 - c2) / np.maximum(np.maximum(c0, c2) - c1, 1e-12)
    return np.clip(np.nan_to_num(off, nan=0.0), -0.5, 0.5).astype(np.float32)


def _normalised(grey: np.ndarray) -> np.ndarray:
    """Local contrast normalisation: (g − local mean) / local standard deviation (scaled)."""
    k = (LCN_WINDOW_PX, LCN_WINDOW_PX)
    mu = cv2.blur(grey, k, borderType=cv2.BORDER_REFLECT)
    var = cv2.blur(grey * grey, k, borderType=cv2.BORDER_REFLECT) - mu * mu
    return ((grey - mu) / np.sqrt(np.maximum(var, 0.0) + np.float32(LCN_EPS)) * np.float32(LCN_SCALE)).astype(np.float32)


def _sample(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``image`` at the points (u, v), bilinear (remap takes maps under 32767 columns: rows of 4096)."""
    n = len(u)
    rows = max(1, -(-n // 4096))
    mu = np.zeros(rows * 4096, np.float32)
    mv = np.zeros(rows * 4096, np.float32)
    mu[:n], mv[:n] = u, v
    out = cv2.remap(image, mu.reshape(rows, 4096), mv.reshape(rows, 4096), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1)[:n]


def snap_edges(reference: np.ndarray, neighbours: Sequence[Neighbour], disp: np.ndarray) -> np.ndarray:
    """At depth edges, the farther surface unless the nearer matches clearly better: where the
    disparities within :data:`SNAP_WINDOW_PX` span more than :data:`EDGE_JUMP_PX`, a pixel nearer to
    the local maximum than to the minimum takes the minimum unless its own grey value matches the
    maximum better by :data:`FAR_BIAS` in the best half-plane or line of views (a window would
    straddle the edge: the cost here is the pixel's own)."""
    k = np.ones((SNAP_WINDOW_PX, SNAP_WINDOW_PX), np.uint8)
    finite = np.isfinite(disp)
    lo = cv2.erode(np.where(finite, disp, np.float32(1e6)).astype(np.float32), k)
    hi = cv2.dilate(np.where(finite, disp, np.float32(-1e6)).astype(np.float32), k)
    edge = finite & (hi - lo > EDGE_JUMP_PX) & (lo < 1e5) & (hi > -1e5)
    if not edge.any():
        return disp
    ys, xs = np.nonzero(edge)
    c_lo, c_hi = _pixel_costs(reference, neighbours, ys, xs, (lo[ys, xs], hi[ys, xs]))
    out = disp.copy()
    d0 = disp[ys, xs]
    on_near = (hi[ys, xs] - d0) < (d0 - lo[ys, xs])
    # a pixel on the nearer surface goes to the farther one unless the nearer matches clearly better
    # (a window fattens the nearer surface)
    take_lo = on_near & (c_lo * FAR_BIAS <= c_hi)
    out[ys, xs] = np.where(take_lo, lo[ys, xs], d0)
    return out


def colour_edges(disp: np.ndarray, colour: np.ndarray, radius: int | None = None) -> np.ndarray:
    """At depth edges (the disparities within :data:`SNAP_WINDOW_PX` span more than
    :data:`EDGE_JUMP_PX`), each pixel takes the surface of the pixel within ``radius``
    (:data:`COLOUR_RADIUS_PX`) whose colour is nearest its own (the two nearest of each side): the local maximum where that pixel is
    on the nearer surface (nearer to the maximum than to the minimum), else the local minimum. An
    anti-aliased pixel of a silhouette mostly showing the background matches the nearer surface's
    edge in the views (it moves with it) but looks like the background. A tie goes to the farther, as
    does a pixel of the nearer surface with none of it around."""
    radius = COLOUR_RADIUS_PX if radius is None else int(radius)
    img = colour if colour.ndim == 3 else colour[:, :, None]
    if img.shape[:2] != disp.shape:
        raise ValueError(f"colour {img.shape[1]} x {img.shape[0]} px is not the map's {disp.shape[1]} x {disp.shape[0]}")
    k = np.ones((SNAP_WINDOW_PX, SNAP_WINDOW_PX), np.uint8)
    finite = np.isfinite(disp)
    lo = cv2.erode(np.where(finite, disp, np.float32(1e6)).astype(np.float32), k)
    hi = cv2.dilate(np.where(finite, disp, np.float32(-1e6)).astype(np.float32), k)
    edge = finite & (hi - lo > EDGE_JUMP_PX) & (lo < 1e5) & (hi > -1e5)
    if not edge.any():
        return disp
    ys, xs = np.nonzero(edge)
    pad_d = np.pad(np.where(finite, disp, np.nan), radius, mode="edge")
    pad_c = np.pad(img, ((radius, radius), (radius, radius), (0, 0)), mode="edge")
    own = img[ys, xs]
    d_lo, d_hi = lo[ys, xs], hi[ys, xs]
    inf = np.float32(np.inf)
    first = {side: np.full(len(ys), inf, np.float32) for side in ("near", "far")}
    second = {side: np.full(len(ys), inf, np.float32) for side in ("near", "far")}
    for oy in range(-radius, radius + 1):
        for ox in range(-radius, radius + 1):
            if oy == 0 and ox == 0:
                continue
            dv = pad_d[ys + radius + oy, xs + radius + ox]
            dist = np.sqrt(((pad_c[ys + radius + oy, xs + radius + ox] - own) ** 2).sum(axis=1))
            near = (d_hi - dv) < (dv - d_lo)                      # NaN compares False: neither side
            far = (dv - d_lo) <= (d_hi - dv)
            for side, m in (("near", near), ("far", far)):
                d_ = np.where(m, dist, inf)
                second[side] = np.minimum(second[side], np.maximum(first[side], d_))
                first[side] = np.minimum(first[side], d_)
    # the mean distance of the two nearest of each side (one pixel given the wrong side does not
    # pull its neighbours over)
    best_near = 0.5 * (first["near"] + second["near"])
    best_far = 0.5 * (first["far"] + second["far"])
    d0 = disp[ys, xs]
    on_near = (d_hi - d0) < (d0 - d_lo)
    out = disp.copy()
    # a tie goes to the farther (a window fattens the nearer; 8-bit colours tie often), as does a
    # pixel with no pixel of the nearer surface around (a lone one)
    out[ys, xs] = np.where(best_near < best_far, np.where(on_near, d0, d_hi), np.where(on_near, d_lo, d0))
    return out


def _pixel_costs(reference: np.ndarray, neighbours: Sequence[Neighbour], ys: np.ndarray, xs: np.ndarray,
                 candidates: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The matching cost of the pixels (ys, xs) alone at each of ``candidates`` (a disparity per
    pixel): the lowest over the half-planes and lines of views (each weighted as in the sweep)."""
    h, w = reference.shape
    planes = [_half_planes(n.dx, n.dy) for n in neighbours]
    used = sorted({p for ps in planes for p in ps})
    weight = _plane_weights(neighbours, planes)
    ref = reference[ys, xs]
    tau = np.float32(TRUNCATE)
    best_cost = []
    for cand in candidates:
        sums = {p: np.zeros(len(ys), np.float32) for p in used}
        counts = {p: np.zeros(len(ys), np.float32) for p in used}
        for n, ps in zip(neighbours, planes):
            u = xs - cand * np.float32(n.dx)
            v = ys - cand * np.float32(n.dy)
            inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
            val = _sample(n.image, u, v)
            ad = np.minimum(np.abs(val - ref), tau) * inside
            for p in ps:
                sums[p] += ad
                counts[p] += inside
        cost = np.full(len(ys), np.inf, np.float32)
        for p in used:
            c = np.where(counts[p] >= 1, sums[p] / np.maximum(counts[p], 1), np.inf)
            cost = np.minimum(cost, c * np.float32(weight[p]))
        best_cost.append(cost)
    return best_cost



def fit_planes(disp: np.ndarray, window_px: int | None = None, inlier_px: float | None = None) -> np.ndarray:
    """Each pixel: the value at its centre of the plane fitted (least squares) to the disparities of
    its ``window_px`` neighbourhood (:data:`PLANE_WINDOW_PX`) that lie within ``inlier_px``
    (:data:`PLANE_INLIER_PX`) of its own; kept as it is where fewer than 6 do, or where the fit is
    degenerate (inliers on a line). NaN stays NaN and is no inlier."""
    r = int(window_px or PLANE_WINDOW_PX) // 2
    t = np.float32(PLANE_INLIER_PX if inlier_px is None else inlier_px)
    d = np.asarray(disp, np.float32)
    h, w = d.shape
    pad = np.pad(d, r, mode="reflect")
    n, sx, sy, sxx, syy, sxy, sq, sxq, syq = (np.zeros((h, w), np.float32) for _ in range(9))
    with np.errstate(invalid="ignore"):
        for oy in range(-r, r + 1):
            for ox in range(-r, r + 1):
                q = pad[r + oy:r + oy + h, r + ox:r + ox + w] - d          # relative to the pixel's own
                m = (np.abs(q) < t).astype(np.float32)
                qm = np.where(m > 0, q, np.float32(0.0))
                n += m
                sx += m * ox
                sy += m * oy
                sxx += m * (ox * ox)
                syy += m * (oy * oy)
                sxy += m * (ox * oy)
                sq += qm
                sxq += qm * ox
                syq += qm * oy
    # Cramer's rule for the plane's value at the centre (the first unknown of [n x y; x xx xy; y xy yy])
    det = n * (sxx * syy - sxy * sxy) - sx * (sx * syy - sxy * sy) + sy * (sx * sxy - sxx * sy)
    num = sq * (sxx * syy - sxy * sxy) - sx * (sxq * syy - sxy * syq) + sy * (sxq * sxy - sxx * syq)
    ok = np.isfinite(d) & (n >= 6) & (np.abs(det) > 1e-3 * np.maximum(n, 1) ** 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(ok, d + num / np.where(ok, det, 1.0), d)
    return out.astype(np.float32)
