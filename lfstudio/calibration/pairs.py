"""Which views and which pairs the self-calibration uses.

A *horizontal* pair is two views of the same row (their rows must line up after rectification),
a *vertical* pair two views of the same column (their columns must line up).

Views (chosen by :meth:`lfstudio.dataset.Dataset.select`): the default is a 5 × 5 array spread over
the whole grid (rows and columns from first to last, capped by the grid), denser than the paper's 2 × 3 (still available as ``"2x3"``): the rig's
position errors, not the features, limit the accuracy, and every further view averages them down
(simulated true error on the reference rig: 2 × 3 0.11 px, 3 × 5 0.077 px, 5 × 5 0.054 px, 5 × 9
0.045 px mean; see ``benchmarks/calibration_accuracy.py``), while detection and matching time grow with
the views and pairs (5 × 5 at 4000 px ≈ 35 CPU-s cold). Denser arrays and explicit view lists work too.

Pair sets within each row and column of the chosen views (:data:`PAIR_SETS`):

- ``"all"`` (default): every combination — the full-row/column pair (the longest baseline, which
  fixes pan and tilt), the neighbours (short baselines: small disparities, robust matching) and
  everything between;
- ``"spanning"``: neighbours plus every pair with an end view (fewer pairs, same longest baselines);
- ``"neighbours"``: adjacent views only. Degenerate: the shortest baselines cannot fix the rotation
  for the whole grid (the report warns with the expected error at the corners).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations
from typing import Iterable, Sequence

from lfstudio.dataset.grid import View
from lfstudio.errors import InputError

PAIR_SETS = ("all", "spanning", "neighbours")
#: the default array, (views along the short axis of the grid, views along the long axis)
DEFAULT_ARRAY = (5, 5)
#: the views the calibration uses without a selection: the default array spread over the grid,
#: capped by it (a selection of :meth:`lfstudio.dataset.grid.Grid.select`)
DEFAULT_VIEWS = f"{DEFAULT_ARRAY[0]}x{DEFAULT_ARRAY[1]}"


@dataclass(frozen=True)
class Pair:
    a: View                # left (horizontal) or upper (vertical) view
    b: View
    direction: str         # "h" | "v"
    baseline_mm: float = 0.0

    @property
    def steps(self) -> int:
        return abs(self.b[1] - self.a[1]) if self.direction == "h" else abs(self.b[0] - self.a[0])


def line_pairs(indices: Sequence[int], pair_set: str = "all") -> list[tuple[int, int]]:
    """Index pairs (i < j) of one row's columns or one column's rows for a pair set (:data:`PAIR_SETS`)."""
    idx = sorted(set(indices))
    if pair_set == "neighbours":
        return list(zip(idx, idx[1:]))
    if pair_set == "all":
        return list(combinations(idx, 2))
    if pair_set == "spanning":
        ends = {idx[0], idx[-1]} if idx else set()
        return sorted({(a, b) for a, b in zip(idx, idx[1:])} | {(a, b) for a, b in combinations(idx, 2)
                                                               if a in ends or b in ends})
    raise InputError("--pairs", f"unknown pair set {pair_set!r}", ", ".join(PAIR_SETS))


def make_pairs(views: Iterable[View], spacing_mm: Sequence[float] = (1.0, 1.0), *, pair_set: str = "all",
               neighbours_only: bool = False, max_pairs_per_line: int | None = None) -> list[Pair]:
    """Horizontal pairs within each row and vertical pairs within each column of ``views``.

    ``pair_set`` chooses which (:data:`PAIR_SETS`; default every combination, several baselines);
    ``neighbours_only`` is the older spelling of ``pair_set="neighbours"``. Pairs are ordered: rows
    first, then columns.
    """
    if neighbours_only:
        pair_set = "neighbours"
    vs = sorted(set(views))
    by_row: dict[int, list[int]] = {}
    by_col: dict[int, list[int]] = {}
    for r, c in vs:
        by_row.setdefault(r, []).append(c)
        by_col.setdefault(c, []).append(r)
    pairs: list[Pair] = []
    for r, cols in sorted(by_row.items()):
        combos = line_pairs(cols, pair_set)
        combos = combos[:max_pairs_per_line] if max_pairs_per_line else combos
        pairs += [Pair(View(r, c1), View(r, c2), "h", (c2 - c1) * float(spacing_mm[0])) for c1, c2 in combos]
    for c, rws in sorted(by_col.items()):
        combos = line_pairs(rws, pair_set)
        combos = combos[:max_pairs_per_line] if max_pairs_per_line else combos
        pairs += [Pair(View(r1, c), View(r2, c), "v", (r2 - r1) * float(spacing_mm[1])) for r1, r2 in combos]
    return pairs
