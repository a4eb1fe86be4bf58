"""The paper's synthetic evaluation of the self-calibration (section 4.1, Figure 3), and more.

Reference rig: 101 × 21 positions, 4 mm × 6 mm apart; camera 7952 × 5304 px, 4.53 µm pitch,
f = 50 mm (11 038 px); random 3-D points in the scene volume 1.77 m … 4.77 m; camera-position noise
σ = 80 µm (x and y, the two axes' repeatability); feature noise σ = 0.5 px per coordinate of each
feature; orientation error drawn per angle with σ = 2.5° and kept within ±5°; principal point shifted
by ``pp_shift_px`` at a uniformly random angle. The views (``SimulationConfig.views``, default the
paper's 2 × 3: rows 0 and 20, columns 0, 50 and 100; any :meth:`lfstudio.dataset.grid.Grid.select`
spec such as ``"array:5x3"``, ``"default"`` or ``"array:101x2"`` for two full rows) and the pair set
(``pair_set``: all, spanning, neighbours) give the pairs. The fit is told the rig's repeatability
(``position_noise_um``) as its prior.

Per trial we report, in pixels of the full-resolution rectified image:

- ``residual``: the RMS of the calibration residuals (v-difference of horizontal matches,
  u-difference of vertical ones) of the noisy matches after calibration — what an operator sees on
  real data; with σ = 0.5 px per feature its floor is ≈ 0.71 px;
- ``true_residual``: the RMS rectification error of exact, noise-free correspondences of the ideal
  rig (no position noise) after applying the recovered homography, on a **fixed evaluation set**:
  every pair of the 3 × 5 array spread over the grid (baselines up to the full row and column),
  whatever views the calibration used — the honest accuracy; ``true_residual_used`` is the same on
  the pairs the calibration used;
- ``rotation_error``: the angle between the recovered and the true orientation (degrees);
- ``coverage``: whether the true error lies within the fit's stated 1σ and 2σ bounds
  (:mod:`lfstudio.calibration.uncertainty`): on the evaluation set (RMS), at the image corners of a
  full row and column (max), and per angle;
- ``linear``: the same errors for the linear epipole method (:mod:`lfstudio.calibration.linear`) on
  the same matches, the baseline.

Statistics over trials: mean, 1st and 99th percentile (residuals), median and 99th percentile
(rotation error), the fractions covered, with and without principal-point estimation (``"auto"``:
estimated only where observable).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from lfstudio.calibration.fit import CalibrationError, PairMatches, fit_rectification, signed_residuals
from lfstudio.calibration.linear import linear_rotation
from lfstudio.calibration.model import (intrinsics, nominal_principal_point, project, rotation_angle_deg,
                                        rotation_matrix)
from lfstudio.calibration.pairs import DEFAULT_PAIR_SET, DEFAULT_VIEWS, PAIR_SETS, Pair, make_pairs
from lfstudio.calibration.uncertainty import (Probes, corner_probes, error_bounds, metric_of,
                                              nearest_disparity_per_mm, probe_errors, probe_jacobian)
from lfstudio.dataset.grid import Grid, View
from lfstudio.jobs import CancelToken, Progress, no_progress
from lfstudio.optics import REFERENCE

#: the fixed evaluation set: every pair of this array (rows × columns) spread over the grid
EVAL_ARRAY = (3, 5)


@dataclass
class SimulationConfig:
    columns: int = REFERENCE.grid[0]
    rows: int = REFERENCE.grid[1]
    spacing_mm: tuple[float, float] = REFERENCE.spacing_mm
    image_size_px: tuple[int, int] = REFERENCE.sensor_px
    pixel_pitch_um: float = REFERENCE.pixel_pitch_um
    focal_length_mm: float = REFERENCE.focal_length_mm
    near_m: float = REFERENCE.near_m
    far_m: float = REFERENCE.far_m
    position_noise_um: float = REFERENCE.repeatability_um[0]
    feature_noise_px: float = 0.5
    rotation_sigma_deg: float = 2.5
    rotation_max_deg: float = 5.0
    points_per_pair: int = 300
    views: str = "array:3x2"                  # a selection (Grid.select): "array:3x2", "array:5x3", "default", "array:101x2", "array:4ex10"
    pair_set: str = DEFAULT_PAIR_SET          # PAIR_SETS ("spanning" = "all" for the 2 × 3 array)
    outlier_fraction: float = 0.0             # share of matches replaced by random wrong ones
    distortion_px: float = 0.0                # uncorrected barrel distortion at the image corners (px)
    eval_points_per_pair: int = 100

    @property
    def focal_length_px(self) -> float:
        return self.focal_length_mm / (self.pixel_pitch_um / 1000.0)

    @property
    def grid(self) -> Grid:
        return Grid(self.columns, self.rows, (float(self.spacing_mm[0]), float(self.spacing_mm[1])))

    def chosen_views(self) -> list[View]:
        grid = self.grid
        return grid.select(self.views, grid.views(), default=DEFAULT_VIEWS, field_name="--views")

    def pairs(self) -> list[Pair]:
        if self.pair_set not in PAIR_SETS:
            raise CalibrationError(f"pair set {self.pair_set!r}: use one of {', '.join(PAIR_SETS)}")
        return make_pairs(self.chosen_views(), spacing_mm=self.spacing_mm, pair_set=self.pair_set)

    def eval_pairs(self) -> list[Pair]:
        return make_pairs(self.grid.spread(*EVAL_ARRAY), spacing_mm=self.spacing_mm)


@dataclass
class Trial:
    rotation_deg: np.ndarray
    principal_point_px: np.ndarray
    matches: list[PairMatches]
    ideal: list[PairMatches]            # noise-free correspondences of the ideal rig, pairs used
    evaluation: Probes                  # ideal rectified correspondences of the evaluation set
    extra: dict = field(default_factory=dict)

    @property
    def truth(self) -> np.ndarray:
        """[rx, ry, rz, cx offset, cy offset] as the fit's parameters."""
        return np.concatenate([self.rotation_deg, self.extra["pp_offset_px"]])


