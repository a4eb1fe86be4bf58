"""import_images: another rig's folder of images → a dataset that calibrates like our own.

The "other rig" is the virtual studio: its rendered views are written under foreign names
(``shot1.png`` … ``shot12.png``, so natural sorting matters) in row-major or meander capture order,
imported, and compared by content with the render's own views (the ground truth).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lfstudio.calibration.calibrate import calibrate_dataset
from lfstudio.calibration.model import save_calibration
from lfstudio.calibration.model import rotation_angle_deg, rotation_matrix
from lfstudio.dataset import Dataset, images, view_stem
from lfstudio.dataset.store import sha256_file
from lfstudio.errors import InputError
from lfstudio.dataset.images import full_size_px as image_size_px
from lfstudio.export.import_images import (ImportOptions, count_message, find_images, grid_cells, import_images,
                                           natural_key)
from lfstudio.jobs import Cancelled, CancelToken
from lfstudio.processing.pipeline import process_dataset
from lfstudio.dataset.profile import Profile
from lfstudio.dataset.grid import grid_order
from lfstudio.sim.virtual_dataset import load_ground_truth, make_virtual_dataset

COLS, ROWS = 4, 3
ROT = (1.2, -2.0, 2.5)
SPACING = (100.0, 120.0)
WIDTH = 480
SENSOR_W_MM = 35.9


@pytest.fixture(scope="module")
def render(tmp_path_factory):
    """The virtual studio's own 4 x 3 dataset (16-bit PNG views) with ground truth."""
    return make_virtual_dataset(tmp_path_factory.mktemp("render") / "ds", COLS, ROWS, spacing_mm=SPACING,
                                width_px=WIDTH, rotation_deg=ROT, seed=2, fmt="png")


def truth_image(render, r, c) -> np.ndarray:
    return cv2.imread(str(render.path_of(render.view(r, c))), cv2.IMREAD_UNCHANGED)


def write_foreign(render, folder: Path, order: str, ext: str = ".png", eight_bit: bool = False) -> Path:
    """The render's views as another rig would leave them: shot1..shotN in capture order."""
    folder.mkdir(parents=True, exist_ok=True)
    cells = [(r, c) for r in range(ROWS) for c in range(COLS)] if order == "row-major" else grid_order(COLS, ROWS, "row-meander")
    for i, (r, c) in enumerate(cells):
        img = truth_image(render, r, c)
        if eight_bit:
            img = (img // 257).astype(np.uint8)
        assert cv2.imwrite(str(folder / f"shot{i + 1}{ext}"), img)
    (folder / "notes.txt").write_text("not an image")
    return folder


def options(folder, out, **kw) -> ImportOptions:
    kw.setdefault("focal_length_mm", 50.0)
    kw.setdefault("pixel_pitch_um", SENSOR_W_MM / WIDTH * 1000.0)
    return ImportOptions(folder=folder, out=out, grid=(COLS, ROWS), spacing_mm=SPACING, **kw)


@pytest.fixture(scope="module")
def imported_png(render, tmp_path_factory):
    base = tmp_path_factory.mktemp("png")
    folder = write_foreign(render, base / "foreign", "row-major")
    calls = []
    root = import_images(options(folder, base / "imported"), progress=lambda d, t, m: calls.append((d, t)))
    return Dataset.open(root), calls


# -- pure parts ----------------------------------------------------------------------------------------
def test_natural_sort_orders_numbers_by_value():
    names = ["img10.png", "img2.png", "IMG1.png", "img2b.png", "img_0003.png", "img1.png"]
    assert sorted(names, key=natural_key) == ["IMG1.png", "img1.png", "img2.png", "img2b.png", "img10.png",
                                              "img_0003.png"]


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 12), st.integers(1, 8), st.sampled_from(["row-major", "meander"]))
def test_grid_cells_visit_every_cell_once_with_adjacent_steps_in_meander(cols, rows, order):
    cells = grid_cells(cols, rows, order)
    assert sorted(cells) == [(r, c) for r in range(rows) for c in range(cols)]
    if order == "meander":
        assert all(abs(a[0] - b[0]) + abs(a[1] - b[1]) == 1 for a, b in zip(cells, cells[1:]))
        assert cells == grid_order(cols, rows, "row-meander")


