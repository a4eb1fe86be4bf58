"""The HCI 4D light-field benchmark layout (Honauer et al. 2016) for a sub-array of the grid.

A folder with ``parameters.cfg`` (INI: ``[intrinsics]``, ``[extrinsics]``, ``[meta]`` as read by the
benchmark toolkit's ``file_io.read_parameters``) and ``input_Cam000.png`` … in row-major order
(top row first, left to right; the toolkit puts file ``idx`` at row ``idx // num_cams_x``, column
``idx % num_cams_x``). With more than 1000 views the number field widens to fit
(``input_Cam0000.png`` …) so that names still sort in view order. Images are 8-bit sRGB PNGs like
the benchmark's (``hci_bit_depth=16``: linear 16-bit). ``lfstudio_manifest.json`` adds our own
description (positions, calibration, intrinsics).

Disparities follow the toolkit's meaning (pixels between horizontally neighbouring views, positive
for near points) for our views, which are parallel (no sensor shift): zero disparity lies at
infinity, so ``disp_min``/``disp_max`` are the neighbour disparities of the plan's far and near
distances, and depth = baseline·f / (disparity·pixel size). ``focus_distance_m`` is the lens focus.
"""

from __future__ import annotations

import configparser
import datetime as _dt
import io
import json
import math
from pathlib import Path
from typing import Any, Sequence


from lfstudio.dataset import Dataset
from lfstudio.errors import InputError
from lfstudio.export import common
from lfstudio.jobs import CancelToken, Progress

PARAMETERS_NAME = "parameters.cfg"
MANIFEST_NAME = "lfstudio_manifest.json"
DEFAULT_COC_MM = 0.029


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
        views = common.select_views(ds, options.views)
        rows = sorted({r for r, _ in views})
        cols = sorted({c for _, c in views})
        have = set(views)
        holes = [(r, c) for r in rows for c in cols if (r, c) not in have]
        if holes:
            raise InputError("views", f"the HCI layout needs a full rectangle of views; {len(holes)} missing in "
                             f"rows {rows[0]}-{rows[-1]}, columns {cols[0]}-{cols[-1]}",
                             "a range like r6-14,c46-54 with every view captured")
        return [(r, c) for r in rows for c in cols]
    n_cols, n_rows = int(options.hci_size[0]), int(options.hci_size[1])
    g_cols, g_rows = int(ds.grid["columns"]), int(ds.grid["rows"])
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
    views = [(r, c) for r in range(r0, r0 + n_rows) for c in range(c0, c0 + n_cols)]
    have = set(common.available_views(ds))
    missing = [v for v in views if v not in have]
    if missing:
        from lfstudio.dataset.paths import view_stem
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
        from lfstudio.planning import optics

        if not isinstance(focus, (int, float)):
            focus = optics.focus_for_range_mm(near * 1000.0, far * 1000.0) / 1000.0
        if not isinstance(fstop, (int, float)):
            fstop = optics.f_number_for_range(near * 1000.0, far * 1000.0, f_mm, float(plan.get("coc_mm") or DEFAULT_COC_MM))
    return {"focal_length_mm": f_mm, "near_m": near, "far_m": far,
            "focus_m": float(focus) if isinstance(focus, (int, float)) else None,
            "fstop": float(fstop) if isinstance(fstop, (int, float)) else None}


def disparity_range(ds: Dataset, size: Sequence[int]) -> tuple[float, float] | None:
    """(disp_min, disp_max) in pixels of the exported images between horizontal neighbours for the
    plan's far and near distances (parallel views: zero at infinity); None without a plan."""
    from lfstudio.planning import optics

    p = _plan_numbers(ds)
    sensor_mm = ds.camera.get("sensor_mm")
    spacing = ds.grid.get("spacing_mm")
    if not (p["near_m"] and p["far_m"] and p["focal_length_mm"] and sensor_mm and spacing):
        return None
    pitch_um = float(sensor_mm[0]) / int(size[0]) * 1000.0
    b = float(spacing[0])
    d_far = optics.disparity_px(b, p["far_m"] * 1000.0, math.inf, p["focal_length_mm"], pitch_um)
    d_near = optics.disparity_px(b, p["near_m"] * 1000.0, math.inf, p["focal_length_mm"], pitch_um)
    return d_far, d_near


def warnings(ds: Dataset, views: Sequence[common.View], size: Sequence[int]) -> list[str]:
    out = []
    if disparity_range(ds, size) is None:
        out.append("the dataset has no scene plan (near/far distance): disp_min/disp_max in parameters.cfg are 0; "
                   "edit them by hand")
    sp = ds.grid.get("spacing_mm") or [0, 0]
    if sp and len(sp) == 2 and abs(float(sp[0]) - float(sp[1])) > 1e-9:
        out.append(f"horizontal and vertical spacing differ ({sp[0]} / {sp[1]} mm); HCI has one baseline_mm "
                   "(the horizontal one); baseline_y_mm holds the vertical")
    return out


#: sensor width written when a dataset knows its focal length only in pixels (a 35 mm-format frame)
NOMINAL_SENSOR_MM = 36.0


