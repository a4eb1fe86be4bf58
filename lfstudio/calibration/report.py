"""Residual statistics, warnings and the ``calibration.json`` document; a text rendering for the CLI.

Residual statistics (``mean``, ``median``, ``p99``) are of the **absolute** residual; ``rms`` is the
root mean square. A residual is the v-difference of a horizontal match or the u-difference of a
vertical match, in full-resolution pixels of the rectified image. ``before`` is the captured image
(no rectification), ``after`` the rectified one; both over the same matches (those the fit kept).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from lfstudio.calibration.fit import FitResult, PairMatches
from lfstudio.calibration.model import ROTATION_CONVENTION
from lfstudio.dataset.paths import view_stem

FORMAT = "lfstudio-calibration"
VERSION = 1
MIN_PAIR_MATCHES = 20
WEAK_ANGLE_STD_DEG = 0.05   # warn when the views determine an angle worse than this


def stats(residuals: np.ndarray) -> dict[str, float | int | None]:
    r = np.abs(np.asarray(residuals, float))
    if r.size == 0:
        return {"count": 0, "mean": None, "median": None, "rms": None, "p99": None}
    return {"count": int(r.size), "mean": float(r.mean()), "median": float(np.median(r)),
            "rms": float(np.sqrt(np.mean(r * r))), "p99": float(np.percentile(r, 99))}


def _both(before: np.ndarray, after: np.ndarray, horizontal: np.ndarray) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, r in (("before", before), ("after", after)):
        s = stats(r)
        s["horizontal"] = stats(r[horizontal])
        s["vertical"] = stats(r[~horizontal])
        out[name] = s
    return out


def _name(v: Sequence[int]) -> str:
    return view_stem(int(v[0]), int(v[1]))


def build_report(fit: FitResult, matches: Sequence[PairMatches], *, views: Sequence[tuple[int, int]],
                 feature_counts: dict[tuple[int, int], int] | None = None, settings: dict | None = None,
                 high_residual_px: float | None = None, created: str | None = None) -> dict[str, Any]:
    """The ``calibration.json`` document (plain JSON types)."""
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
        views_out.append(entry)
        if ra.size == 0:
            warnings.append(f"view {_name(v)}: no usable matches with any other view; it did not take part")
        elif entry["residual_px"]["after"]["rms"] > limit:
            warnings.append(f"view {_name(v)}: residual {entry['residual_px']['after']['rms']:.2f} px RMS after "
                            f"calibration (limit {limit:.2f} px); the view may have moved or be blurred")
    if not fit.success:
        warnings.append(f"the optimiser did not report convergence: {fit.message}")
    std = fit.extra.get("rotation_std_deg")
    if std is not None:
        weak = [f"{name} ±{sd:.3f}°" for name, sd in zip(("rx (tilt)", "ry (pan)", "rz (roll)"), std)
                if not sd <= WEAK_ANGLE_STD_DEG]
        if weak:
            warnings.append(f"these views determine {', '.join(weak)} only (formal standard error; the true "
                            f"uncertainty is larger): use views farther apart (wider baselines, e.g. --views 2x3 "
                            f"across the whole grid) for rectification that holds over wide baselines")
    if overall["after"]["vertical"]["count"] == 0:
        warnings.append("no vertical pairs: the tilt angle (rx) is not constrained; use views from two or more rows")

    w, h = fit.image_size_px
    nominal = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    doc = {
        "format": FORMAT, "version": VERSION,
        "created": created,
        "rotation_deg": [float(a) for a in fit.rotation_deg],
        "rotation_convention": ROTATION_CONVENTION,
        "rotation_std_deg": None if std is None else [float(x) for x in std],
        "principal_point_px": [float(p) for p in fit.principal_point_px],
        "principal_point_offset_px": [float(p) for p in fit.principal_point_px - nominal],
        "principal_point_estimated": bool(fit.estimate_principal_point),
        "focal_length_px": float(fit.focal_length_px),
        "image_size_px": [int(w), int(h)],
        "homography": [[float(x) for x in row] for row in fit.homography],
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


def _fmt(x: Any, digits: int = 2) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def format_report(doc: dict[str, Any]) -> str:
    """A readable summary of a calibration document."""
    rx, ry, rz = doc["rotation_deg"]
    cx, cy = doc["principal_point_px"]
    std = doc.get("rotation_std_deg")
    lines = [
        f"rotation      rx {rx:+.4f}°  ry {ry:+.4f}°  rz {rz:+.4f}°   (Euler 'xyz', see docs/conventions.md)",
        *([f"  std. error  rx ±{std[0]:.4f}°  ry ±{std[1]:.4f}°  rz ±{std[2]:.4f}°   (formal, from the fit)"]
          if std else []),
        f"principal pt  ({cx:.1f}, {cy:.1f}) px  {'estimated' if doc['principal_point_estimated'] else 'nominal centre'}"
        f"   focal length {doc['focal_length_px']:.1f} px   image {doc['image_size_px'][0]} × {doc['image_size_px'][1]} px",
        "",
        "residuals (full-resolution px; mean/median/p99 of |r|, rms)",
        f"  {'':19} {'mean':>8} {'median':>8} {'rms':>8} {'p99':>8} {'count':>7}",
    ]
    for when in ("before", "after"):
        for part, label in (("", "all"), ("horizontal", "rows (v)"), ("vertical", "columns (u)")):
            s = doc["residual_px"][when] if not part else doc["residual_px"][when][part]
            lines.append(f"  {when + ' ' + label:19} {_fmt(s['mean']):>8} {_fmt(s['median']):>8} {_fmt(s['rms']):>8} "
                         f"{_fmt(s['p99']):>8} {s['count']:>7}")
    lines += ["", "pairs", f"  {'views':22} {'dir':4} {'base mm':>8} {'matches':>8} {'inliers':>8} "
              f"{'rms before':>11} {'rms after':>10}"]
    for p in doc["pairs"]:
        lines.append(f"  {p['views'][0] + '–' + p['views'][1]:22} {p['direction'][0]:4} {p['baseline_mm']:8.0f} "
                     f"{p['matches']:8d} {p['inliers']:8d} {_fmt(p['residual_px']['before']['rms']):>11} "
                     f"{_fmt(p['residual_px']['after']['rms']):>10}")
    lines += ["", "views", f"  {'view':10} {'features':>9} {'rms before':>11} {'rms after':>10}"]
    for v in doc["views"]:
        lines.append(f"  {v['view']:10} {v['features']:9d} {_fmt(v['residual_px']['before']['rms']):>11} "
                     f"{_fmt(v['residual_px']['after']['rms']):>10}")
    if doc["warnings"]:
        lines += ["", "warnings"] + [f"  ! {w}" for w in doc["warnings"]]
    return "\n".join(lines)
