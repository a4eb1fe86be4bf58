"""Fit the shared orientation error (and the principal point when observable) from feature matches.

Model: ``H = K0 · Rᵀ · K_true⁻¹`` (see :mod:`lfstudio.calibration.model`). The residual of a match
``(a, b)`` of a *horizontal* pair (same row) is ``v(H·a) − v(H·b)``; of a *vertical* pair (same
column) ``u(H·a) − u(H·b)``, in pixels of the rectified full-resolution image.

Steps:

1. Start: the linear epipole closed form (:mod:`lfstudio.calibration.linear`) or, when a coarse
   grid over the angles explains the matches better (short baselines), the grid's best point.
2. Robust rotation fit (soft L1, angles bounded to ±``max_angle_deg``), trimmed twice at 3 robust
   sigmas: finds the inliers.
3. Refinement with the rig's position errors in the model. A camera ``η`` mm off its nominal row
   (column) shifts every match of a horizontal (vertical) pair by ``d / B · (η_b − η_a)`` px, where
   ``d`` is the match's disparity and ``B`` the pair's baseline in mm: errors shared by all matches
   of a view, which independent-residual fits ignore (their stated errors were 8× too small on
   short baselines). The offsets of every view are estimated jointly with the angles, with the
   rig's repeatability as their prior (raised when the data show larger offsets), and each pair's
   residuals weighted by its own observed spread. Gauss-Newton on the inliers, then one re-trim.
4. The covariance of the angles (and the principal point) is the inverse of that problem's
   information matrix with the view offsets marginalised out, scaled by the observed residuals:
   measured, not assumed. A floor per angle covers systematic feature errors the model cannot see
   (``SYSTEMATIC_PX``: SIFT's sub-pixel bias, half-size RAW reading, lens residuals): the angle a
   pattern of that size, shaped like the angle's own effect, would fake. It matters only on short
   baselines, where the angles barely move the matches (and barely matter for the grid).
   :mod:`lfstudio.calibration.uncertainty` turns the covariance into pixels.

The principal point: to first order a shift of it translates every view alike, which no residual
sees, so it is nearly unobservable from a translating rig. ``principal_point="auto"`` estimates it
only when the information matrix determines it to ``PP_OBSERVABLE_STD_PX`` (and 4× better than its
prior); otherwise it stays at the nominal centre, and its prior uncertainty (``PP_PRIOR_FRACTION`` of
the width) is propagated into the stated uncertainty of the angles.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from lfstudio.calibration.linear import linear_rotation
from lfstudio.calibration.model import MAX_ANGLE_DEG, apply_homography, nominal_principal_point, \
    rectifying_homography
from lfstudio.dataset.paths import view_stem
from lfstudio.errors import LfError, words

#: the reference rig's repeatability (horizontal, vertical axis), the default prior of the view offsets
DEFAULT_POSITION_SIGMA_UM = (80.0, 50.0)
#: prior of the principal point offset, as a fraction of the image width (1 σ; 159 px on the
#: reference 7952 px sensor, 0.72 mm: a generous tolerance for where a lens centres on a sensor)
PP_PRIOR_FRACTION = 0.02
#: the principal point is estimated only if the views determine it at least this well (1 σ, px)
PP_OBSERVABLE_STD_PX = 10.0
PRINCIPAL_POINT_MODES = ("auto", "centre")
#: a radial distortion term is fitted (and warned about) when the views determine it to this many σ
RADIAL_SIGNIFICANCE = 4.0
#: ... and it moves the corners by at least this much (px)
RADIAL_DETECT_PX = 1.0
#: the first-order radial correction of the angles is trusted to this fraction (added to their variance)
RADIAL_STEP_MARGIN = 0.25
RADIAL_TERMS = ("auto", "none")
#: fewer matches than this agreeing with the fit in a direction it uses: refused (too little evidence)
MIN_EVIDENCE_MATCHES = 24
#: resamples of the block bootstrap that widens the stated uncertainty on sparse or clustered matches
BOOTSTRAP_SAMPLES = 200
#: the robust first fit (which finds the outliers) uses at most this many matches
ROBUST_SAMPLE = 20000
#: systematic feature error (px RMS at full resolution) behind the per-angle floor of the covariance
#: and of the radial term: the pattern no resampling can see because every match carries it. Measured
#: (issue 37): on distortion-free virtual-studio captures (5 × 3 views at 800 px, no rotation) the
#: matches carry a radial-shaped pattern of 0.022 px RMS against the true geometry, and the rendered
#: HCI views patterns of the same size shaped like a tilt; 0.01 px called them 10-25 σ significant.
SYSTEMATIC_PX = 0.02
#: no pair's residuals are weighted as if its matches were better than this: with near-perfect
#: features the weights would otherwise grow without bound and the refinement diverge
_MIN_SIGMA_PX = 0.01
#: image regions per side of the scene-region block bootstrap (:func:`_bootstrap_angles`)
SCENE_CELLS = 6


class CalibrationError(LfError):
    """Calibration cannot proceed (too few matches, no pairs, a failed fit). The message names views."""

    kind = "calibration"


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


#: the three angles: key, name, what determines it
ANGLES = (("rx", "tilt"), ("ry", "pan"), ("rz", "roll"))


def held_angle_std_deg(max_angle_deg: float = 15.0) -> float:
    """The stated 1σ of an angle the views do not determine: its prior, anywhere within the fit's
    bounds (uniform over ±``max_angle_deg``: ``max_angle_deg / √3``)."""
    return float(max_angle_deg) / float(np.sqrt(3.0))


@dataclass(frozen=True)
class Observability:
    """Which angles the pair geometry determines.

    Pairs in a row (horizontal) line up rows: they see the direction of the row baseline, which fixes
    pan (ry) and roll (rz) but not the tilt (rx), a rotation about that baseline, which keeps every
    row a row. Pairs in a column fix tilt and roll, not pan. Both: all three. A direction counts when
    it has at least ``min_matches`` matches. An angle not determined is held at its prior (0°).
    """

    n_rows: int            # matches of horizontal pairs
    n_columns: int         # matches of vertical pairs
    rows: bool             # enough horizontal matches to use
    columns: bool

    @property
    def free(self) -> tuple[bool, bool, bool]:
        if self.rows and self.columns:
            return (True, True, True)
        if self.rows:
            return (False, True, True)
        if self.columns:
            return (True, False, True)
        return (False, False, False)

    @property
    def all_three(self) -> bool:
        return all(self.free)

    @property
    def directions(self) -> str:
        return ("rows and columns" if self.rows and self.columns else "rows only" if self.rows
                else "columns only" if self.columns else "none")

    @property
    def determined(self) -> list[str]:
        return [key for (key, _), f in zip(ANGLES, self.free) if f]

    def held(self) -> list[dict]:
        """Each held angle: key, name, value (0°), its stated prior σ and the reason, in words."""
        out = []
        for (key, name), f in zip(ANGLES, self.free):
            if f:
                continue
            if not self.rows and not self.columns:
                why = "no pairs"
            elif key == "rx":
                why = (f"{name} ({key}): not determined by one row — held at 0°; rows will line up, the grid's "
                       f"common {name} is unknown (add a second row of views to determine it)")
            else:
                why = (f"{name} ({key}): not determined by one column — held at 0°; columns will line up, the "
                       f"grid's common {name} is unknown (add a second column of views to determine it)")
            out.append({"angle": key, "name": name, "value_deg": 0.0, "reason": why})
        return out

    def to_json(self, max_angle_deg: float = 15.0) -> dict:
        held = self.held()
        for entry in held:
            entry["prior_std_deg"] = held_angle_std_deg(max_angle_deg)
        return {"pairs": self.directions, "matches_in_rows": self.n_rows, "matches_in_columns": self.n_columns,
                "determined": self.determined, "held": held,
                "rule": "rows (horizontal pairs) determine pan and roll, columns (vertical pairs) tilt and "
                        "roll, both all three; an angle not determined is held at 0° with the fit's bounds "
                        "as its prior"}


def observability(matches: Sequence["PairMatches"], min_matches: int = 8) -> Observability:
    """What the pair geometry of ``matches`` determines (see :class:`Observability`)."""
    n_h = sum(m.count for m in matches if m.direction == "h")
    n_v = sum(m.count for m in matches if m.direction == "v")
    return Observability(int(n_h), int(n_v), n_h >= min_matches, n_v >= min_matches)


@dataclass
class FitResult:
    rotation_deg: np.ndarray
    principal_point_px: np.ndarray
    focal_length_px: float
    image_size_px: tuple[int, int]
    homography: np.ndarray
    estimate_principal_point: bool     # True when the principal point was estimated (observable)
    residual_before_px: np.ndarray     # per match, concatenated over pairs (signed)
    residual_after_px: np.ndarray
    inlier: np.ndarray                 # bool per match (used in the final fit)
    pair_slices: list[slice]
    sigma_px: float                    # robust spread of the final residuals
    success: bool
    message: str
    covariance: np.ndarray             # 5 × 5 over [rx, ry, rz (deg), cx, cy offset (px)]
    evaluations: int = 0
    principal_point_reason: str = ""
    view_offsets_mm: dict = field(default_factory=dict)   # view -> [x, y] estimated position error (mm)
    position_sigma_mm: tuple[float, float] = (0.0, 0.0)   # the prior used (after the data check)
    observability: Observability | None = None             # which angles the views determine
    max_angle_deg: float = 15.0                            # the fit's bounds (±)
    extra: dict = field(default_factory=dict)

    @property
    def params(self) -> np.ndarray:
        """[rx, ry, rz, cx offset, cy offset]: the parameter vector of :attr:`covariance`."""
        nominal = nominal_principal_point(self.image_size_px)
        return np.concatenate([self.rotation_deg, self.principal_point_px - nominal])

    @property
    def rotation_std_deg(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance)[:3])


def signed_residuals(H: np.ndarray, xy_a: np.ndarray, xy_b: np.ndarray, horizontal: np.ndarray) -> np.ndarray:
    """v-difference for horizontal matches, u-difference for vertical ones, after warping with H."""
    pa = apply_homography(H, xy_a)
    pb = apply_homography(H, xy_b)
    d = pa - pb
    return np.where(horizontal, d[:, 1], d[:, 0])


def _warp_row(H: np.ndarray, x: np.ndarray, y: np.ndarray, row: int) -> tuple[np.ndarray, np.ndarray]:
    """Coordinate ``row`` (0: u, 1: v) of H·(x, y) and the squared norm of its gradient in (x, y)."""
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    w = np.where(np.abs(w) < 1e-12, 1e-12, w)
    c = (H[row, 0] * x + H[row, 1] * y + H[row, 2]) / w
    gx = (H[row, 0] - c * H[2, 0]) / w
    gy = (H[row, 1] - c * H[2, 1]) / w
    return c, gx * gx + gy * gy


def _warp_both(H: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    w = np.where(np.abs(w) < 1e-12, 1e-12, w)
    return (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w, (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w, w


class _Split:
    """Matches split by direction into flat coordinate arrays (fast repeated evaluation)."""

    def __init__(self, xy_a: np.ndarray, xy_b: np.ndarray, horizontal: np.ndarray):
        self.horizontal = np.asarray(horizontal, bool)
        self.h_idx = np.nonzero(self.horizontal)[0]
        self.v_idx = np.nonzero(~self.horizontal)[0]
        self.parts = []
        for idx, row in ((self.h_idx, 1), (self.v_idx, 0)):
            self.parts.append((idx, row, np.ascontiguousarray(xy_a[idx, 0]), np.ascontiguousarray(xy_a[idx, 1]),
                               np.ascontiguousarray(xy_b[idx, 0]), np.ascontiguousarray(xy_b[idx, 1])))
        self.n = len(self.horizontal)

    def evaluate(self, H: np.ndarray) -> np.ndarray:
        """Normalised residuals (see :func:`normalised_residuals`)."""
        return self._evaluate(H, None)

    def evaluate_with_disparity(self, H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised residuals and |disparity| / gain."""
        disp = np.empty(self.n)
        return self._evaluate(H, disp), disp

    def _evaluate(self, H: np.ndarray, disp: np.ndarray | None) -> np.ndarray:
        """The residuals; fills ``disp`` with |disparity| / gain when given."""
        r = np.empty(self.n)
        for idx, row, xa, ya, xb, yb in self.parts:
            if not len(idx):
                continue
            ca, ga = _warp_row(H, xa, ya, row)
            cb, gb = _warp_row(H, xb, yb, row)
            g = np.sqrt(0.5 * (ga + gb))
            r[idx] = (ca - cb) / g
            if disp is not None:
                other = 1 - row
                oa = _warp_row(H, xa, ya, other)[0]
                ob = _warp_row(H, xb, yb, other)[0]
                disp[idx] = np.abs(oa - ob) / g
        return r


