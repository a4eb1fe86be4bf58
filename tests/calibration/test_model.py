import numpy as np
from hypothesis import given, settings, strategies as st

from lfstudio.calibration.model import (apply_homography, intrinsics, nominal_principal_point, project,
                                        rectifying_homography, rotation_matrix, scale_homography)

angles = st.lists(st.floats(-6, 6), min_size=3, max_size=3)
offsets = st.lists(st.floats(-60, 60), min_size=2, max_size=2)


@settings(max_examples=30, deadline=None)
@given(angles, offsets)
def test_homography_maps_captured_pixels_to_the_ideal_camera(rot, pp_off):
    size, f = (1600, 1068), 2200.0
    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(-0.5, 0.5, 50), rng.uniform(-0.3, 0.3, 50), rng.uniform(1.8, 4.8, 50)])
    C = np.array([0.12, -0.04, 0.0])
    K_true = intrinsics(f, nominal_principal_point(size) + np.array(pp_off))
    K0 = intrinsics(f, nominal_principal_point(size))
    captured, _ = project(X, C, rotation_matrix(rot), K_true)
    ideal, _ = project(X, C, np.eye(3), K0)
    H = rectifying_homography(rot, f, size, nominal_principal_point(size) + np.array(pp_off))
    assert np.allclose(apply_homography(H, captured), ideal, atol=1e-6)


@settings(max_examples=20, deadline=None)
@given(angles)
def test_scaled_homography_commutes_with_resizing(rot):
    full, half = (2000, 1334), (500, 333.5)
    H = rectifying_homography(rot, 2800.0, full)
    Hs = scale_homography(H, full, (500, 334))
    s = 500 / 2000
    pts = np.array([[10.0, 20.0], [1000.0, 600.0], [1900.0, 1300.0]])
    to_small = (pts + 0.5) * s - 0.5
    expected = (apply_homography(H, pts) + 0.5) * s - 0.5
    assert np.allclose(apply_homography(Hs, to_small), expected, atol=1e-9)
    assert half[0] == 500


def test_rotation_convention_is_extrinsic_xyz():
    R = rotation_matrix([0, 0, 90])
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-12)   # x turns into y (down) for +rz