def _draw_rotation(rng: np.random.Generator, sigma: float, limit: float) -> np.ndarray:
    out = rng.normal(0.0, sigma, 3)
    while np.any(np.abs(out) > limit):
        bad = np.abs(out) > limit
        out[bad] = rng.normal(0.0, sigma, int(bad.sum()))
    return out


def _camera_centre(view: tuple[int, int], cfg: SimulationConfig) -> np.ndarray:
    r, c = view
    return np.array([c * cfg.spacing_mm[0] / 1000.0, r * cfg.spacing_mm[1] / 1000.0, 0.0])


def _points_seen_by_both(rng, pair: Pair, cfg: SimulationConfig, R: np.ndarray, K: np.ndarray, n_points: int):
    """World points of the scene volume that both views of ``pair`` see (rejection sampling)."""
    w, h = cfg.image_size_px
    Kinv = np.linalg.inv(K)
    ca, cb = _camera_centre(pair.a, cfg), _camera_centre(pair.b, cfg)
    pts = np.zeros((0, 3))
    for _ in range(20):
        n = n_points * 2
        pix = np.column_stack([rng.uniform(0, w - 1, n), rng.uniform(0, h - 1, n), np.ones(n)])
        depth = rng.uniform(cfg.near_m, cfg.far_m, n)
        rays = (pix @ Kinv.T) @ R          # R^T K^-1 p, row-wise
        X = ca + rays * (depth / rays[:, 2])[:, None]
        pb, zb = project(X, cb, R, K)
        ok = (zb > 0) & (pb[:, 0] >= 0) & (pb[:, 0] <= w - 1) & (pb[:, 1] >= 0) & (pb[:, 1] <= h - 1)
        pts = np.concatenate([pts, X[ok]])
        if len(pts) >= n_points:
            break
    return pts[:n_points]


