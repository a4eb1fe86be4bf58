"""Export core: view choice and order, PNG/HEVC/HCI outputs, HEVC round trip, atomic output."""

from __future__ import annotations

import configparser
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lfstudio.errors import InputError
from lfstudio.export import ExportOptions, estimate_export, export_dataset, import_hevc
from lfstudio.export import common, hci
from lfstudio.jobs import CancelToken, Cancelled

SMALL = dict(width_px=241)   # odd width: the HEVC export must pad (x265 needs even sizes)


@pytest.fixture
def small(make_tiny_dataset):
    """5 x 3 views, 241 x 160 px, 16-bit linear PNG."""
    return make_tiny_dataset("png", **SMALL)


def _read16(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None and img.dtype == np.uint16, path
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _source(ds, r, c) -> np.ndarray:
    return _read16(ds.path_of(ds.view(r, c)))


def _leftovers(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if common.PARTIAL_MARK in p.name]


# -- views and order ----------------------------------------------------------------------------------
def test_orders_and_subsets(small, tmp_path):
    est = estimate_export(small, ExportOptions("hevc", tmp_path / "a.mp4"))
    assert est.views[:6] == [(0, 0), (0, 1), (0, 2), (0, 3), (0, 4), (1, 4)]
    assert est.views[5:10] == [(1, 4), (1, 3), (1, 2), (1, 1), (1, 0)]
    assert est.views[10:] == [(2, c) for c in range(5)]
    assert est.image_size_px == (242, 160) and est.source == "raw"
    assert any("padded" in w for w in est.warnings)
    est = estimate_export(small, ExportOptions("png", tmp_path / "p", views="r1-2,c1-3"))
    assert est.views == [(r, c) for r in (1, 2) for c in (1, 2, 3)]
    assert est.image_size_px == (241, 160) and est.bytes_estimate > 0
    est = estimate_export(small, ExportOptions("hevc", tmp_path / "a.mkv", views="r1-2,c1-3"))
    assert est.views == [(1, 1), (1, 2), (1, 3), (2, 3), (2, 2), (2, 1)]   # the first chosen row runs left→right
    est = estimate_export(small, ExportOptions("hci", tmp_path / "h", hci_size=(3, 3)))
    assert est.views == [(r, c) for r in range(3) for c in range(1, 4)]
    with pytest.raises(InputError) as exc:
        estimate_export(small, ExportOptions("png", tmp_path / "p", views="r0-7"))
    assert exc.value.field == "views"
    with pytest.raises(InputError) as exc:
        estimate_export(small, ExportOptions("hci", tmp_path / "h", hci_size=(3, 3), hci_center=(0, 2)))
    assert exc.value.field == "hci_center"
    with pytest.raises(InputError) as exc:
        estimate_export(small, ExportOptions("hevc", tmp_path / "a.avi"))
    assert exc.value.field == "out"
    with pytest.raises(InputError) as exc:
        estimate_export(small, ExportOptions("png", tmp_path / "p", source="processed"))
    assert exc.value.field == "source" and "lfstudio process" in str(exc.value)


@settings(max_examples=40, deadline=None)
@given(st.sets(st.tuples(st.integers(0, 6), st.integers(0, 9)), min_size=1, max_size=40))
def test_meander_visits_each_view_once_snaking(views):
    order = common.meander(views)
    assert sorted(order) == sorted(views)
    rows = sorted({r for r, _ in views})
    for k, r in enumerate(rows):
        cols = [c for rr, c in order if rr == r]
        assert cols == sorted(cols, reverse=bool(k % 2))
    # rows come one after the other
    assert [r for r, _ in order] == sorted(r for r, _ in order)


def test_hci_names_widen_past_1000_views():
    assert hci.cam_name(7, 81) == "input_Cam007.png"
    assert hci.cam_name(999, 1000) == "input_Cam999.png"
    assert hci.cam_name(7, 1001) == "input_Cam0007.png"
    assert hci.cam_name(2120, 2121) == "input_Cam2120.png"


# -- png ----------------------------------------------------------------------------------------------
def test_png_export_manifest_and_pixels(small, tmp_path):
    out = tmp_path / "out" / "png"
    seen = []
    report = export_dataset(small, ExportOptions("png", out, views="r0-1,c0-1"),
                            progress=lambda d, t, m="": seen.append((d, t)))
    assert seen[-1] == (4, 4)
    assert report.views == 4 and report.bytes_written > 0 and out.is_dir()
    umask = os.umask(0)
    os.umask(umask)
    assert out.stat().st_mode & 0o777 == 0o777 & ~umask   # not the temporary folder's private 0700
    doc = json.loads((out / "manifest.json").read_text())
    assert doc["grid"]["columns"] == 5 and doc["grid"]["spacing_mm"] == [4.0, 6.0]
    assert [(v["row"], v["column"]) for v in doc["views"]] == [(0, 0), (0, 1), (1, 0), (1, 1)]
    v = doc["views"][3]
    assert v["file"] == "r01_c001.png" and v["commanded_mm"] == small.view(1, 1)["commanded_mm"]
    assert doc["intrinsics"]["image_size_px"] == [241, 160]
    assert doc["intrinsics"]["focal_length_px"] == pytest.approx(small.focal_length_px(241))
    for e in doc["views"]:
        assert np.array_equal(_read16(out / e["file"]), _source(small, e["row"], e["column"]))
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "r00_c000.png", "r00_c001.png",
                                                     "r01_c000.png", "r01_c001.png"]
    assert _leftovers(out.parent) == []


