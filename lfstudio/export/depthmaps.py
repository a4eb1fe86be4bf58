"""Depth and disparity maps in the exports (``ExportOptions.depth``): the dense maps of
:mod:`lfstudio.depth.run` (stored in ``DATASET/depth/``; views without one are computed first, in
this process: run ``lfstudio depth --cluster`` beforehand for large grids), brought into the
exported images' frame.

The maps are made on rectified views. Exported raw views keep the captured camera's orientation:
their maps are resampled through the calibration's homography (nearest neighbour: no depth is
blended across an edge) and their depth becomes the captured camera's own z,
``z_cam = Z / (Rᵀ K⁻¹ p)_z``. Depth in metres everywhere; disparity in pixels between horizontal
neighbours of the exported images (HCI convention; a sheared dataset's views measure it from their
zero-disparity plane, and its depth uses that plane).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from lfstudio.dataset import Dataset
from lfstudio.dataset.paths import view_stem
from lfstudio.depth.run import depth_from_disparity, estimate_depth, has_disparity, read_disparity, zero_shear_px_per_mm
from lfstudio.errors import DatasetError
from lfstudio.export import common, poses
from lfstudio.jobs import CancelToken, Progress

#: bytes per pixel of the depth files of one view: 16-bit PNG (mm, ~half compresses away), float TIFF
#: (deflate: smooth maps compress little), a confidence PFM
NERFSTUDIO_BYTES_PER_PX = 2 * 0.6 + 4 * 0.9 + 4
HCI_BYTES_PER_PX = 4 + 4


def missing_maps(ds: Dataset, views: Sequence[common.View]) -> list[common.View]:
    return [v for v in views if not has_disparity(ds, v)]


def ensure_maps(ds: Dataset, views: Sequence[common.View], progress: Progress, cancel: CancelToken) -> list[str]:
    """Compute the maps the export needs that ``DATASET/depth/`` lacks (or has out of date); notes."""
    report = estimate_depth(ds, list(views), progress=lambda d, t, m="": progress(d, t, m), cancel=cancel)
    if report.failed:
        name, error = next(iter(report.failed.items()))
        raise DatasetError(f"{ds.root}: the depth of {len(report.failed)} view(s) failed, e.g. {name}: {error}")
    return list(report.warnings)


@dataclass
class ExportMaps:
    disparity_px: np.ndarray              # px between horizontal neighbours of the exported images
    depth_m: np.ndarray                   # camera z, metres (NaN unknown)
    confidence: np.ndarray


def maps_for_export(ds: Dataset, view: common.View, cam: poses.PinholeCamera) -> ExportMaps:
    """One view's maps in the exported images' frame and size (module docstring)."""
    from lfstudio.calibration.model import load_calibration, scale_homography

    disp, conf, record = read_disparity(ds, view)
    map_w, map_h = (int(v) for v in record["size_px"])
    w, h = cam.size_px
    sx_mm = float(ds.grid.step_mm[0])
    rectified_maps = record.get("source") == "processed" and bool((ds.manifest.get("processing") or {}).get("rectified")) \
        or record.get("source") == "raw" and bool((load_calibration(ds) or {}).get("homography"))
    cal = load_calibration(ds) or {}
    f_map = float(cal["focal_length_px"]) * map_w / float(cal["image_size_px"][0]) if cal.get("focal_length_px") \
        else ds.focal_length_px(map_w)
    depth = depth_from_disparity(disp, f_map, sx_mm, zero_shear_px_per_mm(ds, map_w))
    if rectified_maps and not cam.rectified:
        # the export shows the captured camera: sample the rectified maps at H·p (captured -> rectified)
        H = scale_homography(np.asarray(cal["homography"], float), cal["image_size_px"], (map_w, map_h))
        S = np.diag([map_w / w, map_h / h, 1.0])
        M = H @ S                                         # exported pixel -> rectified map pixel
        def warp(a):
            return cv2.warpPerspective(a, M, (w, h), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                                       borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))

        disp, conf, depth = warp(disp), warp(conf), warp(depth)
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        rays = np.stack([u, v, np.ones_like(u)], -1) @ (cam.R.T @ np.linalg.inv(cam.K)).T
        depth = (depth / rays[..., 2]).astype(np.float32)
        conf = np.nan_to_num(conf, nan=0.0)
    elif (map_w, map_h) != (w, h):
        disp = cv2.resize(disp, (w, h), interpolation=cv2.INTER_NEAREST) * np.float32(w / map_w)
        depth = cv2.resize(depth, (w, h), interpolation=cv2.INTER_NEAREST)
        conf = cv2.resize(conf, (w, h), interpolation=cv2.INTER_NEAREST)
    if (map_w, map_h) != (w, h) and rectified_maps and not cam.rectified:
        disp = disp * np.float32(w / map_w)
    return ExportMaps(disp.astype(np.float32), depth.astype(np.float32), conf.astype(np.float32))


def map_name(view: common.View, suffix: str) -> str:
    return f"{view_stem(*view)}{suffix}"
