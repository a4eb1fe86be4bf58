"""The virtual studio: geometry measured from rendered images against its ground truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from lfstudio.sim.studio import VirtualStudio, rotation_matrix

W = 480


@pytest.fixture(scope="module")
def ideal_studio():
    return VirtualStudio(width_px=W, view_region_mm=(0, 40, 0, 12), seed=11)


def _grey8(rgb: np.ndarray) -> np.ndarray:
    return (np.clip(rgb.mean(axis=2), 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)


def _shift(a: np.ndarray, b: np.ndarray, margin: int = 40) -> tuple[float, float]:
    """Sub-pixel translation (dx, dy) of b's content relative to a's (ECC, grey, inner part)."""
    ga, gb = a.mean(axis=2)[margin:-margin, margin:-margin], b.mean(axis=2)[margin:-margin, margin:-margin]
    warp = np.eye(2, 3, dtype=np.float32)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-6)
    _, warp = cv2.findTransformECC(ga, gb, warp, cv2.MOTION_TRANSLATION, criteria, None, 5)
    return float(warp[0, 2]), float(warp[1, 2])


def test_disparity_matches_ground_truth_depth(ideal_studio):
    """SIFT matches between two views 40 mm apart shift by f*b/Z for the depth under each feature."""
    s = ideal_studio
    baseline_mm = 40.0
    a, depth_a = s.render(0.0, 6.0, ideal=True, with_depth=True)
    b = s.render(baseline_mm, 6.0, ideal=True)
    sift = cv2.SIFT_create()
    ka, da = sift.detectAndCompute(_grey8(a), None)
    kb, db = sift.detectAndCompute(_grey8(b), None)
    matches = cv2.BFMatcher(cv2.NORM_L2, crossCheck=True).match(da, db)
    errors, depths = [], []
    for m in matches:
        (ua, va), (ub, vb) = ka[m.queryIdx].pt, kb[m.trainIdx].pt
        z = depth_a[int(round(va)), int(round(ua))]
        # ignore features on depth edges (ambiguous depth)
        r = int(max(4, ka[m.queryIdx].size))
        win = depth_a[max(0, int(va) - r):int(va) + r + 1, max(0, int(ua) - r):int(ua) + r + 1]
        if win.max() - win.min() > 1e-6 or abs(vb - va) > 1.0:
            continue
        errors.append((ua - ub) - s.disparity_px(z, baseline_mm))
        depths.append(round(float(z), 3))
    errors = np.array(errors)
    assert len(errors) > 50
    assert len(set(depths)) >= 3                       # several layers measured
    assert float(np.median(np.abs(errors))) < 0.15
    assert float(np.mean(np.abs(errors) < 0.5)) > 0.9
    # the range of disparities is real parallax, not a constant shift
    disp = np.array([s.disparity_px(z, baseline_mm) for z in depths])
    assert disp.max() - disp.min() > 3.0


def test_vertical_motion_shifts_image_up():
    s = VirtualStudio(width_px=W, view_region_mm=(0, 40, 0, 12), seed=11, n_layers=0, n_objects=0)
    dx, dy = _shift(s.render(20.0, 0.0, ideal=True), s.render(20.0, 12.0, ideal=True))
    assert abs(dx) < 0.02
    expected = -s.disparity_px(s.far_m, 12.0)          # only the background: it moves up
    assert dy == pytest.approx(expected, abs=0.02)


def test_ground_truth_homography_rectifies_captured_view():
    kw = dict(width_px=W, view_region_mm=(0, 8, 0, 6), seed=5)
    s = VirtualStudio(rotation_deg=(1.5, -2.0, 1.0), pp_offset_px=(12.0, -8.0), **kw)
    captured = s.render(4.0, 3.0)
    ideal = s.render(4.0, 3.0, ideal=True)
    rectified = cv2.warpPerspective(captured, s.H, (s.width_px, s.height_px), flags=cv2.INTER_LINEAR)
    m = 40                                              # rotated borders do not overlap
    inner = (slice(m, -m), slice(m, -m))
    err_rectified = np.abs(rectified[inner] - ideal[inner]).mean()
    err_unrectified = np.abs(captured[inner] - ideal[inner]).mean()
    assert err_rectified < 0.2 * err_unrectified
    dx, dy = _shift(ideal, rectified)
    assert abs(dx) < 0.05 and abs(dy) < 0.05
    # and the same H maps projected points: H · p_captured ~ p_rect
    X = np.array([[0.3, -0.2, 2.5], [-0.5, 0.4, 4.0]])
    p = s.project(X, 4.0, 3.0)
    q = s.project(X, 4.0, 3.0, ideal=True)
    ph = (s.H @ np.c_[p, np.ones(2)].T).T
    np.testing.assert_allclose(ph[:, :2] / ph[:, 2:], q, atol=1e-6)


def test_conventions_of_intrinsics_and_rotation():
    s = VirtualStudio(width_px=200, rotation_deg=(0, 0, 0), pp_offset_px=(3, -2), view_region_mm=(0, 4, 0, 4))
    assert s.K_true[0, 2] == pytest.approx((200 - 1) / 2 + 3)
    assert s.K_true[1, 2] == pytest.approx((s.height_px - 1) / 2 - 2)
    assert s.f_px == pytest.approx(50.0 / (35.9 / 200))
    R = rotation_matrix((0, 0, 90))
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    # a point straight ahead of the camera lands on the principal point
    p = s.project([[0.01, 0.02, 3.0]], 10.0, 20.0)
    np.testing.assert_allclose(p[0], s.K_true[:2, 2], atol=1e-9)


def test_background_fills_every_view_of_the_region():
    s = VirtualStudio(width_px=160, rotation_deg=(2, -3, 2), pp_offset_px=(10, 5), view_region_mm=(0, 400, 0, 120),
                      seed=2)
    bg = next(layer for layer in s.layers if layer.kind == "background")
    th, tw = bg.rgba.shape[:2]
    for x in (0.0, 400.0):
        for y in (0.0, 120.0):
            Hinv = np.linalg.inv(s.layer_homography(bg, x, y))
            w, h = s.width_px, s.height_px
            c = Hinv @ np.array([[0, w - 1, 0, w - 1], [0, 0, h - 1, h - 1], [1, 1, 1, 1]], float)
            u, v = c[0] / c[2], c[1] / c[2]
            assert u.min() >= 0 and v.min() >= 0 and u.max() <= tw - 1 and v.max() <= th - 1


def test_deterministic_for_a_seed_and_different_across_seeds():
    kw = dict(width_px=128, view_region_mm=(0, 4, 0, 4))
    a = VirtualStudio(seed=1, **kw).render(1.0, 2.0)
    b = VirtualStudio(seed=1, **kw).render(1.0, 2.0)
    c = VirtualStudio(seed=2, **kw).render(1.0, 2.0)
    assert np.array_equal(a, b)
    assert np.abs(a - c).mean() > 0.02
    assert a.dtype == np.float32 and a.shape == (VirtualStudio(seed=1, **kw).height_px, 128, 3)
    assert 0.0 <= a.min() and a.max() <= 1.0


def test_depth_map_spans_near_to_far():
    s = VirtualStudio(width_px=320, view_region_mm=(0, 4, 0, 4), near_m=1.5, far_m=6.0, seed=4)
    depth = s.depth_map(2.0, 2.0)
    assert depth.max() == pytest.approx(6.0)
    assert depth.min() < 2.0                           # the small objects in front are visible
    assert len(np.unique(depth)) >= 4
    assert np.mean(depth == 6.0) > 0.2                 # the background shows through


def test_invalid_depths_rejected():
    with pytest.raises(ValueError, match="near_m"):
        VirtualStudio(near_m=5.0, far_m=2.0)
