"""A sparse, coloured point cloud from feature tracks and the rig's known camera poses.

Every camera of a light-field grid shares one orientation ``R`` and intrinsics ``K`` (the
calibration's, or the ideal camera's for rectified views) and sits at its known position ``C_i``
(``p ~ K · R · (X − C_i)``; :mod:`lfstudio.export.poses`). So nothing is estimated but the points:

1. SIFT features per view (:func:`lfstudio.calibration.features.detect`), matched between
   neighbours in each row and each column with the calibration's matcher (ratio test, mutual check,
   the one-epipole geometric check of a pure translation);
2. matches chained into **tracks** (union–find over (view, feature)); a track that meets one view
   twice is dropped;
3. each track triangulated in closed form: with the ray ``d_i = Rᵀ K⁻¹ p_i`` scaled to ``d_z = 1`` and
   ``C_i`` on the plane z = 0, ``X = C_i + Z · d_i`` is linear in (X, Y, Z); least squares over the
   track (the reprojection error in normalised coordinates, one scale per point), then refined by
   Gauss–Newton on the pixel reprojection error;
4. kept when seen in at least ``min_track`` views, every observation within ``max_error_px`` of
   its reprojection, in front of the cameras, and with enough parallax across the track
   (``min_parallax_px``: the largest disparity between its views; a short baseline cannot fix depth);
5. coloured with the mean colour of its observations.

With more views than ``max_views`` an evenly spread sub-grid is used (every view of a 2121-view
grid adds nothing to a sparse cloud but time).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from lfstudio.dataset.grid import View
from lfstudio.jobs import CancelToken, Progress, no_progress

MIN_TRACK = 3
MAX_ERROR_PX = 1.0
MIN_PARALLAX_PX = 1.0
#: a point is kept when its views fix its depth to this fraction (1 sigma, from its own residuals)
MAX_DEPTH_SIGMA = 0.006
#: the smallest feature error assumed (px) when a point's residuals are smaller still
SIGMA_FLOOR_PX = 0.02
MAX_VIEWS = 45
DETECT_WIDTH_PX = 2000
#: views narrower than this are enlarged (whole factors) before features are detected
MIN_DETECT_WIDTH_PX = 800
DETECT_FEATURES = 6000
#: SIFT's contrast threshold: a quarter of OpenCV's 0.04, which finds ~150 keypoints on an HCI view (512 px,
#: smooth surfaces) and ~900 on a 400 px virtual-studio view; the strongest DETECT_FEATURES are kept
DETECT_CONTRAST = 0.01


@dataclass
class SparseCloud:
    """Triangulated points (rig frame, m) and where each was observed."""

    xyz_m: np.ndarray                     # (N, 3) float64
    rgb: np.ndarray                       # (N, 3) uint8
    error_px: np.ndarray                  # (N,) mean reprojection error of the point's observations
    views: list[View]                     # the views the features came from
    # per view: (k, 2) pixel coordinates (OpenCV: top-left pixel centre at 0, 0) and (k,) point index
    observations: dict[View, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    stats: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(len(self.xyz_m))

    def track_lengths(self) -> np.ndarray:
        n = np.zeros(len(self), int)
        for _, ids in self.observations.values():
            np.add.at(n, ids, 1)
        return n

    def all_errors_px(self) -> np.ndarray:
        """Reprojection error of every observation (px), in view order."""
        return self.stats.get("observation_errors_px", np.zeros(0))


def spread_views(views: Sequence[View], max_views: int = MAX_VIEWS) -> list[View]:
    """``views`` when at most ``max_views``, else an evenly spread sub-grid of them (whole rows and
    columns of the selection, so that neighbours in the sub-grid share a row or a column)."""
    cells = sorted({(r, c) for r, c in views})
    if len(cells) <= max_views:
        return [View(*v) for v in cells]
    rows = sorted({r for r, _ in cells})
    cols = sorted({c for _, c in cells})
    aspect = len(cols) / max(1, len(rows))
    n_rows = max(1, min(len(rows), int(round(np.sqrt(max_views / aspect)))))
    n_cols = max(1, min(len(cols), max_views // n_rows))

    def pick(seq, n):
        return [seq[int(round(i))] for i in np.linspace(0, len(seq) - 1, n)] if n > 1 else [seq[len(seq) // 2]]

    have = set(cells)
    return [View(r, c) for r in pick(rows, n_rows) for c in pick(cols, n_cols) if (r, c) in have]


def neighbour_pairs(views: Sequence[View]) -> list[tuple[View, View, str]]:
    """(a, b, "h") for b the next view right of a in its row, (a, b, "v") for the next below in its column."""
    have = sorted(set(views))
    by_row: dict[int, list[int]] = {}
    by_col: dict[int, list[int]] = {}
    for r, c in have:
        by_row.setdefault(r, []).append(c)
        by_col.setdefault(c, []).append(r)
    out = []
    for r, cs in by_row.items():
        cs = sorted(cs)
        out += [(View(r, a), View(r, b), "h") for a, b in zip(cs, cs[1:])]
    for c, rs in by_col.items():
        rs = sorted(rs)
        out += [(View(a, c), View(b, c), "v") for a, b in zip(rs, rs[1:])]
    return out


class _UnionFind:
    def __init__(self, n: int):
        self.parent = np.arange(n)

    def find(self, i: int) -> int:
        p = self.parent
        root = i
        while p[root] != root:
            root = p[root]
        while p[i] != root:
            p[i], i = root, p[i]
        return root

    def union(self, a: int, b: int) -> None:
        ra, rb = self.find(a), self.find(b)
        if ra != rb:
            self.parent[max(ra, rb)] = min(ra, rb)


def build_tracks(features: Mapping[View, np.ndarray], matches: Sequence[tuple[View, View, np.ndarray, np.ndarray]]
                 ) -> list[list[tuple[View, int]]]:
    """Tracks (lists of (view, feature index)) from pairwise matches given as coordinates: each
    matched coordinate is found among its view's features (exact: the matcher returns them)."""
    return tracks_and_ambiguous(features, matches)[0]


