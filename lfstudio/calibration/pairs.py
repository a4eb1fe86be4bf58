"""Which views and which pairs the self-calibration uses.

A *horizontal* pair is two views of the same row (their rows must line up after rectification),
a *vertical* pair two views of the same column (their columns must line up).

Views (chosen by :meth:`lfstudio.dataset.Dataset.select`): the default (:data:`DEFAULT_VIEWS`,
``"array:4ex10"``, COLUMNSxROWS) is the first two and the last two columns × ten rows spread over
the grid, capped by
the grid. Why: on a translating rig the roll (the rotation about the optical axis) cannot be told
from a straight line through the views' position errors (a camera ``η`` mm off its row shifts a
horizontal pair's matches exactly as a roll of ``η / baseline`` does), so the rig's position noise,
not the features, sets its accuracy, and only more views far apart average it down: the roll's
information is Σ (x − x̄)² over the views of each row, largest with the views at the two ends of the
rows (each end measured twice, every row adding its own). Simulated on the reference rig
(``benchmarks/calibration_accuracy.py``, 80 µm position noise): the true rectification error is
0.072 px RMS with a 5 × 5 array spread evenly (100 pairs) and 0.043 px RMS with the default (40
views, 156 pairs); with exact features it is the same (the features are not the limit). The
paper's 2 × 3 is still available as ``"array:3x2"`` (3 columns, 2 rows); denser arrays and explicit view lists work too.

Pair sets within each row and column of the chosen views (:data:`PAIR_SETS`):

- ``"spanning"`` (default, :data:`DEFAULT_PAIR_SET`): neighbours (short baselines: small
  disparities, robust matching) plus every pair with an end view (the full-row/column pair, the
  longest baseline, which fixes pan and tilt); for rows of the default's four views every pair;
- ``"all"``: every combination (more pairs, the same longest baselines);
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
#: the views the calibration uses without a selection (of :meth:`lfstudio.dataset.grid.Grid.select`):
#: ten rows spread over the grid × the first two and the last two columns, capped by the grid
DEFAULT_VIEWS = "array:4ex10"
#: the pair set the calibration uses without one
DEFAULT_PAIR_SET = "spanning"


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