# -- importing -----------------------------------------------------------------------------------------
def test_row_major_png_import_puts_every_view_in_its_grid_place(render, imported_png):
    ds, calls = imported_png
    assert [(v["row"], v["column"]) for v in ds.views] == [(r, c) for r in range(ROWS) for c in range(COLS)]
    for v in ds.views:
        r, c = v["row"], v["column"]
        assert v["status"] == "done" and v["file"] == ds.raw_name(r, c, ".png")
        assert v["commanded_mm"] == [c * SPACING[0], r * SPACING[1]]
        assert v["sha256"] == sha256_file(ds.path_of(v))
        got = cv2.imread(str(ds.path_of(v)), cv2.IMREAD_UNCHANGED)
        assert got.dtype == np.uint16 and np.array_equal(got, truth_image(render, r, c)), (r, c)
    assert ds.view(0, 1)["source_file"] == "shot2.png" and ds.view(2, 1)["source_file"] == "shot10.png"
    assert ds.grid.order == "raster" and ds.grid.spacing_mm == tuple(SPACING)
    assert ds.camera["sensor_px"] == [WIDTH, 320]
    assert ds.focal_length_px(WIDTH) == pytest.approx(50.0 / SENSOR_W_MM * WIDTH)
    assert not ds.verify_files()
    assert calls[-1][0] == calls[-1][1] and all(a[0] <= b[0] for a, b in zip(calls, calls[1:]))
    for v in ds.views:                                 # each view's thumbnail, made during the import
        thumb = cv2.imread(str(ds.root / v["thumb"]))
        want = images.thumbnail_array(ds.path_of(v), 160)
        assert v["thumb"] == f"thumbs/{view_stem(v['row'], v['column'])}.jpg" and thumb.shape == want.shape
        blocks = [cv2.resize(t, (16, 11), interpolation=cv2.INTER_AREA).astype(int) for t in (thumb, want)]
        assert np.abs(blocks[0] - blocks[1]).mean() < 3, v["thumb"]          # the same picture (JPEG q85)
    assert not [p for p in ds.root.parent.iterdir() if p.name.startswith(".")]   # no temporary left


def test_meander_jpeg_import_matches_the_render_by_content(render, tmp_path):
    folder = write_foreign(render, tmp_path / "jpeg", "meander", ".jpg", eight_bit=True)
    ds = Dataset.open(import_images(options(folder, tmp_path / "ds", order="meander")))
    assert ds.grid.order == "row-meander"
    truths = {(r, c): truth_image(render, r, c).astype(np.float32) / 257.0 for r in range(ROWS) for c in range(COLS)}
    for v in ds.views:
        got = cv2.imread(str(ds.path_of(v)), cv2.IMREAD_UNCHANGED).astype(np.float32)
        errors = {cell: float(np.mean(np.abs(got - t))) for cell, t in truths.items()}
        assert min(errors, key=errors.get) == (v["row"], v["column"])
        assert errors[(v["row"], v["column"])] < 3.0   # JPEG loss only
    assert ds.view(1, 3)["source_file"] == "shot5.jpg"   # the first view of the second (reversed) row


def test_imported_dataset_calibrates_close_to_the_truth_and_processes(render, imported_png):
    ds, _ = imported_png
    run = calibrate_dataset(ds, "array:3x2", max_width_px=None)
    assert len(run.views) == 6
    truth = load_ground_truth(render.root)
    err = rotation_angle_deg(rotation_matrix(run.document["rotation_deg"]), rotation_matrix(truth["rotation_deg"]))
    assert err < 0.1
    # and it processes like our own captures: decode (PNG), colour, de-flicker, rectify, resample
    save_calibration(ds, run.document)
    report = process_dataset(ds.root, Profile(), workers=0)
    assert report.processed == COLS * ROWS and not report.failed
    out = cv2.imread(str(ds.root / "processed" / "r01_c002.png"), cv2.IMREAD_UNCHANGED)
    assert out.dtype == np.uint16 and out.shape[1] == WIDTH // 2


