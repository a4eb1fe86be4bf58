"""Depth and points against the virtual studio's ground truth: the sparse point cloud of the COLMAP
export and the dense disparity maps of ``lfstudio depth`` (ours vs OpenCV's single-pair SGBM),
CPU time per view at 2000 px, and dense depth on a Dask cluster of one and two local workers.

    ./.venv/bin/python benchmarks/depth_points.py [--grids 9x3,21x5] [--width 1000] [--keep DIR]
        [--dense-views 7] [--cluster-views 16] [--skip-cluster] [--skip-2000] [--cluster-grid CxR
        [--cluster-grid-views N]] [--skip-small] [--hci DIR] [--seeds 0,1]

First (issue 37, ``--skip-small`` leaves it out): the 5 × 3 capture at 800 px as a user makes it (DNG,
calibrated, processed to 400 px views, exported as COLMAP) and every HCI scene found (``--hci DIR``,
default ../shared/data/lightfield: imported, calibrated, exported from the raw views; depth against the
benchmark's centre-view disparity): points, reprojection error, share within 2 % of the true depth,
and the tracks dropped, by reason.

Each grid is rendered (16-bit PNG, orientation error (1, -1.5, 0.7) deg, principal point offset
(8, -5) px, the reference rig's position noise 80 x 50 µm), **self-calibrated** (``calibrate_dataset``,
defaults: nothing from the ground truth) and exported as COLMAP (8-bit sRGB views, the sparse
cloud). Points: count, reprojection error of every observation (mean, p95; targets ≤ 0.5 / 1.0 px),
share whose depth is within 2 % of the true depth where it is observed (target ≥ 90 %). Dense: for
``--dense-views`` views of the centre row, our map and SGBM's on the widest horizontal pair the sweep
uses (the same images rectified with the same calibration), each against the true rectified
disparity: median relative depth error and BadPix(0.07) (share of pixels more than 0.07 px off;
SGBM's holes count as bad; also over SGBM's own valid pixels), 12 px border left out; then ours per
view (mean, range, standard deviation: the figure moves by tenths of a percent from view to view,
so three views are not enough to compare two methods) and against the truth carried into the maps'
own frame (:func:`own_frame_figures`: the self-calibration's rectification differs from the ideal
one by a few px, which the pixel-by-pixel comparison counts as error at every depth edge);
``--seeds 0,1,…`` renders each grid once per scene seed (its own scene and position noise) and pools
the per-view figures. For given code and data the figures are deterministic (no random draw at run
time, no dependence on the load); they move with the view, the scene and the self-calibration.
2000 px: the CPU seconds of one view (its worker's own CPU). Cluster: ``--cluster-views`` views of the
largest grid on a ``distributed.LocalCluster`` of 1 then 2 single-threaded worker processes (wall
time, views per minute, scaling) and the 2121-view wall time extrapolated from it (said so).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from benchmarks._measure import Timer, load_text  # noqa: E402


def render(root: Path, cols: int, rows: int, width: int, only=None, noise=(80.0, 50.0), seed: int = 0):
    from lfstudio.sim.virtual_dataset import make_virtual_dataset

    if (root / "dataset.json").is_file():
        from lfstudio.dataset import Dataset

        return Dataset.open(root)
    return make_virtual_dataset(root, cols, rows, width_px=width, fmt="png", rotation_deg=(1.0, -1.5, 0.7),
                                pp_offset_px=(8.0, -5.0), position_noise_um=noise, workers=2, only_views=only,
                                seed=seed)


def calibrate(ds):
    from lfstudio.calibration.calibrate import calibrate_dataset
    from lfstudio.calibration.model import save_calibration

    if not (ds.root / "calibration.json").is_file():
        run = calibrate_dataset(ds)
        save_calibration(ds, run.document)
    from lfstudio.calibration.model import load_calibration

    return load_calibration(ds)


def points_figures(ds, out: Path, truth: bool = True) -> dict:
    import json

    import pycolmap

    from lfstudio.calibration.model import load_calibration
    from lfstudio.export import ExportOptions, export_dataset
    from lfstudio.sim.virtual_dataset import read_truth_map

    with Timer() as span:
        export_dataset(ds, ExportOptions("colmap", out, overwrite=True))
    rec = pycolmap.Reconstruction(out / "sparse" / "0")
    manifest = json.loads((out / "lfstudio_manifest.json").read_text())
    cal = load_calibration(ds)
    H_inv = np.linalg.inv(np.asarray(cal["homography"], float)) \
        if cal and manifest.get("pinhole", {}).get("rectified") else None
    by_id = {im.image_id: im for im in rec.images.values()}
    truth_cache: dict = {}
    errors, rel = [], []
    for p in rec.points3D.values():
        if not truth:
            for el in p.track.elements:
                im = by_id[el.image_id]
                proj = np.asarray(im.camera.img_from_cam(im.cam_from_world() * p.xyz))
                errors.append(float(np.hypot(*(proj - np.asarray(im.points2D[el.point2D_idx].xy)))))
            continue
        rels = []
        for el in p.track.elements:
            im = by_id[el.image_id]
            xy = np.asarray(im.points2D[el.point2D_idx].xy)
            proj = np.asarray(im.camera.img_from_cam(im.cam_from_world() * p.xyz))
            errors.append(float(np.hypot(*(proj - xy))))
            r, c = int(im.name[1:3]), int(im.name[5:8])
            if (r, c) not in truth_cache:
                truth_cache[(r, c)] = read_truth_map(ds.root, "depth", r, c)
            t = truth_cache[(r, c)]
            # the truth is the captured view's, at its size: exported pixel -> captured pixel
            xy_t = captured_pixel(xy, (im.camera.width, im.camera.height), (t.shape[1], t.shape[0]), H_inv)
            u, v = np.clip(np.rint(xy_t).astype(int), 0, [t.shape[1] - 1, t.shape[0] - 1])
            rels.append(abs(p.xyz[2] - t[v, u]) / t[v, u])
        rel.append(float(np.median(rels)))        # the true depth where most of its observations lie
    errors, rel = np.array(errors), np.array(rel)
    return {"points": rec.num_points3D(), "err_mean": errors.mean() if len(errors) else float("nan"),
            "err_p95": np.percentile(errors, 95) if len(errors) else float("nan"),
            "within_2pct": (rel < 0.02).mean() if len(rel) else float("nan"),
            "track": np.mean([p.track.length() for p in rec.points3D.values()]) if rec.num_points3D() else 0,
            "tracks": (manifest.get("point_cloud") or {}).get("tracks"),
            "dropped": (manifest.get("point_cloud") or {}).get("dropped"),
            "export_wall_s": span.wall_s, "export_cpu_s": span.cpu_s}


def captured_pixel(xy, size, truth_size, H_inv):
    """An exported image's pixel ``xy`` (image ``size``) as a pixel of the captured view at
    ``truth_size`` (the truth maps' frame): scaled to full resolution, then through the inverse of the
    rectifying homography when the export is rectified (pixel centres at integers)."""
    s = truth_size[0] / float(size[0])
    full = (np.asarray(xy, float) + 0.5) * s - 0.5
    if H_inv is None:
        return full
    q = H_inv @ np.array([full[0], full[1], 1.0])
    return q[:2] / q[2]


def dense_figures(ds, views) -> dict:
    import cv2

    from lfstudio.calibration.model import load_calibration
    from lfstudio.depth import dense
    from lfstudio.depth.run import estimate_depth, read_disparity
    from lfstudio.sim.virtual_dataset import read_truth_map

    from lfstudio.sim.virtual_dataset import load_ground_truth

    cal = load_calibration(ds)
    H = np.asarray(cal["homography"], float)
    H_true = np.asarray(load_ground_truth(ds.root)["H"], float)
    out = {"ours_rel": [], "ours_bad": [], "sgbm_rel": [], "sgbm_bad": [], "sgbm_bad_valid": [], "ours_bad_valid": [],
           "sgbm_density": [], "cpu_s": [], "ours_rel_own": [], "ours_bad_own": []}
    m = 12
    for view in views:
        estimate_depth(ds, [view], force=True)
        disp, conf, record = read_disparity(ds, view)
        truth = read_truth_map(ds.root, "disparity_rectified", *view)[m:-m, m:-m]
        ours = disp[m:-m, m:-m]
        out["cpu_s"].append(record["cpu_s"])
        k = max(abs(int(n[1]) - view[1]) for n in record["neighbours"] if n[0] == view[0])
        right = (view[0], view[1] + k) if view[1] + k < ds.grid.columns else None
        w, h = record["size_px"]

        def grey(v):
            img = cv2.cvtColor(cv2.imread(str(ds.path_of(ds.view(*v))), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGR2RGB)
            return dense.to_uint8(dense.prepare(cv2.warpPerspective(img, H, (w, h), flags=cv2.INTER_LINEAR,
                                                                    borderMode=cv2.BORDER_REPLICATE)))
        dmax = record["d_range_px"][1] * k
        if right is not None:
            s = dense.sgbm_disparity(grey(view), grey(right), dmax) / k
        else:
            s = dense.sgbm_disparity(grey(view)[:, ::-1], grey((view[0], view[1] - k))[:, ::-1], dmax)[:, ::-1] / k
        s = s[m:-m, m:-m]
        valid = np.isfinite(s)
        with np.errstate(divide="ignore", invalid="ignore"):
            for name, d in (("ours", ours), ("sgbm", s)):
                err = np.abs(np.nan_to_num(d, nan=1e9) - truth)
                out[f"{name}_bad"].append(float((err > 0.07).mean()))
                out[f"{name}_bad_valid"].append(float((err[valid] > 0.07).mean()))
                rel = np.abs(truth / d - 1.0)
                out[f"{name}_rel"].append(float(np.median(np.where(np.isfinite(rel), rel, np.inf))))
        out["sgbm_density"].append(float(valid.mean()))
        rel_own, bad_own = own_frame_figures(disp, read_truth_map(ds.root, "disparity_rectified", *view), H, H_true, m)
        out["ours_rel_own"].append(rel_own)
        out["ours_bad_own"].append(bad_own)
    return {k: float(np.mean(v)) for k, v in out.items()} | {f"{k}_views": v for k, v in out.items()}


def own_frame_figures(disp: np.ndarray, truth: np.ndarray, H_used: np.ndarray, H_true: np.ndarray,
                      m: int) -> tuple[float, float]:
    """Median relative depth error and BadPix(0.07) of a map against the truth carried into the map's
    own frame: the map is made in views rectified by the self-calibration (``H_used``), the truth in
    the ideal rectified frame (``H_true``); the two differ by a few px (the principal point held at
    the centre, the rotation's error), so a pixel-by-pixel comparison also counts that shift at every
    depth edge. Each pixel p of the map is the truth's pixel ``t = H_true · H_used⁻¹ · p`` (nearest),
    and its expected disparity the horizontal distance ``G(t + d) − G(t)``, ``G = H_used · H_true⁻¹``.
    ``m`` px border left out in both frames."""
    import cv2

    h, w = truth.shape
    G = H_used @ np.linalg.inv(H_true)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    P = np.stack([xx.ravel(), yy.ravel(), np.ones(xx.size)])
    T = np.linalg.inv(G) @ P
    T = T[:2] / T[2]
    tu, tv = T[0].reshape(h, w).astype(np.float32), T[1].reshape(h, w).astype(np.float32)
    dt = cv2.remap(truth, tu, tv, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    Q = G @ np.stack([T[0] + dt.ravel(), T[1], np.ones(T[0].size)])
    expected = (Q[0] / Q[2] - P[0]).reshape(h, w)
    inside = (tu >= m) & (tu < w - m) & (tv >= m) & (tv < h - m) & np.isfinite(expected)
    inside[:m] = inside[-m:] = False
    inside[:, :m] = inside[:, -m:] = False
    err = np.abs(np.nan_to_num(disp, nan=1e9) - expected)[inside]
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.abs(expected / disp - 1.0)[inside]
    return float(np.median(np.where(np.isfinite(rel), rel, np.inf))), float((err > 0.07).mean())


def spread(values) -> str:
    """'mean (min … max over N)' of per-view figures, in %."""
    v = np.asarray(values, float)
    return f"{v.mean():.2%} (views {v.min():.2%} … {v.max():.2%}, sd {v.std():.2%}, n {len(v)})"


def cpu_at_2000(tmp: Path) -> float:
    from lfstudio.depth.run import estimate_depth, read_disparity

    only = [(1, c) for c in range(9)] + [(0, 4), (2, 4)]
    ds = render(tmp / "w2000", 9, 3, 2000, only=only, noise=(0.0, 0.0))
    calibrate_exact(ds)
    estimate_depth(ds, [(1, 4)], force=True)
    return float(read_disparity(ds, (1, 4))[2]["cpu_s"])


def calibrate_exact(ds):
    """Timing only (2000 px): the true camera as calibration.json, no self-calibration run."""
    from lfstudio.calibration.model import rectifying_homography
    from lfstudio.dataset.atomic import atomic_write_json
    from lfstudio.sim.virtual_dataset import load_ground_truth

    t = load_ground_truth(ds.root)
    w, h = t["image_size_px"]
    pp = [(w - 1) / 2 + t["pp_offset_px"][0], (h - 1) / 2 + t["pp_offset_px"][1]]
    atomic_write_json(ds.root / "calibration.json", {
        "format": "lfstudio-calibration", "version": 1, "rotation_deg": list(t["rotation_deg"]),
        "image_size_px": [w, h], "focal_length_px": t["focal_length_px"], "principal_point_px": pp,
        "principal_point_estimated": True,
        "homography": rectifying_homography(t["rotation_deg"], t["focal_length_px"], (w, h), pp).tolist()})


def cluster_figures(ds, n_views: int) -> dict:
    from distributed import Client, LocalCluster

    from lfstudio.depth.run import estimate_depth

    views = [v for v in ds.captured_views()][:n_views]
    out = {}
    for workers in (1, 2):
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
                Client(cluster) as client:
            client.run(lambda: __import__("lfstudio.depth.run"))          # workers import before the clock
            with Timer() as span:
                report = estimate_depth(ds, views, executor=client.get_executor(pure=False), workers=workers,
                                        force=True)
            out[workers] = {"wall_s": span.wall_s, "views": report.computed, "cpu_per_view": report.cpu_s / max(1, report.computed),
                            "load": span.load_1min}
    return out


def whole_grid_on_the_cluster(tmp: Path, grid: str, width: int, limit: int | None = None) -> int:
    """Dense depth for every view of a ``grid`` capture (or its first ``limit`` views, the rest
    extrapolated and said so) on a Dask LocalCluster of 1, then 2 workers: measured wall time, views
    per minute and the scaling."""
    cols, rows = (int(v) for v in grid.lower().split("x"))
    with Timer() as span:
        ds = render(tmp / f"g{cols}x{rows}_{width}", cols, rows, width)
    print(f"{cols} x {rows} at {width} px rendered in {span.wall_s:.0f} s")
    calibrate_exact(ds)
    total = cols * rows
    n = min(total, limit or total)
    c = cluster_figures(ds, n)
    one, two = c[1], c[2]
    for workers, f in c.items():
        print(f"  {workers} worker(s): {f['views']} views in {f['wall_s'] / 60:.1f} min wall "
              f"({f['views'] / f['wall_s'] * 60:.0f} views/min), {f['cpu_per_view']:.2f} CPU s per view, "
              f"load {f['load']:.1f}")
    what = f"all {n} views" if n == total else f"the first {n} of {total} views"
    print(f"Dask LocalCluster, {what} of {cols} x {rows} at {width} px (measured): 1 worker "
          f"{one['wall_s'] / 60:.1f} min, 2 workers {two['wall_s'] / 60:.1f} min: scaling "
          f"{one['wall_s'] / two['wall_s']:.2f}x on this {os.cpu_count()}-core machine")
    if n < total:
        print(f"  all {total} views extrapolated (not measured) from those {n}: 1 worker "
              f"{one['wall_s'] / n * total / 60:.0f} min, 2 workers {two['wall_s'] / n * total / 60:.0f} min")
    print(load_text())
    return 0


def small_capture(tmp: Path) -> None:
    """Issue 37: the 5 × 3 capture at 800 px as a user makes it (``lfstudio virtual-dataset`` defaults: DNG,
    orientation error (1, -1.5, 0.7)°, exact positions), calibrated, processed (half-size views: 400 px) and
    exported as COLMAP: the sparse cloud's figures and the tracks it dropped, by reason."""
    from lfstudio.calibration.model import load_calibration
    from lfstudio.processing.pipeline import process_dataset
    from lfstudio.sim.virtual_dataset import make_virtual_dataset
    from lfstudio.dataset import Dataset
    from lfstudio.dataset.profile import Profile

    root = tmp / "small_5x3_800_dng"
    if not (root / "dataset.json").is_file():
        make_virtual_dataset(root, 5, 3, width_px=800, fmt="dng", rotation_deg=(1.0, -1.5, 0.7))
    ds = Dataset.open(root)
    calibrate(ds)
    if not (root / "processed").is_dir():
        process_dataset(root, Profile.for_dataset(root), workers=0)
    ds = Dataset.open(root)
    decision = (load_calibration(ds) or {}).get("rectification", {}).get("decision", "")
    p = points_figures(ds, tmp / "colmap_small_5x3_800")
    print(f"5 x 3 at 800 px (DNG, calibrated, processed, exported at 400 px; {decision}):")
    print_points(p)


def print_points(p: dict) -> None:
    print(f"  points: {p['points']}, reprojection error mean {p['err_mean']:.3f} px, p95 {p['err_p95']:.3f} px "
          f"(targets <= 0.5 / 1.0), within 2 % of the true depth {p['within_2pct']:.1%} (target >= 90 %), "
          f"mean track {p['track']:.1f} views; export {p['export_wall_s']:.0f} s wall, {p['export_cpu_s']:.0f} s CPU")
    if p.get("dropped") is not None:
        print(f"  {p['tracks']} feature tracks; dropped: "
              + (", ".join(f"{n} {reason}" for reason, n in sorted(p["dropped"].items(), key=lambda kv: -kv[1]) if n)
                 or "none"))


def hci_scenes(folders: list[Path]) -> list[Path]:
    """Every HCI scene (a folder with parameters.cfg, input_Cam*.png and gt_disp_lowres.pfm) under ``folders``."""
    found = []
    for folder in folders:
        if folder.is_dir():
            found += [cfg.parent for cfg in sorted(folder.rglob("parameters.cfg"))
                      if (cfg.parent / "gt_disp_lowres.pfm").is_file() and any(cfg.parent.glob("input_Cam*.png"))]
    return found


def hci_points(scene: Path, tmp: Path) -> dict:
    """An HCI scene imported as a user does, calibrated and exported as COLMAP: the sparse cloud's
    figures; depth against the benchmark's centre-view disparity (each point projected into the centre
    view, ``Z = f·B / (d + f·B/Z_focus)``, the relation ``parameters.cfg`` states: offset = f·B/Z_focus)."""
    import re
    import subprocess

    import pycolmap

    from lfstudio.dataset import Dataset
    from lfstudio.depth.files import read_pfm

    root = tmp / f"hci_{scene.name}"
    if not (root / "dataset.json").is_file():
        subprocess.run([sys.executable, "-m", "lfstudio", "import-images", str(scene), "--out", str(root)], check=True,
                       capture_output=True)
    ds = Dataset.open(root)
    calibrate(ds)
    out = tmp / f"colmap_hci_{scene.name}"
    p = points_figures(ds, out, truth=False)
    cfg = dict(re.findall(r"^(\w+)\s*=\s*(\S+)", (scene / "parameters.cfg").read_text(), re.M))
    w = int(cfg["image_resolution_x_px"])
    h = int(cfg["image_resolution_y_px"])
    f = float(cfg["focal_length_mm"]) / float(cfg["sensor_size_mm"]) * max(w, h)
    fb = f * float(cfg["baseline_mm"]) / 1000.0
    offset = fb / float(cfg["focus_distance_m"])
    gt = read_pfm(scene / "gt_disp_lowres.pfm")
    rec = pycolmap.Reconstruction(out / "sparse" / "0")
    n = int(cfg["num_cams_x"])
    centre = next(im for im in rec.images.values() if im.name.startswith(f"r{n // 2:02d}_c{n // 2:03d}"))
    rel = []
    for point in rec.points3D.values():
        uv = np.asarray(centre.camera.img_from_cam(centre.cam_from_world() * point.xyz), float)
        u, v = np.rint(uv - 0.5).astype(int)
        if 0 <= u < w and 0 <= v < h:
            z_true = fb / (float(gt[v, u]) + offset)
            rel.append(abs(point.xyz[2] - z_true) / z_true)
    p["within_2pct"] = float((np.array(rel) < 0.02).mean()) if rel else float("nan")
    return p


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--grids", default="9x3,21x5")
    ap.add_argument("--width", type=int, default=1000)
    ap.add_argument("--keep", type=Path, help="render into (and reuse) this folder")
    ap.add_argument("--dense-views", type=int, default=7,
                    help="views of the centre row whose maps are scored (spread across it; 3: last round's figure)")
    ap.add_argument("--cluster-views", type=int, default=16)
    ap.add_argument("--skip-cluster", action="store_true")
    ap.add_argument("--skip-2000", action="store_true")
    ap.add_argument("--skip-small", action="store_true",
                    help="leave out the 5 x 3 capture at 800 px as a user makes it and the HCI scenes")
    ap.add_argument("--hci", type=Path, action="append", default=[],
                    help="a folder to search for HCI scenes (repeatable; default ../shared/data/lightfield)")
    ap.add_argument("--cluster-grid", metavar="CxR",
                    help="only the cluster figure, measured on every view of this grid (e.g. 101x21: all 2121 "
                         "views at --width, true calibration) instead of extrapolated from a subset")
    ap.add_argument("--seeds", default="0",
                    help="render each grid with these scene seeds (comma-separated; each its own scene and position "
                         "noise) and pool the per-view figures")
    ap.add_argument("--cluster-grid-views", type=int, metavar="N",
                    help="with --cluster-grid: measure only its first N views (row by row) and extrapolate the rest")
    args = ap.parse_args()
    tmp = args.keep or Path(tempfile.mkdtemp(prefix="depth_points_"))
    tmp.mkdir(parents=True, exist_ok=True)
    print(load_text())
    if args.cluster_grid:
        return whole_grid_on_the_cluster(tmp, args.cluster_grid, args.width, args.cluster_grid_views)
    if not args.skip_small:
        small_capture(tmp)
        default_hci = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "lightfield"
        for scene in hci_scenes(args.hci or [default_hci]):
            print(f"HCI {scene.name} (imported, calibrated, exported as COLMAP from the raw views):")
            print_points(hci_points(scene, tmp))
    rows_out = []
    last = None
    seeds = [int(v) for v in args.seeds.split(",")]
    pooled: dict[str, list] = {}
    for text, seed in ((t, sd) for t in args.grids.split(",") for sd in seeds):
        cols, rows = (int(v) for v in text.lower().split("x"))
        with Timer() as span:
            ds = render(tmp / f"g{cols}x{rows}_{args.width}{f'_seed{seed}' if seed else ''}", cols, rows, args.width,
                        seed=seed)
        print(f"{cols} x {rows} at {args.width} px{f' (seed {seed})' if seed else ''} rendered in {span.wall_s:.0f} s")
        cal = calibrate(ds)
        print(f"  self-calibration: rotation {np.round(cal['rotation_deg'], 3).tolist()} deg (true [1, -1.5, 0.7])")
        p = points_figures(ds, tmp / f"colmap_{cols}x{rows}{f'_seed{seed}' if seed else ''}")
        print_points(p)
        if not p["points"]:
            print(f"FAILED: the COLMAP export of {cols} x {rows} views at {args.width} px has no sparse point "
                  "(no figure to give)", file=sys.stderr)
            return 1
        mid_row = (rows - 1) // 2
        cs = np.linspace(0, cols - 1, args.dense_views + 2)[1:-1].round().astype(int)
        d = dense_figures(ds, [(mid_row, int(c)) for c in cs])
        print(f"  dense ({args.dense_views} views of row {mid_row}): ours median rel depth error {d['ours_rel']:.2%}, "
              f"BadPix(0.07) {d['ours_bad']:.1%}; SGBM {d['sgbm_rel']:.2%}, {d['sgbm_bad']:.1%} (its valid pixels "
              f"{d['sgbm_density']:.0%}: SGBM {d['sgbm_bad_valid']:.1%}, ours {d['ours_bad_valid']:.1%}); "
              f"ours {d['cpu_s']:.1f} CPU s per view at {args.width} px")
        print(f"    per view (columns {', '.join(str(int(c)) for c in cs)}): median rel depth error "
              f"{spread(d['ours_rel_views'])}; BadPix(0.07) {spread(d['ours_bad_views'])}")
        print(f"    against the truth carried into the maps' own (self-calibrated) frame: median rel depth error "
              f"{spread(d['ours_rel_own_views'])}; BadPix(0.07) {spread(d['ours_bad_own_views'])}")
        if not np.isfinite(d["ours_rel"]):
            print(f"FAILED: the dense depth of {cols} x {rows} views gave no figure (no valid pixel?)", file=sys.stderr)
            return 1
        rows_out.append((text, p, d))
        for k in ("ours_rel_views", "ours_bad_views", "ours_rel_own_views", "ours_bad_own_views"):
            pooled.setdefault(f"{text}:{k}", []).extend(d[k])
        last = ds
    if len(seeds) > 1:
        for text in args.grids.split(","):
            print(f"{text}, seeds {args.seeds} pooled: median rel depth error {spread(pooled[f'{text}:ours_rel_views'])}; "
                  f"BadPix(0.07) {spread(pooled[f'{text}:ours_bad_views'])}; in the maps' own frame "
                  f"{spread(pooled[f'{text}:ours_rel_own_views'])}, {spread(pooled[f'{text}:ours_bad_own_views'])}")
    if not args.skip_2000:
        print(f"2000 px: {cpu_at_2000(tmp):.1f} CPU s per view (one view, 10 neighbours)")
    if not args.skip_cluster and last is not None:
        c = cluster_figures(last, args.cluster_views)
        one, two = c[1], c[2]
        scaling = one["wall_s"] / two["wall_s"]
        print(f"Dask LocalCluster, {args.cluster_views} views at {args.width} px: 1 worker {one['wall_s']:.0f} s, "
              f"2 workers {two['wall_s']:.0f} s: scaling {scaling:.2f}x (load {one['load']:.1f} / {two['load']:.1f}); "
              f"{one['cpu_per_view']:.1f} / {two['cpu_per_view']:.1f} CPU s per view")
        per_view = two["wall_s"] / max(1, two["views"])
        print(f"2121 views on 2 workers, extrapolated from {two['views']} views: {per_view * 2121 / 60:.0f} min at "
              f"{args.width} px (not measured: {per_view * 2121 / 3600:.1f} h of a shared two-core machine)")
    print(load_text())
    print(f"data in {tmp}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