def _center(views: Sequence[common.View]) -> common.View:
    rows = sorted({r for r, _ in views})
    cols = sorted({c for _, c in views})
    return rows[(len(rows) - 1) // 2], cols[(len(cols) - 1) // 2]


def parameters_text(ds: Dataset, views: Sequence[common.View], size: Sequence[int], source: str) -> str:
    """The ``parameters.cfg`` text."""
    from lfstudio.calibration.calibrate import load_calibration

    w, h = int(size[0]), int(size[1])
    rows = sorted({r for r, _ in views})
    cols = sorted({c for _, c in views})
    p = _plan_numbers(ds)
    sensor_mm = ds.camera.get("sensor_mm") or [0.0, 0.0]
    spacing = ds.grid.get("spacing_mm") or [0.0, 0.0]
    center = ds.view(*_center(views))
    pos = center.get("reported_mm") or center.get("commanded_mm") or [0.0, 0.0]
    rot = [0.0, 0.0, 0.0]
    processing = ds.manifest.get("processing") or {}
    rectified = source == "processed" and bool(processing.get("rectified"))
    cal = load_calibration(ds)
    if cal and not rectified and cal.get("rotation_deg"):
        rot = [math.radians(float(a)) for a in cal["rotation_deg"]]
    disp = disparity_range(ds, size)
    f_mm = p["focal_length_mm"]
    sensor_w_mm = float(sensor_mm[0])
    nominal_sensor = False
    if not (f_mm and sensor_w_mm > 0):
        # a dataset that knows its focal length only in pixels (imported with --focal-length-px, or
        # calibrated): HCI's tools use focal_length_mm / sensor_size_mm · image_resolution_x_px, so a
        # nominal 36 mm sensor with the matching focal length gives them the right geometry
        f_px = common.intrinsics(ds, (w, h), cal).get("focal_length_px")
        if f_px:
            sensor_w_mm, f_mm, nominal_sensor = NOMINAL_SENSOR_MM, float(f_px) * NOMINAL_SENSOR_MM / w, True
    cfg = configparser.ConfigParser()
    cfg.optionxform = str
    cfg["intrinsics"] = {
        "image_resolution_x_px": str(w), "image_resolution_y_px": str(h),
        "focal_length_mm": f"{f_mm or 0.0:.6g}",
        "sensor_size_mm": f"{sensor_w_mm:.6g}",
        "fstop": f"{p['fstop'] or 0.0:.4g}"}
    cfg["extrinsics"] = {
        "focus_distance_m": f"{p['focus_m'] or 0.0:.6g}",
        "center_cam_x_m": f"{float(pos[0]) / 1000.0:.6g}", "center_cam_y_m": f"{float(pos[1]) / 1000.0:.6g}",
        "center_cam_z_m": "0",
        "center_cam_rx_rad": f"{rot[0]:.8g}", "center_cam_ry_rad": f"{rot[1]:.8g}", "center_cam_rz_rad": f"{rot[2]:.8g}",
        "baseline_mm": f"{float(spacing[0]):.6g}", "baseline_y_mm": f"{float(spacing[1]):.6g}",
        "num_cams_x": str(len(cols)), "num_cams_y": str(len(rows)),
        "first_row": str(rows[0]), "first_column": str(cols[0])}
    d_min, d_max = disp if disp is not None else (0.0, 0.0)
    cfg["meta"] = {
        "disp_min": f"{d_min:.4f}", "disp_max": f"{d_max:.4f}",
        "frustum_disp_min": f"{d_min:.4f}", "frustum_disp_max": f"{d_max:.4f}",
        "zero_disparity_distance_m": "inf",
        "depth_map_scale": "1",
        "scene": ds.root.name, "category": "lfstudio",
        "date": _dt.date.today().isoformat(), "version": "lfstudio-hci-1",
        "authors": str((ds.manifest.get("rig") or {}).get("name") or "lfstudio"), "contact": ""}
    buf = io.StringIO()
    buf.write("# HCI 4D light-field benchmark parameters written by lfstudio.\n"
              "# Views are parallel (no sensor shift): disparity is zero at infinity;\n"
              "# depth_m = baseline_mm * focal_length_mm / (disparity_px * sensor_size_mm / image_resolution_x_px) / 1000.\n"
              "# disp_min/disp_max: neighbour disparity (px) of the planned far/near distance.\n")
    if nominal_sensor:
        buf.write(f"# The dataset gives its focal length in pixels only: sensor_size_mm is a nominal "
                  f"{NOMINAL_SENSOR_MM:g} mm and\n# focal_length_mm the matching value (only their ratio is meaningful).\n")
    cfg.write(buf)
    return buf.getvalue()


to_srgb8 = common.to_srgb8   # the benchmark's 8-bit sRGB (kept here: tests and callers use hci.to_srgb8)


def export_hci(ds: Dataset, views: Sequence[common.View], source: str, size: tuple[int, int], out: Path,
               options, progress: Progress, cancel: CancelToken) -> list[Path]:
    bit_depth = int(getattr(options, "hci_bit_depth", 8) or 8)
    if bit_depth not in (8, 16):
        raise InputError("hci_bit_depth", f"{bit_depth} is not supported", "8 (sRGB, like the benchmark) or 16 (linear)")
    n = len(views)
    names = {v: cam_name(i, n) for i, v in enumerate(views)}
    progress(0, n, "exporting HCI layout")
    with common.partial_folder(out, options.overwrite) as tmp:
        common.write_images(ds, views, source, size, tmp, names, bit_depth, progress, cancel)
        (tmp / PARAMETERS_NAME).write_text(parameters_text(ds, views, size, source), encoding="utf-8")
        doc: dict[str, Any] = common.describe(ds, views, source, size, names)
        doc["kind"] = "hci"
        doc["bit_depth"] = bit_depth
        doc["color"] = "sRGB (8-bit)" if bit_depth == 8 else doc["color"]
        (tmp / MANIFEST_NAME).write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return [out / PARAMETERS_NAME, out / MANIFEST_NAME] + [out / names[v] for v in views]