def normalised_residuals(H: np.ndarray, xy_a: np.ndarray, xy_b: np.ndarray, horizontal: np.ndarray) -> np.ndarray:
    """:func:`signed_residuals` divided by how much H scales the features' noise (Sampson-style).

    Minimising the plain residuals lets H shrink the noise where it can (a homography's local scale
    varies by a few per cent over the image): a bias ∝ σ²/d² in pan and roll that dominated short
    baselines (neighbours-only pair sets: 4× the stated error). The normalised residual's noise does
    not depend on H. Still in pixels (the scale is ≈ 1).
    """
    return _Split(np.asarray(xy_a, float), np.asarray(xy_b, float), horizontal).evaluate(H)


def undistort_radial(xy: np.ndarray, corner_px: float, image_size_px: Sequence[int]) -> np.ndarray:
    """Undo one radial term that moved the image corners ``corner_px`` towards the centre (barrel;
    negative: pincushion): ``x_u = c + (x − c)(1 + k (r / r_c)²)``, ``k = corner_px / r_c``, about the
    nominal centre (``r_c``: centre to corner). To first order the inverse of
    :func:`lfstudio.calibration.simulate.distort`."""
    w, h = image_size_px
    c = nominal_principal_point((w, h))
    rc = float(np.hypot(w / 2.0, h / 2.0))
    d = np.asarray(xy, float) - c
    r2 = np.sum(d * d, axis=1, keepdims=True) / rc ** 2
    return c + d * (1.0 + (float(corner_px) / rc) * r2)


