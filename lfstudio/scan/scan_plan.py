"""The scan plan: which grid positions, where in the rig's travel, in which order. Pure data.

Rows and columns count from 0; row 0 is the top row (y = origin_y), column 0 the leftmost
(x = origin_x). View (row r, column c) is commanded to
``(origin_x + c * spacing_x, origin_y + r * spacing_y)`` in mm in the rig's frame
(:meth:`lfstudio.dataset.grid.Grid.position_mm`). The orders (``row-meander`` by default,
``column-meander``, ``raster``) are the dataset model's (:func:`lfstudio.dataset.grid.grid_order`).

A plan may be restricted to a ``subset`` of grid cells (re-capture, resume); the order of the
remaining views is the order of the full grid with the others left out.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Iterable

from lfstudio.dataset.bracket import Bracket
from lfstudio.dataset.grid import DEFAULT_ORDER, ORDERS, Grid, View, grid_order
from lfstudio.errors import InputError
from lfstudio.numbers import OFFSET_MM, SETTLE_S, SPACING_MM, Number, check_grid
from lfstudio.rig.motion import RigConfig

__all__ = ["DEFAULT_ORDER", "ORDERS", "PlannedView", "ScanPlan", "grid_order"]


@dataclass(frozen=True)
class PlannedView:
    """One position of the scan, in capture order (``index`` counts from 0 over the plan's views)."""

    index: int
    row: int
    column: int
    x_mm: float
    y_mm: float

    @property
    def view(self) -> View:
        """The grid cell (:class:`lfstudio.dataset.grid.View`: its name, its place in the grid)."""
        return View(self.row, self.column)

    @property
    def position_mm(self) -> tuple[float, float]:
        return (self.x_mm, self.y_mm)

    @property
    def cell(self) -> tuple[int, int]:
        return (self.row, self.column)


@dataclass(frozen=True)
class ScanPlan:
    """A grid of camera positions and the order to visit them."""

    columns: int
    rows: int
    spacing_mm: tuple[float, float]            # (horizontal, vertical) distance between neighbours
    origin_mm: tuple[float, float] = (0.0, 0.0)   # position of view (row 0, column 0)
    order: str = DEFAULT_ORDER
    settle_s: float = 0.3
    subset: frozenset[tuple[int, int]] | None = field(default=None)   # (row, column) cells; None: all
    #: an exposure bracket taken at every view (None: one picture per view as the camera is set)
    bracket: Bracket | None = None

    def __post_init__(self) -> None:
        for name, val in (("grid columns", self.columns), ("grid rows", self.rows)):
            if not isinstance(val, int) or isinstance(val, bool) or val < 1:
                raise InputError(name, f"must be a positive whole number, got {val!r}", "1 or more")
        check_grid("grid", self.columns, self.rows)          # bounded before any view is listed
        sx, sy = ((SPACING_MM if count > 1 else Number("mm")).check(f"{axis} spacing_mm", v)   # one view: any
                  for axis, v, count in (("horizontal", self.spacing_mm[0], self.columns),
                                         ("vertical", self.spacing_mm[1], self.rows)))
        if self.order not in ORDERS:
            raise InputError("order", f"unknown scan order {self.order!r}", ", ".join(ORDERS))
        SETTLE_S.check("settle_s", self.settle_s)
        object.__setattr__(self, "spacing_mm", (sx, sy))
        object.__setattr__(self, "origin_mm", tuple(OFFSET_MM.check(f"{axis} origin_mm", v)
                                                    for axis, v in zip(("horizontal", "vertical"), self.origin_mm)))
        if self.subset is not None:
            cells = frozenset((int(r), int(c)) for r, c in self.subset)
            bad = sorted(rc for rc in cells if not (0 <= rc[0] < self.rows and 0 <= rc[1] < self.columns))
            if bad:
                raise InputError("subset", f"view row {bad[0][0]}, column {bad[0][1]} is outside the "
                                 f"{self.columns} x {self.rows} grid",
                                 f"rows 0-{self.rows - 1}, columns 0-{self.columns - 1}")
            object.__setattr__(self, "subset", cells)

    # -- construction -------------------------------------------------------------------------------
    @classmethod
    def centered(cls, columns: int, rows: int, spacing_mm: tuple[float, float], rig: RigConfig, *,
                 offset_mm: tuple[float, float] = (0.0, 0.0), order: str = DEFAULT_ORDER,
                 settle_s: float | None = None, subset: Iterable[tuple[int, int]] | None = None,
                 check: bool = True) -> "ScanPlan":
        """A grid centred in the rig's soft-limit range, shifted by ``offset_mm``; checked against
        the limits (raises :class:`InputError` naming the field) unless ``check`` is False."""
        h, v = rig.horizontal, rig.vertical
        sx, sy = float(spacing_mm[0]), float(spacing_mm[1])
        x0 = (h.soft_min_mm + h.soft_max_mm) / 2 - (columns - 1) * sx / 2 + float(offset_mm[0])
        y0 = (v.soft_min_mm + v.soft_max_mm) / 2 - (rows - 1) * sy / 2 + float(offset_mm[1])
        if settle_s is None:
            settle_s = max(h.settle_s, v.settle_s)
        plan = cls(columns, rows, (sx, sy), (x0, y0), order, float(settle_s),
                   None if subset is None else frozenset(subset))
        if check:
            plan.check_limits(rig)
        return plan

    @classmethod
    def from_scene_plan(cls, scene_plan: Any, rig: RigConfig, *, order: str | None = None,
                        offset_mm: tuple[float, float] = (0.0, 0.0), settle_s: float | None = None) -> "ScanPlan":
        """The scan of a planner plan (``lfstudio.planning.scene_plan.ScenePlan`` or its grid dict):
        its grid and spacing centred in the rig's travel."""
        try:
            grid = getattr(scene_plan, "grid", None)
            if not isinstance(grid, Grid):
                grid = Grid.from_manifest(scene_plan.grid_dict() if hasattr(scene_plan, "grid_dict")
                                          else dict(scene_plan))
        except (KeyError, TypeError, ValueError, OverflowError):
            grid = None
        if grid is None or grid.spacing_mm is None:
            raise InputError("plan grid", "needs columns, rows and spacing_mm [h, v]")
        if settle_s is None:
            settle_s = grid.settle_s if grid.settle_s is not None else getattr(scene_plan, "settle_s", None)
        return cls.centered(grid.columns, grid.rows, grid.spacing_mm, rig, offset_mm=offset_mm,
                            order=order or grid.order or DEFAULT_ORDER, settle_s=settle_s)

    @classmethod
    def from_grid(cls, grid: Grid) -> "ScanPlan":
        """The scan of a dataset's grid (:attr:`lfstudio.dataset.Dataset.grid`)."""
        if grid.spacing_mm is None:
            raise InputError("grid", "the dataset's grid has no spacing_mm", "columns, rows, spacing_mm, origin_mm, order")
        return cls(grid.columns, grid.rows, grid.spacing_mm, grid.origin_mm or (0.0, 0.0), grid.order or DEFAULT_ORDER,
                   0.3 if grid.settle_s is None else grid.settle_s)

    @classmethod
    def from_grid_dict(cls, grid: dict[str, Any]) -> "ScanPlan":
        """The inverse of :meth:`grid_dict` (a dataset manifest's ``grid``)."""
        try:
            return cls.from_grid(Grid.from_manifest(grid))
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise InputError("grid", f"incomplete grid description ({exc})",
                             "columns, rows, spacing_mm, origin_mm, order") from None

    def with_subset(self, cells: Iterable[tuple[int, int]] | None) -> "ScanPlan":
        return replace(self, subset=None if cells is None else frozenset(cells))

    # -- queries ---------------------------------------------------------------------------------
    @property
    def total_cells(self) -> int:
        return self.columns * self.rows

    @property
    def grid(self) -> Grid:
        """The grid the plan covers (the dataset's model; what the manifest stores as ``grid``)."""
        return Grid(self.columns, self.rows, self.spacing_mm, self.origin_mm, self.order, self.settle_s)

    def position_mm(self, row: int, column: int) -> tuple[float, float]:
        return self.grid.position_mm((row, column))

    def extent_mm(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` of the full grid."""
        x0, y0 = self.origin_mm
        return (x0, x0 + (self.columns - 1) * self.spacing_mm[0], y0, y0 + (self.rows - 1) * self.spacing_mm[1])

    def views(self) -> list[PlannedView]:
        """The plan's views in capture order, with their commanded positions."""
        cells = grid_order(self.columns, self.rows, self.order)
        if self.subset is not None:
            cells = [rc for rc in cells if rc in self.subset]
        return [PlannedView(i, r, c, *self.position_mm(r, c)) for i, (r, c) in enumerate(cells)]

    def __len__(self) -> int:
        return self.total_cells if self.subset is None else len(self.subset)

    def path_mm(self) -> list[tuple[float, float]]:
        """The commanded positions in order (for drawing the path preview)."""
        return [v.position_mm for v in self.views()]

    def check_limits(self, rig: RigConfig) -> None:
        """Raise :class:`InputError` naming the field if any position lies outside the soft limits."""
        x_min, x_max, y_min, y_max = self.extent_mm()
        for side, axis, n, what, spacing in (("horizontal", rig.horizontal, self.columns, "columns", self.spacing_mm[0]),
                                             ("vertical", rig.vertical, self.rows, "rows", self.spacing_mm[1])):
            travel = axis.soft_max_mm - axis.soft_min_mm
            span = (n - 1) * spacing
            if span > travel + 1e-9:
                raise InputError(f"grid {what} / {side} spacing_mm",
                                 f"{n} {what} x {spacing:g} mm span {span:g} mm, more than "
                                 f"the {travel:g} mm {side} travel of {rig.label or rig.name}",
                                 f"at most {int(travel // max(spacing, 1e-9)) + 1} {what} at this spacing")
        for side, axis, lo, hi, coord in (("horizontal", rig.horizontal, x_min, x_max, "x"),
                                          ("vertical", rig.vertical, y_min, y_max, "y")):
            if not (axis.contains(lo, 1e-6) and axis.contains(hi, 1e-6)):
                raise InputError(f"{side} origin/offset_mm",
                                 f"the grid spans {coord} = {lo:g} … {hi:g} mm, outside the {side} soft limits",
                                 f"{axis.soft_min_mm:g} … {axis.soft_max_mm:g} mm")

    def grid_dict(self) -> dict[str, Any]:
        """The manifest's ``grid`` object."""
        return self.grid.to_manifest()

    def move_distances_mm(self) -> list[tuple[float, float]]:
        """(|dx|, |dy|) of each move between consecutive views (len = views - 1)."""
        path = self.path_mm()
        return [(abs(b[0] - a[0]), abs(b[1] - a[1])) for a, b in zip(path, path[1:])]

    def estimate_duration_s(self, rig: RigConfig, exposure_s: float, transfer_s: float,
                            pipelined: bool = True) -> float:
        """Critical-path duration of the scan (:func:`lfstudio.optics.scan_duration_s`): per view
        the longer axis move + settle, exposure and (pipelined) the transfer overlapping the next
        move and settle. With a bracket, the view's exposure is every frame's exposure (EV steps
        around ``exposure_s``) and the transfers between them (:func:`lfstudio.optics.bracket_camera_s`)."""
        from lfstudio.optics import bracket_camera_s, move_time_s, scan_duration_s

        if self.bracket is not None:
            exposure_s = bracket_camera_s(self.bracket.shutter_times_s(exposure_s), transfer_s)

        h, v = rig.horizontal, rig.vertical
        moves = [(0.0, 1)] + [(max(move_time_s(dx, h.max_speed_mm_s, h.acceleration_mm_s2),
                                   move_time_s(dy, v.max_speed_mm_s, v.acceleration_mm_s2)), 1)
                              for dx, dy in self.move_distances_mm()]
        return scan_duration_s(moves[:len(self)], self.settle_s, exposure_s, transfer_s, pipelined)
