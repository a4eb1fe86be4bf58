"""Dense disparity from the light field: file formats, the multi-baseline estimate against the
virtual studio's true disparity (and against OpenCV's single-pair SGBM), the resumable job, the
exports that carry the maps."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from lfstudio.depth import dense
from lfstudio.depth.files import depth_png_mm, read_depth_tiff, read_pfm, write_pfm
from lfstudio.depth.run import estimate_depth, map_path, read_disparity
from lfstudio.export import ExportOptions, estimate_export, export_dataset
from lfstudio.jobs import Cancelled, CancelToken
from lfstudio.sim.virtual_dataset import load_ground_truth, read_truth_map


def test_pfm_is_little_endian_bottom_row_first_and_reads_back(tmp_path):
    img = np.arange(12, dtype=np.float32).reshape(3, 4) + 0.5
    write_pfm(tmp_path / "d.pfm", img)
    raw = (tmp_path / "d.pfm").read_bytes()
    assert raw.startswith(b"Pf\n4 3\n-1.0\n")
    data = np.frombuffer(raw[len(b"Pf\n4 3\n-1.0\n"):], "<f4")
    np.testing.assert_array_equal(data[:4], img[-1])          # the bottom row comes first
    np.testing.assert_array_equal(read_pfm(tmp_path / "d.pfm"), img)


def test_depth_png_is_millimetres_with_zero_for_unknown():
    out = depth_png_mm(np.array([[1.7775, np.nan, 70.0, -1.0]], np.float32))
    assert out.dtype == np.uint16 and out.tolist() == [[1778, 0, 0, 0]]


def _inner(a: np.ndarray, m: int = 12) -> np.ndarray:
    return a[m:-m, m:-m]


def test_multi_baseline_beats_single_pair_sgbm_against_the_truth(calibrated):
    ds = calibrated
    report = estimate_depth(ds, "r01_c002")
    assert report.computed == 1 and not report.failed and report.source == "raw (rectified)"
    disp, conf, record = read_disparity(ds, (1, 2))
    truth = read_truth_map(ds.root, "disparity_rectified", 1, 2)
    assert disp.shape == conf.shape == truth.shape
    ours_bad = (_inner(np.abs(np.nan_to_num(disp, nan=1e9) - truth)) > 0.07).mean()
    ours_rel = np.median(_inner(np.abs(truth / disp - 1)))
    # the baseline: OpenCV's SGBM on the widest horizontal pair the sweep used (2 steps right)
    t = load_ground_truth(ds.root)
    H = t["H"]
    w, h = t["image_size_px"]

    def grey(view):
        img = cv2.cvtColor(cv2.imread(str(ds.path_of(ds.view(*view))), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGR2RGB)
        return dense.to_uint8(dense.prepare(cv2.warpPerspective(img, H, (w, h), flags=cv2.INTER_LINEAR,
                                                                borderMode=cv2.BORDER_REPLICATE)))

    sgbm = dense.sgbm_disparity(grey((1, 2)), grey((1, 4)), 2 * float(truth.max())) / 2.0
    sgbm_bad = (_inner(np.abs(np.nan_to_num(sgbm, nan=1e9) - truth)) > 0.07).mean()
    with np.errstate(divide="ignore"):
        sgbm_rel = np.nanmedian(_inner(np.abs(truth / sgbm - 1)))
    # median relative depth error 0.44 % (0.55 % while the sub-pixel fit took the aggregated costs'
    # parabola wherever the equiangular fit was more than 1/4 candidate away)
    assert ours_rel < 0.005 and ours_bad < 0.25, (ours_rel, ours_bad)
    assert ours_bad < sgbm_bad and ours_rel < sgbm_rel, (ours_bad, sgbm_bad, ours_rel, sgbm_rel)
    # confidence ranks the pixels: the confident ones are right more often
    err = np.abs(np.nan_to_num(disp, nan=1e9) - truth)
    sure = conf > np.percentile(conf, 50)
    assert (err[sure] > 0.07).mean() < (err[~sure] > 0.07).mean()
    assert record["neighbours"] and record["source"] == "raw"


def test_the_job_resumes_after_cancel_and_recomputes_what_changed(calibrated):
    ds = calibrated
    token = CancelToken()
    seen = []

    def progress(done, total, message=""):
        seen.append(message)
        if done >= 1 and message.startswith("depth r"):
            token.cancel()

    with pytest.raises(Cancelled):
        estimate_depth(ds, "r1,c1-3", progress=progress, cancel=token)
    done = [v for v in ((1, 1), (1, 2), (1, 3)) if map_path(ds.root, "records", v).is_file()]
    assert len(done) == 1                                          # the first view is kept
    report = estimate_depth(ds, "r1,c1-3")
    assert (report.computed, report.skipped) == (2, 1)
    assert estimate_depth(ds, "r1,c1-3").computed == 0
    # a source file that changed makes the views that use it stale (r01_c004 is a neighbour of all three)
    import os

    path = ds.path_of(ds.view(1, 4))
    st = os.stat(path)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 5_000_000_000))
    assert estimate_depth(ds, "r1,c1-3").computed == 3


def test_maps_of_an_earlier_method_are_computed_again(calibrated, monkeypatch):
    from lfstudio.depth import run

    ds = calibrated
    estimate_depth(ds, "r1,c2")
    assert estimate_depth(ds, "r1,c2").computed == 0
    assert read_disparity(ds, (1, 2))[2]["settings"]["method"] == run.METHOD
    monkeypatch.setattr(run, "METHOD", run.METHOD + "-next")
    assert estimate_depth(ds, "r1,c2").computed == 1


def test_views_computed_one_after_another_decode_each_image_once(calibrated, monkeypatch):
    from lfstudio.depth import run

    ds = calibrated
    run._image_cache.clear()
    estimate_depth(ds, "r1,c1-3", force=True)
    records = [read_disparity(ds, (1, c))[2] for c in (1, 2, 3)]
    used = {(1, c) for c in (1, 2, 3)} | {(n[0], n[1]) for r in records for n in r["neighbours"]}
    # each image decoded and rectified once for the three views (was once per view that uses it);
    # a view's own image is decoded again for its colour (r01_c002 and r01_c003 were neighbours)
    assert sum(r["images_read"] for r in records) == len(used) + 2
    assert records[0]["images_cached"] == 0 and records[1]["images_cached"] > 0
    assert all(r["images_read"] + r["images_cached"] == 1 + len(r["neighbours"]) for r in records)
    # a file changed since is read again; the cache keeps to its budget
    import os

    path = ds.path_of(ds.view(1, 4))
    st = os.stat(path)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 5_000_000_000))
    estimate_depth(ds, "r1,c2", force=True)
    assert read_disparity(ds, (1, 2))[2]["images_read"] == 2             # r01_c004 and its own
    monkeypatch.setattr(run, "IMAGE_CACHE_MB", 2)
    run._image_cache.clear()
    estimate_depth(ds, "r1,c1-3", force=True)
    sizes = [a.nbytes for a in run._image_cache.values()]
    assert 1 <= len(sizes) and sum(sizes) <= 2 * 1024 * 1024


def test_nerfstudio_and_hci_exports_carry_the_maps(calibrated, tmp_path):
    ds = calibrated
    est = estimate_export(ds, ExportOptions("nerfstudio", tmp_path / "n", views="r1,c1-3", depth=True))
    plain = estimate_export(ds, ExportOptions("nerfstudio", tmp_path / "n", views="r1,c1-3"))
    assert est.bytes_estimate > plain.bytes_estimate + 3 * 640 * 426 * 4
    assert any("no depth map yet" in w for w in est.warnings)
    export_dataset(ds, ExportOptions("nerfstudio", tmp_path / "n", views="r1,c1-3", depth=True, points=False))
    doc = json.loads((tmp_path / "n" / "transforms.json").read_text())
    frame = next(f for f in doc["frames"] if f["lfstudio_view"] == [1, 2])
    mm = cv2.imread(str(tmp_path / "n" / frame["depth_file_path"]), cv2.IMREAD_UNCHANGED)
    assert mm.dtype == np.uint16 and mm.shape == (426, 640)
    metres = read_depth_tiff(tmp_path / "n" / "depth" / "r01_c002.tif")
    np.testing.assert_allclose(mm[mm > 0] / 1000.0, metres[mm > 0], atol=0.0006)
    # raw views exported: the captured camera's frame; its z differs from the rig's z by the rays' tilt
    t = load_ground_truth(ds.root)
    u, v = np.meshgrid(np.arange(640.0), np.arange(426.0))
    tilt = (np.stack([u, v, np.ones_like(u)], -1) @ (t["R"].T @ np.linalg.inv(t["K_true"])).T)[..., 2]
    truth = read_truth_map(ds.root, "depth", 1, 2)
    rel = _inner(np.abs(metres * tilt - truth) / truth)
    known = np.isfinite(rel)                # the rectified map does not reach the captured view's every corner
    # (the light-field method of issue 37: 75 % within 2 % here, the row-and-column sweep before it 80 %)
    assert known.mean() > 0.9 and np.median(rel[known]) < 0.01 and (rel[known] < 0.02).mean() > 0.7, \
        (known.mean(), np.median(rel[known]), (rel[known] < 0.02).mean())
    export_dataset(ds, ExportOptions("hci", tmp_path / "h", views="r1,c1-3", depth=True))
    names = sorted(p.name for p in (tmp_path / "h").glob("estimated_disp_*.pfm"))
    assert names == [f"estimated_disp_{k}Cam00{i}.pfm" for k in ("", "confidence_") for i in range(3)]
    assert read_pfm(tmp_path / "h" / "estimated_disp_Cam001.pfm").shape == (426, 640)


def test_depth_is_refused_for_formats_without_maps(calibrated, tmp_path):
    from lfstudio.errors import InputError

    with pytest.raises(InputError, match="depth"):
        estimate_export(calibrated, ExportOptions("png", tmp_path / "p", depth=True))


def test_cli_depth_command(calibrated, run_cli):
    proc = run_cli("depth", calibrated.root, "--views", "r01_c002", "--workers", "0", "--steps", "2,1")
    assert proc.returncode == 0, proc.stderr
    assert "1 view computed" in proc.stdout
    rec = json.loads(map_path(calibrated.root, "records", (1, 2)).read_text())
    assert rec["settings"]["steps_h"] == 2 and len(rec["neighbours"]) == 10       # row, column, diagonals
    proc = run_cli("depth", calibrated.root, "--views", "r01_c002", "--workers", "0", "--steps", "2,1")
    assert "0 views computed, 1 up to date" in proc.stdout
    # the help says what the confidence map is, and what it is not
    text = " ".join(run_cli("depth", "--help").stdout.split())
    assert "lowest cost 3 or more candidate disparities away" in text and "is no probability" in text


def test_views_run_on_an_executor_and_stop_on_cancel(calibrated):
    """The windowed path that the process pool and a Dask cluster take (a real thread pool here)."""
    import concurrent.futures as cf

    ds = calibrated
    with cf.ThreadPoolExecutor(2) as pool:
        report = estimate_depth(ds, "r1,c1-2", executor=pool, workers=2)
    assert report.computed == 2 and not report.failed and report.cpu_s > 0
    token = CancelToken()
    token.cancel()
    with cf.ThreadPoolExecutor(2) as pool, pytest.raises(Cancelled):
        estimate_depth(ds, "r0", executor=pool, workers=2, cancel=token)
    assert not any(map_path(ds.root, "records", (0, c)).is_file() for c in range(5))


def test_sheared_views_are_measured_from_their_zero_plane(tmp_path):
    """An archive-style capture (every view shifted so that 3 m has zero disparity, imported with its
    zero plane stated): the maps hold the views' signed disparities, and depth adds the plane back."""
    from lfstudio.depth.run import depth_from_disparity, zero_shear_px_per_mm
    from lfstudio.errors import InputError
    from lfstudio.sim.virtual_dataset import make_virtual_dataset
    from tests.export.test_sheared_import import GRID, _import, shear_views

    make_virtual_dataset(tmp_path / "v", **GRID)
    f_px, _ = shear_views(tmp_path / "v", tmp_path / "sheared", 3.0)
    ds = _import(tmp_path / "sheared", tmp_path / "ds", focal_length_px=f_px, zero_disparity_depth_m=3.0)
    shear = zero_shear_px_per_mm(ds, 640)
    assert shear == pytest.approx(f_px / 3000.0, rel=1e-6)
    report = estimate_depth(ds, "r02_c002")
    assert report.computed == 1
    disp, _, record = read_disparity(ds, (2, 2))
    assert record["d_range_px"][0] < 0 < record["d_range_px"][1]        # behind the plane: negative
    truth = read_truth_map(tmp_path / "v", "depth", 2, 2)               # the unrotated capture's depth
    depth = depth_from_disparity(disp, f_px, 4.0, shear)
    rel = _inner(np.abs(depth - truth) / truth)
    known = np.isfinite(rel)
    assert known.mean() > 0.9 and np.median(rel[known]) < 0.02, (known.mean(), np.median(rel[known]))
    with pytest.raises(InputError, match="sheared"):
        depth_from_disparity(disp, f_px, 4.0, None)