def test_png_export_imports_back_with_its_focal_length(small, tmp_path):
    from lfstudio.dataset import Dataset
    from lfstudio.export.import_images import ImportOptions, import_images

    out = tmp_path / "png"
    export_dataset(small, ExportOptions("png", out))
    ds = Dataset.open(import_images(ImportOptions(out, tmp_path / "again", (5, 3), (4.0, 6.0))))
    assert ds.manifest["import"]["intrinsics"] == "manifest.json of the lfstudio PNG export"
    assert ds.focal_length_px(241) == pytest.approx(small.focal_length_px(241))
    assert np.array_equal(_read16(ds.path_of(ds.view(2, 4))), _source(small, 2, 4))


def test_png_export_decodes_dng_like_processing(make_tiny_dataset, tmp_path):
    from lfstudio.dataset.profile import DebayerStep
    from lfstudio.dataset import images

    ds = make_tiny_dataset("dng", width_px=160)
    out = tmp_path / "png"
    export_dataset(ds, ExportOptions("png", out, views="r00_c000"))
    got = _read16(out / "r00_c000.png")
    want = images.develop(ds.path_of(ds.view(0, 0)), DebayerStep())
    assert got.shape == (want.shape[0], want.shape[1], 3) and np.array_equal(got, want)


# -- atomic output --------------------------------------------------------------------------------------
@pytest.mark.parametrize("fmt,name", [("png", "p"), ("hevc", "v.mp4"), ("hci", "h"), ("colmap", "c"),
                                      ("nerfstudio", "n")])
def test_cancel_leaves_nothing_behind(small, tmp_path, fmt, name):
    cancel = CancelToken()
    exports = tmp_path / "exports"
    exports.mkdir()
    out = exports / name

    def progress(done, total, message=""):
        if done >= 2:
            cancel.cancel()

    with pytest.raises(Cancelled):
        export_dataset(small, ExportOptions(fmt, out, hci_size=(3, 3)), progress=progress, cancel=cancel)
    assert list(exports.iterdir()) == []


