"""dataset/grid.py: the typed grid and view every stage uses; old manifests read unchanged; one
reader of a view selection, the same for the calibration, the export and the quality check."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, strategies as st

from lfstudio.dataset import Dataset
from lfstudio.dataset.grid import Grid, View
from lfstudio.dataset.paths import view_stem
from lfstudio.errors import InputError


@given(st.integers(0, 999), st.integers(0, 9999))
def test_view_names_are_built_and_read_in_one_place(row, column):
    v = View(row, column)
    assert v.name == view_stem(row, column) and View.parse(v.name) == v == (row, column)
    assert View.parse(f" R{row}C{column} ") == v
    r, c = v                                   # still a (row, column) pair everywhere
    assert (r, c) == (row, column)


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
    assert ds.select("2x3") == [(0, 0), (0, 2), (0, 4), (2, 0), (2, 2), (2, 4)]
    # columns (rows) at the two ends of the grid, side by side
    assert ds.select("2x2e") == [(0, 0), (0, 4), (2, 0), (2, 4)]
    assert ds.select("1x3E") == [(0, 0), (0, 1), (0, 4)]
    assert ds.select("2ex4e") == [(0, 0), (0, 1), (0, 3), (0, 4), (2, 0), (2, 1), (2, 3), (2, 4)] == \
        [v for v in ds.grid.spread(2, 4, ends=(True, True)) if v.row != 1]
    assert ds.select("r00_c001, r2c3") == [(0, 1), (2, 3)]
    assert ds.select([(2, 4), (0, 0)]) == [(0, 0), (2, 4)]
    for spec, words in (("r1_c2", "r01_c002 has no captured image"), ("r0-7", "rows up to 7 asked"),
                        ("r3-1", "range runs backwards"), ("banana", "cannot read 'banana'"),
                        ([(1, 2)], "no captured image for r01_c002"), ("0x2", "at least one row")):
        with pytest.raises(InputError, match=words) as exc:
            ds.select(spec)
        assert exc.value.field == "views"
    # the stages ask the same reader: the calibration with its own default and option name
    from lfstudio.calibration.pairs import DEFAULT_VIEWS

    assert ds.select(None, default=DEFAULT_VIEWS) == ds.grid.select(DEFAULT_VIEWS, ds.captured_views())
    with pytest.raises(InputError, match="--views"):
        ds.select("banana", field_name="--views")
