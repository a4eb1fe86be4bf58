import math

import pytest

from lfstudio.optics import move_time_s, view_period_s


def test_triangular_move():
    # 4 mm at 500 mm/s² never reaches 200 mm/s: t = 2 sqrt(d/a)
    assert move_time_s(4, 200, 500) == pytest.approx(2 * math.sqrt(4 / 500))


def test_trapezoidal_move():
    # 1000 mm: 0.4 s ramp up, 0.4 s down (80 mm each way), 920 mm at 200 mm/s
    assert move_time_s(1000, 200, 500) == pytest.approx(0.8 + 920 / 200)
    assert move_time_s(-1000, 200, 500) == move_time_s(1000, 200, 500)
    assert move_time_s(0, 200, 500) == 0


def test_view_period_transfer_overlaps_move():
    assert view_period_s(0.18, 0.3, 0.5, 2.5) == pytest.approx(3.0)
    assert view_period_s(3.0, 0.3, 0.5, 2.5) == pytest.approx(3.8)


def test_scan_duration_counts_each_move_once_and_overlaps_transfers():
    from lfstudio.optics import scan_duration_s

    assert scan_duration_s([], 0.3, 0.5, 2.5) == 0.0
    # one view: move, settle, exposure, transfer; nothing overlaps
    assert scan_duration_s([(1.0, 1)], 0.3, 0.5, 2.5) == pytest.approx(1.0 + 0.3 + 0.5 + 2.5)
    # three views reached by 0 s, then 2 x 0.4 s moves: transfer 2.5 s hides move + settle
    assert scan_duration_s([(0.0, 1), (0.4, 2)], 0.3, 0.5, 2.5) == pytest.approx(0.8 + 2 * 3.0 + 2.5)
    assert scan_duration_s([(0.0, 1), (0.4, 2)], 0.3, 0.5, 2.5, pipelined=False) == \
        pytest.approx(3.3 + 2 * 3.7)
    # counts may be split or zero: the same path in other pieces gives the same time
    assert scan_duration_s([(0.0, 0), (0.0, 1), (0.4, 1), (0.4, 1)], 0.3, 0.5, 2.5) == pytest.approx(0.8 + 6.0 + 2.5)
