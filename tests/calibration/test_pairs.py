import pytest

from lfstudio.calibration.pairs import DEFAULT_PAIR_SET, DEFAULT_VIEWS, line_pairs, make_pairs
from lfstudio.dataset.grid import Grid, spread_indices
from lfstudio.errors import InputError


def sparse_subset(columns, rows, n_rows=2, n_columns=3, available=None):
    """The calibration's arrays, now Grid.spread (one home for choosing views)."""
    return Grid(columns, rows).spread(n_rows, n_columns, available)


def parse_views(spec, columns, rows, available):
    """The calibration's --views, now Grid.select with the calibration's default (Dataset.select)."""
    return Grid(columns, rows).select(spec, available, default=DEFAULT_VIEWS, field_name="--views")


def default_subset(columns, rows):
    return parse_views(None, columns, rows, Grid(columns, rows).views())


def test_default_is_the_papers_2x3_array_over_the_reference_grid():
    views = sparse_subset(101, 21)
    assert views == [(0, 0), (0, 50), (0, 100), (20, 0), (20, 50), (20, 100)]
    pairs = make_pairs(views, (4.0, 6.0))
    hor = [p for p in pairs if p.direction == "h"]
    ver = [p for p in pairs if p.direction == "v"]
    assert len(hor) == 6 and len(ver) == 3
    assert sorted({p.baseline_mm for p in hor}) == [200.0, 400.0]   # several baselines
    assert {p.baseline_mm for p in ver} == {120.0}
    assert all(p.a[1] < p.b[1] for p in hor) and all(p.a[0] < p.b[0] for p in ver)


def test_neighbours_only_and_denser_arrays():
    views = sparse_subset(101, 21, 3, 5)
    assert len(views) == 15 and spread_indices(21, 3) == [0, 10, 20]
    assert len(make_pairs(views, neighbours_only=True)) == 3 * 4 + 5 * 2
    assert len(make_pairs(views)) == 3 * 10 + 5 * 3


def test_subset_snaps_to_captured_views():
    avail = [(r, c) for r in (1, 19) for c in range(0, 101, 7)]
    views = sparse_subset(101, 21, 2, 3, avail)
    assert views == [(1, 0), (1, 49), (1, 98), (19, 0), (19, 49), (19, 98)]


def test_parse_views_forms_and_errors():
    avail = [(r, c) for r in range(3) for c in range(4)]
    assert parse_views("all", 4, 3, avail) == avail
    assert parse_views("2x2", 4, 3, avail) == [(0, 0), (0, 3), (2, 0), (2, 3)]
    assert parse_views("r00_c001, r2c3", 4, 3, avail) == [(0, 1), (2, 3)]
    with pytest.raises(InputError, match="--views"):
        parse_views("banana", 4, 3, avail)
    with pytest.raises(InputError, match="r05_c001"):
        parse_views("r05_c001", 4, 3, avail)


def test_default_array_and_pair_sets():
    views = default_subset(101, 21)
    # ten rows spread over the grid x the first two and last two columns: the longest baselines,
    # each end measured twice (the roll is fixed by how the views' position errors line up)
    assert views == Grid(101, 21).spread(10, 4, ends=(False, True)) and parse_views(None, 101, 21, views) == views
    assert sorted({c for _, c in views}) == [0, 1, 99, 100] and len({r for r, _ in views}) == 10
    assert parse_views("default", 101, 21, views) == views
    assert default_subset(3, 9) == Grid(3, 9).views()                 # capped by the grid: every view
    assert default_subset(4, 2) == sparse_subset(4, 2, 2, 4)
    pairs = make_pairs(views, (4.0, 6.0), pair_set=DEFAULT_PAIR_SET)
    hor = [p for p in pairs if p.direction == "h"]
    assert len(hor) == 10 * 6 and max(p.baseline_mm for p in hor) == 400.0 and min(p.baseline_mm for p in hor) == 4.0
    assert max(p.baseline_mm for p in pairs if p.direction == "v") == 120.0
    assert line_pairs([0, 25, 50, 75, 100], "spanning") == [(0, 25), (0, 50), (0, 75), (0, 100), (25, 50),
                                                            (25, 100), (50, 75), (50, 100), (75, 100)]
    assert line_pairs([0, 50, 100], "neighbours") == [(0, 50), (50, 100)]
    assert make_pairs(views, pair_set="neighbours") == make_pairs(views, neighbours_only=True)
    with pytest.raises(InputError, match="--pairs"):
        make_pairs(views, pair_set="some")
