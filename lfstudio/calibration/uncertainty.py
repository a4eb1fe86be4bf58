"""What the fit's uncertainty means in pixels: the rectification error it allows, and bounds on it.

A *probe* is an ideal correspondence in the rectified frame: a point at ``q_a`` in one view and
``q_b`` in the other of a horizontal (rows must agree) or vertical pair. With the truth ``p_t`` and
the estimate ``p̂`` (both ``[rx, ry, rz, cx offset, cy offset]``), the probe's captured points are
``H(p_t)⁻¹ q`` and its rectification error is the v- (u-) difference after ``H(p̂)``; linearised,
``e ≈ J · (p̂ − p_t)``.

- :func:`corner_probes`: the four image corners of a full grid row (a horizontal pair as far apart
  as the grid's first and last column) and a full grid column, at the nearest scene depth (the
  largest disparity per mm of baseline the matches show). Their largest error is the "rectification
  error at the image corners" a report states.
- :func:`error_bounds`: the 68.3 % and 95.4 % quantiles (the "1σ" and "2σ" bounds) of an error
  metric (RMS or max over the probes) when ``p̂ − p_t`` follows the fit's covariance, by sampling.
  The simulation checks these bounds against the true error (coverage).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from lfstudio.calibration.fit import FitResult, PairMatches, homography_of, signed_residuals
from lfstudio.calibration.model import CalibrationUncertainty, apply_homography

LEVELS = (0.6827, 0.9545)      # the probabilities of ±1σ and ±2σ of a normal distribution
_STEPS = np.array([1e-3, 1e-3, 1e-3, 0.05, 0.05])


@dataclass
class Probes:
    q_a: np.ndarray             # N × 2 rectified (ideal) pixels
    q_b: np.ndarray
    horizontal: np.ndarray      # bool per probe


def corner_probes(image_size_px: Sequence[int], row_disparity_px: float | None,
                  column_disparity_px: float | None) -> Probes:
    """Probes at the four image corners: a horizontal pair with ``row_disparity_px`` between its
    points and a vertical pair with ``column_disparity_px`` (None or 0: no probe of that kind); the
    two points sit symmetrically about the corner."""
    w, h = image_size_px
    corners = np.array([[0.0, 0.0], [w - 1.0, 0.0], [0.0, h - 1.0], [w - 1.0, h - 1.0]])
    qa, qb, hor = [], [], []
    for disparity, direction in ((row_disparity_px, np.array([1.0, 0.0])), (column_disparity_px, np.array([0.0, 1.0]))):
        if not disparity:
            continue
        half = 0.5 * float(disparity) * direction
        qa.append(corners + half)        # view a sees the point shifted right (down) of view b
        qb.append(corners - half)
        hor.append(np.full(4, direction[0] > 0))
    if not qa:
        return Probes(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, bool))
    return Probes(np.concatenate(qa), np.concatenate(qb), np.concatenate(hor))


def probe_errors(probes: Probes, estimate: ArrayLike, truth: ArrayLike, focal_length_px: float,
                 image_size_px: Sequence[int]) -> np.ndarray:
    """Rectification error of each probe (px) when ``estimate`` is used and ``truth`` is the camera."""
    H_true_inv = np.linalg.inv(homography_of(_five(truth), focal_length_px, image_size_px))
    xa = apply_homography(H_true_inv, probes.q_a)
    xb = apply_homography(H_true_inv, probes.q_b)
    return signed_residuals(homography_of(_five(estimate), focal_length_px, image_size_px), xa, xb,
                            probes.horizontal)


def probe_jacobian(probes: Probes, estimate: ArrayLike, focal_length_px: float,
                   image_size_px: Sequence[int]) -> np.ndarray:
    """J (N × 5) with ``e ≈ J · (estimate − truth)``."""
    p = _five(estimate)
    cols = []
    for k, step in enumerate(_STEPS):
        d = np.zeros(5)
        d[k] = step
        cols.append((probe_errors(probes, p, p - d, focal_length_px, image_size_px)
                     - probe_errors(probes, p, p + d, focal_length_px, image_size_px)) / (2 * step))
    return np.column_stack(cols)


def error_bounds(J: np.ndarray, covariance: np.ndarray, metric: str = "max", levels: Sequence[float] = LEVELS,
                 samples: int = 4000, seed: int = 0) -> list[float]:
    """Quantiles of ``metric`` ("max": largest |e|, "rms") of ``e = J · δ``, ``δ ~ N(0, covariance)``."""
    if J.size == 0:
        return [0.0 for _ in levels]
    cov = np.asarray(covariance, float)
    n = cov.shape[0]
    J = J[:, :n]
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    L = vecs * np.sqrt(np.clip(vals, 0.0, None))
    delta = np.random.default_rng(seed).standard_normal((samples, n)) @ L.T
    if metric == "max":
        m = np.max(np.abs(delta @ J.T), axis=1)
    else:   # rms² = δᵀ (JᵀJ / N) δ: no need to form every probe's error
        M = J.T @ J / len(J)
        m = np.sqrt(np.maximum(np.einsum("si,ij,sj->s", delta, M, delta), 0.0))
    return [float(np.quantile(m, q)) for q in levels]


def metric_of(errors: np.ndarray, metric: str = "max") -> float:
    e = np.asarray(errors, float)
    if e.size == 0:
        return 0.0
    return float(np.max(np.abs(e))) if metric == "max" else float(np.sqrt(np.mean(e * e)))


def nearest_disparity_per_mm(matches, homography: np.ndarray, inlier: np.ndarray | None = None,
                             quantile: float = 0.98) -> float | None:
    """Disparity per mm of baseline of the nearest scene (the ``quantile`` over all matches), px/mm."""
    ratios = []
    start = 0
    for m in matches:
        sl = slice(start, start + m.count)
        start += m.count
        if m.count == 0 or not m.baseline_mm > 0:
            continue
        keep = np.ones(m.count, bool) if inlier is None else inlier[sl]
        d = apply_homography(homography, m.xy_a[keep]) - apply_homography(homography, m.xy_b[keep])
        disparity = d[:, 0] if m.direction == "h" else d[:, 1]
        ratios.append(np.abs(disparity) / float(m.baseline_mm))
    if not ratios:
        return None
    r = np.concatenate(ratios)
    return float(np.quantile(r, quantile)) if r.size else None


def _five(params: ArrayLike) -> np.ndarray:
    p = np.asarray(params, float)
    return p if len(p) == 5 else np.concatenate([p[:3], np.zeros(2)])


def _pair(values: Iterable[Any]) -> tuple[float, float]:
    a, b = (float(x) for x in values)
    return a, b


def _triple(values: Iterable[Any]) -> tuple[float, float, float]:
    a, b, c = (float(x) for x in values)
    return a, b, c


def describe_fit(fit: FitResult, matches: Sequence[PairMatches], row_baseline_mm: float | None,
                 column_baseline_mm: float | None) -> CalibrationUncertainty:
    """The :class:`lfstudio.calibration.model.CalibrationUncertainty` of a fit over a grid whose
    full row spans ``row_baseline_mm`` and full column ``column_baseline_mm`` (None: no such pairs).

    ``degenerate``: the stated 1σ error at the corners exceeds the rig's own repositioning error
    between two views at the nearest depth (``√2 · σ_position · d/B``): the calibration, not the
    rig, would then limit the rectification.
    """
    k = nearest_disparity_per_mm(matches, fit.homography, fit.inlier)
    row_d = k * row_baseline_mm if k and row_baseline_mm else None
    col_d = k * column_baseline_mm if k and column_baseline_mm else None
    corners = corner_probes(fit.image_size_px, row_d, col_d)
    bounds = error_bounds(probe_jacobian(corners, fit.params, fit.focal_length_px, fit.image_size_px),
                          fit.covariance, "max")
    floor = rig_floor_px(fit, k)
    # degenerate is a statement about the evidence (too short baselines), so it leaves out the
    # systematic floor (fit.SYSTEMATIC_PX), which no choice of views removes from a grid this size
    systematic = np.zeros(5)
    systematic[:3] = np.asarray(fit.extra.get("systematic_floor_deg") or np.zeros(3), float) ** 2
    evidence = np.asarray(fit.covariance, float) - np.diag(systematic)
    evidence_bound = error_bounds(probe_jacobian(corners, fit.params, fit.focal_length_px, fit.image_size_px),
                                  evidence, "max")[0]
    degenerate = bool(floor and evidence_bound > floor)
    pair_sigma = fit.extra.get("pair_sigma_px") or []
    linear = fit.extra.get("linear_deg")
    linear_rms = None
    if linear is not None:
        xa = np.concatenate([m.xy_a for m in matches])[fit.inlier]
        xb = np.concatenate([m.xy_b for m in matches])[fit.inlier]
        hor = np.concatenate([np.full(m.count, m.direction == "h") for m in matches])[fit.inlier]
        r = signed_residuals(homography_of(linear, fit.focal_length_px, fit.image_size_px), xa, xb, hor)
        linear_rms = float(np.sqrt(np.mean(r * r))) if len(r) else None
    return CalibrationUncertainty(
        rotation_std_deg=_triple(fit.rotation_std_deg),
        covariance=tuple(tuple(float(x) for x in row) for row in fit.covariance),
        corner_error_px=(bounds[0], bounds[1]),
        row_baseline_mm=row_baseline_mm, column_baseline_mm=column_baseline_mm,
        row_disparity_px=row_d, column_disparity_px=col_d,
        position_sigma_um=_pair(1000.0 * float(s) for s in fit.position_sigma_mm),
        feature_sigma_px=float(np.median(pair_sigma)) if len(pair_sigma) else None,
        formal_rotation_std_deg=_triple(fit.extra.get("formal_rotation_std_deg", (np.nan,) * 3)),
        principal_point_std_px=_pair(fit.extra.get("principal_point_std_px", (np.nan,) * 2)),
        linear_rotation_deg=None if linear is None else _triple(linear),
        linear_residual_px=linear_rms, degenerate=degenerate,
        method="covariance of the fit with every view's position error in the model (prior: the rig's "
               "repeatability, raised to what the data show) and each pair's residuals scaled by their "
               "observed spread; the principal point's prior included when it is held; at least the spread of "
               "block bootstraps over pair regions and over scene regions (one feature's error is shared by "
               "all its pairs) and of a delete-one-view jackknife; plus the angle a systematic feature "
               "error would fake")


def rig_floor_px(fit, nearest_px_per_mm: float | None) -> float | None:
    """The rig's own misalignment of two views at the nearest depth (1σ, px): √2 · σ_position · d/B."""
    if not nearest_px_per_mm or not any(fit.position_sigma_mm):
        return None
    return float(np.sqrt(2.0) * max(fit.position_sigma_mm) * nearest_px_per_mm)
