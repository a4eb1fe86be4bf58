"""Fit the shared orientation error (and optionally the principal point) from feature matches.

Model: ``H = K0 · Rᵀ · K_true⁻¹`` (see :mod:`lfstudio.calibration.model`). The residual of a match
``(a, b)`` of a *horizontal* pair (same row) is ``v(H·a) − v(H·b)``; of a *vertical* pair (same
column) ``u(H·a) − u(H·b)``, in pixels of the rectified full-resolution image. H is a pure rotation
homography whose scale is fixed by the focal length, so residuals cannot shrink by a degenerate
scaling; the angles are bounded anyway (default ±15°) and the principal point to a few percent of
the width. Outliers are handled by a robust loss (soft L1) and a trimmed refit at 3 robust sigmas.

The principal point is only weakly observable (to first order a shift of it is the same as a small
rotation), so when it is estimated a weak prior pulls it to the nominal centre
(``pp_prior_sigma_px``), and the rotation is first fitted with the nominal centre.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.optimize import least_squares

from lfstudio.calibration.model import apply_homography, nominal_principal_point, rectifying_homography
from lfstudio.errors import LfError


class CalibrationError(LfError):
    """Calibration cannot proceed (too few matches, no pairs, a failed fit). The message names views."""


@dataclass
class PairMatches:
    """Matched points of one pair of views, in full-resolution pixels of the captured images.

    ``a`` is the left (horizontal pair) or upper (vertical pair) view, ``b`` the other one.
    ``direction`` is ``"h"`` (same row: rows must line up) or ``"v"`` (same column).
    """

    view_a: tuple[int, int]            # (row, column)
    view_b: tuple[int, int]
    direction: str                     # "h" | "v"
    xy_a: np.ndarray                   # N × 2
    xy_b: np.ndarray                   # N × 2
    raw_matches: int = 0               # after ratio test + mutual check, before geometric check
    baseline_mm: float = 0.0

    @property
    def count(self) -> int:
        return int(len(self.xy_a))


@dataclass
class FitResult:
    rotation_deg: np.ndarray
    principal_point_px: np.ndarray
    focal_length_px: float
    image_size_px: tuple[int, int]
    homography: np.ndarray
    estimate_principal_point: bool
    residual_before_px: np.ndarray     # per match, concatenated over pairs (signed)
    residual_after_px: np.ndarray
    inlier: np.ndarray                 # bool per match (used in the final fit)
    pair_slices: list[slice]
    sigma_px: float                    # robust spread of the final residuals
    success: bool
    message: str
    evaluations: int = 0
    extra: dict = field(default_factory=dict)


def signed_residuals(H: np.ndarray, xy_a: np.ndarray, xy_b: np.ndarray, horizontal: np.ndarray) -> np.ndarray:
    """v-difference for horizontal matches, u-difference for vertical ones, after warping with H."""
    pa = apply_homography(H, xy_a)
    pb = apply_homography(H, xy_b)
    d = pa - pb
    return np.where(horizontal, d[:, 1], d[:, 0])


def _batched_residuals(Hs: np.ndarray, xy_a: np.ndarray, xy_b: np.ndarray, horizontal: np.ndarray) -> np.ndarray:
    """Residuals for many homographies at once: Hs (M × 3 × 3) → M × N."""
    def warp(xy):
        p = Hs[:, :, :2] @ xy.T + Hs[:, :, 2:3]          # M × 3 × N
        w = p[:, 2]
        w = np.where(np.abs(w) < 1e-12, 1e-12, w)
        return p[:, 0] / w, p[:, 1] / w
    ua, va = warp(xy_a)
    ub, vb = warp(xy_b)
    return np.where(horizontal[None, :], va - vb, ua - ub)


def fit_rectification(matches: Sequence[PairMatches], focal_length_px: float, image_size_px: Sequence[int], *,
                      estimate_principal_point: bool = False, max_angle_deg: float = 15.0,
                      max_pp_offset_px: float | None = None, pp_prior_sigma_px: float | None = None,
                      min_matches: int = 8, trim_sigmas: float = 3.0) -> FitResult:
    """Estimate ``rotation_deg`` (and the principal point) from the matches of several pairs.

    ``focal_length_px`` and ``image_size_px`` ([w, h]) refer to the full-resolution captured image.
    Raises :class:`CalibrationError` when there are too few matches overall or in either direction
    where both are needed.
    """
    w, h = int(image_size_px[0]), int(image_size_px[1])
    f = float(focal_length_px)
    if not (f > 0):
        raise CalibrationError(f"focal length {f!r} px must be positive; give --focal-length-px")
    used = [m for m in matches if m.count > 0]
    total = sum(m.count for m in used)
    n_h = sum(m.count for m in used if m.direction == "h")
    n_v = sum(m.count for m in used if m.direction == "v")
    if total < min_matches or n_h < min_matches // 2 or (n_v < min_matches // 2 and n_h < 2 * min_matches):
        names = ", ".join(f"{_vname(m.view_a)}–{_vname(m.view_b)} ({m.count})" for m in matches) or "none"
        raise CalibrationError(
            f"too few feature matches to calibrate: {n_h} in rows, {n_v} in columns (need at least "
            f"{min_matches} in total, and both directions for all three angles); pairs: {names}. "
            "Use views with more texture and overlap, or more views (--views)")
    xy_a = np.concatenate([m.xy_a for m in used]).astype(float)
    xy_b = np.concatenate([m.xy_b for m in used]).astype(float)
    horizontal = np.concatenate([np.full(m.count, m.direction == "h") for m in used])
    slices, start = [], 0
    for m in matches:
        slices.append(slice(start, start + m.count))
        start += m.count

    nominal = nominal_principal_point((w, h))
    max_pp = float(max_pp_offset_px if max_pp_offset_px is not None else 0.05 * w)
    prior_sigma = float(pp_prior_sigma_px if pp_prior_sigma_px is not None else 0.02 * w)
    residual_before = signed_residuals(np.eye(3), xy_a, xy_b, horizontal)

    def homography(params: np.ndarray) -> np.ndarray:
        pp = nominal + params[3:5] if len(params) > 3 else nominal
        return rectifying_homography(params[:3], f, (w, h), pp)

    def residual_fn(params, sel):
        r = signed_residuals(homography(params), xy_a[sel], xy_b[sel], horizontal[sel])
        if len(params) > 3:
            r = np.concatenate([r, params[3:5] / prior_sigma])
        return r

    # 1. coarse start: the grid point with the smallest median |residual| (robust to outliers)
    rng = np.random.default_rng(0)
    sub = np.arange(total) if total <= 1500 else np.sort(rng.choice(total, 1500, replace=False))
    steps = np.arange(-max_angle_deg * 2 / 3, max_angle_deg * 2 / 3 + 1e-9, max_angle_deg / 3)
    grid = np.array(list(itertools.product(steps, steps, steps)))
    Hs = np.stack([rectifying_homography(g, f, (w, h)) for g in grid])
    med = np.median(np.abs(_batched_residuals(Hs, xy_a[sub], xy_b[sub], horizontal[sub])), axis=1)
    x0 = grid[int(np.argmin(med))]
    bounds3 = (np.full(3, -max_angle_deg), np.full(3, max_angle_deg))

    # 2. robust rotation fit with the nominal principal point, then trimmed refits
    all_sel = np.ones(total, bool)
    spread = max(1.4826 * float(np.min(med)), 1.0)
    sol = least_squares(residual_fn, x0, args=(all_sel,), bounds=bounds3, loss="soft_l1",
                        f_scale=spread, x_scale=1.0, method="trf")
    evaluations = sol.nfev
    params = sol.x
    inlier = all_sel
    sigma = spread
    for _ in range(2):
        r = residual_fn(params, all_sel)[:total]
        sigma = max(1.4826 * float(np.median(np.abs(r))), 0.05)
        inlier = np.abs(r) <= max(trim_sigmas * sigma, 0.5)
        if inlier.sum() < min_matches:
            raise CalibrationError(f"only {int(inlier.sum())} of {total} matches agree with one orientation; "
                                   "the matches are mostly wrong (repetitive texture?) — check the views")
        sol = least_squares(residual_fn, params, args=(inlier,), bounds=bounds3, loss="soft_l1",
                            f_scale=sigma, x_scale=1.0, method="trf")
        params = sol.x
        evaluations += sol.nfev

    # 3. optionally free the principal point, starting from the rotation-only solution
    if estimate_principal_point:
        lo = np.concatenate([bounds3[0], [-max_pp, -max_pp]])
        hi = np.concatenate([bounds3[1], [max_pp, max_pp]])
        x5 = np.concatenate([params, [0.0, 0.0]])
        sol = least_squares(residual_fn, x5, args=(inlier,), bounds=(lo, hi), loss="soft_l1",
                            f_scale=sigma, x_scale=np.array([0.01, 0.01, 0.01, 1.0, 1.0]), method="trf")
        params = sol.x
        evaluations += sol.nfev

    H = homography(params)
    residual_after = signed_residuals(H, xy_a, xy_b, horizontal)
    sigma = max(1.4826 * float(np.median(np.abs(residual_after[inlier]))), 0.0)
    # formal standard errors (Gauss-Newton, independent residuals of spread sigma): how well these
    # views determine each parameter; small baselines leave pan and tilt weakly determined
    try:
        std = sigma * np.sqrt(np.diag(np.linalg.pinv(sol.jac.T @ sol.jac)))
    except (np.linalg.LinAlgError, ValueError):
        std = np.full(len(params), np.inf)
    pp = nominal + (params[3:5] if len(params) > 3 else 0.0)
    return FitResult(rotation_deg=np.asarray(params[:3], float), principal_point_px=np.asarray(pp, float),
                     focal_length_px=f, image_size_px=(w, h), homography=H,
                     estimate_principal_point=estimate_principal_point,
                     residual_before_px=residual_before, residual_after_px=residual_after, inlier=inlier,
                     pair_slices=slices, sigma_px=sigma, success=bool(sol.success), message=str(sol.message),
                     evaluations=int(evaluations),
                     extra={"start_deg": x0.tolist(), "rotation_std_deg": [float(x) for x in std[:3]],
                            "principal_point_std_px": [float(x) for x in std[3:5]] if len(std) > 3 else None})


def _vname(view: tuple[int, int]) -> str:
    return f"r{view[0]:02d}_c{view[1]:03d}"
