"""COLMAP text model with the rig's known poses, beside the exported views.

Layout (what COLMAP's ``image_undistorter``, 3D Gaussian splatting and gsplat read)::

    OUT/images/rRR_cCCC.png        the views (8-bit sRGB by default, 16-bit linear on request)
    OUT/sparse/0/cameras.txt       one PINHOLE camera: WIDTH HEIGHT fx fy cx cy (exported size)
    OUT/sparse/0/images.txt        per view: IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, then an
                                   empty line (no 2-D points)
    OUT/sparse/0/points3D.txt      empty (no triangulated points)
    OUT/lfstudio_manifest.json     our description (grid, positions, calibration, the camera)

World frame = the rig frame (x right, y down, z into the scene) in **metres**; the origin is the
axes' origin. ``Q``/``T`` are COLMAP's world-to-camera rotation (unit quaternion, w first) and
translation: ``x_cam = R·X + T``; ``R`` is the calibrated orientation (identity for rectified views,
see :mod:`lfstudio.export.poses`) and the camera centre ``−Rᵀ·T`` is the view's reported position.
COLMAP puts the centre of the top-left pixel at (0.5, 0.5): cx, cy are ours + 0.5.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

from lfstudio.dataset import Dataset
from lfstudio.dataset.paths import view_stem
from lfstudio.export import common, poses
from lfstudio.jobs import CancelToken, Progress

IMAGES_DIR = "images"
MODEL_DIR = "sparse/0"
MANIFEST_NAME = "lfstudio_manifest.json"


def image_names(views: Sequence[common.View]) -> dict[common.View, str]:
    return {v: f"{view_stem(*v)}.png" for v in views}


def cameras_text(cam: poses.PinholeCamera) -> str:
    w, h = cam.size_px
    cx, cy = cam.principal_point_corner_px()
    return ("# Camera list with one line of data per camera:\n"
            "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
            "# Number of cameras: 1\n"
            f"1 PINHOLE {w} {h} {cam.fx_px:.10g} {cam.fy_px:.10g} {cx:.10g} {cy:.10g}\n")


def images_text(ds: Dataset, views: Sequence[common.View], names: dict[common.View, str],
                cam: poses.PinholeCamera) -> str:
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: {len(views)}, mean observations per image: 0"]
    qw, qx, qy, qz = poses.quaternion_wxyz(cam.R)
    for image_id, v in enumerate(views, start=1):
        _, t = cam.world_to_camera(poses.centre_m(ds, v))
        lines.append(f"{image_id} {qw:.12g} {qx:.12g} {qy:.12g} {qz:.12g} {t[0]:.12g} {t[1]:.12g} {t[2]:.12g} 1 "
                     f"{names[v]}")
        lines.append("")
    return "\n".join(lines) + "\n"


POINTS3D_TEXT = ("# 3D point list with one line of data per point:\n"
                 "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
                 "# Number of points: 0, mean track length: 0\n")


def export_colmap(ds: Dataset, views: Sequence[common.View], source: str, size: tuple[int, int], out: Path,
                  options, progress: Progress, cancel: CancelToken) -> list[Path]:
    bit_depth = int(options.image_bit_depth)
    cam = poses.camera_for(ds, size, common.is_rectified(ds, source))
    names = image_names(views)
    progress(0, len(views), "exporting COLMAP model")
    with common.partial_folder(out, options.overwrite) as tmp:
        (tmp / IMAGES_DIR).mkdir()
        common.write_images(ds, views, source, size, tmp / IMAGES_DIR, names, bit_depth, progress, cancel,
                            label="colmap ")
        model = tmp / MODEL_DIR
        model.mkdir(parents=True)
        (model / "cameras.txt").write_text(cameras_text(cam), encoding="utf-8")
        (model / "images.txt").write_text(images_text(ds, views, names, cam), encoding="utf-8")
        (model / "points3D.txt").write_text(POINTS3D_TEXT, encoding="utf-8")
        doc: dict[str, Any] = common.describe(ds, views, source, size, {v: f"{IMAGES_DIR}/{n}" for v, n in names.items()})
        doc["kind"] = "colmap"
        doc["bit_depth"] = bit_depth
        doc["color"] = "sRGB (8-bit)" if bit_depth == 8 else doc["color"]
        doc["pinhole"] = cam.describe()
        doc["world_frame"] = "rig frame: x right, y down, z into the scene; metres; origin at the axes' origin"
        (tmp / MANIFEST_NAME).write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return [out / MODEL_DIR / "cameras.txt", out / MODEL_DIR / "images.txt", out / MODEL_DIR / "points3D.txt",
            out / MANIFEST_NAME] + [out / IMAGES_DIR / names[v] for v in views]
