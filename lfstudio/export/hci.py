"""The HCI 4D light-field benchmark layout (Honauer et al. 2016) for a sub-array of the grid.

A folder with ``parameters.cfg`` (INI: ``[intrinsics]``, ``[extrinsics]``, ``[meta]`` as read by the
benchmark toolkit's ``file_io.read_parameters``) and ``input_Cam000.png`` … in row-major order
(top row first, left to right; the toolkit puts file ``idx`` at row ``idx // num_cams_x``, column
``idx % num_cams_x``). With more than 1000 views the number field widens to fit
(``input_Cam0000.png`` …) so that names still sort in view order. Images are 8-bit sRGB PNGs like
the benchmark's (``hci_bit_depth=16``: linear 16-bit). ``lfstudio_manifest.json`` adds our own
description (positions, calibration, intrinsics).

Disparities follow the toolkit's meaning: pixels between horizontally neighbouring views, positive
for near points, ``disparity = baseline·f·max(w, h)/sensor · (1/Z − 1/focus_distance_m)`` (the
toolkit's ``depth2disp``/``disp2depth``). Our views are parallel (no sensor shift), so zero disparity
lies at infinity: ``focus_distance_m`` is :data:`FOCUS_AT_INFINITY_M` (1e9 m; the formulas' 1/focus
term is then under a millionth of 1/Z for any depth up to 1 km, and nothing divides by zero) — *not* the lens focus, which
the toolkit would take for the zero-disparity plane (``lens_focus_distance_m`` in ``[meta]`` keeps
it). The views are not shifted to put zero disparity at a finite plane: that would resample every
view once more (blur that differs from view to view, lost borders) for no gain in geometry.
``focal_length_mm``/``sensor_size_mm`` are chosen so that ``focal_length_mm/sensor_size_mm·max(w, h)``
is the exported camera's focal length in pixels (:func:`lfstudio.export.poses.camera_for`).
``disp_min``/``disp_max``: the neighbour disparities of the plan's far and near distance, or, for a
dataset without a plan (a CLI scan), measured from the views (:func:`measured_disparity_range`).
"""

from __future__ import annotations

import configparser
import datetime as _dt
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from lfstudio import optics
from lfstudio.dataset import Dataset
from lfstudio.dataset.paths import view_stem
from lfstudio.dataset.zero_plane import zero_plane
from lfstudio.errors import DatasetError, InputError
from lfstudio.export import common
from lfstudio.jobs import CancelToken, Progress

PARAMETERS_NAME = "parameters.cfg"
MANIFEST_NAME = "lfstudio_manifest.json"


def cam_name(index: int, count: int) -> str:
    """``input_Cam007.png``; the number widens past 1000 views (``input_Cam0007.png``)."""
    digits = max(3, len(str(max(count - 1, 0))))
    return f"input_Cam{index:0{digits}d}.png"