def test_overwrite_refused_unless_allowed(small, tmp_path):
    out = tmp_path / "p"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(InputError) as exc:
        export_dataset(small, ExportOptions("png", out, views="r00_c000"))
    assert exc.value.field == "out" and "already exists" in str(exc.value)
    assert (out / "keep.txt").read_text() == "mine"
    with pytest.raises(InputError, match="replaces only an earlier export"):   # never deletes the operator's files
        export_dataset(small, ExportOptions("png", out, views="r00_c000", overwrite=True))
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]
    (out / "keep.txt").unlink()                      # an empty folder, then an earlier export: replaced
    export_dataset(small, ExportOptions("png", out, views="r00_c000", overwrite=True))
    export_dataset(small, ExportOptions("png", out, views="r00_c001", overwrite=True))
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "r00_c001.png"]
    (tmp_path / "was_a_file").write_text("x")       # overwrite replaces a file by a folder, and back
    export_dataset(small, ExportOptions("png", tmp_path / "was_a_file", views="r00_c000", overwrite=True))
    assert (tmp_path / "was_a_file" / "manifest.json").is_file()
    export_dataset(small, ExportOptions("hevc", tmp_path / "was_a_dir.mkv", views="r00_c000"))
    (tmp_path / "was_a_dir.mkv").unlink()
    (tmp_path / "was_a_dir.mkv").mkdir()
    export_dataset(small, ExportOptions("hevc", tmp_path / "was_a_dir.mkv", views="r00_c000", overwrite=True))
    assert (tmp_path / "was_a_dir.mkv").is_file()
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
    video = tmp_path / "v.mkv"
    (tmp_path / "v.mkv.json").write_text("{}")
    with pytest.raises(InputError) as exc:   # the sidecar counts too
        export_dataset(small, ExportOptions("hevc", video, views="r00_c000"))
    assert exc.value.field == "out" and not video.exists()
    assert _leftovers(tmp_path) == []


def test_out_over_the_dataset_or_video_is_refused_even_with_overwrite(small, tmp_path):
    before = sorted(p.name for p in small.root.iterdir())
    for out in (small.root, small.root.parent, small.root / "raw", small.root / "dataset.json"):
        with pytest.raises(InputError) as exc:
            export_dataset(small, ExportOptions("png", out, views="r00_c000", overwrite=True))
        assert exc.value.field == "out" and "dataset being exported" in str(exc.value), out
    with pytest.raises(InputError):
        estimate_export(small, ExportOptions("hci", small.root, hci_size=(1, 1)))
    assert sorted(p.name for p in small.root.iterdir()) == before
    export_dataset(small, ExportOptions("png", small.root / "exports" / "p", views="r00_c000"))  # beside: fine
    video = tmp_path / "v" / "lf.mkv"
    export_dataset(small, ExportOptions("hevc", video, views="r00_c000"))
    with pytest.raises(InputError) as exc:
        import_hevc(video, video.parent, overwrite=True)
    assert exc.value.field == "out" and video.is_file()


def test_an_empty_destination_takes_the_new_folder_in_one_rename_and_a_filled_one_is_kept(tmp_path):
    """partial_folder without overwrite: an empty folder is replaced by the finished one; if files were
    put into it meanwhile the system refuses the rename and they stay (nothing replaced, no leftovers)."""
    out = tmp_path / "empty"
    out.mkdir()
    with common.partial_folder(out, False) as tmp:
        (tmp / "view.png").write_text("new")
    assert [p.name for p in out.iterdir()] == ["view.png"]
    busy = tmp_path / "busy"
    busy.mkdir()
    with pytest.raises(InputError, match=r"busy is not empty \(files were put there meanwhile\)"):
        with common.partial_folder(busy, False) as tmp:
            (tmp / "view.png").write_text("new")
            (busy / "mine.txt").write_text("mine")
    assert [p.name for p in busy.iterdir()] == ["mine.txt"] and (busy / "mine.txt").read_text() == "mine"
    assert _leftovers(tmp_path) == []


def test_the_final_rename_never_replaces_a_folder_a_scan_started_in_meanwhile(tmp_path):
    """A scan (another process) that takes the folder's dataset.lock after the importer's first check is
    named at the final rename, with and without overwrite, and its folder stays as it was. A lock left by
    a process that is gone is no file of the folder (no "put there meanwhile"), and no obstacle to replacing."""
    from lfstudio.support.locks import LockBusy
    from tests.support.test_locks import hold_in_child

    for overwrite in (False, True):
        out = tmp_path / f"scan-{overwrite}"
        out.mkdir()
        (out / "dataset.json").write_text("theirs")
        child = None
        try:
            with pytest.raises(LockBusy) as refused:
                with common.partial_folder(out, overwrite) as tmp:
                    (tmp / "dataset.json").write_text("ours")
                    child = hold_in_child("dataset_lock", out)       # the scan starts there meanwhile
            text = str(refused.value)
            assert f"dataset {out} is in use by" in text and f"pid {child.pid}" in text and "stop that scan" in text
            assert (out / "dataset.json").read_text() == "theirs"
        finally:
            if child is not None:
                child.kill()
                child.wait(10)
                child.stdin.close()
                child.stdout.close()
        assert '"pid"' in (out / "dataset.lock").read_text()        # its holder line, now stale
        if overwrite:
            with common.partial_folder(out, True) as tmp:
                (tmp / "dataset.json").write_text("ours")
            assert sorted(p.name for p in out.iterdir()) == ["dataset.json"]
            assert (out / "dataset.json").read_text() == "ours"
        else:
            (out / "dataset.json").unlink()                           # only the stale lock is left
            with common.partial_folder(out, False) as tmp:
                (tmp / "view.png").write_text("new")
            assert sorted(p.name for p in out.iterdir()) == ["view.png"]
    assert _leftovers(tmp_path) == []