def test_tiff_and_dng_are_read_and_focal_length_in_pixels_is_kept(tmp_path):
    import tifffile

    from lfstudio.sim.dng import write_dng

    tif, dng = tmp_path / "tif", tmp_path / "dng"
    tif.mkdir()
    dng.mkdir()
    rng = np.random.default_rng(0)
    for i in range(2):
        tifffile.imwrite(tif / f"v{i}.tif", rng.integers(0, 65535, (24, 40, 3), dtype=np.uint16))
        write_dng(dng / f"v{i}.dng", rng.integers(512, 16383, (24, 40), dtype=np.uint16))
    assert image_size_px(tif / "v0.tif") == (40, 24) and image_size_px(dng / "v1.dng") == (40, 24)
    for folder in (tif, dng):
        root = import_images(ImportOptions(folder, tmp_path / f"{folder.name}_ds", (2, 1), (5.0, 5.0),
                                           focal_length_px=1234.0))
        ds = Dataset.open(root)
        assert ds.focal_length_px(20) == pytest.approx(617.0)
        assert ds.view(0, 1)["file"] == f"raw/r00_c001{folder.suffix or '.' + folder.name}"
        assert ds.manifest["import"]["intrinsics"] == "--focal-length-px"
    # HCI export of a dataset that knows its focal length only in pixels: a nominal 36 mm sensor with
    # the matching focal length, so HCI's f_mm / sensor_mm · width is the real focal length in pixels
    import configparser

    from lfstudio.export import ExportOptions, export_dataset

    export_dataset(Dataset.open(tmp_path / "tif_ds"), ExportOptions("hci", tmp_path / "hci", hci_size=(2, 1)))
    cfg = configparser.ConfigParser()
    cfg.read(tmp_path / "hci" / "parameters.cfg")
    intr = cfg["intrinsics"]
    assert intr.getfloat("sensor_size_mm") == 36.0
    assert intr.getfloat("focal_length_mm") / 36.0 * intr.getint("image_resolution_x_px") == pytest.approx(1234.0, rel=1e-5)


def test_without_intrinsics_the_import_warns_that_calibration_needs_them(render, tmp_path):
    folder = write_foreign(render, tmp_path / "f", "row-major")
    ds = Dataset.open(import_images(ImportOptions(folder, tmp_path / "ds", (COLS, ROWS), SPACING)))
    assert ds.manifest["import"]["intrinsics"] == "none"
    assert "calibration will need" in ds.manifest["import"]["warnings"][0]
    with pytest.raises(Exception, match="focal length"):
        ds.focal_length_px(WIDTH)


# -- clear errors ----------------------------------------------------------------------------------------
def test_count_mismatch_says_the_numbers_and_the_pattern(render, tmp_path):
    folder = write_foreign(render, tmp_path / "f", "row-major")
    with pytest.raises(InputError, match=r"found 12 images .* but a 5x3 grid needs 15") as exc:
        import_images(ImportOptions(folder, tmp_path / "a", (5, 3), SPACING))
    assert exc.value.field == "--grid"
    with pytest.raises(InputError, match=r"found 4 images in .* matching 'shot1\*', but a 4x3 grid needs 12"):
        import_images(ImportOptions(folder, tmp_path / "b", (COLS, ROWS), SPACING, pattern="shot1*"))
    # a camera that wrote JPEG + RAW pairs: the message says which pattern takes one kind
    for p in list(folder.glob("*.png")):
        shutil.copy(p, p.with_suffix(".tif"))
    with pytest.raises(InputError, match=r"mixes 12 \.png, 12 \.tif.*--pattern '\*\.png'"):
        import_images(ImportOptions(folder, tmp_path / "c", (COLS, ROWS), SPACING))
    with pytest.raises(InputError, match="notes.txt, which is not"):
        import_images(ImportOptions(folder, tmp_path / "d", (COLS, ROWS), SPACING, pattern="*"))
    assert not [p for p in tmp_path.iterdir() if p.name in "abcd" or p.name.startswith(".")]


def test_pattern_matches_camera_upper_case_names(tmp_path):
    """Cameras write IMG_0001.JPG + IMG_0001.DNG; the mixed-kind hint says --pattern '*.dng', which
    must then take the .DNG files (it found none: glob is case-sensitive)."""
    for i in (1, 2, 10):
        (tmp_path / f"IMG_{i}.JPG").write_bytes(b"")
        (tmp_path / f"IMG_{i}.DNG").write_bytes(b"")
    assert [p.name for p in find_images(tmp_path, "*.dng")] == ["IMG_1.DNG", "IMG_2.DNG", "IMG_10.DNG"]
    assert [p.name for p in find_images(tmp_path, "img_1*.JPG")] == ["IMG_1.JPG", "IMG_10.JPG"]
    assert "--pattern '*.dng'" in count_message(find_images(tmp_path), (3, 1), tmp_path, None)


