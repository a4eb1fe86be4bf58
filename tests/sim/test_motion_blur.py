"""The motion-blur estimator (#40, lfstudio.sim.motion_blur) measures what it claims: on pictures of the
virtual studio blurred by a known camera travel (a dense box of standing renders, through the simulated
sensor's noise and a real DNG file), it finds that travel, and a sharp picture comes out sharp."""

from __future__ import annotations

import numpy as np
import pytest

from lfstudio.sim.dng import DEFAULT_NEUTRAL, mosaic_from_rgb, write_dng
from lfstudio.sim.motion_blur import box_weights, estimate_travel_mm, mosaic_of, path_renders, read_mosaic
from lfstudio.sim.sensor import SensorModel
from lfstudio.sim.studio import demo_studio

WIDTH, HEIGHT = 96, 64
CENTRE = (150.0, 60.0)


@pytest.fixture(scope="module")
def studio():
    # the reference camera's 4.53 µm pixel on a 96 px crop, as benchmarks/fly_scan.py renders the views
    return demo_studio(width_px=WIDTH, height_px=HEIGHT, sensor_width_mm=WIDTH * 4.53e-3)


@pytest.fixture(scope="module")
def standing(studio):
    px_per_mm = float(studio.disparity_px(studio.near_m, 1.0))
    offsets, stack = path_renders(studio.render, CENTRE, (1.0, 0.0), 3.0 / px_per_mm, 64)
    return px_per_mm, offsets, stack


def _blurred_dng(studio, path, travel_mm, shot):
    """A picture exposed while the camera travelled ``travel_mm`` along x: 401 standing renders averaged
    (not the estimator's grid), the sensor's noise, a 14-bit DNG."""
    pos = np.linspace(-travel_mm / 2, travel_mm / 2, 401) if travel_mm > 0 else [0.0]
    rgb = np.mean([studio.render(CENTRE[0] + o, CENTRE[1]) for o in pos], axis=0) * 3.0
    recorded, _ = SensorModel(noise=0.002, seed=0).apply(rgb, shot)
    write_dng(path, mosaic_from_rgb(recorded, 512, 16383, DEFAULT_NEUTRAL), black_level=512, white_level=16383,
              as_shot_neutral=DEFAULT_NEUTRAL)
    return path


@pytest.mark.parametrize("blur_px", [0.0, 0.5, 1.0, 2.0])
def test_the_estimator_finds_a_known_blur(studio, standing, tmp_path, blur_px):
    px_per_mm, offsets, stack = standing
    path = _blurred_dng(studio, tmp_path / "v.dng", blur_px / px_per_mm, shot=3)
    observed, pattern, white = read_mosaic(path)
    assert pattern == "RGGB" and observed.shape == (HEIGHT, WIDTH)
    measured = estimate_travel_mm(observed, offsets, stack, white) * px_per_mm
    assert measured == pytest.approx(blur_px, abs=0.12), measured


def test_box_weights_are_a_centred_box(standing):
    _, offsets, _ = standing
    step = offsets[1] - offsets[0]
    w0 = box_weights(offsets, 0.0)
    assert w0.sum() == 1.0 and offsets[int(np.argmax(w0))] == 0.0
    w = box_weights(offsets, 10.5 * step)
    assert w.sum() == pytest.approx(1.0)
    assert np.allclose(w, w[::-1])                          # symmetric about the centre
    assert np.count_nonzero(w) == 11 and w.max() / w[w > 0].min() == pytest.approx(1 / 0.75)   # 9 whole, 2 ends
    # the box's second moment: T²/12 up to the cells' own width
    assert float(np.sum(w * offsets ** 2)) == pytest.approx((10.5 * step) ** 2 / 12, rel=0.02)


def test_mosaic_of_takes_each_sites_channel():
    rgb = np.zeros((4, 4, 3))
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 1.0, 2.0, 3.0
    m = mosaic_of(rgb, "RGGB")
    assert m[0, 0] == 1.0 and m[0, 1] == 2.0 and m[1, 0] == 2.0 and m[1, 1] == 3.0