# -- hevc -----------------------------------------------------------------------------------------------
def test_hevc_round_trip_12bit_meander(small, tmp_path):
    video = tmp_path / "lf.mp4"
    report = export_dataset(small, ExportOptions("hevc", video))
    assert report.psnr_db is not None and report.psnr_db >= 45.0
    assert report.compression_ratio_vs_png is not None and report.compression_ratio_vs_png > 2.0
    side = json.loads((tmp_path / "lf.mp4.json").read_text())
    assert side["frames"] == [list(v) for v in common.meander([(r, c) for r in range(3) for c in range(5)])]
    assert side["encoding"]["bit_depth"] == 12 and side["encoding"]["pix_fmt"] == "yuv444p12le"
    assert side["pad_px"] == [1, 0] and side["frame_size_px"] == [242, 160]

    back = import_hevc(video, tmp_path / "restored")
    from lfstudio.dataset import Dataset

    ds = Dataset.open(back)
    assert ds.grid.columns == 5 and ds.status_counts()["done"] == 15
    assert cv2.imread(str(ds.root / ds.view(2, 3)["thumb"])).shape[1] == 160   # the grid view's thumbnails
    sources = {(r, c): _source(small, r, c).astype(np.float64) for r in range(3) for c in range(5)}
    for (r, c), src in sources.items():
        v = ds.view(r, c)
        assert v["commanded_mm"] == small.view(r, c)["commanded_mm"]
        got = _read16(ds.path_of(v)).astype(np.float64)
        assert got.shape == src.shape
        mse = {k: float(np.mean((got - s) ** 2)) for k, s in sources.items()}
        assert 10 * np.log10(65535.0 ** 2 / mse[(r, c)]) >= 45.0
        assert min(mse, key=mse.get) == (r, c)     # the frame landed on its own view, not a neighbour
    with pytest.raises(InputError):
        import_hevc(video, back)                   # refuses to overwrite the restored dataset


def test_import_hevc_needs_its_sidecar(small, tmp_path):
    video = tmp_path / "one.mkv"
    export_dataset(small, ExportOptions("hevc", video, views="r0,c0-1", bit_depth=10))
    (tmp_path / "one.mkv.json").rename(tmp_path / "elsewhere.json")
    with pytest.raises(InputError) as exc:
        import_hevc(video, tmp_path / "ds")
    assert exc.value.field == "file" and "one.mkv.json" in str(exc.value)
    assert not (tmp_path / "ds").exists() and _leftovers(tmp_path) == []
    doc = json.loads((tmp_path / "elsewhere.json").read_text())
    doc["frames"][1] = ["one", 0]
    (tmp_path / "one.mkv.json").write_text(json.dumps(doc))
    from lfstudio.errors import DatasetError
    with pytest.raises(DatasetError, match="damaged"):
        import_hevc(video, tmp_path / "ds")
    assert not (tmp_path / "ds").exists() and _leftovers(tmp_path) == []


