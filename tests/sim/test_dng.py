"""The DNG writer: rawpy reads our files back bit-exact and demosaics them to the rendered image."""

from __future__ import annotations

import numpy as np
import pytest
import rawpy

from lfstudio.sim.dng import DEFAULT_NEUTRAL, mosaic_from_rgb, rgb_from_mosaic_nearest, write_dng
from lfstudio.sim.studio import VirtualStudio


def _develop_linear(path) -> np.ndarray:
    with rawpy.imread(str(path)) as raw:
        # adjust_maximum_thr=0: otherwise LibRaw takes the image's own maximum as white when it is
        # above 75 % of WhiteLevel, which brightens every well-exposed image
        out = raw.postprocess(adjust_maximum_thr=0.0, use_camera_wb=True, output_color=rawpy.ColorSpace.raw, gamma=(1, 1),
                              no_auto_bright=True, output_bps=16, user_flip=0)
    return out.astype(np.float32) / 65535.0


def test_rawpy_reads_mosaic_and_levels_bit_exact(tmp_path):
    rng = np.random.default_rng(1)
    mosaic = rng.integers(512, 16384, size=(64, 96), dtype=np.uint16)
    path = write_dng(tmp_path / "x.dng", mosaic, black_level=512, white_level=16383, exposure_s=0.25, iso=100)
    assert not list(tmp_path.glob(".*"))          # no temporary left behind
    with rawpy.imread(str(path)) as raw:
        assert np.array_equal(raw.raw_image, mosaic)
        assert raw.raw_pattern.tolist() == [[0, 1], [3, 2]]
        assert raw.color_desc == b"RGBG"
        assert list(raw.black_level_per_channel) == [512] * 4
        assert raw.white_level == 16383
        wb = raw.camera_whitebalance
        assert wb[0] == pytest.approx(1 / DEFAULT_NEUTRAL[0], rel=1e-3)
        assert wb[2] == pytest.approx(1 / DEFAULT_NEUTRAL[2], rel=1e-3)


def test_flat_colour_round_trips_through_camera_white_balance(tmp_path):
    colour = np.array([0.1, 0.25, 0.4], np.float32)
    rgb = np.broadcast_to(colour, (40, 60, 3)).copy()
    path = write_dng(tmp_path / "flat.dng", mosaic_from_rgb(rgb))
    out = _develop_linear(path)
    np.testing.assert_allclose(out[20, 30], colour, atol=2e-4)


def test_rendered_view_demosaics_back_to_render(tmp_path):
    studio = VirtualStudio(width_px=320, view_region_mm=(0, 8, 0, 6), seed=3)
    rgb = studio.render(4.0, 3.0)
    path = write_dng(tmp_path / "view.dng", mosaic_from_rgb(rgb))
    out = _develop_linear(path)
    assert out.shape == rgb.shape
    err = np.abs(out[4:-4, 4:-4] - np.clip(rgb, 0, 1)[4:-4, 4:-4])
    assert float(np.median(err)) < 0.003         # demosaicing errors only at fine detail
    assert float(err.mean()) < 0.015
    half = rgb_from_mosaic_nearest(mosaic_from_rgb(rgb))
    assert float(np.abs(half - rgb[::2, ::2]).mean()) < 0.05


def test_mosaic_clips_and_needs_even_size():
    rgb = np.full((4, 4, 3), 2.0, np.float32)
    assert mosaic_from_rgb(rgb, 512, 16383).max() == 16383
    assert mosaic_from_rgb(-rgb, 512, 16383).min() == 0
    with pytest.raises(ValueError, match="even"):
        mosaic_from_rgb(np.zeros((3, 4, 3), np.float32))


def test_real_camera_dng_rewritten_by_our_writer_develops_identically(shared_data, tmp_path):
    """The real DNG in ../shared/data: read it, write its mosaic with our writer, develop both."""
    src = shared_data / "raw" / "colorchart.dng"
    if not src.is_file():
        pytest.skip(f"{src} is absent")
    with rawpy.imread(str(src)) as raw:
        assert raw.raw_pattern.shape == (2, 2)
        sizes = raw.sizes
        mosaic = raw.raw_image_visible.copy()
        black, white = int(raw.black_level_per_channel[0]), int(raw.white_level)
        wb = raw.camera_whitebalance
        desc = raw.color_desc
    assert mosaic.dtype == np.uint16 and mosaic.max() <= white
    assert desc == b"RGBG"
    # crop to the visible area on an even origin so that the CFA phase stays RGGB-compatible
    assert sizes.top_margin % 2 == 0 and sizes.left_margin % 2 == 0
    h, w = (mosaic.shape[0] // 2) * 2, (mosaic.shape[1] // 2) * 2
    mosaic = mosaic[:h, :w]
    neutral = (1 / wb[0], 1 / wb[1], 1 / wb[2])      # rawpy gives the multipliers 1 / AsShotNeutral
    path = write_dng(tmp_path / "copy.dng", mosaic, black_level=black, white_level=white,
                     as_shot_neutral=neutral)
    with rawpy.imread(str(path)) as ours:
        assert np.array_equal(ours.raw_image, mosaic)
        assert ours.camera_whitebalance[2] == pytest.approx(wb[2], rel=1e-3)
    img = _develop_linear(path)
    assert img.shape[:2] == (h, w)
    assert 0.01 < float(img.mean()) < 0.9         # a real exposure, not black or clipped
    original = _develop_linear(src)[:h, :w]
    assert float(np.abs(original - img)[8:-8, 8:-8].mean()) < 0.002
