"""COLMAP text model with the rig's known poses, beside the exported views.

Layout (what COLMAP's ``image_undistorter``, 3D Gaussian splatting and gsplat read)::

    OUT/images/rRR_cCCC.png        the views (8-bit sRGB by default, 16-bit linear on request)
    OUT/sparse/0/cameras.txt       one PINHOLE camera: WIDTH HEIGHT fx fy cx cy (exported size)
    OUT/sparse/0/images.txt        per view: IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, then its
                                   POINTS2D as X Y POINT3D_ID (empty for a view no point uses)
    OUT/sparse/0/points3D.txt      the sparse point cloud: POINT3D_ID X Y Z R G B ERROR TRACK[] as
                                   (IMAGE_ID, POINT2D_IDX), each track entry naming a POINTS2D entry
    OUT/sparse/0/points3D.ply      the same points as a coloured PLY (rig frame, metres)
    OUT/lfstudio_manifest.json     our description (grid, positions, calibration, the camera, the
                                   point cloud's figures and filters)

The points (``options.points``, on by default) are triangulated from SIFT tracks with the known
poses, never estimated poses (:mod:`lfstudio.depth.points`): kept when seen in 3 or more views,
every observation within 1 px of its reprojection and the depth fixed to 0.6 % by the views' spread.

World frame = the rig frame (x right, y down, z into the scene) in **metres**; the origin is the
axes' origin. ``Q``/``T`` are COLMAP's world-to-camera rotation (unit quaternion, w first) and
translation: ``x_cam = R·X + T``; ``R`` is the calibrated orientation (identity for rectified views,
see :mod:`lfstudio.export.poses`) and the camera centre ``−Rᵀ·T`` is the view's reported position.
COLMAP puts the centre of the top-left pixel at (0.5, 0.5): cx, cy are ours + 0.5.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from lfstudio.dataset import Dataset
from lfstudio.dataset.paths import view_stem
from lfstudio.errors import InputError
from lfstudio.export import common, poses
from lfstudio.jobs import CancelToken, Progress

IMAGES_DIR = "images"
MODEL_DIR = "sparse/0"
MANIFEST_NAME = "lfstudio_manifest.json"
PLY_NAME = "points3D.ply"

if TYPE_CHECKING:
    from lfstudio.depth.points import SparseCloud


def image_names(views: Sequence[common.View], suffix: str = ".png") -> dict[common.View, str]:
    return {v: f"{view_stem(*v)}{suffix}" for v in views}


def cameras_text(cam: poses.PinholeCamera, shifts: list[tuple[float, float]] | None = None) -> str:
    """One PINHOLE camera; with ``shifts`` (sheared views, :func:`poses.principal_point_shifts_px`) one
    per image, CAMERA_ID = IMAGE_ID, each with its principal point moved by its shift."""
    w, h = cam.size_px
    cx, cy = cam.principal_point_corner_px()
    moved = shifts if shifts is not None else [(0.0, 0.0)]
    return ("# Camera list with one line of data per camera:\n"
            "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
            f"# Number of cameras: {len(moved)}\n"
            + "".join(f"{i} PINHOLE {w} {h} {cam.fx_px:.10g} {cam.fy_px:.10g} {cx + dx:.10g} {cy + dy:.10g}\n"
                      for i, (dx, dy) in enumerate(moved, start=1)))


def images_text(ds: Dataset, views: Sequence[common.View], names: dict[common.View, str],
                cam: poses.PinholeCamera, cloud: "SparseCloud | None" = None, per_image_camera: bool = False) -> str:
    """images.txt; with ``cloud``, each image's POINTS2D are its observations (COLMAP pixel
    coordinates: ours + 0.5), POINT3D_ID = the cloud's index + 1."""
    observations = cloud.observations if cloud is not None else {}
    n_obs = sum(len(ids) for _, ids in observations.values())
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: {len(views)}, mean observations per image: {n_obs / max(1, len(views)):.6g}"]
    qw, qx, qy, qz = poses.quaternion_wxyz(cam.R)
    for image_id, v in enumerate(views, start=1):
        _, t = cam.world_to_camera(poses.centre_m(ds, v))
        lines.append(f"{image_id} {qw:.12g} {qx:.12g} {qy:.12g} {qz:.12g} {t[0]:.12g} {t[1]:.12g} {t[2]:.12g} "
                     f"{image_id if per_image_camera else 1} {names[v]}")
        xy, ids = observations.get(v, (np.zeros((0, 2)), np.zeros(0, int)))
        lines.append(" ".join(f"{x + 0.5:.4f} {y + 0.5:.4f} {int(i) + 1}" for (x, y), i in zip(xy, ids)))
    return "\n".join(lines) + "\n"


def points3d_text(views: Sequence[common.View], cloud: "SparseCloud | None") -> str:
    """points3D.txt: each point with its track (IMAGE_ID, POINT2D_IDX into that image's POINTS2D)."""
    n = len(cloud) if cloud is not None else 0
    tracks: list[list[str]] = [[] for _ in range(n)]
    if cloud is not None:
        image_id = {v: i for i, v in enumerate(views, start=1)}
        for v in views:
            _, ids = cloud.observations.get(v, (None, np.zeros(0, int)))
            for k, pid in enumerate(ids):
                tracks[int(pid)].append(f"{image_id[v]} {k}")
    mean_track = sum(len(t) for t in tracks) / n if n else 0
    lines = ["# 3D point list with one line of data per point:",
             "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
             f"# Number of points: {n}, mean track length: {mean_track:.6g}"]
    for i in range(n):
        assert cloud is not None                  # n is 0 without a cloud
        x, y, z = cloud.xyz_m[i]
        r, g, b = (int(c) for c in cloud.rgb[i])
        lines.append(f"{i + 1} {x:.9g} {y:.9g} {z:.9g} {r} {g} {b} {cloud.error_px[i]:.6g} {' '.join(tracks[i])}")
    return "\n".join(lines) + "\n"