def test_without_a_plan_the_range_is_measured_on_views_that_have_an_image(tmp_path):
    """No scene plan: the disparity range comes from matching two views of the chosen row. A view of
    that row outside the chosen ones whose processed image is gone is passed over (it raised
    TypeError from a None path)."""
    from lfstudio.dataset import Dataset
    from lfstudio.dataset.profile import Profile
    from lfstudio.processing.pipeline import process_dataset
    from lfstudio.sim.virtual_dataset import make_virtual_dataset

    root = tmp_path / "ds"
    make_virtual_dataset(root, fmt="png", columns=8, rows=1, spacing_mm=(4.0, 6.0), width_px=320, seed=7)
    profile = Profile()
    profile.color.enabled = profile.deflicker.enabled = profile.rectify.enabled = False
    assert process_dataset(root, profile, workers=0).ok
    ds = Dataset.open(root)
    ds.manifest["plan"] = {k: v for k, v in ds.manifest["plan"].items() if k not in ("near_m", "far_m")}
    ds.save()
    ds = Dataset.open(root)
    gone = ds.processed_path(ds.view(0, 0))
    assert gone is not None
    gone.unlink()
    report = estimate_depth(ds, "r00_c006")
    assert report.source == "processed" and report.computed == 1 and not report.failed
    _, _, record = read_disparity(ds, (0, 6))
    assert record["d_range_px"][0] < record["d_range_px"][1]


def test_the_neighbours_offsets_are_measured_from_the_images_where_the_rig_missed_the_grid(calibrated_noisy):
    """The rig stands off its grid position by its repeatability (80 µm of a 4 mm spacing, 2 %): the
    neighbours' offsets measured from the images (SIFT matches, scale pinned to the grid) bring the
    maps closer to the truth: median relative depth error 0.49 / 0.47 % (with the grid's offsets
    0.52 / 0.78 %)."""
    ds = calibrated_noisy
    t = load_ground_truth(ds.root)
    miss = np.array([np.subtract(v["true_mm"], v["commanded_mm"]) for v in t["views"]])
    assert np.sqrt((miss ** 2).mean()) > 0.03                # the views really stand off the grid (mm)
    for view in ((1, 1), (1, 2)):
        estimate_depth(ds, [view])
        disp, _, record = read_disparity(ds, view)
        truth = read_truth_map(ds.root, "disparity_rectified", *view)
        rel = float(np.median(_inner(np.abs(truth / disp - 1))))
        got = record["offsets_measured"]
        assert got["measured"] == got["of"] == len(record["neighbours"]), got
        assert rel < 0.006, (view, rel, got)
