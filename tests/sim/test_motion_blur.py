"""The motion-blur estimator (#40, lfstudio.sim.motion_blur) measures what it claims: on pictures of the
virtual studio blurred by a known camera travel (a dense box of standing renders, through the simulated
sensor's noise and a real DNG file), it finds that travel, and a sharp picture comes out sharp."""

from __future__ import annotations

import numpy as np
import pytest

from lfstudio.sim.dng import DEFAULT_NEUTRAL, mosaic_from_rgb, write_dng
from lfstudio.sim.motion_blur import box_weights, estimate_travel_mm, fit_travel, mosaic_of, path_renders, read_mosaic
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
    travel, sigma = fit_travel(observed, offsets, stack, white)
    measured = travel * px_per_mm
    assert measured == pytest.approx(blur_px, abs=0.12), measured
    assert measured == estimate_travel_mm(observed, offsets, stack, white) * px_per_mm
    if blur_px >= 0.5:                       # a textured picture tells its blur (near 0 it is quartic)
        assert sigma * px_per_mm < 0.1 and abs(measured - blur_px) < 4 * sigma * px_per_mm + 0.01


def test_a_picture_without_texture_across_the_motion_cannot_tell_its_blur(standing):
    """A plain picture fits every travel alike: its uncertainty is large (never a confident wrong figure)."""
    px_per_mm, offsets, stack = standing
    rng = np.random.default_rng(1)
    plain = 3000.0 + rng.normal(0.0, 20.0, stack.shape[1:])
    travel, sigma = fit_travel(plain, offsets, stack, 16383)
    assert sigma * px_per_mm > 0.3, (travel * px_per_mm, sigma * px_per_mm)


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


class _Carriage:
    """A carriage crossing the row at constant speed (monotonic time), as the GRBL simulator's history."""

    def __init__(self, speed_mm_s: float):
        import time

        self.t0, self.speed = time.monotonic(), speed_mm_s

    def true_position_at(self, t: float):
        return (CENTRE[0] + self.speed * (t - self.t0), CENTRE[1])

    def position_mm(self):
        import time

        return self.true_position_at(time.monotonic())


def test_frames_taken_while_moving_have_the_blur_their_truth_states(studio, tmp_path):
    """The simulated camera's moving frames, measured on their RAWs (noise off), have the blur their truth
    sidecars state (blur_px_near, 0.5 px): the sub-frames stand for the whole exposure. Before, 0.5 px
    was rendered as 2 sub-frames at ±0.125 px, a blur like a 0.43 px box (√(1 - 1/k²) of it). A frame
    alone varies by a few 0.01 px with where its sub-frames fall on the texture's pixels: 6 are averaged."""
    from lfstudio.sim.sim_camera import SimulatedCamera

    px_per_mm = float(studio.disparity_px(studio.near_m, 1.0))
    exposure_s, blur_px = 0.02, 0.5
    measured, stated = [], []
    for k in range(6):
        carriage = _Carriage(blur_px / px_per_mm / exposure_s)
        camera = SimulatedCamera(studio=studio, position_mm=carriage.position_mm, exposure_s=exposure_s,
                                 time_scale=1.0, noise=0.0, trigger_jitter_s=0.0, frame_rate_fps=5.0)
        camera.connect()
        try:
            camera.arm(1)
            camera.trigger()
            result = camera.fetch(tmp_path / f"moving{k}", timeout_s=30)
        finally:
            camera.disconnect()
        truth = result.metadata["ground_truth"]
        observed, _, white = read_mosaic(result.files[0])
        offsets, stack = path_renders(studio.render, truth["true_position_mm"], truth["blur_mm"], 3.0 / px_per_mm, 96)
        measured.append(estimate_travel_mm(observed, offsets, stack, white) * px_per_mm)
        stated.append(truth["blur_px_near"])
    assert stated == pytest.approx([blur_px] * 6, rel=0.02)
    assert 0.465 <= float(np.mean(measured)) <= 0.53, measured
    assert all(abs(m - blur_px) < 0.08 for m in measured), measured


def test_a_plain_flown_view_is_not_reported_as_a_confident_wrong_blur():
    """View r02 c093 of a 101 x 21 fly scan (regenerated exactly: the renderer's 10 sub-frames, the sensor's
    noise of its shot): the picture is plain across the motion, so its blur cannot be told. The noise
    weights once let a few dark sites (whose fitted variance fell to a floor 1000x below the median)
    decide it: 0.70 ± 0.01 px for a stated 0.499. Now a site weighs at most 10x the median."""
    from lfstudio.sim.studio import VirtualStudio

    studio = VirtualStudio(width_px=96, height_px=64, focal_length_mm=50.0, sensor_width_mm=96 * 4.53e-3,
                           near_m=1.77, far_m=4.77, rotation_deg=(1.0, -1.5, 0.7), pp_offset_px=(8.0, -5.0),
                           view_region_mm=(1800.0, 2200.0, 190.0, 310.0), seed=0, n_layers=4, n_objects=4,
                           texture_density=1.0, max_texture_px=40000000.0, highlight_gain=0.0)
    centre = np.array([2171.9419271242095, 201.96338663226481])
    blur_mm = np.array([0.08000000005820766, 0.0])
    p0, k = centre - blur_mm / 2, 10
    rgb = np.mean([studio.render(*(p0 + blur_mm * ((i + 0.5) / k))) for i in range(k)], axis=0).astype(np.float32)
    exposure = 0.001 * 1600 / 100 / (2.8 / 16) ** 2 / 0.5          # 1 ms at ISO 1600, f/2.8
    recorded, _ = SensorModel(noise=0.002, seed=0).apply(rgb * np.float32(exposure), 296)
    observed = mosaic_from_rgb(recorded, 512, 16383, DEFAULT_NEUTRAL).astype(np.float64)
    px_per_mm = float(studio.disparity_px(studio.near_m, 1.0))
    offsets, stack = path_renders(studio.render, centre.tolist(), blur_mm.tolist(), 3.0 / px_per_mm, 64)
    travel, sigma = fit_travel(observed, offsets, stack, 16383)
    stated = float(studio.disparity_px(studio.near_m, 0.08))
    assert abs(travel - 0.08) * px_per_mm <= 3 * sigma * px_per_mm, (travel * px_per_mm, sigma * px_per_mm, stated)
