"""The SPEC formulas against values computed by hand, and their inverse relations."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lfstudio import optics

F_MM, PITCH_UM = 50.0, 4.53


def test_image_coordinate():
    # u = f·X/(s_p·Z) = 50 mm · 100 mm / (0.00453 mm · 2000 mm) = 551.9 px
    assert optics.image_coordinate_px(100, 2000, F_MM, PITCH_UM) == pytest.approx(5000 / (0.00453 * 2000))


def test_disparity_between_two_depths():
    # f·b/s_p = 50·4/0.00453 = 44150.1 px·mm; (1/1770 − 1/4770) = 3.5533e-4 /mm → 15.69 px
    assert optics.disparity_px(4, 1770, 4770, F_MM, PITCH_UM) == pytest.approx(15.688, abs=1e-3)
    assert optics.disparity_px(4, 2000, math.inf, F_MM, PITCH_UM) == pytest.approx(200 / 0.00453 / 2000)


def test_worked_check_min_distance():
    # Z_min = f·ε/(0.5·s_p) = 50 · 0.080 / (0.5 · 0.00453) mm = 1766 mm
    z = optics.min_distance_mm(80, F_MM, PITCH_UM, 0.5)
    assert z == pytest.approx(1766.0, abs=0.1)
    assert round(z / 1000, 2) == 1.77
    assert optics.reposition_error_px(80, z, F_MM, PITCH_UM) == pytest.approx(0.5)


def test_worked_check_f_number_and_focus():
    # N = f²/c · (D_F − D_N)/(2 D_F D_N) = 2500/0.029 · 3000/(2·4770·1770) = 15.32
    n = optics.f_number_for_range(1770, 4770, F_MM, 0.029)
    assert n == pytest.approx(15.3159, abs=1e-3)
    assert round(n, 1) == 15.3
    assert optics.focus_for_range_mm(1770, 4770) == pytest.approx(2 * 1770 * 4770 / 6540)


def test_worked_check_row_parallax():
    # B = 100 · 4 mm = 400 mm; d = 50·400/0.00453 · (1/1770 − 1/4770) = 1568.8 px = 19.7 % of 7952 px
    b = optics.baseline_mm(101, 4.0)
    assert b == 400.0
    d = optics.disparity_px(b, 1770, 4770, F_MM, PITCH_UM)
    assert d == pytest.approx(1568.8, abs=0.1)
    assert d / 7952 == pytest.approx(0.20, abs=0.005)


def test_hyperfocal_and_dof():
    # H = f + f²/(N c) = 50 + 2500/(8 · 0.03) = 10466.7 mm; approximation drops the "+ f"
    assert optics.hyperfocal_mm(50, 8, 0.03) == pytest.approx(50 + 2500 / 0.24)
    h = optics.hyperfocal_mm(50, 8, 0.03, exact=False)
    assert h == pytest.approx(2500 / 0.24)
    assert optics.dof_near_mm(h, 3000) == pytest.approx(h * 3000 / (h + 3000))
    assert optics.dof_far_mm(h, 3000) == pytest.approx(h * 3000 / (h - 3000))
    assert optics.dof_far_mm(h, h) == math.inf and optics.dof_far_mm(h, 2 * h) == math.inf
    assert optics.dof_near_mm(h, h) == pytest.approx(h / 2)    # focused at H: sharp from H/2


def test_f_number_for_infinite_far():
    # sharp to infinity: H = 2·D_N, focus at 2·D_N (= H)
    n = optics.f_number_for_range(2000, math.inf, 50, 0.03)
    assert optics.hyperfocal_mm(50, n, 0.03, exact=False) == pytest.approx(4000)
    assert optics.focus_for_range_mm(2000, math.inf) == 4000


def test_diffraction():
    assert optics.airy_disk_um(8) == pytest.approx(2.44 * 0.55 * 8)
    assert optics.diffraction_check(4, 0.029, 4.53)[0] == "ok"        # 5.4 µm < 9.06 µm
    assert optics.diffraction_check(15.3, 0.029, 4.53)[0] == "pixels"  # 20.5 µm
    assert optics.diffraction_check(32, 0.029, 4.53)[0] == "coc"       # 42.9 µm > 29 µm
    n = optics.diffraction_limit_f_number(2 * 4.53)
    assert optics.airy_disk_um(n) == pytest.approx(9.06)


def test_positions_for_parallax():
    per_step = optics.disparity_px(4, 1770, 4770, F_MM, PITCH_UM)
    assert optics.positions_for_parallax(per_step * 100, 4, 1770, 4770, F_MM, PITCH_UM) == 101
    assert optics.positions_for_parallax(per_step * 100 + 0.01, 4, 1770, 4770, F_MM, PITCH_UM) == 102
    assert optics.positions_for_parallax(0, 4, 1770, 4770, F_MM, PITCH_UM) == 1


def test_raw_bytes():
    assert optics.raw_bytes_per_image(7952, 5304, 14) == 7952 * 5304 * 2
    assert optics.raw_bytes_per_image(100, 10, 8) == 1000


depth = st.floats(min_value=300, max_value=50_000)
focal = st.floats(min_value=8, max_value=300)
pitch = st.floats(min_value=1, max_value=20)


@settings(max_examples=60, deadline=None)
@given(d=st.floats(min_value=0.01, max_value=1000), near=depth, extra=st.floats(min_value=10, max_value=50_000),
       f=focal, sp=pitch)
def test_spacing_from_disparity_and_back(d, near, extra, f, sp):
    far = near + extra
    spacing = optics.spacing_for_disparity_mm(d, near, far, f, sp)
    assert optics.disparity_px(spacing, near, far, f, sp) == pytest.approx(d, rel=1e-9)


@settings(max_examples=60, deadline=None)
@given(near=depth, extra=st.floats(min_value=10, max_value=50_000), f=focal,
       c=st.floats(min_value=0.005, max_value=0.1))
def test_dof_from_f_number_and_back(near, extra, f, c):
    far = near + extra
    n = optics.f_number_for_range(near, far, f, c)
    s = optics.focus_for_range_mm(near, far)
    h = optics.hyperfocal_mm(f, n, c, exact=False)
    assert near < s < far and s < h
    assert optics.dof_near_mm(h, s) == pytest.approx(near, rel=1e-9)
    assert optics.dof_far_mm(h, s) == pytest.approx(far, rel=1e-9)


@settings(max_examples=60, deadline=None)
@given(n=st.floats(min_value=1, max_value=64), s=depth, f=focal, c=st.floats(min_value=0.005, max_value=0.1))
def test_f_number_from_dof_and_back(n, s, f, c):
    h = optics.hyperfocal_mm(f, n, c, exact=False)
    if s >= h * 0.999:          # sharp to infinity: the range does not determine N
        return
    near, far = optics.dof_near_mm(h, s), optics.dof_far_mm(h, s)
    assert optics.f_number_for_range(near, far, f, c) == pytest.approx(n, rel=1e-6)
    assert optics.focus_for_range_mm(near, far) == pytest.approx(s, rel=1e-6)


@settings(max_examples=60, deadline=None)
@given(spacing=st.floats(min_value=0.1, max_value=100), steps=st.integers(min_value=0, max_value=2000),
       near=depth, extra=st.floats(min_value=10, max_value=50_000))
def test_grid_from_parallax_covers_it_minimally(spacing, steps, near, extra):
    far = near + extra
    per_step = optics.disparity_px(spacing, near, far, F_MM, PITCH_UM)
    wanted = per_step * (steps + 0.5)
    n = optics.positions_for_parallax(wanted, spacing, near, far, F_MM, PITCH_UM)
    assert n == steps + 2
    assert optics.disparity_px(optics.baseline_mm(n, spacing), near, far, F_MM, PITCH_UM) >= wanted
    assert optics.disparity_px(optics.baseline_mm(n - 1, spacing), near, far, F_MM, PITCH_UM) < wanted


def test_blur_is_the_coc_at_the_dof_limits():
    h = optics.hyperfocal_mm(50, 11, 0.03, exact=False)
    s = 3000.0
    for limit in (optics.dof_near_mm(h, s), optics.dof_far_mm(h, s)):
        assert optics.blur_diameter_mm(limit, s, 50, 11) == pytest.approx(0.03)
    assert optics.blur_diameter_mm(s, s, 50, 11) == 0