def make_trial(rng: np.random.Generator, pp_shift_px: float, cfg: SimulationConfig | None = None,
               rotation_deg: ArrayLike | None = None) -> Trial:
    """Draw one synthetic experiment: true orientation, principal point, noisy and ideal matches,
    and the evaluation set."""
    cfg = cfg or SimulationConfig()
    w, h = cfg.image_size_px
    f = cfg.focal_length_px
    rot = _draw_rotation(rng, cfg.rotation_sigma_deg, cfg.rotation_max_deg) if rotation_deg is None \
        else np.asarray(rotation_deg, float)
    phi = rng.uniform(0.0, 2 * np.pi)
    offset = pp_shift_px * np.array([np.cos(phi), np.sin(phi)])
    pp = nominal_principal_point((w, h)) + offset
    R = rotation_matrix(rot)
    K = intrinsics(f, pp)
    pairs = cfg.pairs()
    views = sorted({p.a for p in pairs} | {p.b for p in pairs})
    sigma_c = cfg.position_noise_um * 1e-6
    noisy_centre = {v: _camera_centre(v, cfg) + np.array([*rng.normal(0.0, sigma_c, 2), 0.0]) for v in views}
    matches, ideal = [], []
    for pair in pairs:
        pts = _points_seen_by_both(rng, pair, cfg, R, K, cfg.points_per_pair)
        n = len(pts)
        a_true, _ = project(pts, noisy_centre[pair.a], R, K)
        b_true, _ = project(pts, noisy_centre[pair.b], R, K)
        a = distort(a_true, cfg.distortion_px, (w, h)) + rng.normal(0.0, cfg.feature_noise_px, (n, 2))
        b = distort(b_true, cfg.distortion_px, (w, h)) + rng.normal(0.0, cfg.feature_noise_px, (n, 2))
        if cfg.outlier_fraction > 0:
            k = int(round(cfg.outlier_fraction * n))
            idx = rng.choice(n, k, replace=False)
            b[idx] = np.column_stack([rng.uniform(0, w - 1, k), rng.uniform(0, h - 1, k)])
        matches.append(PairMatches(pair.a, pair.b, pair.direction, a, b, raw_matches=n,
                                   baseline_mm=pair.baseline_mm))
        ca, cb = _camera_centre(pair.a, cfg), _camera_centre(pair.b, cfg)
        ia, _ = project(pts, ca, R, K)
        ib, _ = project(pts, cb, R, K)
        ideal.append(PairMatches(pair.a, pair.b, pair.direction, ia, ib, raw_matches=n,
                                 baseline_mm=pair.baseline_mm))
    K0 = intrinsics(f, nominal_principal_point((w, h)))
    qa, qb, hor = [], [], []
    for pair in cfg.eval_pairs():
        pts = _points_seen_by_both(rng, pair, cfg, R, K, cfg.eval_points_per_pair)
        qa.append(project(pts, _camera_centre(pair.a, cfg), np.eye(3), K0)[0])
        qb.append(project(pts, _camera_centre(pair.b, cfg), np.eye(3), K0)[0])
        hor.append(np.full(len(pts), pair.direction == "h"))
    evaluation = Probes(np.concatenate(qa), np.concatenate(qb), np.concatenate(hor))
    return Trial(rotation_deg=rot, principal_point_px=pp, matches=matches, ideal=ideal, evaluation=evaluation,
                 extra={"pp_offset_px": offset})


def distort(xy: np.ndarray, corner_px: float, image_size_px: Sequence[int]) -> np.ndarray:
    """Barrel distortion that moves the image corners ``corner_px`` towards the centre (one radial
    term about the image centre: ``x_d = c + (x − c)(1 − k (r / r_c)²)``, ``k = corner_px / r_c``,
    ``r_c`` the centre-to-corner distance): what a lens without a lens model leaves in the captures."""
    if not corner_px:
        return xy
    w, h = image_size_px
    c = nominal_principal_point((w, h))
    rc = float(np.hypot(w / 2.0, h / 2.0))
    d = xy - c
    r2 = np.sum(d * d, axis=1, keepdims=True) / rc ** 2
    return c + d * (1.0 - (float(corner_px) / rc) * r2)


