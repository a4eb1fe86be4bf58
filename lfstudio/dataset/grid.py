"""The grid of camera positions and a view on it: the typed model every stage uses.

- :class:`View`: a cell of the grid, ``(row, column)`` (a tuple, so it sorts row-major and unpacks
  as ``r, c = view``), with its name ``r07_c042`` (:func:`lfstudio.dataset.paths.view_stem`) and
  :meth:`View.parse` of such a name;
- :class:`Grid`: columns × rows, spacing, origin and scan order as ``dataset.json`` → ``grid``
  stores them (:meth:`Grid.from_manifest`; the file's format does not change), the commanded
  position of a view, the baselines, an array of views spread over the grid (:meth:`Grid.spread`)
  and the one reader of a view selection (:meth:`Grid.select`), which ``Dataset.select``, the
  calibration, the export and the quality check share.

The order views are taken in (``Grid.order``, :func:`grid_order`): ``row-meander`` (row 0 left→right,
row 1 right→left, ...: the paper's meander and the default), ``column-meander`` (column 0
top→bottom, column 1 bottom→top, ...) or ``raster`` (every row left→right).

A selection (``spec``) is ``"all"``; rows/columns ranges ``"r0-8,c10-18"``, ``"r3"``,
``"c0-4,c10"`` (the available views in those rows and columns); an array ``"array:3x2"``
(COLUMNSxROWS like every grid-shaped value: 3 columns by 2 rows spread over the grid, each snapped
to available views; an ``e`` after a count puts those columns or rows at the ends of the grid
instead, half at each end, side by side: ``"array:4ex10"`` is the first two and last two columns ×
ten rows spread over the grid; a square one may be written ``"5x5"``); view names
``"r00_c000,r00_c050"``; or a sequence of (row, column). ``None``/``""`` mean the caller's default.

A bare non-square ``"2x3"`` is refused with the new form: arrays used to be ROWSxCOLUMNS, and
reading an existing script's ``2x3`` as 2 columns would silently choose other views.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, Iterable, NamedTuple, Sequence

from lfstudio.dataset.paths import parse_view_stem, view_label, view_stem
from lfstudio.errors import InputError

#: what a selection may be (shown when one cannot be read)
SELECTION_SYNTAX = ("'all', rows/columns like r0-8,c10-18, an array like array:5x3 (columns x rows; array:4ex10: "
                    "the columns at the ends), or view names like r00_c000,r00_c050")
_ARRAY = re.compile(r"^\s*(array\s*:)?\s*(\d+)\s*(e?)\s*[x×]\s*(\d+)\s*(e?)\s*$", re.IGNORECASE)
_RANGE_PART = re.compile(r"^\s*([rc])\s*(\d+)\s*(?:-\s*(\d+))?\s*$", re.IGNORECASE)


ORDERS = ("row-meander", "column-meander", "raster")
DEFAULT_ORDER = "row-meander"


def grid_order(columns: int, rows: int, order: str = DEFAULT_ORDER) -> list[tuple[int, int]]:
    """Every ``(row, column)`` of a ``columns`` x ``rows`` grid in capture ``order`` (:data:`ORDERS`)."""
    if order == "row-meander":
        return [(r, c if r % 2 == 0 else columns - 1 - c) for r in range(rows) for c in range(columns)]
    if order == "column-meander":
        return [(r if c % 2 == 0 else rows - 1 - r, c) for c in range(columns) for r in range(rows)]
    if order == "raster":
        return [(r, c) for r in range(rows) for c in range(columns)]
    raise InputError("order", f"unknown scan order {order!r}", ", ".join(ORDERS))


class View(NamedTuple):
    """A cell of the grid (row 0 at the top, column 0 at the left)."""

    row: int
    column: int

    @property
    def name(self) -> str:
        """``r07_c042``: the stem of the view's files."""
        return view_stem(self.row, self.column)

    @property
    def label(self) -> str:
        """``r07 c042``: the view as messages and the GUI name it."""
        return view_label(self.row, self.column)

    @classmethod
    def parse(cls, name: str) -> "View":
        """The view a name like ``r07_c042`` (also ``r7c42``, ``R07 C042``) stands for; ValueError if none."""
        return cls(*parse_view_stem(name))


def spread_indices(n_total: int, n_pick: int) -> list[int]:
    """``n_pick`` indices spread evenly over ``0 … n_total−1`` including both ends."""
    if n_pick <= 1 or n_total <= 1:
        return [0] if n_total >= 1 and n_pick >= 1 else []
    n_pick = min(n_pick, n_total)
    return sorted({round(i * (n_total - 1) / (n_pick - 1)) for i in range(n_pick)})