def test_mixed_sizes_and_unreadable_files_are_named(render, tmp_path):
    folder = write_foreign(render, tmp_path / "f", "row-major")
    cv2.imwrite(str(folder / "shot7.png"), np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(InputError, match=r"shot7.png is 10x10 px but shot1.png is 480x320 px"):
        import_images(options(folder, tmp_path / "ds"))
    (folder / "shot7.png").write_bytes(b"\x89PNG broken")
    with pytest.raises(InputError, match=r"shot7.png: cannot be read as an image"):
        import_images(options(folder, tmp_path / "ds"))
    assert not (tmp_path / "ds").exists()


def test_out_folder_follows_the_new_dataset_rule(render, tmp_path):
    """An empty folder takes the import; a dataset is replaced only with overwrite; a folder of other
    files is refused even with overwrite (it used to be deleted), naming it and a new sub-folder."""
    folder = write_foreign(render, tmp_path / "f", "row-major")
    out = tmp_path / "ds"
    out.mkdir()
    root = import_images(options(folder, out))                      # empty: no --overwrite needed
    assert root == out.absolute() and len(Dataset.open(out).views) == 12
    with pytest.raises(InputError, match="already holds a dataset.*--overwrite") as exc:
        import_images(options(folder, out))
    assert exc.value.field == "--out"
    (out / "raw" / "r00_c000.png").unlink()                         # the replacement is a whole new dataset
    assert import_images(options(folder, out, overwrite=True)) == out.absolute()
    assert (out / "raw" / "r00_c000.png").is_file() and Dataset.open(out).status_counts()["done"] == 12
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "keep.txt").write_text("earlier work")
    for overwrite in (False, True):
        with pytest.raises(InputError) as exc:
            import_images(options(folder, mine, overwrite=overwrite))
        assert exc.value.field == "--out" and f"{mine} is not empty (keep.txt)" in str(exc.value)
        assert f"a new sub-folder, e.g. {mine / 'lfstudio-import'}" in str(exc.value)
        assert sorted(p.name for p in mine.iterdir()) == ["keep.txt"]
        assert (mine / "keep.txt").read_text() == "earlier work"
    assert len(Dataset.open(import_images(options(folder, mine / "lfstudio-import"))).views) == 12
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "f", "mine"]
    with pytest.raises(InputError, match="holds the images"):
        import_images(options(folder, tmp_path, overwrite=True))