def homography_of(params: ArrayLike, focal_length_px: float, image_size_px: Sequence[int]) -> np.ndarray:
    """H for ``params`` = [rx, ry, rz] or [rx, ry, rz, cx offset, cy offset] (offsets from the nominal centre)."""
    p = np.asarray(params, float)
    pp = nominal_principal_point(image_size_px) + (p[3:5] if len(p) > 3 else 0.0)
    return rectifying_homography(p[:3], focal_length_px, image_size_px, pp)


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


@dataclass
class _Data:
    """Concatenated matches with the bookkeeping the refinement needs."""

    xy_a: np.ndarray
    xy_b: np.ndarray
    horizontal: np.ndarray
    pair: np.ndarray          # pair index per match
    baseline_mm: np.ndarray   # per pair
    eta_a: np.ndarray         # per pair: column of view a's offset (-1: none)
    eta_b: np.ndarray
    eta_axis: np.ndarray      # per offset column: 0 = x (vertical pairs), 1 = y (horizontal pairs)
    eta_view: list            # per offset column: the view

    def subset(self, sel: np.ndarray) -> "_Data":
        return _Data(self.xy_a[sel], self.xy_b[sel], self.horizontal[sel], self.pair[sel], self.baseline_mm,
                     self.eta_a, self.eta_b, self.eta_axis, self.eta_view)


def _make_data(used: Sequence[PairMatches], axes: tuple[bool, bool]) -> _Data:
    """``axes``: whether x (vertical pairs) and y (horizontal pairs) position errors are modelled."""
    xy_a = np.concatenate([m.xy_a for m in used]).astype(float)
    xy_b = np.concatenate([m.xy_b for m in used]).astype(float)
    horizontal = np.concatenate([np.full(m.count, m.direction == "h") for m in used])
    pair = np.concatenate([np.full(m.count, i) for i, m in enumerate(used)])
    baseline = np.array([float(m.baseline_mm) for m in used])
    columns: dict[tuple, int] = {}
    eta_a = np.full(len(used), -1)
    eta_b = np.full(len(used), -1)
    for i, m in enumerate(used):
        axis = 1 if m.direction == "h" else 0
        if not axes[axis] or not baseline[i] > 0:
            continue
        eta_a[i] = columns.setdefault((m.view_a, axis), len(columns))
        eta_b[i] = columns.setdefault((m.view_b, axis), len(columns))
    keys = sorted(columns, key=columns.__getitem__)
    return _Data(xy_a, xy_b, horizontal, pair, baseline, eta_a, eta_b,
                 np.array([k[1] for k in keys], int), [k[0] for k in keys])


