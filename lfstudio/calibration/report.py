"""Residual statistics, warnings and the ``calibration.json`` document; a text rendering for the CLI.

Residual statistics (``mean``, ``median``, ``p99``) are of the **absolute** residual; ``rms`` is the
root mean square. A residual is the v-difference of a horizontal match or the u-difference of a
vertical match, in full-resolution pixels of the rectified image. ``before`` is the captured image
(no rectification), ``after`` the rectified one; both over the same matches (those the fit kept).

The uncertainty (:class:`lfstudio.calibration.model.CalibrationUncertainty`, key ``uncertainty``)
is the fit's measured covariance per angle and as the rectification error it allows at the image
corners across the whole grid; warnings say when the views cannot fix the rotation for the grid
(``degenerate``) or determine an angle only loosely (fine for this grid, not for reuse).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from lfstudio.calibration.fit import FitResult, PairMatches
from lfstudio.calibration.model import RECTIFICATION_KEY, ROTATION_CONVENTION, UNCERTAINTY_KEY, \
    CalibrationUncertainty, held_angles, rectification_decision, rotation_angle_deg, \
    rotation_decision, rotation_matrix
from lfstudio.calibration.uncertainty import describe_fit, nearest_disparity_per_mm, rig_floor_px
from lfstudio.dataset.paths import view_stem

FORMAT = "lfstudio-calibration"
VERSION = 1
MIN_PAIR_MATCHES = 20
WEAK_ANGLE_STD_DEG = 0.05   # note when the views determine an angle worse than this (1σ)
ANGLE_NAMES = ("rx (tilt)", "ry (pan)", "rz (roll)")


def stats(residuals: np.ndarray) -> dict[str, float | int | None]:
    r = np.abs(np.asarray(residuals, float))
    if r.size == 0:
        return {"count": 0, "mean": None, "median": None, "rms": None, "p99": None}
    return {"count": int(r.size), "mean": float(r.mean()), "median": float(np.median(r)),
            "rms": float(np.sqrt(np.mean(r * r))), "p99": float(np.percentile(r, 99))}


def _both(before: np.ndarray, after: np.ndarray, horizontal: np.ndarray) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, r in (("before", before), ("after", after)):
        out[name] = {**stats(r), "horizontal": stats(r[horizontal]), "vertical": stats(r[~horizontal])}
    return out


def _name(v: Sequence[int]) -> str:
    return view_stem(int(v[0]), int(v[1]))


def build_report(fit: FitResult, matches: Sequence[PairMatches], *, views: Sequence[tuple[int, int]],
                 feature_counts: dict[tuple[int, int], int] | None = None, settings: dict | None = None,
                 high_residual_px: float | None = None, created: str | None = None,
                 grid_extent_mm: Sequence[float | None] | None = None) -> dict[str, Any]:
    """The ``calibration.json`` document (plain JSON types).

    ``grid_extent_mm``: (full row, full column) baselines of the dataset's grid, for the error at the
    corners; default: the longest baselines among the pairs.
    """
    hor_all = np.concatenate([np.full(m.count, m.direction == "h") for m in matches]) if matches else np.zeros(0, bool)
    inl = fit.inlier
    before, after = fit.residual_before_px, fit.residual_after_px
    overall = _both(before[inl], after[inl], hor_all[inl])
    rms_after = overall["after"]["rms"] or 0.0
    limit = float(high_residual_px) if high_residual_px is not None else max(2.0, 3.0 * rms_after)
    warnings: list[str] = []

    pairs_out = []
    per_view_before: dict[tuple[int, int], list[np.ndarray]] = {}
    per_view_after: dict[tuple[int, int], list[np.ndarray]] = {}
    per_view_xy: dict[tuple[int, int], list[np.ndarray]] = {}
    for m, sl in zip(matches, fit.pair_slices):
        keep = inl[sl]
        rb, ra = before[sl][keep], after[sl][keep]
        pair_stats = {"before": stats(rb), "after": stats(ra)}
        pairs_out.append({
            "views": [_name(m.view_a), _name(m.view_b)], "direction": "horizontal" if m.direction == "h" else "vertical",
            "baseline_mm": float(m.baseline_mm), "matches": int(m.raw_matches), "inliers": int(m.count),
            "used": int(keep.sum()), "residual_px": pair_stats,
        })
        if m.count < MIN_PAIR_MATCHES:
            warnings.append(f"pair {_name(m.view_a)}–{_name(m.view_b)}: only {m.count} good matches "
                            f"(want ≥ {MIN_PAIR_MATCHES}); little overlap or texture — add views or check the images")
        elif pair_stats["after"]["rms"] is not None and pair_stats["after"]["rms"] > limit:
            warnings.append(f"pair {_name(m.view_a)}–{_name(m.view_b)}: residual {pair_stats['after']['rms']:.2f} px "
                            f"RMS after calibration (limit {limit:.2f} px)")
        for v, xy in ((m.view_a, m.xy_a), (m.view_b, m.xy_b)):
            per_view_before.setdefault(v, []).append(rb)
            per_view_after.setdefault(v, []).append(ra)
            per_view_xy.setdefault(v, []).append(xy[keep])

    views_out = []
    for v in sorted(set(views)):
        rb = np.concatenate(per_view_before.get(v, [np.zeros(0)]))
        ra = np.concatenate(per_view_after.get(v, [np.zeros(0)]))
        entry = {"view": _name(v), "row": int(v[0]), "column": int(v[1]),
                 "features": int((feature_counts or {}).get(v, 0)),
                 "residual_px": {"before": stats(rb), "after": stats(ra)}}
        if v in fit.view_offsets_mm:
            entry["position_offset_um"] = [round(1000.0 * float(x), 1) for x in fit.view_offsets_mm[v]]
        views_out.append(entry)
        if ra.size == 0:
            warnings.append(f"view {_name(v)}: no usable matches with any other view; it did not take part")
        elif entry["residual_px"]["after"]["rms"] > limit:
            warnings.append(f"view {_name(v)}: residual {entry['residual_px']['after']['rms']:.2f} px RMS after "
                            f"calibration (limit {limit:.2f} px); the view may have moved or be blurred")
    if not fit.success:
        warnings.append(f"the optimiser did not report convergence: {fit.message}")
    if grid_extent_mm is None:
        grid_extent_mm = tuple(max([m.baseline_mm for m in matches if m.direction == d], default=0.0) or None
                               for d in ("h", "v"))
    uncertainty = describe_fit(fit, matches, *grid_extent_mm)
    warnings += _uncertainty_warnings(fit, matches, uncertainty)
    obs = fit.observability
    if obs is not None:
        warnings += [h["reason"] for h in obs.held()]
    warnings += list(fit.extra.get("warnings") or [])

    w, h = fit.image_size_px
    nominal = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    decision = rotation_decision(fit.rotation_deg, uncertainty.rotation_std_deg,
                                 obs.free if obs is not None else (True, True, True))
    # a rotation the views cannot tell from none is not applied: the homography leaves the views as
    # they are (a principal point alone only translates every view alike, which rectification ignores)
    homography = fit.homography if decision["rotation_applied"] else np.eye(3)
    doc = {
        "format": FORMAT, "version": VERSION,
        "created": created,
        "rotation_deg": [float(a) for a in fit.rotation_deg],
        "rotation_convention": ROTATION_CONVENTION,
        "rotation_std_deg": list(uncertainty.rotation_std_deg),
        "principal_point_px": [float(p) for p in fit.principal_point_px],
        "principal_point_offset_px": [float(p) for p in fit.principal_point_px - nominal],
        "principal_point_estimated": bool(fit.estimate_principal_point),
        "principal_point_reason": fit.principal_point_reason,
        UNCERTAINTY_KEY: uncertainty.to_json(),
        "observability": None if obs is None else obs.to_json(fit.max_angle_deg),
        "radial_distortion": fit.extra.get("radial_distortion"),
        "focal_length_px": float(fit.focal_length_px),
        "image_size_px": [int(w), int(h)],
        "homography": [[float(x) for x in row] for row in homography],
        RECTIFICATION_KEY: decision,
        "homography_maps": "captured full-resolution pixel -> rectified pixel (pixel centres at integers)",
        "residual_px": {"kind": "mean/median/p99 of |residual|, rms = root mean square; full-resolution px",
                        **overall},
        "pairs": pairs_out,
        "views": views_out,
        "views_used": [_name(v) for v in sorted(set(views))],
        "warnings": warnings,
        "fit": {"success": bool(fit.success), "message": fit.message, "evaluations": fit.evaluations,
                "sigma_px": float(fit.sigma_px), "matches_total": int(len(inl)), "matches_used": int(inl.sum())},
        "settings": dict(settings or {}),
    }
    return doc


def _uncertainty_warnings(fit: FitResult, matches: Sequence[PairMatches], u: CalibrationUncertainty) -> list[str]:
    out = []
    c1, c2 = u.corner_error_px or (None, None)
    span = " and ".join(x for x in (f"{u.row_baseline_mm:g} mm along a row" if u.row_baseline_mm else "",
                                    f"{u.column_baseline_mm:g} mm along a column" if u.column_baseline_mm else "")
                        if x)
    if u.degenerate:
        floor = rig_floor_px(fit, nearest_disparity_per_mm(matches, fit.homography, fit.inlier))
        out.append(f"these views cannot fix the rotation for this grid: rows and columns may be off by up to "
                   f"{c1:.2f} px at the image corners (1σ; {c2:.2f} px at 2σ) between views {span} apart, more "
                   f"than the rig's own ±{floor:.2f} px — the pairs' baselines are too short for the grid "
                   "(neighbours only?); use views spread over the whole grid and every pair between them "
                   "(--views default)")
    else:
        free = fit.observability.free if fit.observability is not None else (True, True, True)
        # what the views determine: the stated σ without the systematic floor (which is in it, and
        # which no choice of views at this size removes)
        floor = np.asarray(fit.extra.get("systematic_floor_deg") or np.zeros(3), float)
        evidence = np.sqrt(np.maximum(np.asarray(u.rotation_std_deg, float) ** 2 - floor ** 2, 0.0))
        weak = [f"{name} ±{sd:.3f}°" for name, sd, ev, f in zip(ANGLE_NAMES, u.rotation_std_deg, evidence, free)
                if f and not ev <= WEAK_ANGLE_STD_DEG]
        if weak:
            lines_up = {"rows only": "rows", "columns only": "columns"}.get(
                fit.observability.directions if fit.observability is not None else "", "rows and columns")
            out.append(f"these views determine {', '.join(weak)} only (1σ): enough for this grid ({lines_up} "
                       f"within {c1:.2f} px at the corners, 1σ) but not for reuse on a wider scan "
                       "(longer baselines need longer-baseline views)")
    return out


def uncertainty_lines(doc: dict[str, Any]) -> list[str]:
    """The uncertainty of a calibration document as text lines (the CLI report; the wizard shows the same)."""
    u = CalibrationUncertainty.from_document(doc)
    if u is None:
        return []
    held = held_angles(doc)
    parts = [f"{key} held" if key in held else f"{key} ±{sd:.4f}°"
             for key, sd in zip(("rx", "ry", "rz"), u.rotation_std_deg)]
    measured = u.covariance is not None
    out = [f"  uncertainty {'  '.join(parts)}   (1σ, "
           + ("measured: the views' position errors and the observed residuals)" if measured
              else "formal only: written before measured uncertainties)")]
    out += [f"  held        {entry['reason']}" for entry in held.values()]
    if u.corner_error_px:
        span = ", ".join(x for x in (f"full row {u.row_baseline_mm:g} mm" if u.row_baseline_mm else "",
                                     f"full column {u.column_baseline_mm:g} mm" if u.column_baseline_mm else "")
                         if x)
        out.append(f"  at corners  ≤ {u.corner_error_px[0]:.3f} px (1σ), ≤ {u.corner_error_px[1]:.3f} px (2σ): "
                   f"rectification error at the image corners across the grid ({span}, nearest scene)")
    if u.linear_rotation_deg:
        diff = rotation_angle_deg(rotation_matrix(u.linear_rotation_deg), rotation_matrix(doc["rotation_deg"]))
        lx, ly, lz = u.linear_rotation_deg
        fit_rms = (doc.get("residual_px", {}).get("after") or {}).get("rms")
        if u.linear_residual_px is not None and fit_rms and u.linear_residual_px > 2 * fit_rms + 0.05:
            out.append(f"  closed form not usable with these baselines (the linear epipole method leaves "
                       f"{u.linear_residual_px:.3g} px RMS against the fit's {fit_rms:.2f} px)")
        else:
            out.append(f"  closed form rx {lx:+.4f}°  ry {ly:+.4f}°  rz {lz:+.4f}°   (linear epipole method, the "
                       f"cross-check: {diff:.4f}° from the fit)")
    return out


def _fmt(x: Any, digits: int = 2) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def format_report(doc: dict[str, Any]) -> str:
    """A readable summary of a calibration document."""
    rx, ry, rz = doc["rotation_deg"]
    cx, cy = doc["principal_point_px"]
    lines = [f"rotation      rx {rx:+.4f}°  ry {ry:+.4f}°  rz {rz:+.4f}°   (Euler 'xyz', see docs/conventions.md)"]
    obs = doc.get("observability")
    if isinstance(obs, dict):
        lines.append(f"  determined  {', '.join(obs.get('determined') or []) or 'nothing'} (pairs in "
                     f"{obs.get('pairs')}: {obs.get('matches_in_rows', 0)} matches in rows, "
                     f"{obs.get('matches_in_columns', 0)} in columns)")
    lines += uncertainty_lines(doc)
    decided = rectification_decision(doc)
    if decided:
        lines.append(f"  decision    {decided}")
    pp_text = doc.get("principal_point_reason") or ("estimated" if doc["principal_point_estimated"]
                                                    else "nominal centre")
    lines += [
        f"principal pt  ({cx:.1f}, {cy:.1f}) px   focal length {doc['focal_length_px']:.1f} px   "
        f"image {doc['image_size_px'][0]} × {doc['image_size_px'][1]} px",
        f"  {pp_text}",
        "",
        "residuals (full-resolution px; mean/median/p99 of |r|, rms)",
        f"  {'':19} {'mean':>8} {'median':>8} {'rms':>8} {'p99':>8} {'count':>7}",
    ]
    for when in ("before", "after"):
        for part, label in (("", "all"), ("horizontal", "rows (v)"), ("vertical", "columns (u)")):
            s = doc["residual_px"][when] if not part else doc["residual_px"][when][part]
            lines.append(f"  {when + ' ' + label:19} {_fmt(s['mean']):>8} {_fmt(s['median']):>8} {_fmt(s['rms']):>8} "
                         f"{_fmt(s['p99']):>8} {s['count']:>7}")
    if (doc.get("settings") or {}).get("positions") == "recorded":
        lines += ["", "positions     as the rig recorded them (import --positions): each pair's baseline from the "
                  "record, not the regular grid"]
    lines += ["", "pairs", f"  {'views':22} {'dir':4} {'base mm':>8} {'matches':>8} {'inliers':>8} "
              f"{'rms before':>11} {'rms after':>10}"]
    for p in doc["pairs"]:
        lines.append(f"  {p['views'][0] + '–' + p['views'][1]:22} {p['direction'][0]:4} {p['baseline_mm']:8.{0 if p['baseline_mm'] >= 100 else 2}f} "
                     f"{p['matches']:8d} {p['inliers']:8d} {_fmt(p['residual_px']['before']['rms']):>11} "
                     f"{_fmt(p['residual_px']['after']['rms']):>10}")
    lines += ["", "views", f"  {'view':10} {'features':>9} {'rms before':>11} {'rms after':>10}"]
    for v in doc["views"]:
        lines.append(f"  {v['view']:10} {v['features']:9d} {_fmt(v['residual_px']['before']['rms']):>11} "
                     f"{_fmt(v['residual_px']['after']['rms']):>10}")
    if doc["warnings"]:
        lines += ["", "warnings"] + [f"  ! {w}" for w in doc["warnings"]]
    return "\n".join(lines)