# -- hci ------------------------------------------------------------------------------------------------
def read_hci(folder: Path) -> tuple[dict, np.ndarray]:
    """A small reader following the HCI toolkit (lightfield-analysis/python-tools file_io)."""
    cfg = configparser.ConfigParser()
    cfg.read(folder / "parameters.cfg")
    p = {"width": cfg.getint("intrinsics", "image_resolution_x_px"),
         "height": cfg.getint("intrinsics", "image_resolution_y_px"),
         "focal_length_mm": cfg.getfloat("intrinsics", "focal_length_mm"),
         "sensor_size_mm": cfg.getfloat("intrinsics", "sensor_size_mm"),
         "fstop": cfg.getfloat("intrinsics", "fstop"),
         "num_cams_x": cfg.getint("extrinsics", "num_cams_x"), "num_cams_y": cfg.getint("extrinsics", "num_cams_y"),
         "baseline_mm": cfg.getfloat("extrinsics", "baseline_mm"),
         "focus_distance_m": cfg.getfloat("extrinsics", "focus_distance_m"),
         "disp_min": cfg.getfloat("meta", "disp_min"), "disp_max": cfg.getfloat("meta", "disp_max")}
    for key in ("center_cam_x_m", "center_cam_y_m", "center_cam_z_m", "center_cam_rx_rad", "center_cam_ry_rad",
                "center_cam_rz_rad"):
        p[key] = cfg.getfloat("extrinsics", key)
    for key in ("frustum_disp_min", "frustum_disp_max", "depth_map_scale"):
        p[key] = cfg.getfloat("meta", key)
    for key in ("scene", "category", "date", "version", "authors", "contact"):
        p[key] = cfg.get("meta", key)
    lf = np.zeros((p["num_cams_y"], p["num_cams_x"], p["height"], p["width"], 3), np.uint8)
    names = sorted(f for f in os.listdir(folder) if f.startswith("input_") and f.endswith(".png"))
    assert len(names) == p["num_cams_x"] * p["num_cams_y"]
    for idx, name in enumerate(names):
        img = cv2.imread(str(folder / name), cv2.IMREAD_UNCHANGED)
        lf[idx // p["num_cams_x"], idx % p["num_cams_x"]] = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return p, lf


def test_hci_export_readable_by_toolkit_reader(small, tmp_path):
    out = tmp_path / "hci"
    export_dataset(small, ExportOptions("hci", out, hci_size=(3, 2), hci_center=(1, 3)))
    p, lf = read_hci(out)
    assert (p["num_cams_x"], p["num_cams_y"], p["width"], p["height"]) == (3, 2, 241, 160)
    assert p["baseline_mm"] == 4.0 and p["focal_length_mm"] == 50.0 and p["sensor_size_mm"] == 35.9
    # the plan's near/far (1.77 / 4.77 m) as neighbour disparities in these 241 px images
    f_px = 50.0 / (35.9 / 241)
    assert p["disp_max"] == pytest.approx(f_px * 4.0 / 1770.0, abs=1e-3)
    assert p["disp_min"] == pytest.approx(f_px * 4.0 / 4770.0, abs=1e-3)
    assert p["center_cam_x_m"] == pytest.approx(small.view(1, 3)["commanded_mm"][0] / 1000)
    for i, r in enumerate((1, 2)):   # even count: the centre is the upper of the middle two
        for j, c in enumerate((2, 3, 4)):
            assert np.array_equal(lf[i, j], hci.to_srgb8(_source(small, r, c)))


# -- processed source -------------------------------------------------------------------------------------
def test_processed_views_are_copied_and_auto_falls_back_to_raw(small, tmp_path):
    from lfstudio.dataset import Dataset
    from lfstudio.processing.pipeline import process_dataset
    from lfstudio.dataset.profile import Profile

    profile = Profile()
    profile.rectify.enabled = False
    profile.deflicker.enabled = False
    assert process_dataset(small.root, profile, workers=0).ok
    ds = Dataset.open(small.root)
    out = tmp_path / "exports" / "png"
    est = estimate_export(ds, ExportOptions("png", out, views="r0,c0-1"))
    assert est.source == "processed" and not any("without processing" in w for w in est.warnings)
    report = export_dataset(ds, ExportOptions("png", out, views="r0,c0-1"))
    assert report.source == "processed"
    for c in (0, 1):
        src = ds.root / ds.view(0, c)["processed"]["file"]
        assert (out / f"r00_c00{c}.png").read_bytes() == src.read_bytes()
    assert json.loads((out / "manifest.json").read_text())["source"] == "processed"
    video = tmp_path / "exports" / "proc.mkv"
    report = export_dataset(ds, ExportOptions("hevc", video, views="r0,c0-1"))
    assert report.source == "processed" and report.psnr_db >= 45.0
    assert report.details["png_bytes"] == sum((ds.root / ds.view(0, c)["processed"]["file"]).stat().st_size
                                              for c in (0, 1))   # the ratio is against the real PNGs
    back = Dataset.open(import_hevc(video, tmp_path / "restored"))
    v = back.view(0, 1)
    assert v["file"] == "processed/r00_c001.png" and v["processed"]["status"] == "done"
    assert back.manifest["processing"]["restored_from_hevc"] is True
    assert back.view(1, 1)["status"] == "skipped" and back.status_counts()["done"] == 2
    (ds.root / ds.view(0, 1)["processed"]["file"]).unlink()
    est = estimate_export(ds, ExportOptions("hevc", tmp_path / "v.mp4", views="r0,c0-1"))
    assert est.source == "raw" and any("without processing" in w for w in est.warnings)


def test_calibration_travels_with_the_export(small, tmp_path):
    from lfstudio.dataset.atomic import atomic_write_json

    doc = {"created": "2026-11-22T00:00:00+00:00", "rotation_deg": [1.0, -1.5, 0.7], "image_size_px": [482, 320],
           "principal_point_px": [250.5, 150.5], "principal_point_estimated": True, "focal_length_px": 671.3,
           "homography": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "residual_px": {"after": {"rms": 0.4}}}
    atomic_write_json(small.root / "calibration.json", doc)
    out = tmp_path / "exports" / "png"
    export_dataset(small, ExportOptions("png", out, views="r00_c000"))
    m = json.loads((out / "manifest.json").read_text())
    assert m["calibration"] == doc
    # half the calibration's size: x_s = 0.5 (x + 0.5) - 0.5
    assert m["intrinsics"]["principal_point_px"] == pytest.approx([125.0, 75.0])
    assert m["intrinsics"]["focal_length_px"] == pytest.approx(671.3 / 2)
    assert m["intrinsics"]["principal_point_from"] == "calibration (estimated)"
    export_dataset(small, ExportOptions("hci", tmp_path / "exports" / "hci", hci_size=(3, 3)))
    p, _ = read_hci(tmp_path / "exports" / "hci")
    assert (p["center_cam_rx_rad"], p["center_cam_ry_rad"]) == pytest.approx((0.0174533, -0.0261799), abs=1e-6)


def test_leftovers_of_a_killed_export_are_removed_by_the_next(small, tmp_path):
    import subprocess
    import sys

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(dead.stdout)      # that process has exited: its pid is free (unless reused, then kept)
    exports = tmp_path / "exports"
    stale = exports / f".p.partial-{dead_pid}-abcd"
    stale.mkdir(parents=True)
    (stale / "r00_c000.png").write_bytes(b"half")
    stale_video = exports / f".v.mkv.partial-{dead_pid}-efgh"
    stale_video.write_bytes(b"half")
    running = exports / f".p.partial-{os.getppid()}-live"   # a running process's export is left alone
    running.mkdir()
    export_dataset(small, ExportOptions("png", exports / "p", views="r00_c000"))
    export_dataset(small, ExportOptions("hevc", exports / "v.mkv", views="r00_c000"))
    assert not stale.exists() and not stale_video.exists() and running.is_dir()


def test_tiny_odd_frames_are_padded_for_x265_and_cropped_back(tmp_path):
    from lfstudio.dataset import Dataset
    from lfstudio.export import hevc

    assert hevc.even_size((241, 160)) == ((242, 160), (1, 0))
    assert hevc.even_size((11, 9)) == ((16, 16), (5, 7))
    root = tmp_path / "tiny"
    (root / "raw").mkdir(parents=True)
    views = []
    for c in range(2):
        yy, xx = np.mgrid[0:9, 0:11]
        img = np.stack([xx * 5000 + 1000 * c, yy * 6000, (xx + yy) * 2500], axis=2).astype(np.uint16)
        cv2.imwrite(str(root / "raw" / f"r00_c00{c}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        views.append({"row": 0, "column": c, "commanded_mm": [4.0 * c, 0.0], "reported_mm": None,
                      "captured_at": None, "exposure_s": None, "file": f"raw/r00_c00{c}.png", "sha256": None,
                      "status": "done"})
    ds = Dataset.create(root, camera={"name": "tiny"}, lens={"name": "tiny"},
                        grid={"columns": 2, "rows": 1, "spacing_mm": [4.0, 4.0]}, views=views)
    video = tmp_path / "tiny.mkv"
    report = export_dataset(ds, ExportOptions("hevc", video))
    assert json.loads((tmp_path / "tiny.mkv.json").read_text())["pad_px"] == [5, 7]
    assert report.psnr_db >= 45.0
    back = Dataset.open(import_hevc(video, tmp_path / "back"))
    for c in range(2):
        got = _read16(back.path_of(back.view(0, c))).astype(float)
        src = _source(ds, 0, c).astype(float)
        assert got.shape == (9, 11, 3)
        assert 10 * np.log10(65535.0 ** 2 / np.mean((got - src) ** 2)) >= 45.0


# -- hci: the toolkit's zero-disparity convention ------------------------------------------------------------
def toolkit_depth2disp(depth_m, p):
    """The HCI toolkit's BaseScene.depth2disp (evaluation-toolkit, toolkit/scenes/base_scene.py)."""
    f = (p["baseline_mm"] / 1000.0) * p["focal_length_mm"] * max(p["width"], p["height"])
    return (f * p["focus_distance_m"] / depth_m - f) / p["focus_distance_m"] / p["sensor_size_mm"]


def toolkit_disp2depth(disp_px, p):
    """The HCI toolkit's BaseScene.disp2depth."""
    q = p["baseline_mm"] * p["focal_length_mm"] * max(p["width"], p["height"])
    return 1.0 / ((1000.0 * p["sensor_size_mm"]) * disp_px / q + (1.0 / p["focus_distance_m"]))


def _check_toolkit_round_trip(p, near_m, far_m, tolerance=0.02):
    for depth, disp in ((near_m, p["disp_max"]), (far_m, p["disp_min"])):
        assert toolkit_depth2disp(depth, p) == pytest.approx(disp, rel=tolerance), (depth, disp)
        assert toolkit_disp2depth(disp, p) == pytest.approx(depth, rel=tolerance), (depth, disp)
        # float32 depth maps (the benchmark's .pfm) convert as well: no overflow, no 1/0, no nan
        d32 = toolkit_depth2disp(np.full((2, 2), depth, np.float32), p)
        assert np.isfinite(d32).all() and d32[0, 0] == pytest.approx(disp, rel=tolerance)


def test_hci_zero_disparity_at_infinity_round_trips_with_the_toolkit(make_tiny_dataset, tmp_path):
    ds = make_tiny_dataset("png")                              # rendered 1.77 ... 4.77 m, plan stored
    truth = json.loads((ds.root / "ground_truth.json").read_text())
    out = tmp_path / "hci"
    report = export_dataset(ds, ExportOptions("hci", out, hci_size=(5, 3)))
    p, _ = read_hci(out)
    _check_toolkit_round_trip(p, truth["near_m"], truth["far_m"])
    # the true neighbour disparity of the nearest plane, f·b/Z in these 640 px views
    assert p["disp_max"] == pytest.approx(truth["focal_length_px"] * 0.004 / truth["near_m"], abs=1e-4)
    # what the export used to write (the lens focus as focus_distance_m) fails the same check
    cfg = configparser.ConfigParser()
    cfg.read(out / "parameters.cfg")
    lens_focus = cfg.getfloat("meta", "lens_focus_distance_m")
    assert 1.77 < lens_focus < 4.77
    with pytest.raises(AssertionError):
        _check_toolkit_round_trip({**p, "focus_distance_m": lens_focus}, truth["near_m"], truth["far_m"])
    assert cfg.get("meta", "disp_range_from") == "plan" and p["authors"] == ""
    assert not any("disp_min" in w for w in report.warnings)


def test_hci_without_a_plan_measures_its_disparities(make_tiny_dataset, tmp_path):
    from lfstudio.dataset import Dataset

    ds = make_tiny_dataset("png")
    truth = json.loads((ds.root / "ground_truth.json").read_text())
    ds.manifest["plan"] = {}                                    # a CLI scan stores no plan
    ds.manifest["authors"] = "Studio A"
    ds.save()
    ds = Dataset.open(ds.root)
    est = estimate_export(ds, ExportOptions("hci", tmp_path / "h", hci_size=(5, 3)))
    assert any("no scene plan" in w and "measured" in w for w in est.warnings)
    report = export_dataset(ds, ExportOptions("hci", tmp_path / "h", hci_size=(5, 3)))
    assert any(w.startswith("disp_min/disp_max measured from the views") for w in report.warnings)
    p, _ = read_hci(tmp_path / "h")
    assert p["authors"] == "Studio A"
    # the nearest and farthest scene planes' neighbour disparity, measured within 5 %
    f_b = truth["focal_length_px"] * 0.004
    assert p["disp_max"] == pytest.approx(f_b / truth["near_m"], rel=0.05)
    assert p["disp_min"] == pytest.approx(f_b / truth["far_m"], rel=0.05)
    _check_toolkit_round_trip(p, f_b / p["disp_max"], f_b / p["disp_min"])
    export_dataset(ds, ExportOptions("hci", tmp_path / "one", hci_size=(1, 1), authors="Jane Doe"))
    p, _ = read_hci(tmp_path / "one")
    assert (p["disp_min"], p["disp_max"], p["authors"]) == (0.0, 0.0, "Jane Doe")   # nothing to measure from


def test_hci_measures_only_matches_that_move_the_way_the_rig_steps(make_tiny_dataset):
    """The outer views of the centre row are matched as a horizontal pair ("h": the right view's
    points move left). With the two views swapped every match moves right, against the rig's step:
    the geometric check keeps none and nothing is measured (a vertical check would keep them all
    and report negative disparities)."""
    ds = make_tiny_dataset("png")
    views = [(r, c) for r in range(3) for c in range(5)]
    size = (640, 427)
    assert hci.measured_disparity_range(ds, views, "raw", size).d_min_px > 0
    left, right = ds.path_of(ds.view(1, 0)), ds.path_of(ds.view(1, 4))
    swap = left.with_name("swap.png")
    left.rename(swap)
    right.rename(left)
    swap.rename(right)
    assert hci.measured_disparity_range(ds, views, "raw", size) is None


def test_feature_matching_refuses_an_unknown_direction():
    from lfstudio.calibration.features import epipole_ransac

    xy = np.array([[10.0, 10.0], [50.0, 20.0], [30.0, 40.0]])
    for direction in ("horizontal", "vertical", "x"):
        with pytest.raises(ValueError, match="'h' or 'v'"):
            epipole_ransac(xy, xy - [2.0, 0.0], direction, 1.0)


def test_the_calibration_comes_back_from_an_hevc_export_through_its_one_writer(small, tmp_path):
    """import-hevc restores calibration.json with calibration.model.save_calibration (validated, noted
    in the manifest); a sidecar whose calibration is unusable is refused, nothing written."""
    from lfstudio.calibration.model import load_calibration
    from lfstudio.dataset import Dataset
    from lfstudio.dataset.atomic import atomic_write_json
    from lfstudio.errors import DatasetError

    doc = {"created": "2026-11-22T00:00:00+00:00", "rotation_deg": [1.0, -1.5, 0.7], "image_size_px": [241, 160],
           "focal_length_px": 671.3, "homography": [[1, 0, 2], [0, 1, 0], [0, 0, 1]],
           "residual_px": {"after": {"rms": 0.4}}}
    atomic_write_json(small.root / "calibration.json", doc)
    video = tmp_path / "lf.mkv"
    export_dataset(small, ExportOptions("hevc", video, views="r0,c0-1", source="raw"))
    back = Dataset.open(import_hevc(video, tmp_path / "restored"))
    assert load_calibration(back) == doc
    assert back.manifest["calibration"]["residual_after_rms_px"] == 0.4
    side = json.loads((tmp_path / "lf.mkv.json").read_text())
    side["calibration"]["homography"] = [[1, 0], [0, 1]]
    (tmp_path / "lf.mkv.json").write_text(json.dumps(side))
    with pytest.raises(DatasetError, match=r"lf\.mkv\.json: calibration: cannot be used"):
        import_hevc(video, tmp_path / "again")
    assert not (tmp_path / "again").exists() and _leftovers(tmp_path) == []
