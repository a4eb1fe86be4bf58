"""dataset/grid.py: the typed grid and view every stage uses; old manifests read unchanged; one
reader of a view selection, the same for the calibration, the export and the quality check."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, strategies as st

from lfstudio.dataset import Dataset
from lfstudio.dataset.grid import Grid, View
from lfstudio.dataset.paths import view_label, view_stem
from lfstudio.errors import InputError


@given(st.integers(0, 999), st.integers(0, 9999))
def test_view_names_are_built_and_read_in_one_place(row, column):
    v = View(row, column)
    assert v.name == view_stem(row, column) and View.parse(v.name) == v == (row, column)
    assert View.parse(f" R{row}C{column} ") == v
    r, c = v                                   # still a (row, column) pair everywhere
    assert (r, c) == (row, column)


def test_messages_name_a_view_in_one_way():
    assert View(7, 42).label == view_label(7, 42) == "r07 c042"
    assert View.parse(View(7, 42).label) == (7, 42)          # what a message says can be typed back


def test_a_name_that_is_no_view_is_refused():
    for text in ("banana", "r1", "c2", "r-1_c2", ""):
        with pytest.raises(ValueError):
            View.parse(text)


def test_old_manifests_read_as_a_typed_grid(tmp_path):
    """A manifest grid without spacing, origin, order or settle time (older datasets, imports)."""
    ds = Dataset.create(tmp_path / "ds", camera={"name": "c"}, lens={"name": "l"}, grid={"columns": 4, "rows": 2})
    grid = Dataset.open(ds.root).grid
    assert (grid.columns, grid.rows, grid.spacing_mm, grid.origin_mm, grid.order) == (4, 2, None, None, None)
    assert grid.step_mm == (1.0, 1.0) and grid.baselines_mm == (3.0, 1.0) and grid.centre == View(0, 1)
    on_disk = json.loads((ds.root / "dataset.json").read_text())["grid"]
    assert on_disk == {"columns": 4, "rows": 2}          # the file's format is unchanged
    full = Grid.from_manifest({"columns": 3, "rows": 2, "spacing_mm": [4, 6], "origin_mm": [10, 20],
                               "order": "row-meander", "settle_s": 0.3, "note": "kept"})
    assert full.position_mm(View(1, 2)) == (18.0, 26.0) and full.extra == {"note": "kept"}
    assert View(1, 2) in full and View(2, 0) not in full and len(full.views()) == 6


def test_the_manifest_grid_round_trips_and_gives_the_capture_order():
    """Grid.to_manifest is from_manifest's inverse (what the scan plan, the planner, the export and
    the virtual dataset write); in_order lists the views in the grid's own order."""
    doc = {"columns": 3, "rows": 2, "spacing_mm": [4.0, 6.0], "origin_mm": [10.0, 20.0],
           "order": "column-meander", "settle_s": 0.3, "note": "kept"}
    assert Grid.from_manifest(doc).to_manifest() == doc
    assert Grid.from_manifest({"columns": 4, "rows": 2}).to_manifest() == {"columns": 4, "rows": 2}
    assert Grid.from_manifest(doc).in_order() == [(0, 0), (1, 0), (1, 1), (0, 1), (0, 2), (1, 2)]
    assert Grid(3, 2).in_order() == [(0, 0), (0, 1), (0, 2), (1, 2), (1, 1), (1, 0)]   # unknown: meander
    assert Grid(2, 2, order="raster").in_order() == [(0, 0), (0, 1), (1, 0), (1, 1)]
    with pytest.raises(InputError, match="unknown scan order"):
        Grid(2, 2, order="spiral").in_order()


def test_one_selection_for_every_stage(tmp_path):
    ds = Dataset.create(tmp_path / "ds", camera={"name": "c"}, lens={"name": "l"},
                        grid={"columns": 5, "rows": 3, "spacing_mm": [4.0, 6.0]})
    for r in range(3):
        for c in range(5):
            if (r, c) != (1, 2):
                (ds.root / "raw").mkdir(exist_ok=True)
                (ds.root / "raw" / f"{view_stem(r, c)}.png").write_bytes(b"x")
                ds.record_view(r, c, status="done", file=f"raw/{view_stem(r, c)}.png")
    assert View(1, 2) not in ds.captured_views() and len(ds.captured_views()) == 14
    assert ds.select("all") == ds.select(None) == ds.captured_views()
    assert ds.select("r1-2,c1-3") == [(1, 1), (1, 3), (2, 1), (2, 2), (2, 3)]
    assert ds.select("array:3x2") == [(0, 0), (0, 2), (0, 4), (2, 0), (2, 2), (2, 4)]
    # columns (rows) at the two ends of the grid, side by side
    assert ds.select("array:2ex2") == [(0, 0), (0, 4), (2, 0), (2, 4)]
    assert ds.select("array:3Ex1") == [(0, 0), (0, 1), (0, 4)]
    assert ds.select("array:4ex2e") == [(0, 0), (0, 1), (0, 3), (0, 4), (2, 0), (2, 1), (2, 3), (2, 4)] == \
        [v for v in ds.grid.spread(2, 4, ends=(True, True)) if v.row != 1]
    assert ds.select("r00_c001, r2c3") == [(0, 1), (2, 3)]
    assert ds.select([(2, 4), (0, 0)]) == [(0, 0), (2, 4)]
    for spec, words in (("r1_c2", "r01_c002 has no captured image"), ("r0-7", "rows up to 7 asked"),
                        ("r3-1", "range runs backwards"), ("banana", "cannot read 'banana'"),
                        ([(1, 2)], "no captured image for r01_c002"), ("array:0x2", "at least one column and one row")):
        with pytest.raises(InputError, match=words) as exc:
            ds.select(spec)
        assert exc.value.field == "views"
    # the stages ask the same reader: the calibration with its own default and option name
    from lfstudio.calibration.pairs import DEFAULT_VIEWS

    assert ds.select(None, default=DEFAULT_VIEWS) == ds.grid.select(DEFAULT_VIEWS, ds.captured_views())
    with pytest.raises(InputError, match="--views"):
        ds.select("banana", field_name="--views")


def test_an_array_is_columns_by_rows_and_a_bare_rows_by_columns_is_refused():
    """Issue 20: arrays were ROWSxCOLUMNS ('--views 3x5') while --grid is COLUMNSxROWS. The new
    spelling array:CxR is columns x rows; a bare non-square RxC, which an existing script means as
    rows x columns, is refused with the new form instead of being read the other way."""
    grid = Grid(9, 5)
    everything = grid.views()
    wide = grid.select("array:5x3", everything)             # 5 columns, 3 rows
    assert sorted({v.column for v in wide}) == [0, 2, 4, 6, 8] and sorted({v.row for v in wide}) == [0, 2, 4]
    assert grid.select("ARRAY: 5 x 3", everything) == wide
    assert grid.select("3x3", everything) == grid.select("array:3x3", everything)   # square: the same either way
    ends = grid.select("array:4ex3", everything)            # the first two and last two columns x 3 rows
    assert sorted({v.column for v in ends}) == [0, 1, 7, 8] and sorted({v.row for v in ends}) == [0, 2, 4]
    for old, new in (("3x5", "array:5x3 for 5 columns by 3 rows"), ("10x4e", "array:4ex10 for 4 columns by 10 rows"),
                     ("3x3e", "array:3ex3")):
        with pytest.raises(InputError, match=f"'{old}': an array is written array:COLUMNSxROWS") as exc:
            grid.select(old, everything, field_name="--views")
        assert exc.value.field == "--views" and new in str(exc.value)