def tracks_and_ambiguous(features: Mapping[View, np.ndarray],
                         matches: Sequence[tuple[View, View, np.ndarray, np.ndarray]]
                         ) -> tuple[list[list[tuple[View, int]]], int]:
    """:func:`build_tracks` and how many tracks were dropped for meeting a view twice."""
    order = list(features)
    offset, total = {}, 0
    lookup = {}
    for v in order:
        offset[v] = total
        xy = np.asarray(features[v], np.float64)
        lookup[v] = {(float(x), float(y)): i for i, (x, y) in enumerate(xy)}
        total += len(xy)
    uf = _UnionFind(total)
    used = np.zeros(total, bool)
    for a, b, xa, xb in matches:
        la, lb = lookup[a], lookup[b]
        for (x1, y1), (x2, y2) in zip(np.asarray(xa, np.float64), np.asarray(xb, np.float64)):
            i, j = la.get((float(x1), float(y1))), lb.get((float(x2), float(y2)))
            if i is None or j is None:
                continue
            gi, gj = offset[a] + i, offset[b] + j
            used[gi] = used[gj] = True
            uf.union(gi, gj)
    groups: dict[int, list[tuple[View, int]]] = {}
    view_of = np.repeat(np.arange(len(order)), [len(features[v]) for v in order])
    for g in np.nonzero(used)[0]:
        v = order[view_of[g]]
        groups.setdefault(uf.find(int(g)), []).append((v, int(g - offset[v])))
    tracks = []
    ambiguous = 0
    for obs in groups.values():
        seen = [v for v, _ in obs]
        if len(set(seen)) == len(seen):        # a track that meets a view twice is ambiguous
            tracks.append(sorted(obs))
        else:
            ambiguous += 1
    return tracks, ambiguous