def test_files_put_into_the_empty_folder_during_the_import_are_kept(render, tmp_path):
    """The folder is checked again at the end: a file that arrived while the views were copied stays
    and the import is refused, nothing of it left behind."""
    folder = write_foreign(render, tmp_path / "f", "row-major")
    out = tmp_path / "ds"
    out.mkdir()

    def progress(done, total, message):
        if "copied" in message and not (out / "arrived.txt").exists():
            (out / "arrived.txt").write_text("mine")

    with pytest.raises(InputError, match=r"is not empty \(arrived.txt\)"):
        import_images(options(folder, out, link=False), progress=progress)
    assert sorted(p.name for p in out.iterdir()) == ["arrived.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "f"]      # no temporary folder left


def test_cancel_leaves_nothing_behind(render, tmp_path):
    folder = write_foreign(render, tmp_path / "f", "row-major")
    token = CancelToken()

    def progress(done, total, message):
        if "copied" in message or "linked" in message:
            token.cancel()   # after the first file is in the temporary dataset

    with pytest.raises(Cancelled):
        import_images(options(folder, tmp_path / "ds", link=False), progress=progress, cancel=token)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f"]


def test_copy_instead_of_link_gives_independent_files(render, tmp_path):
    folder = write_foreign(render, tmp_path / "f", "row-major")
    ds = Dataset.open(import_images(options(folder, tmp_path / "ds", link=False)))
    assert ds.manifest["import"]["linked"] == 0
    assert os.stat(ds.path_of(ds.view(0, 0))).st_ino != os.stat(folder / "shot1.png").st_ino
    linked = Dataset.open(import_images(options(folder, tmp_path / "ds2")))
    assert linked.manifest["import"]["linked"] == 12   # same file system: hard links
    assert find_images(folder)[:3] == [folder / "shot1.png", folder / "shot2.png", folder / "shot3.png"]


# -- command line ----------------------------------------------------------------------------------------
def test_cli_imports_and_bad_input_exits_2_with_one_line(render, tmp_path, run_cli):
    folder = write_foreign(render, tmp_path / "f", "meander")
    proc = run_cli("import-images", folder, "--grid", "4x3", "--spacing-mm", "100x120", "--order", "meander",
                   "--focal-length-px", "668.5", "--out", tmp_path / "ds")
    assert proc.returncode == 0, proc.stderr
    assert "12 views (4x3, meander)" in proc.stdout and "importing [" in proc.stderr
    manifest = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert manifest["lens"]["focal_length_px"] == 668.5
    bad = run_cli("import-images", folder, "--grid", "4x4", "--spacing-mm", "100x120", "--out", tmp_path / "x")
    assert bad.returncode == 2
    assert bad.stderr.strip().count("\n") == 0 and "grid needs 16" in bad.stderr
    bad = run_cli("import-images", folder, "--grid", "4by3", "--spacing-mm", "100x120", "--out", tmp_path / "x")
    assert bad.returncode == 2 and "--grid: cannot read '4by3'" in bad.stderr
    assert not (tmp_path / "x").exists()


# -- EXIF ------------------------------------------------------------------------------------------------
def _exif_app1(make: str, model: str, focal_mm: float, pitch_um: float, f35_mm: int) -> bytes:
    """A JPEG APP1 Exif segment: little-endian TIFF, IFD0 (Make, Model, ExifIFD) → Exif IFD."""
    import struct

    def ifd(entries, data_offset):
        head, data = struct.pack("<H", len(entries)), b""
        for tag, typ, count, val in sorted(entries):
            if len(val) <= 4:
                head += struct.pack("<HHI", tag, typ, count) + val.ljust(4, b"\0")
            else:
                head += struct.pack("<HHII", tag, typ, count, data_offset + len(data))
                data += val
        return head + struct.pack("<I", 0), data

    text = [(271, 2, len(make) + 1, make.encode() + b"\0"), (272, 2, len(model) + 1, model.encode() + b"\0")]
    ifd0_size = 2 + 12 * 3 + 4
    data0_len = sum(len(v) for *_, v in text if len(v) > 4)
    exif_at = 8 + ifd0_size + data0_len
    ifd0, data0 = ifd(text + [(34665, 4, 1, struct.pack("<I", exif_at))], 8 + ifd0_size)
    exif_entries = [(37386, 5, 1, struct.pack("<II", int(focal_mm * 1000), 1000)),
                    (41486, 5, 1, struct.pack("<II", int(1e6 / pitch_um), 1000)),     # pixels per mm
                    (41488, 3, 1, struct.pack("<H", 4)), (41989, 3, 1, struct.pack("<H", f35_mm))]
    exif, data1 = ifd(exif_entries, exif_at + 2 + 12 * len(exif_entries) + 4)
    payload = b"Exif\0\0II*\0" + struct.pack("<I", 8) + ifd0 + data0 + exif + data1
    return b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload


def test_intrinsics_come_from_exif_and_stale_pitch_is_not_trusted(tmp_path):
    for width, expected_px in ((4000, 50.0 / 0.0045), (48, 75.0 / 36.0 * 48)):
        folder = tmp_path / f"w{width}"
        folder.mkdir()
        ok, jpg = cv2.imencode(".jpg", np.zeros((16, width, 3), np.uint8))
        data = jpg.tobytes()
        for i in range(2):
            (folder / f"DSC{i:04d}.JPG").write_bytes(data[:2] + _exif_app1("Sony", "ILCE-7RM2", 50.0, 4.5, 75)
                                                     + data[2:])
        ds = Dataset.open(import_images(ImportOptions(folder, tmp_path / f"ds{width}", (2, 1), (4.0, 4.0))))
        assert ds.camera["name"] == "Sony ILCE-7RM2" and ds.camera["sensor_px"] == [width, 16]
        assert ds.focal_length_px(width) == pytest.approx(expected_px, rel=1e-3)
        assert "EXIF of DSC0000.JPG" in ds.manifest["import"]["intrinsics"]
        assert not ds.manifest["import"]["warnings"]
    # 4000 px wide at 4.5 µm = 18 mm: a plausible sensor, so FocalLength + FocalPlaneXResolution are used;
    # 48 px "at 4.5 µm" = 0.2 mm: the image was resized, so the 35 mm equivalent (75 mm) is used instead