def sub_array(ds: Dataset, options) -> list[common.View]:
    """The chosen sub-array, row-major: ``options.views`` when given (must be a full rectangle of
    captured views), else ``hci_size`` (columns, rows) around ``hci_center`` (row, column) or the
    grid centre. ``None``/``"all"`` mean no explicit subset."""
    chosen = options.views
    if isinstance(chosen, str) and chosen.strip().lower() in ("", "all"):
        chosen = None    # "all" means "no explicit subset": the sub-array from hci_size/hci_center
    if chosen is not None:
        views = ds.select(options.views)
        rows = sorted({r for r, _ in views})
        cols = sorted({c for _, c in views})
        have = set(views)
        holes = [(r, c) for r in rows for c in cols if (r, c) not in have]
        if holes:
            raise InputError("views", f"the HCI layout needs a full rectangle of views; {len(holes)} missing in "
                             f"rows {rows[0]}-{rows[-1]}, columns {cols[0]}-{cols[-1]}",
                             "a range like r6-14,c46-54 with every view captured")
        return [common.View(r, c) for r in rows for c in cols]
    n_cols, n_rows = int(options.hci_size[0]), int(options.hci_size[1])
    g_cols, g_rows = ds.grid.columns, ds.grid.rows
    if n_cols > g_cols or n_rows > g_rows:
        raise InputError("hci_size", f"{n_cols}x{n_rows} is larger than the {g_cols} x {g_rows} grid",
                         f"up to {g_cols}x{g_rows}")
    if options.hci_center is None:
        r0 = min(max((g_rows - 1) // 2 - (n_rows - 1) // 2, 0), g_rows - n_rows)
        c0 = min(max((g_cols - 1) // 2 - (n_cols - 1) // 2, 0), g_cols - n_cols)
    else:
        cr, cc = int(options.hci_center[0]), int(options.hci_center[1])
        r0, c0 = cr - (n_rows - 1) // 2, cc - (n_cols - 1) // 2
        if r0 < 0 or c0 < 0 or r0 + n_rows > g_rows or c0 + n_cols > g_cols:
            raise InputError("hci_center", f"a {n_cols}x{n_rows} array centred on row {cr}, column {cc} leaves the "
                             f"{g_cols} x {g_rows} grid",
                             f"rows {(n_rows - 1) // 2}-{g_rows - 1 - n_rows // 2}, "
                             f"columns {(n_cols - 1) // 2}-{g_cols - 1 - n_cols // 2}")
    views = [common.View(r, c) for r in range(r0, r0 + n_rows) for c in range(c0, c0 + n_cols)]
    have = set(ds.captured_views())
    missing = [v for v in views if v not in have]
    if missing:
        raise InputError("hci_center", f"the sub-array has {len(missing)} views without a capture "
                         f"({', '.join(view_stem(*v) for v in missing[:4])}{' …' if len(missing) > 4 else ''})",
                         "a centre whose whole sub-array is captured")
    return views


def estimate_bytes(n: int, size: Sequence[int], bit_depth: int = 8) -> int:
    return common.images_bytes_estimate(n, size, bit_depth) + 8192


def _plan_numbers(ds: Dataset) -> dict[str, float | None]:
    plan = ds.manifest.get("plan") or {}
    f_mm = float(ds.lens.get("focal_length_mm") or plan.get("focal_length_mm") or 0) or None
    near = plan.get("near_m")
    far = plan.get("far_m")
    near = float(near) if isinstance(near, (int, float)) and near > 0 else None
    far = float(far) if isinstance(far, (int, float)) and far > 0 else None
    focus = plan.get("focus_m")
    fstop = plan.get("f_number")
    if near and far and f_mm:
        if not isinstance(focus, (int, float)):
            focus = optics.focus_for_range_mm(near * 1000.0, far * 1000.0) / 1000.0
        if not isinstance(fstop, (int, float)):
            coc_mm = float(plan.get("coc_mm") or optics.REFERENCE.coc_mm)
            fstop = optics.f_number_for_range(near * 1000.0, far * 1000.0, f_mm, coc_mm)
    return {"focal_length_mm": f_mm, "near_m": near, "far_m": far,
            "focus_m": float(focus) if isinstance(focus, (int, float)) else None,
            "fstop": float(fstop) if isinstance(fstop, (int, float)) else None}


#: estimated (not ground-truth) disparity maps: estimated_disp_Cam000.pfm, estimated_disp_confidence_Cam000.pfm
ESTIMATE_PREFIX = "estimated_disp_"
#: focus_distance_m written for parallel views: the toolkit's 1/focus term vanishes (zero disparity at
#: infinity) without dividing by zero (``inf`` would give inf/inf = nan in depth2disp)
FOCUS_AT_INFINITY_M = 1e9
#: sensor size written when a dataset knows its focal length only in pixels (a 35 mm-format frame)
NOMINAL_SENSOR_MM = 36.0
#: matches needed to trust a measured disparity range
MIN_MATCHES = 30


@dataclass(frozen=True)
class DisparityRange:
    d_min_px: float           # neighbour disparity (px of the exported images) of the farthest point
    d_max_px: float           # ... of the nearest point
    source: str               # "plan" | "measured"
    detail: str = ""


def _focal_px(ds: Dataset, size: Sequence[int], source: str) -> float | None:
    """Focal length in pixels of the exported images (the camera every export describes)."""
    from lfstudio.export import poses

    try:
        return poses.camera_for(ds, size, common.is_rectified(ds, source)).fx_px
    except DatasetError:
        return None


def disparity_range(ds: Dataset, views: Sequence[common.View], source: str, size: Sequence[int], *,
                    measure: bool = True) -> DisparityRange | None:
    """Neighbour disparity range of the exported images: from the plan's near/far distance, else
    (``measure``) measured from the views; None when neither is possible."""
    p = _plan_numbers(ds)
    spacing = ds.grid.spacing_mm
    f_px = _focal_px(ds, size, source)
    if p["near_m"] and p["far_m"] and f_px and spacing:
        k = f_px * float(spacing[0]) / 1000.0            # px · m: d = f·b · (1/Z − 1/Z0)
        shear = zero_plane(ds).shear_or_zero(size[0]) * float(spacing[0])   # sheared views: f·b/Z0 per step
        return DisparityRange(k / p["far_m"] - shear, k / p["near_m"] - shear, "plan",
                              f"the plan's far {p['far_m']:g} m and near {p['near_m']:g} m")
    zp = zero_plane(ds)
    declared = (ds.manifest.get("zero_disparity") or {}).get("declared_step_disparity_px")
    if isinstance(declared, list) and len(declared) == 2 and zp.width_px and source == "raw":
        # an imported HCI folder's own disp_min/disp_max (parameters.cfg), at the exported size
        scale = float(size[0]) / float(zp.width_px)
        return DisparityRange(float(declared[0]) * scale, float(declared[1]) * scale, "parameters.cfg",
                              "disp_min/disp_max of the imported HCI folder")
    step = zp.measured.get("step_disparity_px")
    if isinstance(step, list) and len(step) == 2 and zp.width_px and source == "raw":
        # measured at import from the tracks of the views as they are (signed, sheared or not)
        scale = float(size[0]) / float(zp.width_px)
        return DisparityRange(float(step[0]) * scale, float(step[1]) * scale, "measured",
                              f"tracks of {zp.measured.get('views')} views measured at import")
    return measured_disparity_range(ds, views, source, size) if measure else None


def measured_disparity_range(ds: Dataset, views: Sequence[common.View], source: str,
                             size: Sequence[int]) -> DisparityRange | None:
    """Neighbour disparity range measured from SIFT matches between the outer views of the
    sub-array's centre row (rectified with the calibration when they are raw): horizontal shift /
    column distance, 2nd and 98th percentile, in pixels of the exported images. None with one
    column or too few matches.

    Hook: the quality check (``lfstudio.quality``, being built) measures disparities over the whole
    grid; once it stores them in the dataset, read them here first."""
    from lfstudio.calibration.features import detect, match_pair
    from lfstudio.calibration.model import apply_homography, homography_for, load_calibration

    rows = sorted({r for r, _ in views})
    row = rows[(len(rows) - 1) // 2]
    cols = sorted(c for r, c in views if r == row)
    if len(cols) < 2:
        return None
    a, b = common.View(row, cols[0]), common.View(row, cols[-1])
    fa = detect(common.source_path(ds, a, source))
    fb = detect(common.source_path(ds, b, source))
    m = match_pair(fa, fb, "h")          # b is to the right of a
    xa, xb = m.xy_a, m.xy_b
    cal = load_calibration(ds)
    if source == "raw" and cal and cal.get("homography"):
        H = homography_for(cal, fa.image_size_px)
        xa, xb = apply_homography(H, xa), apply_homography(H, xb)
    if len(xa) < MIN_MATCHES:
        return None
    d = (xa[:, 0] - xb[:, 0]) / (cols[-1] - cols[0]) * (float(size[0]) / float(fa.image_size_px[0]))
    lo, hi = (float(v) for v in np.percentile(d, [2, 98]))
    return DisparityRange(lo, hi, "measured", f"{len(d)} matches between {view_stem(*a)} and {view_stem(*b)}")


def warnings(ds: Dataset, views: Sequence[common.View], size: Sequence[int], source: str,
             disparities: DisparityRange | None = None, measured: bool = False) -> list[str]:
    """Notes on an HCI export (``measured``: ``disparities`` is the export's final answer)."""
    out = []
    if disparities is None and not measured:
        disparities = disparity_range(ds, views, source, size, measure=False)
    if disparities is None and not measured:
        out.append("the dataset has no scene plan (near/far distance): disp_min/disp_max will be measured from "
                   "feature matches in the views")
    elif disparities is None:
        out.append("the dataset has no scene plan and too few feature matches to measure disparities: "
                   "disp_min/disp_max in parameters.cfg are 0; edit them by hand")
    elif disparities.source == "measured":
        out.append(f"disp_min/disp_max measured from the views ({disparities.detail}): "
                   f"{disparities.d_min_px:.3f} … {disparities.d_max_px:.3f} px")
    if _focal_px(ds, size, source) is None:
        out.append("the dataset has no focal length: focal_length_mm and sensor_size_mm in parameters.cfg are 0; "
                   "give it one (lens focal length, or calibrate with --focal-length-px)")
    sp = ds.grid.spacing_mm or (0.0, 0.0)
    if sp and len(sp) == 2 and abs(float(sp[0]) - float(sp[1])) > 1e-9:
        out.append(f"horizontal and vertical spacing differ ({sp[0]} / {sp[1]} mm); HCI has one baseline_mm "
                   "(the horizontal one); baseline_y_mm holds the vertical")
    return out


def _center(views: Sequence[common.View]) -> common.View:
    rows = sorted({r for r, _ in views})
    cols = sorted({c for _, c in views})
    return common.View(rows[(len(rows) - 1) // 2], cols[(len(cols) - 1) // 2])


class _KeysAsWritten(configparser.ConfigParser):
    """parameters.cfg with its keys as written (ConfigParser lowercases them)."""

    def optionxform(self, optionstr: str) -> str:
        return optionstr


def parameters_text(ds: Dataset, views: Sequence[common.View], size: Sequence[int], source: str,
                    disparities: DisparityRange | None = None, authors: str = "") -> str:
    """The ``parameters.cfg`` text."""
    from lfstudio.calibration.model import load_calibration

    w, h = int(size[0]), int(size[1])
    rows = sorted({r for r, _ in views})
    cols = sorted({c for _, c in views})
    p = _plan_numbers(ds)
    spacing = ds.grid.spacing_mm or (0.0, 0.0)
    center = ds.view(*_center(views))
    pos = center.get("reported_mm") or center.get("commanded_mm") or [0.0, 0.0]
    rot = [0.0, 0.0, 0.0]
    rectified = common.is_rectified(ds, source)
    cal = load_calibration(ds)
    if cal and not rectified and cal.get("rotation_deg"):
        rot = [math.radians(float(a)) for a in cal["rotation_deg"]]
    # the toolkit's focal length in pixels is focal_length_mm / sensor_size_mm · max(w, h): write the
    # lens focal length and the sensor size that make it the exported camera's (a nominal 36 mm
    # sensor when the dataset knows its focal length in pixels only)
    f_px = _focal_px(ds, size, source)
    f_mm = p["focal_length_mm"]
    nominal_sensor = not f_mm
    if f_px and not f_mm:
        f_mm = f_px * NOMINAL_SENSOR_MM / max(w, h)
    sensor_mm = f_mm * max(w, h) / f_px if f_px and f_mm else 0.0
    cfg = _KeysAsWritten()
    cfg["intrinsics"] = {
        "image_resolution_x_px": str(w), "image_resolution_y_px": str(h),
        "focal_length_mm": f"{f_mm or 0.0:.8g}",
        "sensor_size_mm": f"{sensor_mm:.8g}",
        "fstop": f"{p['fstop'] or 0.0:.4g}"}
    zp = zero_plane(ds)
    sheared = bool(zp.shear_px_per_mm) and zp.depth_m is not None
    focus_m = zp.depth_m if sheared else FOCUS_AT_INFINITY_M
    cfg["extrinsics"] = {
        "focus_distance_m": f"{focus_m:.8g}",
        "center_cam_x_m": f"{float(pos[0]) / 1000.0:.6g}", "center_cam_y_m": f"{float(pos[1]) / 1000.0:.6g}",
        "center_cam_z_m": "0",
        "center_cam_rx_rad": f"{rot[0]:.8g}", "center_cam_ry_rad": f"{rot[1]:.8g}", "center_cam_rz_rad": f"{rot[2]:.8g}",
        "baseline_mm": f"{float(spacing[0]):.6g}", "baseline_y_mm": f"{float(spacing[1]):.6g}",
        "num_cams_x": str(len(cols)), "num_cams_y": str(len(rows)),
        "first_row": str(rows[0]), "first_column": str(cols[0])}
    d_min, d_max = (disparities.d_min_px, disparities.d_max_px) if disparities is not None else (0.0, 0.0)
    cfg["meta"] = {
        "disp_min": f"{d_min:.4f}", "disp_max": f"{d_max:.4f}",
        "frustum_disp_min": f"{d_min:.4f}", "frustum_disp_max": f"{d_max:.4f}",
        "disp_range_from": disparities.source if disparities is not None else "none",
        "zero_disparity_distance_m": f"{zp.depth_m:.8g}" if sheared else "inf",
        "lens_focus_distance_m": f"{p['focus_m'] or 0.0:.6g}",
        "depth_map_scale": "1",
        "scene": ds.root.name, "category": "lfstudio",
        "date": _dt.date.today().isoformat(), "version": "lfstudio-hci-2",
        "authors": str(authors or ds.manifest.get("authors") or ""), "contact": ""}
    buf = io.StringIO()
    if sheared:
        buf.write("# HCI 4D light-field benchmark parameters written by lfstudio.\n"
                  f"# The views are sheared (as imported, {zp.source}): zero disparity at focus_distance_m = "
                  f"{zp.depth_m:g} m,\n# negative disparity behind it. disparity_px = baseline_mm/1000 * "
                  "focal_length_mm * max(w, h) / sensor_size_mm\n# * (1/depth_m - 1/focus_distance_m), as the "
                  "toolkit's depth2disp. disp_min/disp_max: signed neighbour\n# disparity (px) of the farthest/"
                  "nearest scene point.\n")
    buf.write("" if sheared else "# HCI 4D light-field benchmark parameters written by lfstudio.\n"
              "# Views are parallel (no sensor shift): disparity is zero at infinity, so focus_distance_m is\n"
              f"# {FOCUS_AT_INFINITY_M:g} m (the toolkit's 1/focus_distance_m term vanishes); the lens focus is\n"
              "# lens_focus_distance_m in [meta]. disparity_px = baseline_mm/1000 * focal_length_mm *\n"
              "# max(w, h) / sensor_size_mm * (1/depth_m - 1/focus_distance_m), as the toolkit's depth2disp.\n"
              "# disp_min/disp_max: neighbour disparity (px) of the farthest/nearest scene point\n"
              "# (disp_range_from: plan = the planned far/near distance, measured = feature matches).\n")
    if nominal_sensor and f_px:
        buf.write(f"# The dataset gives its focal length in pixels only: focal_length_mm is that of a nominal "
                  f"{NOMINAL_SENSOR_MM:g} mm\n# sensor over max(w, h); only their ratio is meaningful.\n")
    cfg.write(buf)
    return buf.getvalue()


to_srgb8 = common.to_srgb8   # the benchmark's 8-bit sRGB (kept here: tests and callers use hci.to_srgb8)


def export_hci(ds: Dataset, views: Sequence[common.View], source: str, size: tuple[int, int], out: Path,
               options, progress: Progress, cancel: CancelToken) -> tuple[list[Path], list[str]]:
    """Write the layout; returns (files, notes for the user)."""
    bit_depth = int(getattr(options, "hci_bit_depth", 8) or 8)
    if bit_depth not in (8, 16):
        raise InputError("hci_bit_depth", f"{bit_depth} is not supported", "8 (sRGB, like the benchmark) or 16 (linear)")
    n = len(views)
    names = {v: cam_name(i, n) for i, v in enumerate(views)}
    progress(0, n, "exporting HCI layout")
    disparities = disparity_range(ds, views, source, size)
    notes = warnings(ds, views, size, source, disparities, measured=True)
    with_depth = bool(getattr(options, "depth", False))
    if with_depth:
        from lfstudio.export import depthmaps, poses

        notes += depthmaps.ensure_maps(ds, views, progress, cancel)
    with common.partial_folder(out, options.overwrite) as tmp:
        common.write_images(ds, views, source, size, tmp, names, bit_depth, progress, cancel)
        if with_depth:
            from lfstudio.depth.files import write_pfm

            cam = poses.camera_for(ds, size, common.is_rectified(ds, source))
            for v in views:
                cancel.check()
                maps = depthmaps.maps_for_export(ds, v, cam)
                stem = names[v].rsplit(".", 1)[0].replace("input_", "")
                write_pfm(tmp / f"{ESTIMATE_PREFIX}{stem}.pfm", maps.disparity_px)
                write_pfm(tmp / f"{ESTIMATE_PREFIX}confidence_{stem}.pfm", maps.confidence)
        (tmp / PARAMETERS_NAME).write_text(parameters_text(ds, views, size, source, disparities,
                                                           getattr(options, "authors", "")), encoding="utf-8")
        doc: dict[str, Any] = common.describe(ds, views, source, size, names)
        doc["kind"] = "hci"
        doc["bit_depth"] = bit_depth
        doc["color"] = "sRGB (8-bit)" if bit_depth == 8 else doc["color"]
        (tmp / MANIFEST_NAME).write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    estimates = [out / f"{ESTIMATE_PREFIX}{kind}{names[v].rsplit('.', 1)[0].replace('input_', '')}.pfm"
                 for v in views for kind in ("", "confidence_")] if with_depth else []
    return [out / PARAMETERS_NAME, out / MANIFEST_NAME] + [out / names[v] for v in views] + estimates, notes
