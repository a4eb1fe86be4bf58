"""Which views and which pairs the self-calibration uses.

A *horizontal* pair is two views of the same row (their rows must line up after rectification),
a *vertical* pair two views of the same column (their columns must line up).

Views: the default is a 5 × 5 array spread over the whole grid (rows and columns from first to last,
capped by the grid), denser than the paper's 2 × 3 (still available as ``"2x3"``): the rig's
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

import re
from dataclasses import dataclass
from itertools import combinations
from typing import Iterable, Sequence

from lfstudio.errors import InputError

View = tuple[int, int]   # (row, column)

PAIR_SETS = ("all", "spanning", "neighbours")
#: the default array, (views along the short axis of the grid, views along the long axis)
DEFAULT_ARRAY = (5, 5)


@dataclass(frozen=True)
class Pair:
    a: View                # left (horizontal) or upper (vertical) view
    b: View
    direction: str         # "h" | "v"
    baseline_mm: float = 0.0

    @property
    def steps(self) -> int:
        return abs(self.b[1] - self.a[1]) if self.direction == "h" else abs(self.b[0] - self.a[0])


def spread_indices(n_total: int, n_pick: int) -> list[int]:
    """``n_pick`` indices spread evenly over ``0 … n_total−1`` including both ends."""
    if n_pick <= 1 or n_total <= 1:
        return [0] if n_total >= 1 and n_pick >= 1 else []
    n_pick = min(n_pick, n_total)
    return sorted({round(i * (n_total - 1) / (n_pick - 1)) for i in range(n_pick)})


def _nearest(index: int, available: Sequence[int]) -> int:
    return min(available, key=lambda a: (abs(a - index), a))


def sparse_subset(columns: int, rows: int, n_rows: int = 2, n_columns: int = 3,
                  available: Iterable[View] | None = None) -> list[View]:
    """The ``n_rows × n_columns`` array spread over the grid (the paper uses 2 × 3).

    With ``available`` (views that have images), each chosen row/column index snaps to the nearest
    index whose whole sub-array is available where possible, otherwise views are dropped.
    """
    want_rows = spread_indices(rows, n_rows)
    want_cols = spread_indices(columns, n_columns)
    if available is None:
        return [(r, c) for r in want_rows for c in want_cols]
    avail = set(available)
    rows_av = sorted({r for r, _ in avail})
    cols_av = sorted({c for _, c in avail})
    if not rows_av:
        return []
    pick_rows = sorted({_nearest(r, rows_av) for r in want_rows})
    pick_cols = sorted({_nearest(c, cols_av) for c in want_cols})
    return [(r, c) for r in pick_rows for c in pick_cols if (r, c) in avail]


def default_subset(columns: int, rows: int, available: Iterable[View] | None = None) -> list[View]:
    """The default array (:data:`DEFAULT_ARRAY`: 5 × 5 spread over the grid), capped by the grid."""
    short, long_ = DEFAULT_ARRAY
    n_rows, n_cols = (min(short, rows), min(long_, columns)) if columns >= rows else \
        (min(long_, rows), min(short, columns))
    return sparse_subset(columns, rows, n_rows, n_cols, available)


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
        pairs += [Pair((r, c1), (r, c2), "h", (c2 - c1) * float(spacing_mm[0])) for c1, c2 in combos]
    for c, rws in sorted(by_col.items()):
        combos = line_pairs(rws, pair_set)
        combos = combos[:max_pairs_per_line] if max_pairs_per_line else combos
        pairs += [Pair((r1, c), (r2, c), "v", (r2 - r1) * float(spacing_mm[1])) for r1, r2 in combos]
    return pairs


_ARRAY = re.compile(r"^\s*(\d+)\s*[x×]\s*(\d+)\s*$")
_VIEW = re.compile(r"^\s*r(\d+)[_\s]*c(\d+)\s*$", re.IGNORECASE)


def parse_views(spec: str | None, columns: int, rows: int, available: Iterable[View]) -> list[View]:
    """Views from a user spec: ``"default"`` (the default array, see :func:`default_subset`; also
    None or empty), ``"2x3"`` (rows × columns spread over the grid), ``"all"``, or a comma list of
    view names ``"r00_c000,r00_c050,r20_c000"``."""
    avail = sorted(set(available))
    field = "--views"
    if spec is None or not spec.strip():
        spec = "default"
    text = spec.strip().lower()
    if text == "all":
        return avail
    if text == "default":
        return default_subset(columns, rows, avail)
    m = _ARRAY.match(text)
    if m:
        n_rows, n_cols = int(m.group(1)), int(m.group(2))
        if n_rows < 1 or n_cols < 1:
            raise InputError(field, f"{spec!r} needs at least one row and one column", "e.g. 2x3")
        return sparse_subset(columns, rows, n_rows, n_cols, avail)
    out: list[View] = []
    for part in text.split(","):
        mv = _VIEW.match(part)
        if not mv:
            raise InputError(field, f"cannot read {part.strip()!r}",
                             "ROWSxCOLUMNS like 2x3, 'default', 'all', or view names like r00_c000,r00_c050")
        v = (int(mv.group(1)), int(mv.group(2)))
        if v not in set(avail):
            raise InputError(field, f"view r{v[0]:02d}_c{v[1]:03d} has no captured image in this dataset")
        out.append(v)
    return sorted(set(out))
