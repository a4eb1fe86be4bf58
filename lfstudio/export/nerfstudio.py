"""nerfstudio / instant-ngp ``transforms.json`` with the rig's known poses, beside the exported views.

Layout::

    OUT/images/rRR_cCCC.png        the views (8-bit sRGB by default, 16-bit linear on request)
    OUT/transforms.json            camera_model "PINHOLE", fl_x, fl_y, cx, cy, w, h (exported size);
                                   frames: file_path "images/rRR_cCCC.png" + 4 x 4 transform_matrix;
                                   applied_transform; train/val/test_filenames with a hold-out;
                                   ply_file_path "sparse_pc.ply" (with ``options.points``)
    OUT/depth/rRR_cCCC.png         with ``options.depth``: depth in mm (16-bit; 0 unknown), the frame's
                                   ``depth_file_path`` (nerfstudio's default depth_unit_scale_factor 1e-3);
                                   beside it rRR_cCCC.tif (float32 m) and rRR_cCCC.confidence.pfm
                                   (:mod:`lfstudio.export.depthmaps`)
    OUT/sparse_pc.ply              the sparse point cloud (:mod:`lfstudio.depth.points`) in the
                                   transforms.json world (``X_json = A · X_rig``), as nerfstudio's own
                                   COLMAP conversion writes it (splatfacto starts from it)
    OUT/lfstudio_manifest.json     our description (grid, positions, calibration, the camera)

``transform_matrix`` is camera-to-world in nerfstudio's (OpenGL) camera convention: x right, y up,
the camera looking along −z; i.e. the OpenCV camera-to-world ``[Rᵀ | C]`` with its y and z columns
negated. The world is the rig frame (metres) turned z-up as nerfstudio turns a COLMAP world:
``X_json = A · X_rig`` with ``A = [[1, 0, 0], [0, 0, 1], [0, −1, 0]]`` (x right, y into the scene,
z up), written as ``applied_transform`` so that nerfstudio maps results back onto our COLMAP export
(:mod:`lfstudio.export.colmap`, world = the rig frame). cx, cy put the centre of the top-left pixel
at (0.5, 0.5) (nerfstudio's pixel convention): ours + 0.5.

Hold-out (``holdout``): ``none`` (no split lists: nerfstudio picks its own), ``centre`` (the centre
view) or ``every-K`` (every K-th row and column of the exported grid, starting at K // 2 so each
held-out view is surrounded by training views). The held-out views are listed as ``val_filenames``
and ``test_filenames`` (nerfstudio asks for both), all others as ``train_filenames``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from lfstudio.dataset import Dataset
from lfstudio.errors import InputError
from lfstudio.export import colmap, common, poses
from lfstudio.jobs import CancelToken, Progress

TRANSFORMS_NAME = "transforms.json"
PLY_NAME = "sparse_pc.ply"
DEPTH_DIR = "depth"
IMAGES_DIR = colmap.IMAGES_DIR
MANIFEST_NAME = colmap.MANIFEST_NAME

#: rig frame (x right, y down, z forward) -> transforms.json world (x right, y forward, z up)
APPLIED_TRANSFORM = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: OpenCV camera axes (x right, y down, z forward) -> OpenGL (x right, y up, z backward)
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0])
HOLDOUT_HELP = "none, centre, or every-K (every K-th row and column, e.g. every-4)"
_EVERY = re.compile(r"^\s*every[-_ ]?(\d+)\s*$", re.IGNORECASE)


def parse_holdout(text: str | None) -> tuple[str, int]:
    """``"none"`` → ("none", 0); ``"centre"``/``"center"`` → ("centre", 0); ``"every-K"`` → ("every", K)."""
    t = (text or "none").strip().lower()
    if t in ("none", ""):
        return "none", 0
    if t in ("centre", "center"):
        return "centre", 0
    m = _EVERY.match(t)
    if m and int(m.group(1)) >= 2:
        return "every", int(m.group(1))
    raise InputError("holdout", f"cannot read {text!r}", HOLDOUT_HELP + "; K at least 2")


def held_out(views: Sequence[common.View], holdout: str | None) -> list[common.View]:
    """The views held out of training (row-major)."""
    kind, k = parse_holdout(holdout)
    if kind == "none":
        return []
    rows = sorted({r for r, _ in views})
    cols = sorted({c for _, c in views})
    if kind == "centre":
        centre = common.View(rows[(len(rows) - 1) // 2], cols[(len(cols) - 1) // 2])
        if centre not in set(views):
            raise InputError("holdout", f"the centre view (row {centre[0]}, column {centre[1]}) is not exported",
                             "export it too, or another hold-out")
        out = [centre]
    else:
        r0, c0 = rows[0], cols[0]
        out = [common.View(r, c) for r, c in sorted(views) if (r - r0) % k == k // 2 and (c - c0) % k == k // 2]
        if not out:
            raise InputError("holdout", f"every-{k} holds out no view of this {len(cols)} x {len(rows)} selection",
                             "a smaller K, or centre")
    if len(out) >= len(views):
        raise InputError("holdout", "no view would be left for training", "export more views, or hold out none")
    return out


def camera_to_world(cam: poses.PinholeCamera, centre_m: Sequence[float] | np.ndarray) -> np.ndarray:
    """4 x 4 transform_matrix of the camera centred at ``centre_m`` (rig frame, m)."""
    c2w = np.eye(4)
    c2w[:3, :3] = cam.R.T @ OPENCV_TO_OPENGL
    c2w[:3, 3] = np.asarray(centre_m, float)
    A = np.eye(4)
    A[:3, :3] = APPLIED_TRANSFORM
    return A @ c2w


def transforms_doc(ds: Dataset, views: Sequence[common.View], names: dict[common.View, str],
                   cam: poses.PinholeCamera, holdout: str | None) -> dict[str, Any]:
    w, h = cam.size_px
    cx, cy = cam.principal_point_corner_px()
    frames = []
    shifts = poses.principal_point_shifts_px(ds, views, cam.size_px)
    for v in views:
        frames.append({"file_path": f"{IMAGES_DIR}/{names[v]}",
                       "transform_matrix": camera_to_world(cam, poses.centre_m(ds, v)).tolist(),
                       "lfstudio_view": [int(v[0]), int(v[1])]})
        if shifts is not None:      # sheared views: each frame's own principal point (per-frame intrinsics)
            frames[-1].update({"cx": cx + shifts[v][0], "cy": cy + shifts[v][1]})
    doc: dict[str, Any] = {"camera_model": "PINHOLE", "fl_x": cam.fx_px, "fl_y": cam.fy_px, "cx": cx, "cy": cy,
                           "w": int(w), "h": int(h), "frames": frames,
                           "applied_transform": np.hstack([APPLIED_TRANSFORM, np.zeros((3, 1))]).tolist()}
    test = held_out(views, holdout)
    if test:
        test_set = set(test)
        doc["train_filenames"] = [f"{IMAGES_DIR}/{names[v]}" for v in views if v not in test_set]
        doc["val_filenames"] = [f"{IMAGES_DIR}/{names[v]}" for v in test]
        doc["test_filenames"] = list(doc["val_filenames"])
    return doc


def export_nerfstudio(ds: Dataset, views: Sequence[common.View], source: str, size: tuple[int, int], out: Path,
                      options, progress: Progress, cancel: CancelToken) -> list[Path]:
    bit_depth = int(options.image_bit_depth)
    cam = poses.camera_for(ds, size, common.is_rectified(ds, source))
    names = colmap.image_names(views, common.image_suffix(ds, views, source))
    doc = transforms_doc(ds, views, names, cam, options.holdout)      # bad input fails before any image
    with_depth = bool(getattr(options, "depth", False))
    if with_depth:
        from lfstudio.export import depthmaps

        depthmaps.ensure_maps(ds, views, progress, cancel)
    progress(0, len(views), "exporting nerfstudio transforms")
    with common.partial_folder(out, options.overwrite) as tmp:
        (tmp / IMAGES_DIR).mkdir()
        common.write_images(ds, views, source, size, tmp / IMAGES_DIR, names, bit_depth, progress, cancel,
                            label="nerfstudio ")
        if with_depth:
            from lfstudio.depth.files import write_depth_png, write_depth_tiff, write_pfm

            (tmp / DEPTH_DIR).mkdir()
            for i, (v, frame) in enumerate(zip(views, doc["frames"])):
                cancel.check()
                maps = depthmaps.maps_for_export(ds, v, cam)
                write_depth_png(tmp / DEPTH_DIR / depthmaps.map_name(v, ".png"), maps.depth_m)
                write_depth_tiff(tmp / DEPTH_DIR / depthmaps.map_name(v, ".tif"), maps.depth_m)
                write_pfm(tmp / DEPTH_DIR / depthmaps.map_name(v, ".confidence.pfm"), maps.confidence)
                frame["depth_file_path"] = f"{DEPTH_DIR}/{depthmaps.map_name(v, '.png')}"
                progress(i + 1, len(views), f"nerfstudio depth {depthmaps.map_name(v, '')}")
        cloud = colmap.sparse_cloud_of_export(ds, views, cam, tmp / IMAGES_DIR, names, progress, cancel) \
            if getattr(options, "points", True) else None
        if cloud is not None:
            from lfstudio.depth.files import write_ply

            write_ply(tmp / PLY_NAME, cloud.xyz_m @ APPLIED_TRANSFORM.T, cloud.rgb)
            doc["ply_file_path"] = PLY_NAME
        (tmp / TRANSFORMS_NAME).write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
        manifest: dict[str, Any] = common.describe(ds, views, source, size,
                                                   {v: f"{IMAGES_DIR}/{n}" for v, n in names.items()})
        manifest["kind"] = "nerfstudio"
        if source != "hdr":                      # float radiance keeps its own (manifest["color"])
            manifest["bit_depth"] = bit_depth
            manifest["color"] = "sRGB (8-bit)" if bit_depth == 8 else manifest["color"]
        manifest["pinhole"] = cam.describe()
        manifest["point_cloud"] = colmap.describe_cloud(cloud)
        manifest["held_out"] = [[int(r), int(c)] for r, c in held_out(views, options.holdout)]
        (tmp / MANIFEST_NAME).write_text(json.dumps(manifest, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return [out / TRANSFORMS_NAME, out / MANIFEST_NAME] + ([out / PLY_NAME] if cloud is not None else []) + \
        ([out / DEPTH_DIR] if with_depth else []) + [out / IMAGES_DIR / names[v] for v in views]