def equivalent_truth(rotation_deg: ArrayLike, free: Sequence[bool]) -> np.ndarray:
    """The angles a fit that holds the undetermined angle at 0 should find: the truth itself when
    all three are determined; (0, ry, rz) for rows only (a row sees ``R·e_x``, which the tilt does
    not move); for columns only the tilt and roll with pan 0 that turn ``e_y`` to the true ``R·e_y``."""
    rot = np.asarray(rotation_deg, float)
    free = tuple(bool(f) for f in free)
    if all(free):
        return rot
    if free == (False, True, True):
        return np.array([0.0, rot[1], rot[2]])
    v = rotation_matrix(rot) @ np.array([0.0, 1.0, 0.0])
    # R(a, 0, c) e_y = (−sin c cos a, cos c cos a, sin a)
    return np.array([np.degrees(np.arcsin(np.clip(v[2], -1, 1))), 0.0, np.degrees(np.arctan2(-v[0], v[1]))])


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def _concat(matches: Sequence[PairMatches]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (np.concatenate([m.xy_a for m in matches]), np.concatenate([m.xy_b for m in matches]),
            np.concatenate([np.full(m.count, m.direction == "h") for m in matches]))


def evaluate_trial(trial: Trial, cfg: SimulationConfig, estimate_principal_point: bool | str = "auto",
                   *, linear: bool = False) -> dict:
    """Calibrate one trial; return residuals, true errors, rotation error, stated bounds and coverage.

    ``estimate_principal_point``: ``"auto"`` or True (estimated where observable), ``"centre"`` or
    False (held). ``linear``: also evaluate the linear epipole method (key ``linear``).
    """
    mode = estimate_principal_point if isinstance(estimate_principal_point, str) else \
        ("auto" if estimate_principal_point else "centre")
    w, h = cfg.image_size_px
    f = cfg.focal_length_px
    t0 = time.process_time()
    fit = fit_rectification(trial.matches, f, (w, h), principal_point=mode,
                            position_sigma_um=(cfg.position_noise_um, cfg.position_noise_um))
    fit_cpu_s = time.process_time() - t0
    truth = trial.truth
    r_after = fit.residual_after_px[fit.inlier]
    ideal_a, ideal_b, hor = _concat(trial.ideal)
    true_used = signed_residuals(fit.homography, ideal_a, ideal_b, hor)
    true_eval = probe_errors(trial.evaluation, fit.params, truth, f, (w, h))
    # the stated bounds: on the evaluation set (RMS) and at the corners of a full row / column (max)
    J_eval = probe_jacobian(trial.evaluation, fit.params, f, (w, h))
    eval_bounds = error_bounds(J_eval, fit.covariance, "rms")
    k = nearest_disparity_per_mm(trial.matches, fit.homography, fit.inlier)
    corners = corner_probes((w, h), k * (cfg.columns - 1) * cfg.spacing_mm[0] if k and cfg.columns > 1 else None,
                            k * (cfg.rows - 1) * cfg.spacing_mm[1] if k and cfg.rows > 1 else None)
    corner_bounds = error_bounds(probe_jacobian(corners, fit.params, f, (w, h)), fit.covariance, "max")
    corner_true = metric_of(probe_errors(corners, fit.params, truth, f, (w, h)), "max")
    eval_true = _rms(true_eval)
    free = fit.observability.free if fit.observability is not None else (True, True, True)
    target = equivalent_truth(trial.rotation_deg, free)
    err = np.abs(fit.rotation_deg - target)[np.asarray(free)]
    std = fit.rotation_std_deg[np.asarray(free)]
    z = err / np.maximum(std, 1e-12)
    out = {
        "residual_px": _rms(r_after),
        "residual_mean_abs_px": float(np.mean(np.abs(r_after))),
        "residual_before_px": _rms(fit.residual_before_px),
        "true_residual_px": eval_true,
        "true_residual_used_px": _rms(true_used),
        "true_residual_max_px": float(np.max(np.abs(true_eval))),
        "rotation_error_deg": rotation_angle_deg(rotation_matrix(fit.rotation_deg), rotation_matrix(target)),
        "confident_wrong": bool(np.any((err > 1.0) & (std < 0.3))),
        "warnings": list(fit.extra.get("warnings", [])),
        "pp_error_px": float(np.hypot(*(fit.principal_point_px - trial.principal_point_px))),
        "pp_estimated": bool(fit.estimate_principal_point),
        "stated_true_residual_px": eval_bounds,
        "stated_corner_px": corner_bounds,
        "corner_error_px": corner_true,
        "covered": {"eval_1": eval_true <= eval_bounds[0], "eval_2": eval_true <= eval_bounds[1],
                    "corner_1": corner_true <= corner_bounds[0], "corner_2": corner_true <= corner_bounds[1],
                    "angle_1": float(np.mean(z <= 1.0)), "angle_2": float(np.mean(z <= 2.0))},
        "fit_cpu_s": fit_cpu_s,
    }
    if linear:
        t0 = time.process_time()
        lin = linear_rotation(trial.matches, f, (w, h))
        lin_cpu_s = time.process_time() - t0
        if lin is not None:
            lp = np.concatenate([lin.rotation_deg, [0.0, 0.0]])
            out["linear"] = {
                "true_residual_px": _rms(probe_errors(trial.evaluation, lp, truth, f, (w, h))),
                "rotation_error_deg": rotation_angle_deg(rotation_matrix(lin.rotation_deg),
                                                         rotation_matrix(trial.rotation_deg)),
                "fit_cpu_s": lin_cpu_s}
    return out


def _fraction(rows: list[dict], key: str) -> float:
    return float(np.mean([float(r["covered"][key]) for r in rows]))


def summarise(rows: list[dict]) -> dict:
    """Over-trial statistics of :func:`evaluate_trial` rows."""
    def arr(key, src=None):
        return np.array([(r if src is None else r[src])[key] for r in rows if src is None or src in r], float)
    res, true, rot = arr("residual_px"), arr("true_residual_px"), arr("rotation_error_deg")
    pp_err = arr("pp_error_px")
    est = np.array([r["pp_estimated"] for r in rows], bool)
    out = {
        "trials": len(rows),
        "residual_px": {"mean": float(res.mean()), "p1": float(np.percentile(res, 1)),
                        "p99": float(np.percentile(res, 99))},
        "residual_mean_abs_px": {"mean": float(arr("residual_mean_abs_px").mean())},
        "residual_before_px": {"mean": float(arr("residual_before_px").mean())},
        "true_residual_px": {"mean": float(true.mean()), "rms": float(np.sqrt(np.mean(true ** 2))),
                             "p99": float(np.percentile(true, 99)), "max": float(true.max())},
        "true_residual_used_px": {"mean": float(arr("true_residual_used_px").mean())},
        "rotation_error_deg": {"median": float(np.median(rot)), "p99": float(np.percentile(rot, 99))},
        "pp_error_px": {"median": float(np.median(pp_err)),
                        "max_estimated": float(pp_err[est].max()) if est.any() else None,
                        "estimated_trials": int(est.sum())},
        "stated_true_residual_px": {"median_1sigma": float(np.median([r["stated_true_residual_px"][0] for r in rows])),
                                    "median_2sigma": float(np.median([r["stated_true_residual_px"][1] for r in rows]))},
        "stated_corner_px": {"median_1sigma": float(np.median([r["stated_corner_px"][0] for r in rows])),
                             "median_2sigma": float(np.median([r["stated_corner_px"][1] for r in rows]))},
        "corner_error_px": {"mean": float(arr("corner_error_px").mean()),
                            "p99": float(np.percentile(arr("corner_error_px"), 99))},
        "coverage": {"true_residual": [_fraction(rows, "eval_1"), _fraction(rows, "eval_2")],
                     "corner": [_fraction(rows, "corner_1"), _fraction(rows, "corner_2")],
                     "angle": [_fraction(rows, "angle_1"), _fraction(rows, "angle_2")]},
        "fit_cpu_s": {"mean": float(arr("fit_cpu_s").mean())},
        "confident_wrong": int(sum(bool(r["confident_wrong"]) for r in rows)),
        "warned": int(sum(bool(r["warnings"]) for r in rows)),
    }
    lin = [r["linear"] for r in rows if "linear" in r]
    if lin:
        lt = np.array([x["true_residual_px"] for x in lin])
        lr = np.array([x["rotation_error_deg"] for x in lin])
        out["linear"] = {"trials": len(lin), "true_residual_px": {"mean": float(lt.mean()),
                                                                  "rms": float(np.sqrt(np.mean(lt ** 2))),
                                                                  "p99": float(np.percentile(lt, 99))},
                         "rotation_error_deg": {"median": float(np.median(lr)), "p99": float(np.percentile(lr, 99))},
                         "fit_cpu_s": {"mean": float(np.mean([x["fit_cpu_s"] for x in lin]))}}
    return out


def simulate(trials: int = 100, pp_shift_px: float = 0.0, seed: int = 0, cfg: SimulationConfig | None = None,
             modes: Sequence[bool | str] = ("centre", "auto"), progress: Progress = no_progress,
             cancel: CancelToken | None = None, linear: bool = False, allow_all_refused: bool = False) -> dict:
    """Run ``trials`` synthetic calibrations; returns the JSON-ready summary (``refusals``: the
    messages of the trials the fit refused; ``allow_all_refused``: return that instead of raising
    when every trial was refused).

    ``modes``: principal point ``"centre"`` (held, the paper's method) and/or ``"auto"`` (estimated
    where observable); True/False are the older spellings. Top-level keys ``residual_px``,
    ``rotation_error_deg``, ``true_residual_px``, ``coverage`` … hold the first mode's results;
    ``without_principal_point`` ("centre") and ``with_principal_point`` ("auto") hold each mode.
    """
    cfg = cfg or SimulationConfig()
    if trials < 1:
        raise CalibrationError("trials must be at least 1")
    modes = [m if isinstance(m, str) else ("auto" if m else "centre") for m in modes]
    rng = np.random.default_rng(seed)
    per_mode: dict[str, list[dict]] = {m: [] for m in modes}
    failures = 0
    refusals: list[str] = []
    for i in range(trials):
        if cancel is not None:
            cancel.check()
        trial = make_trial(rng, pp_shift_px, cfg)
        for k, mode in enumerate(modes):
            try:
                per_mode[mode].append(evaluate_trial(trial, cfg, mode, linear=linear and k == 0))
            except CalibrationError as exc:
                failures += 1
                refusals.append(str(exc))
        progress(i + 1, trials, f"pp shift {pp_shift_px:g} px")
    pairs = cfg.pairs()
    out: dict = {"trials": trials, "pp_shift_px": float(pp_shift_px), "seed": seed, "failures": failures,
                 "refusals": refusals,
                 "views": len({p.a for p in pairs} | {p.b for p in pairs}), "pairs": len(pairs),
                 "evaluation_set": f"every pair of the {EVAL_ARRAY[0]} x {EVAL_ARRAY[1]} array over the grid "
                                   f"({len(cfg.eval_pairs())} pairs)",
                 "residual_kind": "RMS over matches of one trial (v-difference of horizontal matches, "
                                  "u-difference of vertical ones), full-resolution pixels",
                 "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()}}
    summaries = {mode: summarise(rows) for mode, rows in per_mode.items() if rows}
    if not summaries:
        if allow_all_refused:
            return out
        raise CalibrationError("every simulated calibration failed")
    primary = summaries[next(m for m in modes if m in summaries)]
    out.update({k: v for k, v in primary.items() if k != "trials"})
    if "centre" in summaries:
        out["without_principal_point"] = summaries["centre"]
    if "auto" in summaries:
        out["with_principal_point"] = summaries["auto"]
    return out


def sweep(radii_px: Sequence[float], trials: int = 100, seed: int = 0, cfg: SimulationConfig | None = None,
          modes: Sequence[bool | str] = ("centre", "auto"), progress: Progress = no_progress,
          cancel: CancelToken | None = None, linear: bool = False) -> list[dict]:
    """:func:`simulate` for every principal-point shift radius (Figure 3)."""
    results = []
    all_trials = len(radii_px) * trials
    for k, r in enumerate(radii_px):
        def sub_progress(done: int, total: int, message: str = "", k: int = k) -> None:
            progress(k * trials + done, all_trials, message)
        results.append(simulate(trials, r, seed + k, cfg, modes, sub_progress, cancel, linear))
    return results
