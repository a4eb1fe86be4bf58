"""Each processing step on synthetic input with a known answer."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lfstudio.errors import InputError
from lfstudio.dataset.profile import ColorStep, DebayerStep, DeflickerStep, LensStep, Profile, ShadingStep
from lfstudio.calibration.model import homography_at_scale, pixel_scale_matrix
from lfstudio.dataset import images
from lfstudio.processing.steps import color, debayer, deflicker, lens, rectify, resample, shading
from tests.processing.conftest import scene, write_bayer_dng


# -- profile -----------------------------------------------------------------------------------
def test_profile_toml_round_trip_and_stable_hash(tmp_path):
    p = Profile()
    p.lens.enabled = True
    p.lens.dist_coeffs = [-0.1, 0.02, 0.0, 0.0, 0.0]
    p.color.mode = "points"
    p.save(tmp_path / "p.toml")
    q = Profile.load(tmp_path / "p.toml")
    assert q == p and q.sha256() == p.sha256()
    q.lens.enabled = False
    assert q.sha256() != p.sha256()
    r = q.copy()
    r.lens.dist_coeffs = [0.3, 0, 0, 0, 0]  # a disabled step's parameters do not count
    assert r.sha256() == q.sha256()


@pytest.mark.parametrize("text, field", [
    ("[lens]\nsource = 'magic'\n", "[lens] source"),
    ("[resample]\nscale = 2.0\n", "[resample] scale"),
    ("[color]\nwhite_output = 'x'\n", "[color] white_output"),
    ("[debayer]\nhalfsize = true\n", "[debayer] halfsize"),
    ("[nonsense]\n", "[nonsense]"),
    ("[shading]\nenabled = true\n", "[shading] flat_file"),
])
def test_profile_errors_name_the_field(text, field):
    with pytest.raises(InputError) as err:
        Profile.from_toml(text, "p.toml")
    assert field in str(err.value)


# -- 1 debayer ---------------------------------------------------------------------------------
def test_debayer_is_linear_16bit(tmp_path):
    flat = np.full((32, 48, 3), 0.5, np.float32)
    flat[:, 24:] = 0.25
    write_bayer_dng(tmp_path / "a.dng", flat)
    img = images.develop(tmp_path / "a.dng", DebayerStep())
    assert img.dtype == np.uint16 and img.shape == (32, 48, 3)
    left, right = img[4:-4, 4:20].mean(), img[4:-4, 28:-4].mean()
    assert left == pytest.approx(0.5 * 65535, rel=0.01)
    assert right / left == pytest.approx(0.5, rel=0.01)  # linear: no gamma
    half = images.develop(tmp_path / "a.dng", DebayerStep(half_size=True))
    assert half.shape == (16, 24, 3)
    assert images.full_size_px(tmp_path / "a.dng") == (48, 32)
    assert debayer.processing_scale(tmp_path / "a.dng", DebayerStep(half_size=True)) == 0.5


def test_debayer_fixed_white_balance_scales_channels(tmp_path):
    write_bayer_dng(tmp_path / "g.dng", np.full((32, 48, 3), 0.25, np.float32))
    unit = images.develop(tmp_path / "g.dng", DebayerStep(white_balance="fixed", wb_multipliers=[1, 1, 1, 1],
                                                          color_space="raw"))
    red2 = images.develop(tmp_path / "g.dng", DebayerStep(white_balance="fixed", wb_multipliers=[2, 1, 1, 1],
                                                          color_space="raw"))
    ratio = red2.reshape(-1, 3).mean(axis=0) / unit.reshape(-1, 3).mean(axis=0)
    assert ratio == pytest.approx([2.0, 1.0, 1.0], rel=0.02)
    camera = images.develop(tmp_path / "g.dng", DebayerStep(white_balance="camera"))
    assert camera.reshape(-1, 3).mean(axis=0) == pytest.approx([0.25 * 65535] * 3, rel=0.02)  # neutral grey


def test_png_and_8bit_inputs_are_accepted(tmp_path):
    rgb8 = np.zeros((8, 10, 3), np.uint8)
    rgb8[..., 0] = 255
    cv2.imwrite(str(tmp_path / "a.png"), cv2.cvtColor(rgb8, cv2.COLOR_RGB2BGR))
    img = images.develop(tmp_path / "a.png", DebayerStep())
    assert img.dtype == np.uint16 and img[0, 0].tolist() == [65535, 0, 0]


def test_real_camera_dng(shared_data):
    path = shared_data / "raw" / "colorchart.dng"
    if not path.is_file():
        pytest.skip("colorchart.dng not present")
    img = images.develop(path, DebayerStep(half_size=True))
    w, h = images.full_size_px(path)
    assert img.shape == ((h + 1) // 2, (w + 1) // 2, 3) and img.dtype == np.uint16
    assert 500 < img.mean() < 60000


# -- 2 lens ------------------------------------------------------------------------------------
def test_opencv_lens_model_matches_projectpoints():
    model = lens.OpenCVLens(fx=400, fy=400, cx=50, cy=40, dist=(-0.2, 0.05, 0.001, -0.002, 0.01))
    pts = np.array([[10.0, 5.0], [90.0, 70.0], [50.0, 40.0], [0.0, 79.0]])
    xd, yd = model.distort(pts[:, 0], pts[:, 1])
    K = np.array([[400, 0, 50], [0, 400, 40], [0, 0, 1.0]])
    norm = np.c_[(pts - [50, 40]) / 400, np.ones(len(pts))]
    ref, _ = cv2.projectPoints(norm, np.zeros(3), np.zeros(3), K, np.array(model.dist))
    np.testing.assert_allclose(np.c_[xd, yd], ref.reshape(-1, 2), atol=1e-9)


def test_lens_coefficients_round_trip_undo_distortion():
    w, h = 160, 120
    truth = scene(w, h, seed=3)
    K = np.array([[150.0, 0, (w - 1) / 2], [0, 150.0, (h - 1) / 2], [0, 0, 1]])
    dist = np.array([-0.25, 0.08, 0.0, 0.0, 0.0])
    # make the captured (distorted) image: each captured pixel looks up its undistorted position
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    und = cv2.undistortPoints(np.c_[xs.ravel(), ys.ravel()].reshape(-1, 1, 2), K, dist, P=K).reshape(h, w, 2)
    captured = cv2.remap(truth, und[..., 0], und[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    step = LensStep(enabled=True, source="opencv", fx_px=150, fy_px=150, cx_px=(w - 1) / 2, cy_px=(h - 1) / 2,
                    dist_coeffs=dist.tolist(), tca=False)
    model = lens.lens_model(step, (w, h))
    maps = rectify.build_maps((w, h), 1.0, None, model)
    u16 = (captured * 65535).astype(np.uint16)
    corrected = rectify.apply_maps(u16, maps).astype(np.float64) / 65535
    inner = (slice(20, -20), slice(25, -25))
    before = np.abs(captured[inner] - truth[inner]).mean()
    after = np.abs(corrected[inner] - truth[inner]).mean()
    assert after < 0.004 and after < before / 5


def test_lateral_ca_scales_red_and_blue_about_the_centre():
    model = lens.OpenCVLens(fx=100, fy=100, cx=50, cy=50, dist=(0, 0, 0, 0, 0), red_scale=1.01, blue_scale=0.99)
    (xr, yr), (xg, yg), (xb, yb) = model.source_coords(np.array([150.0]), np.array([50.0]))
    assert xg[0] == pytest.approx(150) and xr[0] == pytest.approx(151) and xb[0] == pytest.approx(149)


def test_lensfun_database_gives_per_channel_maps():
    step = LensStep(enabled=True, source="lensfun", camera_maker="Sony", camera_model="ILCE-7RM2",
                    lens_maker="Sony", lens_model="FE 50mm f/1.8", focal_length_mm=50, aperture=8)
    model = lens.lens_model(step, (120, 80))
    maps = model.source_coords(np.array([[0.0, 119.0]]), np.array([[0.0, 79.0]]))
    assert len(maps) == 3
    corner = np.array([[maps[c][0][0, 0], maps[c][1][0, 0]] for c in range(3)])
    assert np.abs(corner - [0, 0]).max() > 0.01  # a real correction, not the identity
    with pytest.raises(InputError, match="lens_model"):
        lens.lens_model(LensStep(enabled=True, camera_model="ILCE-7RM2", lens_model="Zzz 999mm",
                                 focal_length_mm=50), (120, 80))


# -- 3 colour ----------------------------------------------------------------------------------
def test_picked_black_and_white_points_map_to_black_and_white():
    img = np.full((40, 40, 3), 20000, np.uint16)
    img[5:15, 5:15] = [50000, 40000, 30000]   # a white card under warm light
    img[25:35, 25:35] = [1000, 1200, 1400]    # black velvet
    step = ColorStep(mode="points", white_point_px=[10, 10], black_point_px=[30, 30], patch_px=5, white_output=0.9)
    black, white = color.levels(img, step)
    assert white == pytest.approx([50000, 40000, 30000]) and black == pytest.approx([1000, 1200, 1400])
    out = color.apply(img, black=black, white=white, white_output=0.9)
    assert out[10, 10].tolist() == pytest.approx([0.9 * 65535] * 3, abs=1)  # neutral white
    assert out[30, 30].tolist() == [0, 0, 0]
    with pytest.raises(InputError, match="white_point_px"):
        color.levels(img, ColorStep(mode="points", white_point_px=[400, 10]))


# -- 4 shading ---------------------------------------------------------------------------------
def test_vignetted_flat_comes_out_flat():
    w, h = 120, 80
    v = shading.vignetting((w, h), [-0.3, -0.1, 0.0])
    flat = (np.full((h, w, 3), 30000.0) * v[..., None]).astype(np.uint16)
    flat[40, 60:63] = 10000  # a dust spot is corrected too
    factor, _ = shading.correction(ShadingStep(enabled=True, mode="flat", flat_file="x"), (w, h), flat)
    out = color.apply(flat, factor_map=factor, enabled=False)
    assert out.std() / out.mean() < 0.002
    fitted, coeffs = shading.correction(ShadingStep(enabled=True, mode="model", flat_file="x"), (w, h), flat)
    assert coeffs[0] == pytest.approx(-0.3, abs=0.02)
    out = color.apply(flat, factor_map=fitted, enabled=False).astype(float)
    out[40, 60:63] = out.mean()
    assert out.std() / out.mean() < 0.01


def test_shading_without_its_flat_image_is_refused_naming_the_flat_file():
    """A profile changed after it was checked (shading switched on in code) reaches the step without a
    flat image: one message naming [shading] flat_file, not an AttributeError on None."""
    for step in (ShadingStep(enabled=True, mode="flat"), ShadingStep(enabled=True, mode="model")):
        with pytest.raises(InputError, match=r"\[shading\] flat_file"):
            shading.correction(step, (12, 8), None)
    factor, coeffs = shading.correction(ShadingStep(enabled=True, mode="model", coefficients=[-0.2]), (12, 8), None)
    assert factor.shape == (8, 12, 1) and coeffs == [-0.2]


# -- 5 de-flicker ------------------------------------------------------------------------------
def test_deflicker_gain_brings_a_brighter_view_to_the_reference():
    base = (scene(200, 120) * 65535).astype(np.uint16)
    brighter = np.clip(base.astype(np.float64) * 1.1, 0, 65535).astype(np.uint16)
    step = DeflickerStep()
    ref = deflicker.small_luminance(base, step.size_px)
    g, support = deflicker.gain(ref, deflicker.small_luminance(brighter, step.size_px), step)
    assert g == pytest.approx(1 / 1.1, rel=0.002) and support > 0.5
    out = color.apply(brighter, gain=g, enabled=False)
    assert np.abs(out.astype(float) - base).mean() / base.mean() < 0.003
    g2, _ = deflicker.gain(ref, deflicker.small_luminance(brighter, step.size_px), DeflickerStep(statistic="median"))
    assert g2 == pytest.approx(1 / 1.1, rel=0.01)


# -- 6 rectify ---------------------------------------------------------------------------------
def test_known_homography_is_undone():
    w, h = 160, 120
    truth = scene(w, h, seed=5)
    H = np.array([[1.0, 0.02, -3.0], [-0.015, 1.01, 2.0], [2e-5, -1e-5, 1.0]])
    captured = cv2.warpPerspective(truth, np.linalg.inv(H), (w, h), flags=cv2.INTER_CUBIC,
                                   borderMode=cv2.BORDER_REFLECT)
    maps = rectify.build_maps((w, h), 1.0, H, None)
    out = rectify.apply_maps((captured * 65535).astype(np.uint16), maps).astype(np.float64) / 65535
    inner = (slice(10, -10), slice(10, -10))
    assert np.abs(out[inner] - truth[inner]).mean() < 0.004
    assert np.abs(captured[inner] - truth[inner]).mean() > 0.02


@settings(max_examples=25, deadline=None)
@given(st.floats(0.25, 1.0), st.floats(-0.05, 0.05), st.floats(-20, 20), st.floats(0, 3000), st.floats(0, 2000))
def test_scaled_homography_agrees_with_full_resolution(s, shear, tx, x, y):
    H = np.array([[1.0, shear, tx], [-shear, 1.0, -tx / 2], [1e-6, 2e-6, 1.0]])
    Hs = homography_at_scale(H, s)
    C = pixel_scale_matrix(s)
    full = H @ [x, y, 1.0]
    full /= full[2]
    # a point at full resolution, seen in the scaled image, maps to the scaled image of its target
    scaled = Hs @ (C @ [x, y, 1.0])
    scaled /= scaled[2]
    np.testing.assert_allclose(scaled, C @ full, atol=1e-6)


def test_half_size_pixel_centres():
    # with s = 0.5, the centre of a 2x2 block (full-res 0.5, 0.5) is half-res pixel 0
    assert (pixel_scale_matrix(0.5) @ [0.5, 0.5, 1.0])[:2] == pytest.approx([0.0, 0.0])


# -- 7 resample --------------------------------------------------------------------------------
def test_resample_is_an_area_average():
    img = np.zeros((4, 4, 3), np.uint16)
    img[0, 0] = 40000
    out = resample.apply(img, resample.output_size((4, 4), 0.5))
    assert out.shape == (2, 2, 3) and out[0, 0, 0] == 10000 and out[1, 1, 0] == 0


def test_lens_and_rectification_are_one_warp():
    w, h = 160, 120
    truth = scene(w, h, seed=9)
    K = np.array([[150.0, 0, (w - 1) / 2], [0, 150.0, (h - 1) / 2], [0, 0, 1]])
    dist = np.array([-0.2, 0.05, 0.0, 0.0, 0.0])
    H = np.array([[1.0, 0.015, -2.0], [-0.01, 1.0, 1.5], [1e-5, 0.0, 1.0]])
    # captured pixel q_d -> undistorted q_u -> rectified H·q_u, where the true scene is
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    qu = cv2.undistortPoints(np.c_[xs.ravel(), ys.ravel()].reshape(-1, 1, 2), K, dist, P=K).reshape(-1, 2)
    r = cv2.perspectiveTransform(qu.reshape(-1, 1, 2).astype(np.float64), H).reshape(h, w, 2).astype(np.float32)
    captured = cv2.remap(truth, r[..., 0], r[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    step = LensStep(enabled=True, source="opencv", fx_px=150, fy_px=150, cx_px=(w - 1) / 2, cy_px=(h - 1) / 2,
                    dist_coeffs=dist.tolist(), tca=False)
    maps = rectify.build_maps((w, h), 1.0, H, lens.lens_model(step, (w, h)))
    assert len(maps) == 1  # one remap for all channels
    out = rectify.apply_maps((captured * 65535).astype(np.uint16), maps).astype(np.float64) / 65535
    inner = (slice(20, -20), slice(25, -25))
    assert np.abs(out[inner] - truth[inner]).mean() < 0.005
    assert np.abs(captured[inner] - truth[inner]).mean() > 0.01
    # at half resolution (half-size debayering) the same maps, scaled with the pixel-centre convention
    half = cv2.resize(captured, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    maps_half = rectify.build_maps((w // 2, h // 2), 0.5, H, lens.lens_model(step, (w, h)))
    out_half = rectify.apply_maps((half * 65535).astype(np.uint16), maps_half).astype(np.float64) / 65535
    truth_half = cv2.resize(truth, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    inner = (slice(10, -10), slice(13, -13))
    assert np.abs(out_half[inner] - truth_half[inner]).mean() < 0.01