def end_indices(n_total: int, n_pick: int) -> list[int]:
    """``n_pick`` indices at the two ends of ``0 … n_total−1``, side by side: the first ⌈n/2⌉ and
    the last ⌊n/2⌋ (the longest baselines, each end measured more than once)."""
    n_pick = max(0, min(n_pick, n_total))
    first = (n_pick + 1) // 2
    return sorted(set(range(first)) | set(range(n_total - (n_pick - first), n_total)))


def _nearest(index: int, available: Sequence[int]) -> int:
    return min(available, key=lambda a: (abs(a - index), a))


@dataclass(frozen=True)
class Grid:
    columns: int
    rows: int
    spacing_mm: tuple[float, float] | None = None      # (horizontal, vertical) between neighbours; None: unknown
    origin_mm: tuple[float, float] | None = None       # position of view (0, 0); None: not recorded
    order: str | None = None                           # the order views were taken (docs/dataset-format.md); None: unknown
    settle_s: float | None = None                      # the scan's settle time, when a scan recorded it
    extra: dict[str, Any] = field(default_factory=dict, compare=False)   # other keys of the manifest's grid

    @classmethod
    def from_manifest(cls, grid: dict[str, Any]) -> "Grid":
        """The typed grid of ``dataset.json`` → ``grid`` (validated by the manifest's reader)."""
        known = {"columns", "rows", "spacing_mm", "origin_mm", "order", "settle_s"}
        origin, spacing = grid.get("origin_mm"), grid.get("spacing_mm")
        return cls(int(grid["columns"]), int(grid["rows"]),
                   None if spacing is None else (float(spacing[0]), float(spacing[1])),
                   None if origin is None else (float(origin[0]), float(origin[1])),
                   None if grid.get("order") is None else str(grid["order"]),
                   None if grid.get("settle_s") is None else float(grid["settle_s"]),
                   {k: v for k, v in grid.items() if k not in known})

    def to_manifest(self) -> dict[str, Any]:
        """``dataset.json`` → ``grid`` (the inverse of :meth:`from_manifest`; unknown values left out)."""
        out: dict[str, Any] = {"columns": self.columns, "rows": self.rows}
        if self.spacing_mm is not None:
            out["spacing_mm"] = list(self.spacing_mm)
        if self.origin_mm is not None:
            out["origin_mm"] = list(self.origin_mm)
        if self.order is not None:
            out["order"] = self.order
        if self.settle_s is not None:
            out["settle_s"] = self.settle_s
        return {**out, **self.extra}

    # -- cells -------------------------------------------------------------------------------------
    def views(self) -> list[View]:
        """Every cell, row-major."""
        return [View(r, c) for r in range(self.rows) for c in range(self.columns)]

    def in_order(self) -> list[View]:
        """Every cell in the order the views are taken (:func:`grid_order`; the default when unknown)."""
        return [View(r, c) for r, c in grid_order(self.columns, self.rows, self.order or DEFAULT_ORDER)]

    def __contains__(self, view: object) -> bool:
        return isinstance(view, tuple) and len(view) == 2 and 0 <= view[0] < self.rows and 0 <= view[1] < self.columns

    @property
    def centre(self) -> View:
        return View((self.rows - 1) // 2, (self.columns - 1) // 2)

    @property
    def step_mm(self) -> tuple[float, float]:
        """The spacing, or 1 mm each way when the manifest records none (baselines in grid steps)."""
        return self.spacing_mm or (1.0, 1.0)

    def position_mm(self, view: Sequence[int]) -> tuple[float, float]:
        """Commanded position of a view: origin + (column × horizontal, row × vertical step)."""
        (ox, oy), (sx, sy) = self.origin_mm or (0.0, 0.0), self.step_mm
        return ox + view[1] * sx, oy + view[0] * sy

    @property
    def baselines_mm(self) -> tuple[float | None, float | None]:
        """Baselines of a full row and a full column (None for a single column / row)."""
        sx, sy = self.step_mm
        return ((self.columns - 1) * sx if self.columns > 1 else None, (self.rows - 1) * sy if self.rows > 1 else None)

    def spread(self, n_rows: int, n_columns: int, available: Iterable[Sequence[int]] | None = None, *,
               ends: tuple[bool, bool] = (False, False)) -> list[View]:
        """An ``n_rows × n_columns`` array spread over the grid, first to last row and column (the
        paper's calibration uses 2 × 3); ``ends`` (rows, columns): those at the two ends instead
        (:func:`end_indices`). With ``available`` (views that have images), each chosen
        row/column index snaps to the nearest index whose views are available where possible
        (at the ends: the outermost available ones), otherwise views are dropped."""
        if available is None:
            want_rows = (end_indices if ends[0] else spread_indices)(self.rows, n_rows)
            want_cols = (end_indices if ends[1] else spread_indices)(self.columns, n_columns)
            return [View(r, c) for r in want_rows for c in want_cols]
        avail = {View(*v) for v in available}
        rows_av = sorted({v.row for v in avail})
        cols_av = sorted({v.column for v in avail})
        if not rows_av:
            return []

        def pick(n_total: int, n: int, have: list[int], at_ends: bool) -> list[int]:
            if at_ends:
                return [have[i] for i in end_indices(len(have), n)]
            return sorted({_nearest(i, have) for i in spread_indices(n_total, n)})

        pick_rows = pick(self.rows, n_rows, rows_av, ends[0])
        pick_cols = pick(self.columns, n_columns, cols_av, ends[1])
        return [View(r, c) for r in pick_rows for c in pick_cols if (r, c) in avail]

    # -- a selection -------------------------------------------------------------------------------
    def select(self, spec: str | Iterable[Sequence[int]] | None, available: Iterable[Sequence[int]], *,
               default: str = "all", field_name: str = "views") -> list[View]:
        """The views ``spec`` chooses among ``available`` (see the module docstring), row-major;
        ``None``/``""``/``"default"``: ``default``. :class:`InputError` naming ``field_name`` when the
        spec cannot be read, leaves the grid, selects nothing or names a view without an image."""
        avail = sorted({View(int(r), int(c)) for r, c in available})
        if spec is not None and not isinstance(spec, str):
            return self._chosen(spec, avail, field_name)
        text = (spec or "").strip()
        if not text or text.lower() == "default":
            text = default
        if text.lower() == "all":
            return avail
        m = _ARRAY.match(text)
        if m:
            (n_cols, cols_e), (n_rows, rows_e) = (int(m.group(2)), m.group(3)), (int(m.group(4)), m.group(5))
            if not m.group(1) and (n_cols, cols_e.lower()) != (n_rows, rows_e.lower()):
                # ROWSxCOLUMNS before: never read it the other way
                new = f"array:{n_rows}{rows_e}x{n_cols}{cols_e}"
                raise InputError(field_name, f"{text!r}: an array is written array:COLUMNSxROWS, like every grid "
                                 "(a bare RxC was rows x columns)",
                                 f"{new} for {n_rows} columns by {n_cols} rows")
            if n_rows < 1 or n_cols < 1:
                raise InputError(field_name, f"{text!r} needs at least one column and one row", "e.g. array:3x2")
            return self.spread(n_rows, n_cols, avail, ends=(bool(rows_e), bool(cols_e)))
        ranges = self._ranges(text, field_name)
        if ranges is not None:
            rows, cols = ranges
            out = [v for v in avail if (rows is None or v.row in rows) and (cols is None or v.column in cols)]
            if not out:
                raise InputError(field_name, f"{text!r} selects no captured view", "rows/columns with captures")
            return out
        have = set(avail)
        out = []
        for part in text.split(","):
            try:
                view = View.parse(part)
            except ValueError:
                raise InputError(field_name, f"cannot read {part.strip()!r}", SELECTION_SYNTAX) from None
            if view not in have:
                raise InputError(field_name, f"view {view.name} has no captured image in this dataset")
            out.append(view)
        return sorted(set(out))

    def _ranges(self, text: str, field_name: str) -> tuple[set[int] | None, set[int] | None] | None:
        """``"r0-8,c10-18"`` → (rows, columns) inside the grid; None when ``text`` is not ranges."""
        rows: set[int] | None = None
        cols: set[int] | None = None
        for part in text.split(","):
            m = _RANGE_PART.match(part)
            if not m:
                return None
            lo = int(m.group(2))
            hi = int(m.group(3)) if m.group(3) is not None else lo
            if hi < lo:
                raise InputError(field_name, f"{part.strip()!r}: range runs backwards", "e.g. r0-8,c10-18")
            values = set(range(lo, hi + 1))
            if m.group(1).lower() == "r":
                rows = (rows or set()) | values
            else:
                cols = (cols or set()) | values
        for name, chosen, n in (("rows", rows, self.rows), ("columns", cols, self.columns)):
            if chosen and max(chosen) >= n:
                raise InputError(field_name, f"{name} up to {max(chosen)} asked, the grid has {n} {name}",
                                 f"{name} 0-{n - 1}")
        return rows, cols

    @staticmethod
    def _chosen(views: Iterable[Sequence[int]], avail: list[View], field_name: str) -> list[View]:
        chosen = sorted({View(int(r), int(c)) for r, c in views})
        if not chosen:
            raise InputError(field_name, "no view chosen", "at least one captured view")
        have = set(avail)
        missing = [v.name for v in chosen if v not in have]
        if missing:
            shown = ", ".join(missing[:8]) + (f" and {len(missing) - 8} more" if len(missing) > 8 else "")
            raise InputError(field_name, f"no captured image for {shown}", "captured views of this dataset")
        return chosen
