"""A plain 16-bit grey TIFF is an image, not a RAW: LibRaw opens an uncompressed one (either byte
order) as if it were a Bayer mosaic, and images.kind trusted that, so it was "developed" (demosaiced,
white-balanced) instead of read. What a file is now also comes from its own structure
(images.plain_tiff); DNGs (ours, tifffile-written, and the real one in ../shared/data) stay RAWs."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from lfstudio.dataset import images
from lfstudio.sim.dng import write_dng

@pytest.mark.parametrize("byteorder", ["<", ">"])
def test_a_plain_16_bit_grey_tiff_is_an_image_read_as_it_is(tmp_path, byteorder):
    grey = np.random.default_rng(2).integers(0, 65536, (48, 64), dtype=np.uint16)
    path = tmp_path / "scan.tif"
    tifffile.imwrite(path, grey, byteorder=byteorder)
    assert images.kind(path) == "image" and not images.is_raw(path)
    developed = images.develop(path)                 # the pixels as they are: grey in all three channels
    assert developed.dtype == np.uint16 and developed.shape == (48, 64, 3)
    assert all(np.array_equal(developed[..., c], grey) for c in range(3))
    assert images.full_size_px(path) == (64, 48)


def test_raws_stay_raws(tmp_path):
    rng = np.random.default_rng(3)
    write_dng(tmp_path / "v.dng", rng.integers(512, 16383, (24, 40), dtype=np.uint16))
    (tmp_path / "v.nef").write_bytes((tmp_path / "v.dng").read_bytes())     # a DNG under a maker's suffix
    assert images.kind(tmp_path / "v.dng") == "raw" and images.kind(tmp_path / "v.nef") == "raw"
    assert not images.plain_tiff(tmp_path / "v.dng")
    cv2.imwrite(str(tmp_path / "rgb.tif"), rng.integers(0, 65536, (24, 40, 3), dtype=np.uint16))
    assert images.kind(tmp_path / "rgb.tif") == "image"


def test_the_real_dng_stays_a_raw(shared_data: Path):
    dng = shared_data / "raw" / "colorchart.dng"
    if not dng.is_file():
        pytest.skip("colorchart.dng not present")
    assert images.kind(dng) == "raw" and not images.plain_tiff(dng)