class _Problem:
    """The linearised refinement: residuals, Jacobian, information matrix (offsets marginalised)."""

    def __init__(self, data: _Data, f: float, size: tuple[int, int], pp_prior_sigma_px: float):
        self.data = data
        self.f = f
        self.size = size
        self.pp_prior_sigma = pp_prior_sigma_px
        self.split = _Split(data.xy_a, data.xy_b, data.horizontal)
        self.ka = data.eta_a[data.pair]
        self.kb = data.eta_b[data.pair]
        self.has = self.ka >= 0
        base = data.baseline_mm[data.pair]
        self.inv_base = np.where(self.has & (base > 0), 1.0 / np.where(base > 0, base, 1.0), 0.0)
        #: the parameters the Jacobian and the normal matrix cover (None: every one of ``params``)
        self.free_idx: np.ndarray | None = None

    def columns(self, params: np.ndarray) -> np.ndarray:
        return np.arange(len(params)) if self.free_idx is None else np.asarray(self.free_idx, int)

    def residuals(self, params: np.ndarray) -> np.ndarray:
        return self._split_for(params).evaluate(homography_of(params, self.f, self.size))

    def _split_for(self, params: np.ndarray) -> "_Split":
        """The matches as the parameters see them: with a radial term (``params[5]``, px at the
        corners) undone first (:func:`undistort_radial`)."""
        if len(params) <= 5 or params[5] == 0.0:
            return self.split
        d = self.data
        return _Split(undistort_radial(d.xy_a, params[5], self.size), undistort_radial(d.xy_b, params[5], self.size),
                      d.horizontal)

    def residuals_and_coupling(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised residuals and, per match, d / B (px per mm of relative position error; 0 where
        no offsets are modelled)."""
        r, disp = self._split_for(params).evaluate_with_disparity(homography_of(params, self.f, self.size))
        return r, disp * self.inv_base

    def jacobian(self, params: np.ndarray, r0: np.ndarray | None = None) -> np.ndarray:
        """Forward differences (steps 1e-4° and 0.01 px) over the free parameters (:meth:`columns`)."""
        r0 = self.residuals(params) if r0 is None else r0
        steps = np.array([1e-4, 1e-4, 1e-4, 0.01, 0.01, 0.01])
        cols = self.columns(params)
        J = np.empty((len(r0), len(cols)))
        for j, k in enumerate(cols):
            e = np.zeros(len(params))
            e[k] = steps[k]
            J[:, j] = (self.residuals(params + e) - r0) / steps[k]
        return J

    def normal(self, params, weights, sigma_pos_mm) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Full normal matrix and right-hand side over [δparams, offsets]; also r0 and the coupling."""
        d = self.data
        r0, c = self.residuals_and_coupling(params)
        J = self.jacobian(params, r0)
        n_p, n_e = J.shape[1], len(d.eta_axis)
        ka, kb, has = self.ka, self.kb, self.has
        N = np.zeros((n_p + n_e, n_p + n_e))
        rhs = np.zeros(n_p + n_e)
        wJ = J * weights[:, None]
        N[:n_p, :n_p] = J.T @ wJ
        rhs[:n_p] = -wJ.T @ r0
        for j, k in enumerate(self.columns(params)):   # weak prior of the principal point offset
            if k in (3, 4):
                N[j, j] += 1.0 / self.pp_prior_sigma ** 2
                rhs[j] -= params[k] / self.pp_prior_sigma ** 2
        if n_e:
            # the model residual is r0 + J δp − c (η_b − η_a): columns −c at b, +c at a
            wc = (weights * c)[has]
            ka_h, kb_h = ka[has], kb[has]
            for k in range(n_p):
                v = wc * J[has, k]
                N[k, n_p:] = np.bincount(ka_h, v, n_e) - np.bincount(kb_h, v, n_e)
            N[n_p:, :n_p] = N[:n_p, n_p:].T
            s = np.bincount(d.pair[has], wc * c[has], len(d.baseline_mm))     # per pair Σ w c²
            N[n_p:, n_p:] = _offset_normals(d, s, sigma_pos_mm)
            wr = wc * r0[has]
            rhs[n_p:] = np.bincount(kb_h, wr, n_e) - np.bincount(ka_h, wr, n_e)
        return N, rhs, r0, c

    def model_residuals(self, params, offsets) -> np.ndarray:
        """Residuals after the estimated view offsets are taken out."""
        if not len(offsets):
            return self.residuals(params)
        r0, c = self.residuals_and_coupling(params)
        has = self.has
        out = r0.copy()
        out[has] -= c[has] * (offsets[self.kb[has]] - offsets[self.ka[has]])
        return out


def _pair_sigmas(resid: np.ndarray, pair: np.ndarray, n_pairs: int, fallback: float) -> np.ndarray:
    counts = np.bincount(pair, minlength=n_pairs)
    ss = np.bincount(pair, resid * resid, n_pairs)
    sig = np.sqrt(np.where(counts > 0, ss / np.maximum(counts, 1), fallback ** 2))
    return np.maximum(sig, _MIN_SIGMA_PX)


def _offset_normals(d, s: np.ndarray, sigma_pos_mm: np.ndarray) -> np.ndarray:
    """The view offsets' block of the normal matrix: each pair's Σ w c² (``s``) couples its two
    views' offsets, and each offset has its prior σ (``sigma_pos_mm`` per axis)."""
    n_e = len(d.eta_axis)
    Nee = np.zeros((n_e, n_e))
    for i in np.nonzero(s)[0]:
        a, b = d.eta_a[i], d.eta_b[i]
        Nee[a, a] += s[i]
        Nee[b, b] += s[i]
        Nee[a, b] -= s[i]
        Nee[b, a] -= s[i]
    sig = np.where(d.eta_axis == 0, sigma_pos_mm[0], sigma_pos_mm[1])
    return Nee + np.diag(1.0 / sig ** 2)


def _solve_offsets(problem: "_Problem", r0: np.ndarray, c: np.ndarray, weights: np.ndarray,
                   sigma_pos_mm: np.ndarray) -> np.ndarray:
    """The view offsets that best explain ``r0`` given the coupling ``c`` (linear: exact)."""
    d = problem.data
    n_e = len(d.eta_axis)
    if not n_e:
        return np.zeros(0)
    has = problem.has
    wc = (weights * c)[has]
    s = np.bincount(d.pair[has], wc * c[has], len(d.baseline_mm))
    Nee = _offset_normals(d, s, sigma_pos_mm)
    wr = wc * r0[has]
    rhs = np.bincount(problem.kb[has], wr, n_e) - np.bincount(problem.ka[has], wr, n_e)
    return np.linalg.solve(Nee, rhs)        # positive definite: the prior is on its diagonal


def _refine(problem: "_Problem", params: np.ndarray, sigma_px: float, sigma_pos_mm: np.ndarray,
            iterations: int = 8, free: ArrayLike | None = None,
            bounds: tuple[np.ndarray, np.ndarray] | None = None
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The angles (and principal point) with every view's offset in the model and per-pair weights;
    the offset prior rises to what the data show.

    Levenberg–Marquardt over the ``free`` parameters only (the others stay where ``params`` holds
    them; a direction the views do not determine is held, never inverted): each step solves the
    normal equations over [free parameters, view offsets] damped by λ·diag on the parameter block,
    is clipped to ``bounds`` and is taken only if it lowers the cost (else λ grows tenfold); the
    inverse never amplifies a near-null direction without bound (:func:`_inverse`). Returns
    (params, offsets, per-pair sigmas, offset prior used, inverse normal matrix over [free params,
    offsets]).
    """
    d = problem.data
    params = np.asarray(params, float).copy()
    n_all = len(params)
    free_idx = np.arange(n_all) if free is None else np.nonzero(np.asarray(free, bool)[:n_all])[0]
    if bounds is None:
        lo, hi = np.full(n_all, -np.inf), np.full(n_all, np.inf)
    else:
        lo, hi = np.asarray(bounds[0], float)[:n_all], np.asarray(bounds[1], float)[:n_all]
    params = np.clip(params, lo, hi)
    problem.free_idx = free_idx
    n_p = len(free_idx)
    n_pairs = len(d.baseline_mm)
    sig_pair = np.full(n_pairs, max(sigma_px, _MIN_SIGMA_PX))
    prior = np.asarray(sigma_pos_mm, float).copy()
    offsets = np.zeros(len(d.eta_axis))
    lam = 1e-4

    def cost(p, eta, weights, prior):
        r = problem.model_residuals(p, eta)
        out = float(np.sum(weights * r * r))
        if len(eta):
            sig = np.where(d.eta_axis == 0, prior[0], prior[1])
            out += float(np.sum((eta / sig) ** 2))
        if n_all > 3:
            out += float(np.sum(p[3:5] ** 2)) / problem.pp_prior_sigma ** 2
        return out

    for it in range(iterations):
        weights = 1.0 / sig_pair[d.pair] ** 2
        N, rhs, r0, c = problem.normal(params, weights, prior)
        offsets = _solve_offsets(problem, r0, c, weights, prior)
        before = cost(params, offsets, weights, prior)
        step = 0.0
        for _ in range(12):
            Nd = N.copy()
            Nd[np.arange(n_p), np.arange(n_p)] *= 1.0 + lam
            z = _inverse(Nd) @ rhs
            trial = params.copy()
            trial[free_idx] = np.clip(params[free_idx] + z[:n_p], lo[free_idx], hi[free_idx])
            trial_offsets = z[n_p:]
            after = cost(trial, trial_offsets, weights, prior)
            if after <= before * (1.0 + 1e-12) or not np.isfinite(before):
                step = float(np.max(np.abs(trial[free_idx] - params[free_idx]))) if n_p else 0.0
                params, offsets = trial, trial_offsets
                lam = max(lam / 10.0, 1e-7)
                break
            lam *= 10.0
        resid = problem.model_residuals(params, offsets)
        old = (sig_pair, prior.copy())
        sig_pair = _pair_sigmas(resid, d.pair, n_pairs, sigma_px)
        if len(offsets):
            # expectation-maximisation of the offset variance per axis, never below the rig's value
            second = offsets ** 2 + np.diag(_inverse(N))[n_p:]
            for axis in (0, 1):
                sel = d.eta_axis == axis
                if sel.any():
                    prior[axis] = max(float(sigma_pos_mm[axis]), float(np.sqrt(second[sel].mean())))
        settled = step < 1e-6 and np.allclose(sig_pair, old[0], rtol=0.01) and np.allclose(prior, old[1], rtol=0.01)
        if it >= 1 and settled:
            break
    # the information at the solution, with the final weights and prior
    cov = _inverse(problem.normal(params, 1.0 / sig_pair[d.pair] ** 2, prior)[0])
    return params, offsets, sig_pair, prior, cov


def fit_rectification(matches: Sequence[PairMatches], focal_length_px: float, image_size_px: Sequence[int], *,
                      principal_point: str = "auto", estimate_principal_point: bool | None = None,
                      position_sigma_um: Sequence[float] | None = DEFAULT_POSITION_SIGMA_UM,
                      max_angle_deg: float = MAX_ANGLE_DEG, pp_prior_sigma_px: float | None = None,
                      min_matches: int = 8, trim_sigmas: float = 3.0, radial_term: str = "auto") -> FitResult:
    """Estimate ``rotation_deg`` (and the principal point when observable) with its covariance.

    ``focal_length_px`` and ``image_size_px`` ([w, h]) refer to the full-resolution captured image.
    ``principal_point``: ``"auto"`` (estimated only when the views determine it) or ``"centre"``
    (held at the nominal centre). ``estimate_principal_point`` (older spelling): True = "auto",
    False = "centre". ``position_sigma_um``: the rig's repeatability (x, y) in µm, the prior of each
    view's position error (None or 0: exact positions). Raises :class:`CalibrationError` when there
    are too few matches overall or in either direction where both are needed. ``radial_term``:
    "auto" (the images carry no lens correction: detect one radial distortion term and fit it where
    the views determine it) or "none" (the features were undistorted with the lens model).
    """
    if estimate_principal_point is not None:
        principal_point = "auto" if estimate_principal_point else "centre"
    if principal_point not in PRINCIPAL_POINT_MODES:
        raise CalibrationError(f"principal point mode {principal_point!r}: use one of {', '.join(PRINCIPAL_POINT_MODES)}")
    w, h = int(image_size_px[0]), int(image_size_px[1])
    f = float(focal_length_px)
    if not (f > 0):
        raise CalibrationError(f"focal length {f!r} px must be positive; give "
                               + words("--focal-length-px", "the Focal length (px) in the Calibrate dialog"))
    used = [m for m in matches if m.count > 0]
    total = sum(m.count for m in used)
    obs = observability(used, min_matches)
    if total < min_matches or not (obs.rows or obs.columns):
        names = ", ".join(f"{view_stem(*m.view_a)}–{view_stem(*m.view_b)} ({m.count})" for m in matches) or "none"
        raise CalibrationError(
            f"too few feature matches to calibrate: {obs.n_rows} in rows, {obs.n_columns} in columns (need at "
            f"least {min_matches} in rows (they fix pan and roll) or in columns (tilt and roll), both for all "
            f"three angles); pairs: {names}. Use views with more texture and overlap, or more views (--views)")
    free3 = np.array(obs.free, bool)
    fidx = np.nonzero(free3)[0]
    pos_sigma_mm = np.array([float(s) / 1000.0 for s in (position_sigma_um or (0.0, 0.0))])
    data = _make_data(used, (bool(pos_sigma_mm[0] > 0), bool(pos_sigma_mm[1] > 0)))
    xy_a, xy_b, horizontal = data.xy_a, data.xy_b, data.horizontal
    # slices over ``matches`` (empty pairs included), matching the concatenation order of ``used``
    slices, start = [], 0
    for m in matches:
        slices.append(slice(start, start + m.count))
        start += m.count

    prior_sigma = float(pp_prior_sigma_px if pp_prior_sigma_px is not None else PP_PRIOR_FRACTION * w)
    residual_before = signed_residuals(np.eye(3), xy_a, xy_b, horizontal)
    everything = _Split(xy_a, xy_b, horizontal)
    held_std = held_angle_std_deg(max_angle_deg)

    # 1. start: the linear closed form, or the best point of a coarse grid (over the angles the views
    #    determine; the others at their prior, 0) if that explains more
    rng = np.random.default_rng(0)
    sub = np.arange(total) if total <= 1500 else np.sort(rng.choice(total, 1500, replace=False))
    steps = np.arange(-max_angle_deg * 2 / 3, max_angle_deg * 2 / 3 + 1e-9, max_angle_deg / 3)
    grid = np.zeros((len(steps) ** len(fidx), 3))
    grid[:, fidx] = np.array(list(itertools.product(*([steps] * len(fidx)))))
    linear = linear_rotation(used, f, (w, h)) if obs.all_three else None
    candidates = grid if linear is None or np.any(np.abs(linear.rotation_deg) > max_angle_deg) \
        else np.vstack([grid, linear.rotation_deg[None, :]])
    Hs = np.stack([homography_of(g, f, (w, h)) for g in candidates])
    med = np.median(np.abs(_batched_residuals(Hs, xy_a[sub], xy_b[sub], horizontal[sub])), axis=1)
    x0 = candidates[int(np.argmin(med))]
    lo3, hi3 = np.full(3, -max_angle_deg), np.full(3, max_angle_deg)

    def angles(q):
        p = np.zeros(3)
        p[fidx] = q
        return p

    # 2. robust rotation fit with the nominal principal point, then trimmed refits: the inliers
    #    (on at most ROBUST_SAMPLE matches: the refinement below uses them all)
    sample = np.arange(total) if total <= ROBUST_SAMPLE else np.sort(rng.choice(total, ROBUST_SAMPLE, replace=False))

    def solve(p, sel, scale):
        split = _Split(xy_a[sel], xy_b[sel], horizontal[sel])
        return least_squares(lambda q: split.evaluate(homography_of(angles(q), f, (w, h))),
                             np.clip(p[fidx], lo3[fidx], hi3[fidx]), bounds=(lo3[fidx], hi3[fidx]),
                             loss="soft_l1", f_scale=scale, x_scale=1.0, method="trf")

    spread = max(1.4826 * float(np.min(med)), 1.0)
    sol = solve(x0, sample, spread)
    evaluations = sol.nfev
    params = angles(sol.x)
    sigma = spread
    for _ in range(2):
        r = everything.evaluate(homography_of(params, f, (w, h)))
        sigma = max(1.4826 * float(np.median(np.abs(r))), 0.05)
        inlier = np.abs(r) <= max(trim_sigmas * sigma, 0.5)
        if inlier.sum() < min_matches:
            raise CalibrationError(f"only {int(inlier.sum())} of {total} matches agree with one orientation; "
                                   "the matches are mostly wrong (repetitive texture?) — check the views")
        sol = solve(params, sample[inlier[sample]], sigma)
        params = angles(sol.x)
        evaluations += sol.nfev
    robust_params = params.copy()

    # 3. refinement with the view offsets (damped, bounded, over the determined angles); re-trim once
    #    with the offsets taken out
    def refine(p, sel):
        return _refine(_Problem(data.subset(sel), f, (w, h), prior_sigma), p, sigma, pos_sigma_mm,
                       free=free3, bounds=(lo3, hi3))

    params, offsets, sig_pair, pos_used, cov_full = refine(params, inlier)
    resid_all = _Problem(data, f, (w, h), prior_sigma).model_residuals(params, offsets)
    retrim = np.abs(resid_all) <= np.maximum(trim_sigmas * sig_pair[data.pair], 0.5)
    if retrim.sum() >= min_matches and np.count_nonzero(retrim != inlier) > 0.002 * total:
        inlier = retrim
        params, offsets, sig_pair, pos_used, cov_full = refine(params, inlier)

    # 4. the principal point: free it and see how well the views determine it (only where the views
    #    determine all three angles: one direction cannot tell it from the held angle)
    problem = _Problem(data.subset(inlier), f, (w, h), prior_sigma)
    p5 = np.concatenate([params, [0.0, 0.0]])
    limit = observable_limit_px(prior_sigma)
    estimated = False
    pp_std = None
    free5 = np.concatenate([free3, [True, True]])
    pp_bound = 5.0 * prior_sigma
    lo5, hi5 = np.concatenate([lo3, [-pp_bound] * 2]), np.concatenate([hi3, [pp_bound] * 2])
    if principal_point == "auto" and obs.all_three:
        free = _refine(problem, p5, sigma, pos_sigma_mm, free=free5, bounds=(lo5, hi5))
        pp_std = np.sqrt(np.diag(free[4])[3:5])
        estimated = pp_observable(pp_std, prior_sigma)
    covariance = np.zeros((5, 5))
    cols5 = np.nonzero(free5)[0]
    if estimated:
        assert pp_std is not None           # measured where it was estimated (the "auto" branch above)
        params, offsets, sig_pair, pos_used, cov_full = free
        covariance[np.ix_(cols5, cols5)] = cov_full[:len(cols5), :len(cols5)]
        reason = (f"estimated: the views determine it to ±{pp_std.max():.1f} px (1σ; the limit is "
                  f"{limit:.1f} px)")
    else:
        # held: its prior uncertainty moves the fitted angles by G·Δpp (G from the information matrix
        # at the rotation-only solution)
        w_in = 1.0 / sig_pair[data.pair[inlier]] ** 2
        problem.free_idx = cols5
        N5, _, _, _ = problem.normal(p5, w_in, pos_used)
        k = len(cols5)
        cov5 = _inverse(N5)[:k, :k]
        if pp_std is None:
            pp_std = np.sqrt(np.diag(cov5)[-2:])
        info = _inverse(cov5)          # marginal information over the free angles and the principal point
        na = k - 2
        Sigma_n = _inverse(info[:na, :na])
        G = -Sigma_n @ info[:na, na:]
        S_pp = np.eye(2) * prior_sigma ** 2
        covariance[np.ix_(fidx, fidx)] = cov_full[:na, :na] + G @ S_pp @ G.T
        pp_idx = np.array([3, 4])
        covariance[np.ix_(fidx, pp_idx)] = G @ S_pp
        covariance[np.ix_(pp_idx, fidx)] = (G @ S_pp).T
        covariance[3:5, 3:5] = S_pp
        why = ("not requested" if principal_point == "centre" else
               "not observable from one direction of pairs" if not obs.all_three else
               f"not observable from these views (they determine it only to ±{pp_std.max():.0f} px, 1σ; "
               f"the limit is {limit:.1f} px)")
        reason = f"held at the image centre: {why}; its uncertainty (±{prior_sigma:.0f} px) is included"
    for k in np.nonzero(~free3)[0]:     # a held angle: its prior, nothing the views say
        covariance[k, :] = 0.0
        covariance[:, k] = 0.0
        covariance[k, k] = held_std ** 2

    # 5. uncorrected lens distortion: one radial term, estimated jointly with the angles to first order
    #    (one damped Gauss-Newton step of the joint problem from this solution; the angles' gradient
    #    is ~0 here, so the step is what the radial term moves them by). Where the views determine it
    #    (RADIAL_SIGNIFICANCE σ and RADIAL_DETECT_PX), the angles take the step, their covariance
    #    the term's uncertainty, and a warning names it.
    radial = None
    warnings: list[str] = []
    # the matches the fit kept and their weights (inlier and sig_pair are final from here on)
    kept_data = data.subset(inlier)
    kept_w = 1.0 / sig_pair[data.pair[inlier]] ** 2
    if radial_term == "auto":
        p6 = np.concatenate([params[:5] if len(params) >= 5 else np.concatenate([params, [0.0, 0.0]]), [0.0]])
        cols6 = np.array(list(fidx) + ([3, 4] if estimated else []) + [5])
        prob = _Problem(kept_data, f, (w, h), prior_sigma)
        prob.free_idx = cols6
        N6, rhs6, _, _ = prob.normal(p6, kept_w, pos_used)
        C6 = _inverse(N6)
        delta = C6 @ rhs6
        kk = len(cols6) - 1
        k_hat, k_formal = float(delta[kk]), float(np.sqrt(C6[kk, kk]))
        # how well the views determine it, measured as for the angles: the formal error assumes
        # independent residuals, but a term that moves the matches by ~0.002 px per px at the corners
        # (short baselines) is faked by feature errors shared across pairs (the scene-region bootstrap)
        # and by a systematic pattern of SYSTEMATIC_PX (the floor). On distortion-free virtual captures
        # (5 × 3 views at 800 px) the formal error called 3–11 px of pincushion 7–25 σ (issue 37)
        k_var = k_formal ** 2
        boot6 = _bootstrap_angles(kept_data, p6, cols6, f, (w, h), prior_sigma, offsets, kept_w)
        if boot6 is not None:
            k_var = max(k_var, float(boot6[kk, kk]))
        J6 = prob.jacobian(p6)
        k_floor = SYSTEMATIC_PX / max(float(np.percentile(np.abs(J6[:, kk]), 99)), 1e-12) if len(J6) else 0.0
        k_std = float(np.sqrt(k_var + k_floor ** 2))
        radial = {"corner_px": k_hat, "std_px": k_std, "formal_std_px": k_formal, "floor_px": k_floor,
                  "applied": False}
        if abs(k_hat) >= RADIAL_DETECT_PX and abs(k_hat) > RADIAL_SIGNIFICANCE * k_std:
            keep = np.r_[np.arange(kk), np.arange(len(cols6), len(N6))]
            C5 = _inverse(N6[np.ix_(keep, keep)])
            na = len(fidx)
            grow = C6[:na, :na] - C5[:na, :na]
            step = delta[:kk]
            full = np.zeros(5)
            full[:len(params)] = params[:5]
            full[cols6[:kk]] += step
            params = full if len(params) > 3 else full[:3]
            covariance[np.ix_(fidx, fidx)] += grow + np.diag((RADIAL_STEP_MARGIN * step[:na]) ** 2)
            radial["applied"] = True
            kind = "barrel" if k_hat > 0 else "pincushion"
            warnings.append(
                f"uncorrected lens distortion: the residuals show a radial pattern ({kind}, ≈ {abs(k_hat):.1f} ± "
                f"{k_std:.1f} px at the image corners); the angles were fitted with that term and their uncertainty "
                "includes it, but the images are not undistorted: give the lens a model (processing.toml [lens], "
                "e.g. its lensfun name or k1) and calibrate again")

    # 6. sparse or clustered evidence: a block bootstrap over image regions of every pair (linearised
    #    at the solution). Where it spreads the angles wider than the covariance says (few matches,
    #    bunched in a corner, heavy-tailed errors), the stated variance grows to it.
    n_kept = {d: int(np.count_nonzero(inlier & (horizontal == (d == "h")))) for d in ("h", "v")}
    short = [f"{n_kept[d]} in {name}" for d, name, used_dir in (("h", "rows", obs.rows), ("v", "columns", obs.columns))
             if used_dir and n_kept[d] < MIN_EVIDENCE_MATCHES]
    if short:
        raise CalibrationError(
            f"too little evidence to calibrate: only {' and '.join(short)} of the matches agree with one "
            f"orientation (at least {MIN_EVIDENCE_MATCHES} per direction used); the angles would be guesses. Use "
            "views with more texture (light, focus, a textured target in the scene) or more views (--views)")
    boot = _bootstrap_angles(kept_data, params, fidx, f, (w, h), prior_sigma, offsets, kept_w)
    if boot is not None:
        analytic = np.diag(covariance)[fidx]
        covariance[fidx, fidx] += np.maximum(np.diag(boot) - analytic, 0.0)
    # errors a view shares across all its pairs that the model does not have (a real archive's views
    # each rectified by its own homography, a view's own tilt): a delete-one-view jackknife
    jack = _jackknife_views(kept_data, [(m.view_a, m.view_b) for m in used], params, fidx, f, (w, h),
                            prior_sigma, kept_w, obs)
    if jack is not None:
        analytic = np.diag(covariance)[fidx]
        covariance[fidx, fidx] += np.maximum(np.diag(jack) - analytic, 0.0)

    # the cross-check: the closed form again, on the matches the fit kept
    kept = [PairMatches(m.view_a, m.view_b, m.direction, m.xy_a[inlier[sl]], m.xy_b[inlier[sl]])
            for m, sl in zip(matches, slices) if m.count]
    check = linear_rotation(kept, f, (w, h))
    H = homography_of(params, f, (w, h))
    residual_after = signed_residuals(H, xy_a, xy_b, horizontal)
    sigma = max(1.4826 * float(np.median(np.abs(residual_after[inlier]))), 0.0)
    # the formal error of independent residuals (the old statement), kept to show what it misses
    p_inl = _Problem(kept_data, f, (w, h), prior_sigma)
    p_inl.free_idx = fidx
    J3 = p_inl.jacobian(params[:3])
    formal = np.full(3, held_std)
    formal[fidx] = sigma * np.sqrt(np.diag(_inverse(J3.T @ J3)))
    # the floor: the angle a systematic SYSTEMATIC_PX pattern shaped like the angle's effect would fake
    floor = np.zeros(3)
    if len(J3):
        floor[fidx] = SYSTEMATIC_PX / np.maximum(np.percentile(np.abs(J3), 99, axis=0), 1e-9)
    covariance[:3, :3] += np.diag(floor ** 2)
    at_bound = [ANGLES[k][0] for k in fidx if abs(params[k]) > max_angle_deg - 1e-3]
    if at_bound:
        raise CalibrationError(
            f"the fit ran to its bound (±{max_angle_deg:g}°) in {', '.join(at_bound)}: the matches agree with no "
            "small orientation error of one camera — check that the grid (columns x rows, order) and the views "
            "are right, and that the images come from one camera setting")
    view_offsets: dict = {}
    for k, (view, axis) in enumerate(zip(data.eta_view, data.eta_axis)):
        view_offsets.setdefault(view, [0.0, 0.0])[int(axis)] = float(offsets[k]) if k < len(offsets) else 0.0
    nominal = nominal_principal_point((w, h))
    pp = nominal + (params[3:5] if len(params) > 3 else 0.0)
    std = np.sqrt(np.diag(covariance))
    return FitResult(rotation_deg=np.asarray(params[:3], float), principal_point_px=np.asarray(pp, float),
                     focal_length_px=f, image_size_px=(w, h), homography=H, estimate_principal_point=estimated,
                     residual_before_px=residual_before, residual_after_px=residual_after, inlier=inlier,
                     pair_slices=slices, sigma_px=sigma, success=bool(sol.success), message=str(sol.message),
                     evaluations=int(evaluations), covariance=covariance, principal_point_reason=reason,
                     view_offsets_mm=view_offsets, position_sigma_mm=(float(pos_used[0]), float(pos_used[1])),
                     observability=obs, max_angle_deg=float(max_angle_deg),
                     extra={"start_deg": [float(x) for x in x0],
                            "robust_deg": [float(x) for x in robust_params],
                            "linear_start_deg": None if linear is None else [float(x) for x in linear.rotation_deg],
                            "linear_deg": None if check is None else [float(x) for x in check.rotation_deg],
                            "rotation_std_deg": [float(x) for x in std[:3]],
                            "formal_rotation_std_deg": [float(x) for x in formal],
                            "principal_point_std_px": [float(x) for x in pp_std],
                            "systematic_floor_deg": [float(x) for x in floor],
                            "pair_sigma_px": [float(x) for x in sig_pair],
                            "radial_distortion": radial, "warnings": warnings})


def _bootstrap_angles(data: _Data, params: np.ndarray, fidx: np.ndarray, f: float, size: tuple[int, int],
                      pp_prior_sigma: float, offsets: np.ndarray, weights: np.ndarray,
                      samples: int = BOOTSTRAP_SAMPLES, cells: int = 4, seed: int = 0) -> np.ndarray | None:
    """Covariance of the free parameters ``fidx`` from two block bootstraps, each sample redrawing the
    blocks with replacement and taking the linearised weighted least-squares step from the solution;
    per parameter the larger variance of the two (the diagonal is what the callers use):

    - pair regions: the matches of one pair in one of ``cells`` × ``cells`` image regions (sparse or
      bunched matches, heavy-tailed errors);
    - scene regions: the matches of *every* pair in one of :data:`SCENE_CELLS` × :data:`SCENE_CELLS`
      regions (by the match's mean position). One scene feature is matched in many pairs with the same
      localisation error, so its pairs are not independent evidence; resampling pairs' regions alone
      called a 0.15° tilt of the rendered HCI views 3 σ (issue 37).

    The residuals keep the views' position errors (the offsets the fit estimated are not taken out: on
    few pairs they absorb the scatter they should show; a 2 × 2 grid with 15 matches per pair covered
    its true error at 2σ in 12 of 16 trials with them taken out, 14 of 16 with them in). None with
    fewer than 4 blocks."""
    if not len(fidx):
        return None
    problem = _Problem(data, f, size, pp_prior_sigma)
    problem.free_idx = fidx
    p = np.asarray(params, float)
    r = problem.residuals(p)      # the views' position errors left in: they scatter the angles too
    J = problem.jacobian(p, r)
    w, h = size
    out = None
    mid = 0.5 * (data.xy_a + data.xy_b)
    for key_cells, xy, per_pair in ((cells, data.xy_a, True), (SCENE_CELLS, mid, False)):
        cx = np.clip((xy[:, 0] / w * key_cells).astype(int), 0, key_cells - 1)
        cy = np.clip((xy[:, 1] / h * key_cells).astype(int), 0, key_cells - 1)
        key = cy * key_cells + cx + (data.pair * key_cells * key_cells if per_pair else 0)
        cov = _block_bootstrap(J, r, weights, np.unique(key, return_inverse=True)[1], samples, seed)
        if cov is not None:
            out = cov if out is None else np.where(np.diag(cov)[:, None] > np.diag(out)[:, None], cov, out)
    return out


def _block_bootstrap(J: np.ndarray, r: np.ndarray, weights: np.ndarray, block: np.ndarray, samples: int,
                     seed: int) -> np.ndarray | None:
    """Covariance of the linearised weighted step ``(Jᵀ W J)⁻¹ Jᵀ W r`` over bootstrap samples of the
    blocks ``block`` (label per residual); None with fewer than 4 blocks."""
    nb = int(block.max()) + 1 if len(block) else 0
    if nb < 4:
        return None
    k = J.shape[1]
    wJ = J * weights[:, None]
    G = np.zeros((nb, k))
    Nb = np.zeros((nb, k, k))
    for j in range(k):
        G[:, j] = np.bincount(block, wJ[:, j] * r, nb)
        for i in range(j, k):
            Nb[:, i, j] = Nb[:, j, i] = np.bincount(block, wJ[:, i] * J[:, j], nb)
    rng = np.random.default_rng(seed)
    counts = rng.multinomial(nb, np.full(nb, 1.0 / nb), size=samples).astype(float)
    steps = np.empty((samples, k))
    for s_ in range(samples):
        N = np.einsum("b,bij->ij", counts[s_], Nb)
        steps[s_] = _inverse(N) @ (counts[s_] @ G)
    return np.cov(steps, rowvar=False).reshape(k, k)


def _jackknife_views(data: _Data, pair_views: Sequence[tuple], params: np.ndarray, fidx: np.ndarray, f: float,
                     size: tuple[int, int], pp_prior_sigma: float, weights: np.ndarray, obs: Observability,
                     min_views: int = 4) -> np.ndarray | None:
    """Covariance of the free angles from a delete-one-view jackknife of the linearised weighted
    least-squares step at the solution: each view left out with every pair it is in. The block
    bootstrap (:func:`_bootstrap_angles`) resamples regions of pairs, so an error one view shares
    with all its pairs is invisible to it; on the real Stanford Chess views (each rectified by the
    archive with its own homography) the roll was 3.6 σ off with the default views. The residuals
    keep the views' position errors, as in the bootstrap. A view whose removal leaves a direction the
    fit uses with fewer than :data:`MIN_EVIDENCE_MATCHES` matches is not left out; None with fewer
    than ``min_views`` views left out (2 × 1, 2 × 2: no such spread to measure)."""
    if not len(fidx):
        return None
    problem = _Problem(data, f, size, pp_prior_sigma)
    problem.free_idx = fidx
    p = np.asarray(params, float)
    r = problem.residuals(p)
    J = problem.jacobian(p, r)
    wJ = J * weights[:, None]
    views = sorted({v for pv in pair_views for v in pv})
    steps = []
    for view in views:
        out_pairs = np.array([view in pv for pv in pair_views], bool)
        keep = ~out_pairs[data.pair]
        n_h = int(np.count_nonzero(keep & data.horizontal))
        n_v = int(np.count_nonzero(keep & ~data.horizontal))
        if (obs.rows and n_h < MIN_EVIDENCE_MATCHES) or (obs.columns and n_v < MIN_EVIDENCE_MATCHES):
            continue
        N = J[keep].T @ wJ[keep]
        steps.append(_inverse(N) @ (wJ[keep].T @ r[keep]))
    n = len(steps)
    if n < min_views:
        return None
    steps = np.array(steps)
    dev = steps - steps.mean(axis=0)
    return (n - 1) / n * dev.T @ dev


def observable_limit_px(prior_sigma_px: float) -> float:
    """The 1σ a principal point must be determined to, to be estimated: ``PP_OBSERVABLE_STD_PX`` and
    4× better than its prior."""
    return min(PP_OBSERVABLE_STD_PX, 0.25 * float(prior_sigma_px))


def pp_observable(pp_std_px: ArrayLike, prior_sigma_px: float) -> bool:
    """Whether the views determine both coordinates of the principal point (see :func:`observable_limit_px`)."""
    return bool(np.all(np.asarray(pp_std_px, float) <= observable_limit_px(prior_sigma_px)))


def _inverse(N: np.ndarray, rcond: float = 1e-10) -> np.ndarray:
    """Inverse of a symmetric positive semi-definite (information) matrix that never amplifies noise
    without bound: scaled to unit diagonal and raised by ``rcond`` on the diagonal (every eigenvalue
    at least ``rcond``; more if Cholesky still fails) before it is inverted. A near-null direction
    (one the data barely see) so gets a huge but finite variance, the honest statement, instead of an
    exploding step or the zero variance a pseudo-inverse would claim. (No eigh: OpenBLAS's eigh takes
    ~70 ms for an 85 × 85 matrix here, Cholesky and inv under 1 ms.)"""
    N = 0.5 * (np.asarray(N, float) + np.asarray(N, float).T)
    if N.size == 0:
        return N.copy()
    d = np.sqrt(np.clip(np.diag(N), 1e-300, None))
    S = N / d[:, None] / d[None, :]
    eye = np.eye(len(S))
    ridge = rcond
    while True:
        try:
            A = S + ridge * eye
            np.linalg.cholesky(A)           # positive definite after the ridge, or raise it
            inv = np.linalg.inv(A)
            break
        except np.linalg.LinAlgError:
            ridge *= 100.0
    return inv / d[:, None] / d[None, :]
