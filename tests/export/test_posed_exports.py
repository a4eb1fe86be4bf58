"""COLMAP and nerfstudio exports with the rig's known poses, checked against the virtual studio's
ground truth: pycolmap reads the model; the exported camera projects the scene's 3-D points onto
the features measured in the exported images; transforms.json read as nerfstudio's dataparser
reads it gives the same projections. The sparse point cloud is left out (``points=False``: tests/depth/
test_points.py tests it), so each export here costs its images, not the feature tracking."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from lfstudio.calibration.model import rotation_matrix
from lfstudio.dataset import Dataset
from lfstudio.export import ExportOptions, estimate_export, export_dataset
from lfstudio.sim.studio import VirtualStudio
from lfstudio.sim.virtual_dataset import load_ground_truth

pycolmap = pytest.importorskip("pycolmap")

def studio_of(root: Path) -> VirtualStudio:
    t = load_ground_truth(root)
    return VirtualStudio(width_px=t["image_size_px"][0], height_px=t["image_size_px"][1],
                         focal_length_mm=t["focal_length_mm"], sensor_width_mm=t["sensor_width_mm"],
                         near_m=t["near_m"], far_m=t["far_m"], rotation_deg=tuple(t["rotation_deg"]),
                         pp_offset_px=tuple(t["pp_offset_px"]), view_region_mm=tuple(t["view_region_mm"]),
                         seed=t["seed"])


# -- features measured in the images --------------------------------------------------------------------
def scene_points(studio: VirtualStudio, patch_texels: int = 31, per_layer: int = 7):
    """Ground-truth 3-D points at the centres of fully opaque texture patches of every layer:
    [(X (3,), layer, (s, t))]."""
    half = patch_texels // 2
    m = half + 4                      # opaque with a margin: the rendering blends edges with what lies behind
    out = []
    for layer in studio.layers:
        th, tw = layer.rgba.shape[:2]
        for s in np.linspace(m, tw - m - 1, per_layer).astype(int):
            for t in np.linspace(m, th - m - 1, per_layer).astype(int):
                if s - m < 0 or t - m < 0 or s + m >= tw or t + m >= th:
                    continue
                alpha = layer.rgba[t - m:t + m + 1, s - m:s + m + 1, 3]
                if alpha.min() < 65535:
                    continue
                X = np.array([layer.origin_m[0] + s * layer.pixel_m, layer.origin_m[1] + t * layer.pixel_m,
                              layer.depth_m])
                out.append((X, layer, (int(s), int(t))))
    return out


def _grey(rgb: np.ndarray) -> np.ndarray:
    return rgb.astype(np.float32).mean(axis=2)


def measure(image_grey: np.ndarray, layer, st, scale: float, near_xy, patch_texels: int = 31, search_px: int = 6):
    """Where texel ``st`` of ``layer`` is in the image: normalised cross-correlation of the texture
    patch around it (resized by ``scale`` = image pixels per texel) within ``search_px`` of
    ``near_xy``, refined by a parabola through the peak. Returns ((x, y), score) or None."""
    half = patch_texels // 2
    s, t = st
    patch = _grey(layer.rgba[t - half:t + half + 1, s - half:s + half + 1, :3])
    tpl = cv2.resize(patch, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    # the texel's centre inside the resized template: cv2.resize maps x -> (x + 0.5)·scale - 0.5
    ox = oy = (half + 0.5) * scale - 0.5
    x0 = int(round(near_xy[0] - ox)) - search_px
    y0 = int(round(near_xy[1] - oy)) - search_px
    h, w = image_grey.shape
    x1, y1 = x0 + tpl.shape[1] + 2 * search_px, y0 + tpl.shape[0] + 2 * search_px
    if x0 < 0 or y0 < 0 or x1 > w or y1 > h:
        return None
    ncc = cv2.matchTemplate(image_grey[y0:y1, x0:x1], tpl, cv2.TM_CCOEFF_NORMED)
    py, px = np.unravel_index(int(np.argmax(ncc)), ncc.shape)
    if not (0 < px < ncc.shape[1] - 1 and 0 < py < ncc.shape[0] - 1):
        return None                                   # at the border of the search: not found
    def vertex(a, b, c):
        den = a - 2 * b + c
        return 0.0 if den == 0 else 0.5 * (a - c) / den
    dx = vertex(ncc[py, px - 1], ncc[py, px], ncc[py, px + 1])
    dy = vertex(ncc[py - 1, px], ncc[py, px], ncc[py + 1, px])
    return (x0 + px + dx + ox, y0 + py + dy + oy), float(ncc[py, px])


def read_rgb(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None, path
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def measured_errors(project, images: dict[str, np.ndarray], studio: VirtualStudio, f_px: float,
                    min_score: float = 0.97):
    """Pixel distances between ``project(name, X)`` (OpenCV pixels) and the measured features, over
    every visible patch of every image."""
    errors = []
    for name, img in images.items():
        grey = _grey(img)
        for X, layer, st in scene_points(studio):
            near = project(name, X)
            found = measure(grey, layer, st, f_px * layer.pixel_m / layer.depth_m, near)
            if found is None or found[1] < min_score:
                continue                              # occluded or outside this view
            errors.append(float(np.hypot(found[0][0] - near[0], found[0][1] - near[1])))
    return np.array(errors)


# -- COLMAP -----------------------------------------------------------------------------------------------
def colmap_projector(rec):
    by_name = {im.name: im for im in rec.images.values()}

    def project(name, X):
        im = by_name[name]
        xy = np.asarray(im.camera.img_from_cam(im.cam_from_world() * np.asarray(X, float)), float)
        return xy - 0.5                                # COLMAP: top-left pixel centre at (0.5, 0.5)

    return project


def check_colmap_model(ds: Dataset, out: Path, R_expected: np.ndarray, size: tuple[int, int]):
    rec = pycolmap.Reconstruction(out / "sparse" / "0")
    assert rec.num_images() == len(ds.views) and rec.num_cameras() == 1   # points: tests/depth/test_points.py
    cam = rec.cameras[1]
    assert (cam.model.name, cam.width, cam.height) == ("PINHOLE", size[0], size[1])
    for im in rec.images.values():
        r, c = int(im.name[1:3]), int(im.name[5:8])
        reported = np.array(ds.view(r, c)["reported_mm"] + [0.0]) / 1000.0
        assert np.abs(im.projection_center() - reported).max() < 1e-6, im.name      # 1 µm
        assert np.abs(im.cam_from_world().rotation.matrix() - R_expected).max() < 1e-9, im.name
        assert (out / "images" / im.name).is_file()
    return rec


def test_colmap_raw_views_pycolmap_poses_and_projections(calibrated, tmp_path):
    ds = calibrated
    out = tmp_path / "colmap"
    est = estimate_export(ds, ExportOptions("colmap", out, points=False, image_bit_depth=16))
    assert est.source == "raw" and est.image_size_px == (640, 426) and not any("calibration" in w for w in est.warnings)
    export_dataset(ds, ExportOptions("colmap", out, points=False, image_bit_depth=16))
    cal = json.loads((ds.root / "calibration.json").read_text())
    rec = check_colmap_model(ds, out, rotation_matrix(cal["rotation_deg"]), (640, 426))
    fx, fy, cx, cy = rec.cameras[1].params
    assert (fx, fy) == pytest.approx((cal["focal_length_px"],) * 2)
    assert (cx - 0.5, cy - 0.5) == pytest.approx(cal["principal_point_px"])

    studio = studio_of(ds.root)
    images = {n: read_rgb(out / "images" / n) for n in ("r00_c000.png", "r01_c002.png", "r02_c004.png")}
    project = colmap_projector(rec)
    errors = measured_errors(project, images, studio, fx)
    assert len(errors) >= 60, len(errors)
    assert errors.max() < 0.5 and np.median(errors) < 0.2, (errors.max(), np.median(errors))
    # the measurement can tell: a camera one pixel off misses by about a pixel
    off = measured_errors(lambda n, X: project(n, X) + [1.0, 0.0], images, studio, fx)
    assert np.median(off) > 0.7

    manifest = json.loads((out / "lfstudio_manifest.json").read_text())
    assert manifest["kind"] == "colmap" and manifest["pinhole"]["rotation_from"] == "calibration"
    assert manifest["intrinsics"]["principal_point_px"] == pytest.approx(cal["principal_point_px"])


def test_colmap_rectified_views_use_the_rectified_camera(calibrated, tmp_path):
    from lfstudio.processing.pipeline import process_dataset
    from lfstudio.dataset.profile import Profile

    profile = Profile()                          # rectified and halved (320 x 213), as processing does
    profile.color.enabled = False
    profile.deflicker.enabled = False
    assert process_dataset(calibrated.root, profile, workers=0).ok
    ds = Dataset.open(calibrated.root)
    out = tmp_path / "colmap"
    report = export_dataset(ds, ExportOptions("colmap", out, points=False, image_bit_depth=16))
    assert report.source == "processed"
    rec = check_colmap_model(ds, out, np.eye(3), (320, 213))
    fx, fy, cx, cy = rec.cameras[1].params
    f_full = json.loads((ds.root / "calibration.json").read_text())["focal_length_px"]
    assert (fx, fy) == pytest.approx((f_full * 320 / 640, f_full * 213 / 426))
    assert (cx, cy) == pytest.approx((160.0, 106.5))      # the image centre, COLMAP's pixel convention

    studio = studio_of(ds.root)
    images = {n: read_rgb(out / "images" / n) for n in ("r00_c001.png", "r01_c002.png", "r02_c003.png")}
    errors = measured_errors(colmap_projector(rec), images, studio, fx)
    assert len(errors) >= 40, len(errors)
    assert errors.max() < 0.5 and np.median(errors) < 0.2, (errors.max(), np.median(errors))
    manifest = json.loads((out / "lfstudio_manifest.json").read_text())
    assert manifest["rectified"] is True and manifest["intrinsics"]["principal_point_px"] == pytest.approx([159.5, 106])


def test_colmap_without_calibration_says_so(make_tiny_dataset, tmp_path):
    ds = make_tiny_dataset("png")
    est = estimate_export(ds, ExportOptions("colmap", tmp_path / "c", points=False, views="r1"))
    assert any("no calibration" in w and "lfstudio calibrate" in w for w in est.warnings)
    export_dataset(ds, ExportOptions("colmap", tmp_path / "c", points=False, views="r1"))
    rec = pycolmap.Reconstruction(tmp_path / "c" / "sparse" / "0")
    assert rec.num_images() == 5
    for im in rec.images.values():
        assert np.allclose(im.cam_from_world().rotation.matrix(), np.eye(3))
    img = cv2.imread(str(tmp_path / "c" / "images" / "r01_c000.png"), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint8 and img.shape == (426, 640, 3)      # 8-bit sRGB by default


# -- nerfstudio -------------------------------------------------------------------------------------------
def nerfstudio_cameras(folder: Path, split: str):
    """transforms.json read as nerfstudio's dataparser reads it (nerfstudio_dataparser.py): shared
    fl_x/fl_y/cx/cy/w/h, frames sorted by file name, camera_to_worlds = transform_matrix[:3, :4] in
    the OpenGL camera convention, the split from ``{split}_filenames``."""
    meta = json.loads((folder / "transforms.json").read_text())
    frames = sorted(meta["frames"], key=lambda f: f["file_path"])
    names = [f["file_path"] for f in frames]
    if f"{split}_filenames" in meta:
        wanted = set(meta[f"{split}_filenames"])
        assert wanted <= set(names)
        frames = [f for f in frames if f["file_path"] in wanted]
    assert meta["camera_model"] == "PINHOLE"
    K = np.array([[meta["fl_x"], 0, meta["cx"]], [0, meta["fl_y"], meta["cy"]], [0, 0, 1]], float)
    applied = np.vstack([np.array(meta["applied_transform"], float), [0, 0, 0, 1]])
    return meta, {f["file_path"]: np.array(f["transform_matrix"], float)[:3, :4] for f in frames}, K, applied


def nerfstudio_projector(cameras, K, applied):
    def project(name, X_rig):
        X = (applied @ np.append(np.asarray(X_rig, float), 1.0))[:3]     # our world as the json's world
        c2w = cameras[f"images/{name}"]
        x_gl = c2w[:, :3].T @ (X - c2w[:, 3])                            # camera frame, OpenGL axes
        x_cv = x_gl * np.array([1.0, -1.0, -1.0])                         # OpenGL -> OpenCV
        p = K @ x_cv
        return p[:2] / p[2] - 0.5                                         # nerfstudio: pixel centres at +0.5

    return project


def test_nerfstudio_transforms_reproduce_the_colmap_projections(calibrated, tmp_path):
    ds = calibrated
    export_dataset(ds, ExportOptions("colmap", tmp_path / "colmap", points=False, image_bit_depth=16))
    export_dataset(ds, ExportOptions("nerfstudio", tmp_path / "ns", points=False, image_bit_depth=16,
                                     holdout="centre"))
    meta, train, K, applied = nerfstudio_cameras(tmp_path / "ns", "train")
    _, test, _, _ = nerfstudio_cameras(tmp_path / "ns", "test")
    assert (meta["w"], meta["h"]) == (640, 426) and list(test) == ["images/r01_c002.png"]
    assert len(train) == 14 and not set(train) & set(test)
    assert meta["val_filenames"] == meta["test_filenames"]
    for path in list(train) + list(test):
        assert (tmp_path / "ns" / path).is_file()

    cameras = {**train, **test}
    ns_project = nerfstudio_projector(cameras, K, applied)
    colmap_project = colmap_projector(pycolmap.Reconstruction(tmp_path / "colmap" / "sparse" / "0"))
    studio = studio_of(ds.root)
    points = [X for X, _, _ in scene_points(studio)]
    for name in ("r00_c000.png", "r01_c002.png", "r02_c004.png"):
        for X in points:
            assert np.abs(ns_project(name, X) - colmap_project(name, X)).max() < 1e-6
        c2w = cameras[f"images/{name}"]
        r, c = int(name[1:3]), int(name[5:8])
        assert np.allclose(np.linalg.inv(applied)[:3, :3] @ c2w[:, 3], np.array(ds.view(r, c)["reported_mm"] + [0]) / 1000,
                           atol=1e-9)
    images = {n: read_rgb(tmp_path / "ns" / "images" / n) for n in ("r01_c002.png", "r02_c000.png")}
    errors = measured_errors(ns_project, images, studio, K[0, 0])
    assert len(errors) >= 40 and errors.max() < 0.5, (len(errors), errors.max())
    # z is up in the json world: the rig's y (down) became -z, the viewing direction (-z of OpenGL) is +y
    view_dir = -cameras["images/r01_c002.png"][:, 2]
    assert view_dir[1] > 0.99


def test_nerfstudio_holdout_every_k(make_tiny_dataset, tmp_path):
    ds = make_tiny_dataset("png")
    export_dataset(ds, ExportOptions("nerfstudio", tmp_path / "ns", points=False, holdout="every-2"))
    meta = json.loads((tmp_path / "ns" / "transforms.json").read_text())
    assert meta["test_filenames"] == ["images/r01_c001.png", "images/r01_c003.png"]
    assert len(meta["train_filenames"]) == 13 and len(meta["frames"]) == 15
    export_dataset(ds, ExportOptions("nerfstudio", tmp_path / "all", points=False, views="r0"))
    meta = json.loads((tmp_path / "all" / "transforms.json").read_text())
    assert not any(k.endswith("_filenames") for k in meta) and len(meta["frames"]) == 5
