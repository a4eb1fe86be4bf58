"""dataset/images.py: what a file is comes from LibRaw/OpenCV reading it, never from its name; bit
depth is kept; sizes from headers match the decoded images; a RAW under any suffix goes through
import, processing and export; a file LibRaw cannot read is refused at import with its name."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest
import tifffile

from lfstudio.dataset import Dataset, images
from lfstudio.dataset.profile import DebayerStep, Profile
from lfstudio.errors import DatasetError, InputError
from lfstudio.sim.dng import write_dng


@pytest.fixture
def files(tmp_path):
    rng = np.random.default_rng(1)
    rgb16 = rng.integers(0, 65536, (24, 40, 3), dtype=np.uint16)
    out = {"rgb16": rgb16}
    cv2.imwrite(str(tmp_path / "a16.png"), rgb16[..., ::-1])
    cv2.imwrite(str(tmp_path / "a8.png"), (rgb16 >> 8).astype(np.uint8)[..., ::-1])
    cv2.imwrite(str(tmp_path / "a8.jpg"), (rgb16 >> 8).astype(np.uint8)[..., ::-1])
    tifffile.imwrite(tmp_path / "a16.tif", rgb16)
    write_dng(tmp_path / "v.dng", rng.integers(512, 16383, (24, 40), dtype=np.uint16))
    shutil.copy(tmp_path / "v.dng", tmp_path / "v_named.crw")     # a RAW LibRaw reads, under another suffix
    shutil.copy(tmp_path / "v.dng", tmp_path / "v_named.png")     # ... even under an image suffix
    (tmp_path / "junk.crw").write_bytes(rng.bytes(5000))                 # binary, but no format anyone reads
    (tmp_path / "notes.txt").write_text("shot list\n")
    out["dir"] = tmp_path
    return out


def test_what_a_file_is_comes_from_reading_it(files):
    d = files["dir"]
    assert [images.kind(d / n) for n in ("a16.png", "a8.png", "a8.jpg", "a16.tif")] == ["image"] * 4
    assert [images.kind(d / n) for n in ("v.dng", "v_named.crw", "v_named.png")] == ["raw"] * 3
    for name in ("junk.crw", "notes.txt", "missing.nef"):
        with pytest.raises(images.NotACapture, match=name):
            images.kind(d / name)
        assert not images.is_raw(d / name)
    assert images.is_text(d / "notes.txt") and not images.is_text(d / "a8.jpg") and not images.is_text(d / "v.dng")


def test_bit_depth_is_kept_and_header_sizes_match_the_pixels(files):
    d, rgb16 = files["dir"], files["rgb16"]
    assert np.array_equal(images.read_image(d / "a16.png"), rgb16)
    assert np.array_equal(images.read_image(d / "a16.tif"), rgb16)
    assert np.array_equal(images.read_image(d / "a8.png"), (rgb16 >> 8).astype(np.uint16) * 257)
    for name in ("a16.png", "a8.jpg", "a16.tif", "v.dng", "v_named.crw", "v_named.png"):
        img = images.develop(d / name)
        assert img.dtype == np.uint16 and images.full_size_px(d / name) == (img.shape[1], img.shape[0]) == (40, 24)
    assert images.png_header(d / "a16.png") == (40, 24, 16, 2) and images.png_header(d / "v_named.png") is None


def test_a_raw_under_any_name_develops_like_the_dng(files):
    d = files["dir"]
    step = DebayerStep(white_balance="camera")
    assert np.array_equal(images.develop(d / "v_named.crw", step), images.develop(d / "v.dng", step))
    assert images.read_bayer(d / "v_named.crw") is not None and images.read_bayer(d / "a16.png") is None
    grey, full, scale = images.read_grey(d / "v_named.crw", None)         # what the calibration detects on
    same, _, _ = images.read_grey(d / "v.dng", None)
    assert np.array_equal(grey, same) and grey.dtype == np.uint8 and full == (40, 24) and scale == 2.0


def _real_raw_folder(shared_data, tmp_path, suffix: str, n: int = 2):
    src = shared_data / "raw" / "colorchart.dng"
    if not src.is_file():
        pytest.skip("colorchart.dng not present")
    folder = tmp_path / "camera"
    folder.mkdir()
    for i in range(n):
        shutil.copy(src, folder / f"IMG_{i + 1:04d}{suffix}")
    return folder


@pytest.mark.slow
def test_a_real_raw_named_crw_imports_processes_and_exports(shared_data, tmp_path):
    """A real camera's DNG copied as .CRW/.NEF: LibRaw reads it, so import-images takes it (no
    suffix list), processing develops it and the PNG export writes it."""
    from lfstudio.export import ExportOptions, export_dataset
    from lfstudio.export.import_images import ImportOptions, import_images
    from lfstudio.processing.pipeline import process_dataset

    folder = _real_raw_folder(shared_data, tmp_path, ".CRW")
    shutil.copy(folder / "IMG_0002.CRW", folder / "IMG_0002.NEF")
    (folder / "IMG_0002.CRW").unlink()
    (folder / "IMG_0001.xmp").write_text("<x:xmpmeta/>")      # a sidecar is not a view
    root = import_images(ImportOptions(folder, tmp_path / "ds", (2, 1), (5.0, 5.0), focal_length_px=1500.0))
    ds = Dataset.open(root)
    assert [ds.path_of(v).suffix for v in ds.done_views()] == [".crw", ".nef"]
    w, h = images.full_size_px(folder / "IMG_0001.CRW")
    profile = Profile()
    profile.rectify.enabled = False
    report = process_dataset(root, profile, workers=0)
    assert report.ok and report.processed == 2
    out = cv2.imread(str(root / "processed" / "r00_c001.png"), cv2.IMREAD_UNCHANGED)
    assert out.dtype == np.uint16 and out.shape[1] == round(w * profile.resample.scale)
    export_dataset(Dataset.open(root), ExportOptions("png", tmp_path / "png", source="raw"))
    raw_png = cv2.imread(str(tmp_path / "png" / "r00_c000.png"), cv2.IMREAD_UNCHANGED)
    assert raw_png.shape == (h, w, 3) and raw_png.dtype == np.uint16 and 500 < raw_png.mean() < 60000


def test_a_file_libraw_cannot_read_is_refused_at_import_with_its_name(files, tmp_path):
    from lfstudio.export.import_images import ImportOptions, import_images

    folder = tmp_path / "camera"
    folder.mkdir()
    shutil.copy(files["dir"] / "v.dng", folder / "IMG_0001.CRW")
    shutil.copy(files["dir"] / "junk.crw", folder / "IMG_0002.CRW")
    with pytest.raises(InputError, match=r"IMG_0002\.CRW: cannot be read as an image \(neither LibRaw \(camera RAW\)"):
        import_images(ImportOptions(folder, tmp_path / "ds", (2, 1), (5.0, 5.0), focal_length_px=100.0))
    assert not (tmp_path / "ds").exists()


def test_a_raw_cut_short_is_refused_at_import_with_its_name(files, tmp_path):
    """LibRaw opens a RAW by its headers; one cut short after them fails only when its data is read:
    import-images unpacks every RAW before it writes anything."""
    from lfstudio.export.import_images import ImportOptions, import_images

    folder = tmp_path / "camera"
    folder.mkdir()
    whole = (files["dir"] / "v.dng").read_bytes()
    (folder / "IMG_0001.CRW").write_bytes(whole)
    (folder / "IMG_0002.CRW").write_bytes(whole[: len(whole) - 1500])
    assert images.kind(folder / "IMG_0002.CRW") == "raw"            # its headers still read
    with pytest.raises(DatasetError, match=r"IMG_0002\.CRW: LibRaw cannot read its image data"):
        images.check_raw_data(folder / "IMG_0002.CRW")
    images.check_raw_data(folder / "IMG_0001.CRW")
    with pytest.raises(InputError, match=r"IMG_0002\.CRW: cannot be read as an image \(damaged or truncated\)"):
        import_images(ImportOptions(folder, tmp_path / "ds", (2, 1), (5.0, 5.0), focal_length_px=100.0))
    assert not (tmp_path / "ds").exists()
