"""Scan plan: order, coverage, positions and soft limits."""

from __future__ import annotations

import pytest
from hypothesis import given, settings, strategies as st

from lfstudio.errors import InputError
from lfstudio.optics import move_time_s
from lfstudio.rig.profile import load_rig
from lfstudio.scan.scan_plan import ORDERS, ScanPlan, grid_order

RIG = load_rig()

dims = st.tuples(st.integers(1, 30), st.integers(1, 12))


@settings(max_examples=60, deadline=None)
@given(dims=dims, order=st.sampled_from(ORDERS))
def test_every_cell_exactly_once_and_neighbours_adjacent(dims, order):
    cols, rows = dims
    cells = grid_order(cols, rows, order)
    assert len(cells) == cols * rows
    assert set(cells) == {(r, c) for r in range(rows) for c in range(cols)}
    if order != "raster":
        # a meander never jumps: consecutive views are grid neighbours
        for (r0, c0), (r1, c1) in zip(cells, cells[1:]):
            assert abs(r0 - r1) + abs(c0 - c1) == 1


@settings(max_examples=40, deadline=None)
@given(dims=dims)
def test_row_meander_direction(dims):
    cols, rows = dims
    cells = grid_order(cols, rows, "row-meander")
    for r in range(rows):
        row = [c for rr, c in cells if rr == r]
        assert row == (list(range(cols)) if r % 2 == 0 else list(range(cols - 1, -1, -1)))


@settings(max_examples=40, deadline=None)
@given(dims=dims, order=st.sampled_from(ORDERS), data=st.data())
def test_subset_keeps_relative_order(dims, order, data):
    cols, rows = dims
    full = ScanPlan(cols, rows, (4.0, 6.0), order=order)
    all_cells = [v.cell for v in full.views()]
    subset = data.draw(st.sets(st.sampled_from(all_cells)))
    part = full.with_subset(subset).views()
    assert [v.cell for v in part] == [rc for rc in all_cells if rc in subset]
    assert [v.index for v in part] == list(range(len(subset)))
    assert len(full.with_subset(subset)) == len(subset)


def test_positions_from_origin_and_spacing():
    plan = ScanPlan(3, 2, (4.0, 6.0), origin_mm=(10.0, 20.0))
    views = plan.views()
    assert [v.cell for v in views] == [(0, 0), (0, 1), (0, 2), (1, 2), (1, 1), (1, 0)]
    assert views[2].position_mm == (18.0, 20.0)
    assert views[3].position_mm == (18.0, 26.0)
    assert plan.extent_mm() == (10.0, 18.0, 20.0, 26.0)


def test_reference_grid_is_centred_and_inside_the_travel():
    plan = ScanPlan.centered(101, 21, (4.0, 6.0), RIG)
    x0, x1, y0, y1 = plan.extent_mm()
    assert x1 - x0 == pytest.approx(400.0) and y1 - y0 == pytest.approx(120.0)
    assert (x0 + x1) / 2 == pytest.approx(2000.0) and (y0 + y1) / 2 == pytest.approx(250.0)
    assert len(plan.views()) == 2121
    assert ScanPlan.from_grid_dict(plan.grid_dict()) == plan


def test_grid_outside_the_soft_limits_is_refused_naming_the_field():
    with pytest.raises(InputError) as exc:
        ScanPlan.centered(1100, 2, (4.0, 6.0), RIG)
    assert "horizontal spacing_mm" in str(exc.value) and "4000" in str(exc.value)
    with pytest.raises(InputError) as exc:
        ScanPlan.centered(21, 101, (4.0, 6.0), RIG)
    assert "vertical spacing_mm" in str(exc.value)
    with pytest.raises(InputError) as exc:
        ScanPlan.centered(101, 21, (4.0, 6.0), RIG, offset_mm=(1900.0, 0.0))
    assert exc.value.field == "horizontal origin/offset_mm"


def test_bad_inputs_name_the_field():
    with pytest.raises(InputError, match="grid columns"):
        ScanPlan(0, 3, (4.0, 6.0))
    with pytest.raises(InputError, match="order"):
        ScanPlan(2, 3, (4.0, 6.0), order="spiral")
    with pytest.raises(InputError, match="subset"):
        ScanPlan(2, 3, (4.0, 6.0), subset={(5, 0)})


class _GridPlan:
    def grid_dict(self):
        return {"columns": 5, "rows": 3, "spacing_mm": [4.0, 6.0]}


def test_from_scene_plan_in_one_step():
    plan = ScanPlan.from_scene_plan(_GridPlan(), RIG)
    assert (plan.columns, plan.rows, plan.spacing_mm, plan.order) == (5, 3, (4.0, 6.0), "row-meander")
    assert plan.settle_s == pytest.approx(0.3)


def test_estimated_duration_is_the_critical_path():
    plan = ScanPlan(4, 2, (4.0, 6.0), settle_s=0.3)
    h = RIG.horizontal
    m4 = move_time_s(4.0, h.max_speed_mm_s, h.acceleration_mm_s2)
    m6 = move_time_s(6.0, RIG.vertical.max_speed_mm_s, RIG.vertical.acceleration_mm_s2)
    # transfer 2.5 s dominates every move + settle: exposure + transfer per view after the first
    est = plan.estimate_duration_s(RIG, exposure_s=0.5, transfer_s=2.5)
    assert est == pytest.approx(0.3 + 0.5 + 7 * (0.5 + 2.5) + 2.5)
    # no transfer: moves and settles add up
    est0 = plan.estimate_duration_s(RIG, exposure_s=0.5, transfer_s=0.0)
    assert est0 == pytest.approx(0.3 + 0.5 + 6 * (m4 + 0.8) + (m6 + 0.8))
