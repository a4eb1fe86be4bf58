"""The sparse point cloud: triangulation with known poses, tracks, and the COLMAP/nerfstudio files
(read back by pycolmap; the points checked against the virtual studio's true depth)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lfstudio.dataset.grid import View
from lfstudio.depth.files import read_ply
from lfstudio.depth.points import build_tracks, neighbour_pairs, spread_views, triangulate
from lfstudio.export import ExportOptions, export_dataset
from lfstudio.sim.studio import rotation_matrix
from lfstudio.sim.virtual_dataset import read_truth_map


def test_triangulation_recovers_points_seen_by_translated_cameras():
    rng = np.random.default_rng(3)
    K = np.array([[1400.0, 0, 511.0], [0, 1400.0, 330.0], [0, 0, 1]])
    R = rotation_matrix((1.0, -1.5, 0.7))
    X = np.column_stack([rng.uniform(-0.5, 0.5, 50), rng.uniform(-0.3, 0.3, 50), rng.uniform(1.7, 4.8, 50)])
    centres = np.array([[c * 0.004, r * 0.006, 0.0] for r in range(3) for c in range(5)])
    track = np.repeat(np.arange(50), len(centres))
    C = np.tile(centres, (50, 1))
    q = (X[track] - C) @ (K @ R).T
    xy = q[:, :2] / q[:, 2:3]
    got, err = triangulate(K, R, C, xy, track, 50)
    np.testing.assert_allclose(got, X, rtol=1e-9, atol=1e-9)
    assert err.max() < 1e-6
    # noise of 0.1 px: still close, and the error says so
    got, err = triangulate(K, R, C, xy + rng.normal(0, 0.1, xy.shape), track, 50)
    assert np.median(np.abs(got[:, 2] - X[:, 2]) / X[:, 2]) < 0.02
    assert 0.03 < np.median(err) < 0.3


def test_tracks_chain_matches_and_drop_one_that_meets_a_view_twice():
    a, b, c = View(0, 0), View(0, 1), View(0, 2)
    feats = {a: np.array([[10.0, 5.0], [20.0, 5.0]]), b: np.array([[8.0, 5.0], [18.0, 5.0]]),
             c: np.array([[6.0, 5.0], [16.0, 5.0]])}
    matches = [(a, b, feats[a][:1], feats[b][:1]), (b, c, feats[b][:1], feats[c][:1]),
               # the second feature of a joins both features of c through b: ambiguous
               (a, b, feats[a][1:], feats[b][1:]), (b, c, feats[b][1:], feats[c][1:]),
               (a, c, feats[a][1:], feats[c][:1])]
    tracks = build_tracks(feats, matches)
    assert tracks == []                                  # everything chained into one ambiguous track
    tracks = build_tracks(feats, matches[:4])
    assert sorted(tracks) == [[(a, 0), (b, 0), (c, 0)], [(a, 1), (b, 1), (c, 1)]]


def test_a_large_grid_is_thinned_to_whole_rows_and_columns():
    views = [View(r, c) for r in range(21) for c in range(101)]
    chosen = spread_views(views, 45)
    assert 30 <= len(chosen) <= 45
    rows, cols = {r for r, _ in chosen}, {c for _, c in chosen}
    assert len(chosen) == len(rows) * len(cols) and 0 in rows and 20 in rows and 0 in cols and 100 in cols
    pairs = neighbour_pairs(chosen)
    assert all((a.row == b.row) if d == "h" else (a.column == b.column) for a, b, d in pairs)
    assert len(pairs) == len(rows) * (len(cols) - 1) + len(cols) * (len(rows) - 1)


def test_colmap_points_read_by_pycolmap_reference_their_images_and_lie_at_the_true_depth(calibrated_1000, tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    ds = calibrated_1000
    out = tmp_path / "colmap"
    export_dataset(ds, ExportOptions("colmap", out, image_bit_depth=16))
    rec = pycolmap.Reconstruction(out / "sparse" / "0")
    assert rec.num_points3D() >= 100, rec.num_points3D()
    by_id = {im.image_id: im for im in rec.images.values()}
    rel_errors, reproj = [], []
    for pid, p in rec.points3D.items():
        assert p.track.length() >= 3
        for el in p.track.elements:
            im = by_id[el.image_id]
            p2d = im.points2D[el.point2D_idx]
            assert p2d.point3D_id == pid                       # the track names this image's POINTS2D entry
            xy = np.asarray(im.camera.img_from_cam(im.cam_from_world() * p.xyz), float)
            reproj.append(float(np.hypot(*(xy - np.asarray(p2d.xy)))))
        # the true depth where the point's first observation lies (the view as captured)
        el = p.track.elements[0]
        im = by_id[el.image_id]
        r, c = int(im.name[1:3]), int(im.name[5:8])
        u, v = (np.asarray(im.points2D[el.point2D_idx].xy) - 0.5).round().astype(int)
        z_true = read_truth_map(ds.root, "depth", r, c)[v, u]
        rel_errors.append(abs(p.xyz[2] - z_true) / z_true)
    reproj, rel_errors = np.array(reproj), np.array(rel_errors)
    assert reproj.max() <= 1.0 + 1e-6 and reproj.mean() < 0.5, (reproj.max(), reproj.mean())
    assert (rel_errors < 0.02).mean() >= 0.9, (rel_errors < 0.02).mean()
    # the same points in the PLY beside the model, coloured
    xyz, rgb = read_ply(out / "sparse" / "0" / "points3D.ply")
    assert len(xyz) == rec.num_points3D()
    ours = np.array([rec.points3D[i].xyz for i in sorted(rec.points3D)])
    np.testing.assert_allclose(xyz, ours, atol=1e-5)
    assert rgb.std() > 5                                        # the views' colours, not one grey
    manifest = json.loads((out / "lfstudio_manifest.json").read_text())
    assert manifest["point_cloud"]["points"] == len(xyz)


def test_nerfstudio_names_the_ply_in_its_world(calibrated_1000, tmp_path):
    ds = calibrated_1000
    export_dataset(ds, ExportOptions("colmap", tmp_path / "c", views="r1"))       # one row: its points suffice
    export_dataset(ds, ExportOptions("nerfstudio", tmp_path / "n", views="r1"))
    doc = json.loads((tmp_path / "n" / "transforms.json").read_text())
    assert doc["ply_file_path"] == "sparse_pc.ply"
    xyz_ns, _ = read_ply(tmp_path / "n" / doc["ply_file_path"])
    xyz_rig, _ = read_ply(tmp_path / "c" / "sparse" / "0" / "points3D.ply")
    assert len(xyz_rig) >= 100, len(xyz_rig)
    A = np.array(doc["applied_transform"])[:, :3]
    np.testing.assert_allclose(xyz_ns, xyz_rig @ A.T, atol=1e-5)        # X_json = A · X_rig
    # every point lies in front of the frames' cameras (OpenGL: the camera looks along -z)
    c2w = np.array(doc["frames"][0]["transform_matrix"])
    cam = (xyz_ns - c2w[:3, 3]) @ c2w[:3, :3]
    assert (cam[:, 2] < 0).all()


def test_points_can_be_left_out(calibrated_1000, tmp_path):
    export_dataset(calibrated_1000, ExportOptions("colmap", tmp_path / "c", points=False, views="r0"))
    text = (tmp_path / "c" / "sparse" / "0" / "points3D.txt").read_text()
    assert "Number of points: 0" in text and not (tmp_path / "c" / "sparse" / "0" / "points3D.ply").exists()


def test_a_small_capture_gives_a_thousand_points_and_says_why_others_were_dropped(calibrated, tmp_path):
    """Issue 37: a 5 × 3 capture of small views gave 216 points at 640 px (this one), 25 at 400 px:
    features were few (SIFT's default contrast on small, smooth views) and each point rested on a
    few SIFT positions chained between neighbours, too imprecise to fix its depth. Now the tracks are
    followed into every view with sub-pixel patch alignment; the export says what it dropped and why."""
    pycolmap = pytest.importorskip("pycolmap")
    report = export_dataset(calibrated, ExportOptions("colmap", tmp_path / "c"))
    rec = pycolmap.Reconstruction(tmp_path / "c" / "sparse" / "0")
    assert rec.num_points3D() >= 1000, rec.num_points3D()          # 216 before (3579 measured)
    lengths = [p.track.length() for p in rec.points3D.values()]
    assert np.mean(lengths) >= 10                       # seen in most of the 15 views, not 3 or 4
    cloud = json.loads((tmp_path / "c" / "lfstudio_manifest.json").read_text())["point_cloud"]
    dropped = cloud["dropped"]
    assert set(dropped) >= {"behind the cameras", "tracks meeting a view twice"} and \
        any(k.startswith("depth not fixed") for k in dropped)
    assert cloud["points"] + sum(dropped.values()) == cloud["tracks"]
    assert f"sparse points: {cloud['points']} from {cloud['tracks']} feature tracks" in report.summary()