def triangulate(K: np.ndarray, R: np.ndarray, centres_m: np.ndarray, xy_px: np.ndarray, track: np.ndarray,
                n_tracks: int, iterations: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Points (n_tracks, 3) from observations: ``centres_m[k]`` and ``xy_px[k]`` of track ``track[k]``
    (module docstring, step 3); also the pixel reprojection error of each observation."""
    KR = K @ R
    KR_inv = np.linalg.inv(KR)
    p = np.column_stack([xy_px, np.ones(len(xy_px))])
    d = p @ KR_inv.T
    d = d[:, :2] / d[:, 2:3]                      # rays with d_z = 1 (rig frame)
    a, b = d[:, 0], d[:, 1]
    cx, cy = centres_m[:, 0], centres_m[:, 1]

    def s(values):
        return np.bincount(track, values, minlength=n_tracks)

    n = np.bincount(track, minlength=n_tracks).astype(float)
    M = np.zeros((n_tracks, 3, 3))
    M[:, 0, 0] = M[:, 1, 1] = n
    M[:, 0, 2] = M[:, 2, 0] = -s(a)
    M[:, 1, 2] = M[:, 2, 1] = -s(b)
    M[:, 2, 2] = s(a * a + b * b)
    rhs = np.column_stack([s(cx), s(cy), -s(a * cx + b * cy)])
    M[n < 2] = np.eye(3)
    X = np.linalg.solve(M, rhs[..., None])[..., 0]
    for _ in range(iterations):                   # Gauss–Newton on the pixel reprojection error
        rel = X[track] - centres_m
        q = rel @ KR.T
        z = q[:, 2:3]
        proj = q[:, :2] / z
        r = (proj - xy_px)                        # (k, 2)
        # d proj / d X = (KR[:2] - proj ⊗ KR[2]) / z
        J = (KR[None, :2, :] - proj[:, :, None] * KR[None, 2:3, :]) / z[:, :, None]   # (k, 2, 3)
        JtJ = np.zeros((n_tracks, 3, 3))
        Jtr = np.zeros((n_tracks, 3))
        np.add.at(JtJ, track, np.einsum("kia,kib->kab", J, J))
        np.add.at(Jtr, track, np.einsum("kia,ki->ka", J, r))
        ok = n >= 2
        JtJ[~ok] = np.eye(3)
        Jtr[~ok] = 0.0
        try:
            X = X - np.linalg.solve(JtJ, Jtr[..., None])[..., 0]
        except np.linalg.LinAlgError:
            break
    q = (X[track] - centres_m) @ KR.T
    err = np.hypot(*(q[:, :2] / q[:, 2:3] - xy_px).T)
    err[q[:, 2] <= 0] = np.inf
    return X, err


#: a followed observation is kept when tracking it back lands within this many pixels of where it
#: started (at the detection scale), and it lies within FOLLOW_MAX_MOVE_PX of the point's prediction
FOLLOW_BACK_PX = 0.1
FOLLOW_MAX_MOVE_PX = 3.0
FOLLOW_WINDOW_PX = 15

#: an observation found by following a track (not a SIFT feature): (x, y) in full-resolution pixels
_Followed = tuple[float, float]


def _xy_of(feats, v: View, i) -> tuple[float, float]:
    """The pixel of observation ``i`` in view ``v``: a SIFT feature's index or a followed (x, y)."""
    if isinstance(i, tuple):
        return i
    x, y = feats[v].xy[int(i)]
    return float(x), float(y)


def _follow_tracks(tracks, feats, greys, K: np.ndarray, R: np.ndarray, centres, used):
    """Each track (two or more SIFT observations) followed into every view: triangulated, projected
    into each view and aligned there to its reference view's patch (pyramidal Lucas–Kanade on the
    detection images, from the prediction; kept when tracking back returns within
    :data:`FOLLOW_BACK_PX` and it moved at most :data:`FOLLOW_MAX_MOVE_PX` from the prediction).
    The reference is the track's view nearest the middle of the grid, its SIFT position the point's
    anchor. Sub-pixel patch alignment of every view instead of a few SIFT positions chained between
    neighbours: on a 5 × 3 capture at 400 px the neighbours-only tracks fixed the depth of 28 points
    (issue 37)."""
    import cv2

    obs_view = [v for t in tracks for v, _ in t]
    obs_track = np.repeat(np.arange(len(tracks)), [len(t) for t in tracks])
    xy = np.array([_xy_of(feats, v, i) for t in tracks for v, i in t], np.float64).reshape(-1, 2)
    C = np.array([centres[v] for v in obs_view])
    X, _ = triangulate(K, R, C, xy, obs_track, len(tracks))
    mid = np.mean([centres[v] for v in used], axis=0)
    KR = K @ R
    out = [dict(t) for t in tracks]
    ref_of = [min(t, key=lambda o: (float(np.sum((centres[o[0]] - mid) ** 2)), o[0]))[0] for t in tracks]
    ok_point: np.ndarray = np.asarray(np.isfinite(X).all(axis=1))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.001)
    win = (FOLLOW_WINDOW_PX, FOLLOW_WINDOW_PX)
    by_ref: dict[View, list[int]] = {}
    for k, r in enumerate(ref_of):
        if ok_point[k]:
            by_ref.setdefault(r, []).append(k)
    for ref, ids in by_ref.items():
        idx = np.array(ids)
        s_ref = feats[ref].scale
        start_full = np.array([_xy_of(feats, ref, out[k][ref]) for k in ids], np.float64)
        start = ((start_full + 0.5) / s_ref - 0.5).astype(np.float32)
        for v in used:
            if v == ref:
                continue
            q = (X[idx] - centres[v]) @ KR.T
            front = q[:, 2] > 0
            pred_full = q[:, :2] / np.where(front, q[:, 2], 1.0)[:, None]
            s_v = feats[v].scale
            pred = ((pred_full + 0.5) / s_v - 0.5).astype(np.float32)
            h, w = greys[v].shape[:2]
            m = FOLLOW_WINDOW_PX / 2.0
            inside = front & (pred[:, 0] >= m) & (pred[:, 0] <= w - 1 - m) & (pred[:, 1] >= m) & (pred[:, 1] <= h - 1 - m)
            if not inside.any():
                continue
            p0 = start[inside].reshape(-1, 1, 2)
            p1 = pred[inside].reshape(-1, 1, 2).copy()
            p1, st, _ = cv2.calcOpticalFlowPyrLK(greys[ref], greys[v], p0, p1, winSize=win, maxLevel=1,
                                                 criteria=criteria, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
            back, st2, _ = cv2.calcOpticalFlowPyrLK(greys[v], greys[ref], p1, p0.copy(), winSize=win, maxLevel=1,
                                                    criteria=criteria, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
            p1, back = p1.reshape(-1, 2), back.reshape(-1, 2)
            good = ((st.ravel() == 1) & (st2.ravel() == 1)
                    & (np.hypot(*(back - start[inside]).T) <= FOLLOW_BACK_PX)
                    & (np.hypot(*(p1 - pred[inside]).T) * s_v <= FOLLOW_MAX_MOVE_PX))
            found = (p1.astype(np.float64) + 0.5) * s_v - 0.5
            for k, g, xy_v in zip(idx[inside], good, found):
                if g:
                    out[k][v] = (float(xy_v[0]), float(xy_v[1]))
                else:
                    out[k].pop(v, None)      # a SIFT match the patch does not confirm is left out too
    return [sorted(t.items()) for t in out]


def _srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear [0, 1] → 8-bit sRGB (the colour a point cloud viewer shows)."""
    x = np.clip(linear, 0.0, 1.0)
    return 255.0 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def sparse_cloud(views: Sequence[View], image_of: Callable[[View], np.ndarray], K: np.ndarray, R: np.ndarray,
                 centre_of: Callable[[View], np.ndarray], *, min_track: int = MIN_TRACK,
                 max_error_px: float = MAX_ERROR_PX, min_parallax_px: float = MIN_PARALLAX_PX,
                 max_depth_sigma: float = MAX_DEPTH_SIGMA, sigma_floor_px: float = SIGMA_FLOOR_PX,
                 max_views: int = MAX_VIEWS, detect_width_px: int = DETECT_WIDTH_PX,
                 max_features: int = DETECT_FEATURES, threads: int = 2, refine: bool = True,
                 progress: Progress = no_progress, cancel: CancelToken | None = None) -> SparseCloud:
    """The sparse cloud of ``views`` (module docstring). ``image_of(view)``: its (h, w, 3) RGB image
    (uint8 or uint16) in the pixels ``K`` describes; ``centre_of(view)``: its camera centre (m)."""
    import cv2

    from lfstudio.calibration.features import Features, match_pairs

    cancel = cancel or CancelToken()
    used = spread_views(views, max_views)
    pairs = neighbour_pairs(used)
    total = len(used) + 2
    progress(0, total, "points: features")
    feats: dict[View, Features] = {}
    colours: dict[View, np.ndarray] = {}
    greys: dict[View, np.ndarray] = {}
    for i, v in enumerate(used):
        cancel.check()
        rgb = image_of(v)
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        if grey.dtype != np.uint8:
            lo, hi = np.percentile(grey, (0.5, 99.8))
            grey = np.clip((grey.astype(np.float32) - lo) * (255.0 / max(hi - lo, 1e-6)), 0, 255).astype(np.uint8)
        scale = 1.0
        if detect_width_px and grey.shape[1] > detect_width_px:
            scale = grey.shape[1] / float(detect_width_px)
            grey = cv2.resize(grey, (detect_width_px, int(round(grey.shape[0] / scale))), interpolation=cv2.INTER_AREA)
            scale = rgb.shape[1] / grey.shape[1]
        elif grey.shape[1] < MIN_DETECT_WIDTH_PX:     # small views: features (and their patches) on a larger copy
            up = int(np.ceil(MIN_DETECT_WIDTH_PX / grey.shape[1]))
            grey = cv2.resize(grey, (grey.shape[1] * up, grey.shape[0] * up), interpolation=cv2.INTER_CUBIC)
            scale = rgb.shape[1] / grey.shape[1]
        kps, desc = cv2.SIFT.create(nfeatures=int(max_features), contrastThreshold=DETECT_CONTRAST).detectAndCompute(grey, None)
        greys[v] = grey
        xy = (np.array([k.pt for k in kps], np.float64).reshape(-1, 2) + 0.5) * scale - 0.5
        feats[v] = Features(xy.astype(np.float32), (desc if desc is not None else np.zeros((0, 128))).astype(np.float32),
                            (rgb.shape[1], rgb.shape[0]), scale)
        colours[v] = rgb
        progress(i + 1, total, f"points: features of {len(used)} views")
    cancel.check()
    results = match_pairs(feats, pairs, threads=threads, check=cancel.check)
    progress(len(used) + 1, total, "points: triangulating")
    tracks, n_ambiguous = tracks_and_ambiguous({v: f.xy for v, f in feats.items()},
                                               [(a, b, m.xy_a, m.xy_b) for (a, b, _), m in zip(pairs, results)])
    centres = {v: np.asarray(centre_of(v), float) for v in used}
    Kf, Rf = np.asarray(K, float), np.asarray(R, float)
    if refine and tracks:
        # every track of two or more views: triangulated, then followed into every view (module docstring)
        tracks = _follow_tracks(tracks, feats, greys, Kf, Rf, centres, used)
    n_short = sum(1 for t in tracks if len(t) < min_track)
    tracks = [t for t in tracks if len(t) >= min_track]
    if not tracks:
        progress(total, total, "points: none")
        return SparseCloud(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0), list(used), {},
                           {"tracks": n_short + n_ambiguous, "pairs": len(pairs), "views": len(used),
                            "observation_errors_px": np.zeros(0),
                            "dropped": {"tracks shorter than %d views" % min_track: n_short,
                                        "tracks meeting a view twice": n_ambiguous}})
    obs_view = [v for t in tracks for v, _ in t]
    obs_track = np.repeat(np.arange(len(tracks)), [len(t) for t in tracks])
    xy = np.array([_xy_of(feats, v, i) for t in tracks for v, i in t], np.float64).reshape(-1, 2)
    C = np.array([centres[v] for v in obs_view])
    X, err = triangulate(Kf, Rf, C, xy, obs_track, len(tracks))
    # filters: every observation close to its reprojection, in front, enough parallax across the track
    worst = np.full(len(tracks), 0.0)
    np.maximum.at(worst, obs_track, err)
    f_px = float(K[0, 0])
    depth = X[:, 2]
    cx_min = np.full(len(tracks), np.inf)
    cx_max = np.full(len(tracks), -np.inf)
    cy_min, cy_max = cx_min.copy(), cx_max.copy()
    np.minimum.at(cx_min, obs_track, C[:, 0])
    np.maximum.at(cx_max, obs_track, C[:, 0])
    np.minimum.at(cy_min, obs_track, C[:, 1])
    np.maximum.at(cy_max, obs_track, C[:, 1])
    baseline = np.hypot(cx_max - cx_min, cy_max - cy_min)
    with np.errstate(divide="ignore", invalid="ignore"):
        parallax = f_px * baseline / depth
    # how well the views fix the depth: sigma_Z / Z = sigma_px * Z / (f * B_eff), B_eff the spread of the
    # track's camera centres (least squares over n views), sigma_px the point's own rms error (floored)
    n_t = np.bincount(obs_track, minlength=len(tracks)).astype(float)
    mx = np.bincount(obs_track, C[:, 0], minlength=len(tracks)) / n_t
    my = np.bincount(obs_track, C[:, 1], minlength=len(tracks)) / n_t
    spread = np.sqrt(np.bincount(obs_track, (C[:, 0] - mx[obs_track]) ** 2 + (C[:, 1] - my[obs_track]) ** 2,
                                 minlength=len(tracks)))
    rms = np.sqrt(np.bincount(obs_track, np.where(np.isfinite(err), err, 1e6) ** 2, minlength=len(tracks)) / n_t)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth_sigma = np.maximum(rms, sigma_floor_px) * depth / (f_px * spread)
    finite = np.isfinite(X).all(axis=1)
    tests = (("behind the cameras", (depth > 0) & finite),
             (f"an observation more than {max_error_px:g} px from its reprojection", worst <= max_error_px),
             (f"parallax under {min_parallax_px:g} px", parallax >= min_parallax_px),
             (f"depth not fixed to {100 * max_depth_sigma:g} % (1σ)", depth_sigma <= max_depth_sigma))
    keep = np.ones(len(tracks), bool)
    dropped = {"tracks shorter than %d views" % min_track: n_short, "tracks meeting a view twice": n_ambiguous}
    for reason, ok in tests:          # each track counted once, under the first test it fails
        dropped[reason] = int(np.count_nonzero(keep & ~ok))
        keep &= ok
    new_id = np.full(len(tracks), -1)
    new_id[keep] = np.arange(int(keep.sum()))
    observations: dict[View, tuple[list, list]] = {}
    rgb_sum = np.zeros((int(keep.sum()), 3))
    for k, (v, t) in enumerate(zip(obs_view, obs_track)):
        pid = new_id[t]
        if pid < 0:
            continue
        o = observations.setdefault(v, ([], []))
        o[0].append(xy[k])
        o[1].append(pid)
        img = colours[v]
        u_, v_ = int(round(xy[k, 0])), int(round(xy[k, 1]))
        px = img[min(max(v_, 0), img.shape[0] - 1), min(max(u_, 0), img.shape[1] - 1)].astype(float)
        rgb_sum[pid] += _srgb8(px / 65535.0) if img.dtype == np.uint16 else px
    n_obs = np.bincount(new_id[obs_track][new_id[obs_track] >= 0], minlength=int(keep.sum()))
    rgb = np.clip(np.rint(rgb_sum / np.maximum(n_obs, 1)[:, None]), 0, 255).astype(np.uint8)
    mean_err = np.bincount(obs_track, err, minlength=len(tracks)) / np.maximum(np.bincount(obs_track, minlength=len(tracks)), 1)
    kept_errors = err[keep[obs_track]]
    progress(total, total, f"points: {int(keep.sum())}")
    return SparseCloud(X[keep], rgb, mean_err[keep], list(used),
                       {v: (np.array(a, np.float64).reshape(-1, 2), np.array(b, int)) for v, (a, b) in observations.items()},
                       {"tracks": len(tracks) + n_short + n_ambiguous, "pairs": len(pairs), "views": len(used),
                        "observation_errors_px": kept_errors, "dropped": dropped,
                        "filters": {"min_track": min_track, "max_error_px": max_error_px,
                                    "max_depth_sigma": max_depth_sigma, "sigma_floor_px": sigma_floor_px,
                                    "min_parallax_px": min_parallax_px}})