POINTS3D_TEXT = points3d_text((), None)


def sparse_cloud_of_export(ds: Dataset, views: Sequence[common.View], cam: poses.PinholeCamera, folder: Path,
                           names: dict[common.View, str], progress: Progress, cancel: CancelToken) -> "SparseCloud":
    """The sparse cloud (:mod:`lfstudio.depth.points`) of the exported images in ``folder`` (the
    pixels and colours the user's tools see) with the exported camera and the known positions."""
    import cv2

    from lfstudio.depth.points import sparse_cloud

    shifts = poses.principal_point_shifts_px(ds, views, cam.size_px)

    def image_of(v):
        path = folder / names[v]
        if path.suffix in (".exr", ".tif"):        # float radiance: the points are found on its tone map
            path = common.tonemap_file(ds, ds.view(*v))
            if path is None:
                raise InputError("points", f"{view_stem(*v)} has no tone-mapped HDR picture to find the sparse "
                                 "points on", "process with the HDR previews, or export without the point cloud")
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise OSError(f"{path}: cannot read the exported image back")
        if shifts is not None:      # sheared views: triangulate the parallel ones (shear taken off)
            dx, dy = shifts[v]
            img = cv2.warpAffine(img, np.array([[1, 0, -dx], [0, 1, -dy]], np.float32), (img.shape[1], img.shape[0]),
                                 flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)

    cloud = sparse_cloud(views, image_of, cam.K, cam.R, lambda v: poses.centre_m(ds, v),
                         progress=progress, cancel=cancel)
    if shifts is not None:          # observations where the exported (sheared) images show them
        for v, (xy, ids) in list(cloud.observations.items()):
            cloud.observations[v] = (np.asarray(xy, float) + np.asarray(shifts[v], float), ids)
    return cloud


def describe_cloud(cloud: "SparseCloud | None") -> dict[str, Any] | None:
    """The point cloud's figures for lfstudio_manifest.json."""
    if cloud is None:
        return None
    errors = cloud.all_errors_px()
    lengths = cloud.track_lengths()
    return {"points": len(cloud), "views_used": len(cloud.views),
            "reprojection_error_px": {"mean": float(errors.mean()) if len(errors) else None,
                                      "p95": float(np.percentile(errors, 95)) if len(errors) else None},
            "mean_track_length": float(lengths.mean()) if len(lengths) else None,
            "tracks": cloud.stats.get("tracks"), "dropped": cloud.stats.get("dropped"),
            "filters": cloud.stats.get("filters"), "method": "lfstudio.depth.points (known poses, SIFT tracks)"}


def export_colmap(ds: Dataset, views: Sequence[common.View], source: str, size: tuple[int, int], out: Path,
                  options, progress: Progress, cancel: CancelToken) -> list[Path]:
    bit_depth = int(options.image_bit_depth)
    cam = poses.camera_for(ds, size, common.is_rectified(ds, source))
    names = image_names(views, common.image_suffix(ds, views, source))
    progress(0, len(views), "exporting COLMAP model")
    with common.partial_folder(out, options.overwrite) as tmp:
        (tmp / IMAGES_DIR).mkdir()
        common.write_images(ds, views, source, size, tmp / IMAGES_DIR, names, bit_depth, progress, cancel,
                            label="colmap ")
        cloud = sparse_cloud_of_export(ds, views, cam, tmp / IMAGES_DIR, names, progress, cancel) \
            if getattr(options, "points", True) else None
        model = tmp / MODEL_DIR
        model.mkdir(parents=True)
        shifts = poses.principal_point_shifts_px(ds, views, size)
        (model / "cameras.txt").write_text(cameras_text(cam, None if shifts is None else [shifts[v] for v in views]),
                                           encoding="utf-8")
        (model / "images.txt").write_text(images_text(ds, views, names, cam, cloud, shifts is not None),
                                          encoding="utf-8")
        (model / "points3D.txt").write_text(points3d_text(views, cloud), encoding="utf-8")
        if cloud is not None:
            from lfstudio.depth.files import write_ply

            write_ply(model / PLY_NAME, cloud.xyz_m, cloud.rgb)
        doc: dict[str, Any] = common.describe(ds, views, source, size, {v: f"{IMAGES_DIR}/{n}" for v, n in names.items()})
        doc["kind"] = "colmap"
        if source != "hdr":                      # float radiance keeps its own (doc["color"])
            doc["bit_depth"] = bit_depth
            doc["color"] = "sRGB (8-bit)" if bit_depth == 8 else doc["color"]
        doc["pinhole"] = cam.describe()
        doc["world_frame"] = "rig frame: x right, y down, z into the scene; metres; origin at the axes' origin"
        doc["point_cloud"] = describe_cloud(cloud)
        (tmp / MANIFEST_NAME).write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return [out / MODEL_DIR / "cameras.txt", out / MODEL_DIR / "images.txt", out / MODEL_DIR / "points3D.txt",
            out / MANIFEST_NAME] + ([out / MODEL_DIR / PLY_NAME] if cloud is not None else []) + [out / IMAGES_DIR / names[v] for v in views]
