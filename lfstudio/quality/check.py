"""The dataset quality check: judge every view from its pixels and write ``quality.json`` + pictures.

``check_dataset(dataset, ...)`` is a long job (``progress``, ``cancel``). It decodes each view once,
in row-major order on a few threads (:mod:`lfstudio.quality.measure`), tracks its corners into the
neighbours decoded before it (:mod:`lfstudio.quality.tracks`), keeps only three rows of working
images in memory, then

* compares each view's focus and brightness with its 8 neighbours (sharpness, exposure) and
  reports the de-flicker gain against the processing profile's reference view;
* solves all tracks for the true position of every view and the depth of every track
  (:mod:`lfstudio.quality.positions`): the position error against the manifest (after the best
  global affine fit, outliers ignored), the per-view track residual after rectification, the rig's
  measured repeatability, and the scene's depth and neighbour-disparity range against the plan and
  the ``disp_min``/``disp_max`` the exports write;
* computes the disparity map of the centre view (:mod:`lfstudio.quality.disparity`).

It judges the pixels alone: checksums are not consulted, so a view edited after capture is judged by
what it now shows. :class:`GridCheck` holds the incremental state and is shared with the scan-time
checker (:mod:`lfstudio.quality.live`). The document layout is described in ``docs/quality.md``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from lfstudio.dataset.atomic import atomic_write_json
from lfstudio.dataset.manifest import is_done, now_iso
from lfstudio.dataset.paths import folder_inside, resolve_inside, view_stem
from lfstudio.dataset.zero_plane import ZeroPlane, zero_plane
from lfstudio.errors import DatasetError, LfError
from lfstudio.jobs import CancelToken, Progress, no_progress
from lfstudio.quality import verdicts
from lfstudio.quality.disparity import DisparityMap, disparity_map, partner_cells, steps_for
from lfstudio.quality.measure import DEFAULT_WORK_WIDTH_PX, ViewMeasures, bracket_frames, measure_view, \
    sharpness_ratio, exposure_ratio, deflicker_gain, with_frames
from lfstudio.quality.positions import fit_tracks, position_errors, solve_positions
from lfstudio.quality.tracks import WINDOW, Star, star_neighbours, to_observations, track_star
from lfstudio.quality.verdicts import Thresholds

log = logging.getLogger(__name__)

Cell = tuple[int, int]     # a grid cell (row, column); a dataset View is one
QUALITY_NAME = "quality.json"
PICTURES_FOLDER = "quality"
FORMAT = "lfstudio-quality"
VERSION = 1
#: the 8 views around a view: the ones its focus and brightness are compared with
RING: tuple[Cell, ...] = tuple((dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0))
MIN_TRACK_VIEWS = 3          # tracks seen in fewer views do not count for the depth range
RANGE_SIGMAS = 1.5           # see depth_range
PRECISE_FRACTION = 0.5       # the depth range uses this better-measured share of the tracks
SOLVE_TRACKS_PER_VIEW = 120  # tracks per view the position solve uses (all of them give the depths)


@dataclass
class Geometry:
    """What the manifest says about the grid: commanded positions, spacing, optics, the plan."""

    columns: int
    rows: int
    spacing_mm: tuple[float, float]
    commanded_mm: dict[Cell, tuple[float, float]]
    focal_length_sensor_px: float | None      # for an image as wide as the sensor (sensor_width_px)
    sensor_width_px: float | None
    near_m: float | None
    far_m: float | None
    repeatability_um: tuple[float, float]
    #: the views' zero-disparity plane (parallel for a scan; :mod:`lfstudio.dataset.zero_plane`)
    zero: ZeroPlane = field(default_factory=lambda: ZeroPlane(0.0, None))
    #: the positions are the rig's own record (imported with --positions): errors are measured against them
    recorded_positions: bool = False

    @classmethod
    def from_dataset(cls, ds) -> "Geometry":
        grid = ds.grid
        cols, rows = grid.columns, grid.rows
        spacing = grid.step_mm
        origin = (ds.manifest.get("rig") or {}).get("origin_mm") or (0.0, 0.0)
        commanded: dict[Cell, tuple[float, float]] = {}
        recorded = ds.positions_recorded        # an import's recorded positions, a fly scan's
        for v in ds.views:
            cell = (int(v["row"]), int(v["column"]))
            cmd = (v.get("reported_mm") if recorded else None) or v.get("commanded_mm")
            commanded[cell] = (float(cmd[0]), float(cmd[1])) if cmd else \
                (float(origin[0]) + cell[1] * spacing[0], float(origin[1]) + cell[0] * spacing[1])
        try:
            f_sensor = float(ds.focal_length_px())
        except DatasetError:
            f_sensor = None
        sensor = (ds.camera or {}).get("sensor_px") if isinstance(ds.camera, dict) else None
        sensor_w = float(sensor[0]) if isinstance(sensor, (list, tuple)) and sensor else None
        plan = ds.manifest.get("plan") or {}
        near, far = plan.get("near_m"), plan.get("far_m")
        near = float(near) if isinstance(near, (int, float)) and near > 0 else None
        far = float(far) if isinstance(far, (int, float)) and far > 0 else None
        rep = plan.get("repeatability_um")
        if rep is None and recorded:    # an imported rig's own record: the scatter it logged
            rep = ((ds.manifest.get("import") or {}).get("positions") or {}).get("logged_repeatability_um")
        rep = (float(rep[0]), float(rep[1])) if isinstance(rep, (list, tuple)) and len(rep) == 2 else \
            verdicts.DEFAULT_REPEATABILITY_UM
        return cls(cols, rows, (spacing[0], spacing[1]), commanded, f_sensor, sensor_w, near, far, rep,
                   zero_plane(ds), recorded)

    def shear_work(self, m: "ViewMeasures") -> float:
        """The views' shear in working px per mm of ``m``'s working image (0: parallel or not known)."""
        return self.zero.shear_or_zero(m.full_size_px[0]) / m.work_scale

    def focal_length_px(self, image_width_px: float) -> float | None:
        """The focal length in pixels of a capture ``image_width_px`` wide (None: the manifest lacks it)."""
        if self.focal_length_sensor_px is None:
            return None
        return self.focal_length_sensor_px * (image_width_px / self.sensor_width_px if self.sensor_width_px else 1.0)

    def guess_depth_m(self) -> float:
        if self.near_m and self.far_m:
            return 2.0 / (1.0 / self.near_m + 1.0 / self.far_m)
        return self.near_m or self.far_m or 1e6


@dataclass
class PositionFit:
    """Positions, errors and residuals of a set of views, from one solve."""

    cells: list[Cell]
    measured_mm: dict[Cell, tuple[float, float]]
    error_mm: dict[Cell, tuple[float, float]]
    inlier: dict[Cell, bool]                       # not an outlier of the global affine fit
    residual_rms_px: dict[Cell, float]             # full-resolution px
    tracks: dict[Cell, int]
    s_px_per_mm: np.ndarray                        # working px per mm, per track (NaN: undetermined)
    s_sigma: np.ndarray                            # its standard error
    track_views: np.ndarray                        # how many views see each track
    sigma_px: float

    def typical_residual_px(self) -> float | None:
        return float(np.median(list(self.residual_rms_px.values()))) if self.residual_rms_px else None


class GridCheck:
    """Measured views of one dataset, their neighbour tracks, and the judgements built from them."""

    def __init__(self, geometry: Geometry, thresholds: Thresholds | None = None, *,
                 homography_full: np.ndarray | None = None, calibration_size_px: Sequence[int] | None = None):
        self.geometry = geometry
        self.thresholds = thresholds or Thresholds()
        self.homography_full = homography_full
        self.calibration_size_px = tuple(calibration_size_px) if calibration_size_px is not None else None
        self.measures: dict[Cell, ViewMeasures] = {}
        self.stars: dict[Cell, Star] = {}
        self._h_work: dict[tuple[int, int], np.ndarray | None] = {}

    # -- geometry of the working images ---------------------------------------------------------------
    def homography_work(self, m: ViewMeasures) -> np.ndarray | None:
        """The rectifying homography for ``m``'s working image (None without a calibration)."""
        if self.homography_full is None or m.grey8 is None:
            return None
        size = m.work_size_px
        if size not in self._h_work:
            from lfstudio.calibration.model import pixel_scale_matrix
            full = self.calibration_size_px or m.full_size_px
            # calibration pixels → this capture's full pixels → working pixels
            S_cal = pixel_scale_matrix(m.full_size_px[0] / float(full[0]))
            S_work = pixel_scale_matrix(1.0 / m.work_scale)
            to_work = S_work @ S_cal
            self._h_work[size] = to_work @ self.homography_full @ np.linalg.inv(to_work)
        return self._h_work[size]

    def focal_length_work_px(self, m: ViewMeasures) -> float | None:
        f = self.geometry.focal_length_px(m.full_size_px[0])
        return None if f is None else f / m.work_scale

    # -- incremental ---------------------------------------------------------------------------------
    def add(self, m: ViewMeasures, known: Callable[[Cell], bool] | None = None) -> Star:
        """Store ``m`` and track it into the neighbours ``known`` accepts (default: every stored one
        that still has its working image)."""
        if m.cell in self.stars:
            # a view captured again: what other views tracked into its old image no longer holds
            for star in list(self.stars.values()):
                if m.cell in star.neighbours:
                    star.xy[1 + star.neighbours.index(m.cell)] = np.nan
        self.measures[m.cell] = m
        ok = known or (lambda c: c in self.measures and c != m.cell)
        nbs = [c for c in star_neighbours(m.cell, lambda c: ok(c) and c in self.measures
                                          and self.measures[c].grey8 is not None)]
        f_work = self.focal_length_work_px(m) or float(m.work_size_px[0])
        here = self.geometry.commanded_mm.get(m.cell, (0.0, 0.0))
        offsets = [tuple(np.subtract(self.geometry.commanded_mm.get(c, here), here)) for c in nbs]
        shear = self.geometry.shear_work(m)
        guess = self.geometry.guess_depth_m()
        if shear > 0 and not (self.geometry.near_m or self.geometry.far_m):
            guess = f_work / (1000.0 * shear)      # sheared views: start at the zero plane (no shift)
        star = track_star(m, [self.measures[c] for c in nbs], offsets, f_work, guess, shear)
        self.stars[m.cell] = star
        return star

    def drop_images(self, keep: Callable[[Cell], bool]) -> None:
        for cell, m in list(self.measures.items()):       # reading threads may be adding views
            if m.grey8 is not None and not keep(cell):
                m.grey8 = None

    def ring(self, cell: Cell) -> list[ViewMeasures]:
        r, c = cell
        return [self.measures[(r + dr, c + dc)] for dr, dc in RING if (r + dr, c + dc) in self.measures]

    def relative(self, cell: Cell) -> tuple[float | None, float | None]:
        """(sharpness ratio, exposure ratio) of ``cell`` against its measured ring."""
        m = self.measures[cell]
        ring = self.ring(cell)
        return sharpness_ratio(m, ring), exposure_ratio(m, ring)

    def judge_view(self, cell: Cell, fit: "PositionFit | None", typical_residual_px: float | None,
                   near_m: float | None, deflicker_gain: float | None = None) -> dict[str, Any]:
        """The ``quality.json`` entry of a measured view: every check with its verdict and why."""
        t, g = self.thresholds, self.geometry
        m = self.measures[cell]
        sharp, expo = self.relative(cell)
        err = fit.error_mm.get(cell) if fit is not None else None
        f_full = g.focal_length_px(m.full_size_px[0])
        err_px = f_full * math.hypot(*err) / (1000.0 * near_m) if err is not None and near_m and f_full else None
        checks = {
            "sharpness": verdicts.sharpness(sharp, t),
            "exposure": verdicts.exposure(expo, t, deflicker_gain),
            "clipping": verdicts.clipping(m.clipped_fraction, m.crushed_fraction, t) if not m.frames
            else verdicts.bracket_clipping(m.frames, t),
            "position": verdicts.position(err, t.position_limits_mm(g.repeatability_um, g.spacing_mm), err_px,
                                          fit.measured_mm.get(cell) if fit is not None else None),
            "residual": verdicts.residual(fit.residual_rms_px.get(cell) if fit is not None else None,
                                          typical_residual_px, t),
        }
        if g.recorded_positions:
            checks["position"]["why"] = checks["position"]["why"].replace("where the manifest says",
                                                                          "where the rig recorded it")
            checks["position"]["against"] = "recorded"
        checks["exposure"]["level"] = m.level
        checks["position"]["tracks"] = fit.tracks.get(cell, 0) if fit is not None else 0
        reasons = [f"{name}: {c['why']}" for name, c in checks.items()
                   if c["verdict"] in (verdicts.WARN, verdicts.FAIL)]
        return {"row": cell[0], "column": cell[1], "view": view_stem(*cell),
                "verdict": verdicts.worst(c["verdict"] for c in checks.values()), "status": "done",
                "reasons": reasons, "checks": checks}

    # -- positions -----------------------------------------------------------------------------------
    def solve(self, cells: Iterable[Cell] | None = None, fixed: Iterable[Cell] = (),
              known_mm: dict[Cell, tuple[float, float]] | None = None) -> PositionFit:
        """Solve the positions of ``cells`` (default: all measured) from the stars among them.

        Without ``fixed`` views the errors are taken after the robust global affine fit; ``fixed``
        views keep their ``known_mm`` position (default: the commanded one) and anchor the frame, so
        the other views' errors are their positions minus the commanded ones."""
        cells = sorted(self.measures if cells is None else (c for c in cells if c in self.measures))
        index = {c: i for i, c in enumerate(cells)}
        H = next((self.homography_work(self.measures[c]) for c in cells if self.measures[c].grey8 is not None),
                 next(iter(self._h_work.values()), None))
        stars = [self.stars[c] for c in cells if c in self.stars]
        obs = to_observations(stars, index, H)
        few = to_observations(stars, index, H, max_per_star=SOLVE_TRACKS_PER_VIEW)
        known = known_mm or {}
        if cells and self.geometry.zero.shear_or_zero() != 0.0:
            # sheared views: take the shear (shear · position, as the archive applied it) off every point,
            # so the tracks follow the parallel model of every scan (the zero plane back at infinity)
            shear = self.geometry.shear_work(self.measures[cells[0]])
            q = np.array([self.geometry.commanded_mm.get(c, (0.0, 0.0)) for c in cells], float).reshape(-1, 2)
            for o in (obs, few):
                if o.count:
                    o.xy = o.xy - shear * q[o.view]
        initial = np.array([known.get(c, self.geometry.commanded_mm.get(c, (0.0, 0.0))) for c in cells],
                           float).reshape(-1, 2)
        fixed_set = set(fixed)
        sol = solve_positions(few, initial, fixed=np.array([c in fixed_set for c in cells], bool))
        commanded = np.array([self.geometry.commanded_mm.get(c, (0.0, 0.0)) for c in cells], float).reshape(-1, 2)
        measured = {c: (float(sol.positions_mm[i, 0]), float(sol.positions_mm[i, 1])) for c, i in index.items()}
        observed = np.asarray(sol.observed, bool) & ~np.array([c in fixed_set for c in cells], bool)
        errors: dict[Cell, tuple[float, float]] = {}
        inlier: dict[Cell, bool] = {}
        scale = 1.0
        if observed.any():
            if fixed_set:
                # the fixed views anchor the frame: no global map to remove
                err, w = sol.positions_mm - commanded, np.ones(len(cells))
            else:
                err, w, scale = position_errors(commanded, sol.positions_mm, use=np.asarray(sol.observed, bool))
                scale = scale if 0.5 < scale < 2.0 else 1.0
            for c, i in index.items():
                if observed[i]:
                    errors[c] = (float(err[i, 0]), float(err[i, 1]))
                    inlier[c] = bool(w[i] > 0)
        # depths with the commanded scale (the weak prior alone lets a displaced view stretch the grid)
        tf = fit_tracks(obs, sol.positions_mm / scale, sol.sigma_px)
        residual: dict[Cell, float] = {}
        tracks: dict[Cell, int] = {}
        if obs.count:
            # robust RMS per view: a mismatched point counts at 3 sigma, not at its full size
            rn = np.minimum(np.hypot(tf.residual_px[:, 0], tf.residual_px[:, 1]), 3.0 * sol.sigma_px)
            used = tf.weight > 0
            n = np.bincount(obs.view[used], minlength=len(cells))
            ss = np.bincount(obs.view[used], rn[used] ** 2, minlength=len(cells))
            for c, i in index.items():
                if n[i]:
                    residual[c] = float(np.sqrt(ss[i] / n[i])) * self.measures[c].work_scale
                    tracks[c] = int(n[i])
        return PositionFit(cells, measured, errors, inlier, residual, tracks, tf.s_px_per_mm, tf.s_sigma,
                           tf.views, float(sol.sigma_px))


# -- the whole-dataset check --------------------------------------------------------------------------
@dataclass
class QualityReport:
    document: dict[str, Any]
    disparity: DisparityMap | None = None
    track_disparity_px: np.ndarray = field(default_factory=lambda: np.zeros(0))   # full-res px per step
    depth_scale_m_px: float | None = None      # depth (m) = this / disparity (full-res px per step)
    path: Path | None = None

    @property
    def views(self) -> list[dict[str, Any]]:
        return self.document["views"]

    def flagged(self, verdict: str | None = None) -> list[Cell]:
        """Views whose verdict is ``verdict`` (default: warn or fail)."""
        want = {verdict} if verdict else {verdicts.WARN, verdicts.FAIL}
        return [(v["row"], v["column"]) for v in self.views if v["verdict"] in want]


def calibration_homography(dataset) -> tuple[np.ndarray | None, list[int] | None, dict[str, Any] | None]:
    """The dataset's rectifying homography (full resolution) and its image size, or Nones."""
    from lfstudio.calibration.model import CALIBRATION_NAME, homography_for, load_calibration

    doc = load_calibration(dataset)
    if not doc:
        return None, None, None
    try:
        return homography_for(doc), [int(v) for v in doc["image_size_px"]], doc
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f"{Path(dataset.root) / CALIBRATION_NAME}: incomplete ({exc}); run "
                           "'lfstudio calibrate' again") from None


def choose_views(dataset, views: str | Sequence[Cell] | None) -> tuple[list[Cell], list[Cell]]:
    """(views to judge, views to decode: those plus the neighbours they are compared with)."""
    done = dataset.captured_views()
    if views is None or isinstance(views, str):
        chosen = dataset.grid.select(views, done, field_name="--views")
    else:       # views without a capture are left out (a live check asks for what it has)
        have = set(done)
        chosen = sorted({(int(r), int(c)) for r, c in views if (int(r), int(c)) in have})
    have = set(done)
    around = set(chosen)
    for r, c in chosen:
        around |= {(r + dr, c + dc) for dr, dc in set(WINDOW) | set(RING) if (r + dr, c + dc) in have}
    return chosen, sorted(around)


def centre_cell(cells: Iterable[Cell], columns: int, rows: int) -> Cell | None:
    cells = list(cells)
    if not cells:
        return None
    r0, c0 = (rows - 1) / 2.0, (columns - 1) / 2.0
    return min(cells, key=lambda v: ((v[0] - r0) ** 2 + (v[1] - c0) ** 2, v))


def check_dataset(dataset, views: str | Sequence[Cell] | None = None, *, thresholds: Thresholds | None = None,
                  work_width_px: int = DEFAULT_WORK_WIDTH_PX, threads: int = 2, disparity: bool = True,
                  write: bool = True, progress: Progress = no_progress,
                  cancel: CancelToken | None = None) -> QualityReport:
    """Check ``dataset`` (an open :class:`lfstudio.dataset.Dataset`); write ``quality.json`` and the
    pictures into it unless ``write`` is False. ``views``: ``None``/``"all"``, a view list spec as
    ``lfstudio calibrate --views`` reads it, or (row, column) pairs."""
    t_start, c_start = time.perf_counter(), time.process_time()
    thresholds = thresholds or Thresholds()
    geometry = Geometry.from_dataset(dataset)
    chosen, decode = choose_views(dataset, views)
    if not chosen:
        raise DatasetError(f"{dataset.root}: no captured views to check; scan first")
    H_full, cal_size, cal_doc = calibration_homography(dataset)
    grid = GridCheck(geometry, thresholds, homography_full=H_full, calibration_size_px=cal_size)

    def check_cancel() -> None:
        if cancel is not None:
            cancel.check()

    # the de-flicker reference of the processing profile
    from lfstudio.processing.pipeline import reference_view
    from lfstudio.dataset.profile import Profile

    profile = Profile.for_dataset(dataset.root)
    try:
        ref = reference_view(dataset, profile)
        ref_cell: Cell | None = (int(ref["row"]), int(ref["column"]))
    except Exception:  # a profile naming a view that is not there: no gain, the check still runs
        ref_cell = None
    centre = centre_cell(decode, geometry.columns, geometry.rows) if disparity else None
    keep_forever: set[Cell] = set()
    if centre is not None:
        keep_forever = {centre} | {c for c, _, _ in partner_cells(centre, set(decode), geometry.columns,
                                                                  geometry.rows, 4, 4)}
    total = len(decode) + 3
    done_n = 0
    progress(0, total, "reading views")
    paths = {(int(v["row"]), int(v["column"])): dataset.path_of(v) for v in dataset.views
             if (int(v["row"]), int(v["column"])) in set(decode)}
    # exposure-bracketed views: every frame's (exposure, path), judged on what the merge keeps
    bracketed = {(int(v["row"]), int(v["column"])): bracket_frames(v.get("frames"), dataset.path_of)
                 for v in dataset.views if (int(v["row"]), int(v["column"])) in paths}

    def measure(cell: Cell) -> ViewMeasures:
        check_cancel()
        if ref_measures is not None and cell == ref_measures.cell:
            return ref_measures
        m = measure_view(paths[cell], *cell, work_width_px=work_width_px)
        return with_frames(m, bracketed.get(cell, []), paths[cell])

    ref_measures: ViewMeasures | None = None
    gains: dict[Cell, float] = {}
    unreadable: dict[Cell, str] = {}
    order = {c: i for i, c in enumerate(decode)}          # row-major
    futures: dict[Cell, Any] = {}

    measured_evt = {cell: threading.Event() for cell in decode}

    def task(cell: Cell) -> Cell:
        """Read one view, then track it into the neighbours before it once they are read (their
        tasks started first; tracking needs only their images, so neighbours track in parallel)."""
        try:
            try:
                m = measure(cell)
            except LfError as exc:
                unreadable[cell] = str(exc)
                return cell
            if ref_measures is not None:
                gains[cell] = deflicker_gain(ref_measures, m, profile.deflicker)
            if m is not ref_measures:
                m.small_luminance = None
            grid.measures[cell] = m
        finally:
            measured_evt[cell].set()
        r, c = cell
        for dr, dc in WINDOW:
            nb = (r + dr, c + dc)
            if nb in measured_evt and order[nb] < order[cell]:
                measured_evt[nb].wait()
        check_cancel()
        grid.add(m, known=lambda n: n in order and order[n] < order[cell] and n not in unreadable)
        return cell

    with ThreadPoolExecutor(max_workers=max(1, threads), thread_name_prefix="quality") as pool:
        if ref_cell is not None and ref_cell in paths:
            try:
                ref_measures = measure(ref_cell)
            except LfError:
                ref_measures = None          # reported with the view itself below
        for cell in decode:
            futures[cell] = pool.submit(task, cell)
        try:
            row_left = {r: sum(1 for c in decode if c[0] == r) for r in {c[0] for c in decode}}
            for cell in decode:
                futures[cell].result()
                done_n += 1
                row_left[cell[0]] -= 1
                if row_left[cell[0]] == 0:
                    # every view of this row is tracked: the views two rows up are needed no more
                    grid.drop_images(lambda c, r=cell[0]: c[0] >= r - 1 or c in keep_forever)
                progress(done_n, total, f"read and tracked {view_stem(*cell)}")
        except BaseException:
            for f in futures.values():
                f.cancel()
            for evt in measured_evt.values():       # release tasks waiting for a cancelled neighbour
                evt.set()
            raise
    check_cancel()
    progress(done_n, total, "solving the positions")
    fit = grid.solve(decode)
    done_n += 1
    check_cancel()

    # neighbour disparity of the tracks (full resolution, one horizontal step) and depth
    readable = [c for c in chosen if c in grid.measures]
    if not readable:
        raise DatasetError(f"{dataset.root}: none of the views to check can be read", [unreadable[c] for c in chosen])
    any_m = grid.measures[readable[0]]
    f_work = grid.focal_length_work_px(any_m)
    # with the shear known the tracks' disparities are a parallel capture's (positive); sheared views of an
    # unstated shear give the views' own signed disparities (no depths)
    good = np.isfinite(fit.s_px_per_mm) & (fit.track_views >= MIN_TRACK_VIEWS) & np.isfinite(fit.s_sigma)
    if geometry.zero.known:
        good &= fit.s_px_per_mm > 0
    if PRECISE_FRACTION < 1.0 and good.sum() > 100:
        # the depth range from the better-measured tracks (the noise of the others widens it)
        good &= fit.s_sigma <= np.quantile(fit.s_sigma[good], PRECISE_FRACTION)
    s = fit.s_px_per_mm[good]
    to_full = geometry.spacing_mm[0] * any_m.work_scale          # px/mm (working) → px per step (full)
    step_disp_full = s * to_full
    step_disp_sigma = fit.s_sigma[good] * to_full
    disp_map = None
    if centre is not None and centre in grid.measures and grid.measures[centre].grey8 is not None:
        progress(done_n, total, "disparity map of the centre view")
        images = {c: img for c in keep_forever if c in grid.measures
                  and (img := grid.measures[c].grey8) is not None}
        max_s = float(np.percentile(s, 99.5)) if s.size else (f_work or 1000.0) / (1000.0 * 1.0)
        # sheared by an amount nobody stated: the views' own signed disparities, searched both ways
        min_s = min(0.0, float(np.percentile(s, 0.5))) if s.size and not geometry.zero.known else 0.0
        step_h, step_v = max_s * geometry.spacing_mm[0], max_s * geometry.spacing_mm[1]
        low_h, low_v = min_s * geometry.spacing_mm[0], min_s * geometry.spacing_mm[1]
        parts = partner_cells(centre, set(images), geometry.columns, geometry.rows,
                              steps_for(max(step_h, -low_h)), steps_for(max(step_v, -low_v)))
        # baselines between where the views really were (measured), else where the manifest says
        def where(c: Cell) -> np.ndarray:
            return np.add(geometry.commanded_mm[c], fit.error_mm.get(c, (0.0, 0.0)))
        baselines = {c: float(np.hypot(*(where(c) - where(centre)))) for c, _, _ in parts}
        # sheared views: each partner is moved back by the shear of its offset (the map is a parallel capture's)
        shear_w = geometry.shear_work(any_m)
        shifts = {c: tuple(-shear_w * np.subtract(geometry.commanded_mm[c], geometry.commanded_mm[centre]))
                  for c, _, _ in parts} if shear_w else None
        if parts:
            disp_map = disparity_map(centre, images, parts, baselines, geometry.spacing_mm[0], any_m.work_scale,
                                     {"h": step_h, "v": step_v}, grid.homography_work(grid.measures[centre]),
                                     shifts, {"h": low_h, "v": low_v})
    done_n += 1
    grid.drop_images(lambda c: False)
    check_cancel()

    named = views if isinstance(views, str) else ("all" if views is None else [view_stem(*c) for c in chosen])
    settings = {"work_width_px": work_width_px, "views": named}
    doc = build_document(dataset, grid, fit, chosen, unreadable, gains, ref_cell, step_disp_full, step_disp_sigma,
                         disp_map, cal_doc, settings)
    f_full = geometry.focal_length_px(any_m.full_size_px[0])
    report = QualityReport(doc, disp_map, step_disp_full,     # metres on the map's bar only from infinity
                           f_full * geometry.spacing_mm[0] / 1000.0 if f_full and geometry.zero.known else None)
    doc["timing_s"] = {"wall": round(time.perf_counter() - t_start, 3), "cpu": round(time.process_time() - c_start, 3)}
    if write:
        progress(done_n, total, "writing quality.json and pictures")
        report.path = write_report(dataset, report)
    done_n += 1
    progress(total, total, "done")
    log.info("quality check of %s: %s", dataset.root, doc["summary"])
    return report


def build_document(dataset, grid: GridCheck, fit: PositionFit, chosen: list[Cell], unreadable: dict[Cell, str],
                   gains: dict[Cell, float],
                   ref_cell: Cell | None, step_disp_full: np.ndarray, step_disp_sigma: np.ndarray,
                   disp_map: DisparityMap | None, cal_doc: dict | None, settings: dict[str, Any]) -> dict[str, Any]:
    """The ``quality.json`` document (plain JSON types)."""
    t = grid.thresholds
    g = grid.geometry
    limits = t.position_limits_mm(g.repeatability_um, g.spacing_mm)
    typical_residual = fit.typical_residual_px()
    full_size = grid.measures[next(c for c in chosen if c in grid.measures)].full_size_px
    f_full = g.focal_length_px(full_size[0])
    shear_full = g.zero.shear_at(full_size[0])
    depth = depth_range(step_disp_full, step_disp_sigma, g, f_full, t,
                        None if shear_full is None else shear_full * g.spacing_mm[0])
    from lfstudio.export.hci import disparity_range

    planned = disparity_range(dataset, [], "raw", full_size, measure=False)
    if planned is not None:       # what the exports write as disp_min / disp_max for these images
        depth["export_disp_min_px"], depth["export_disp_max_px"] = float(planned.d_min_px), float(planned.d_max_px)
    near_m = depth.get("near_m")
    views_out = []
    chosen_set = set(chosen)
    for v in sorted(dataset.views, key=lambda v: (v["row"], v["column"])):
        cell = (int(v["row"]), int(v["column"]))
        if cell not in chosen_set:
            if not is_done(v):
                if settings.get("views") in (None, "all"):
                    views_out.append({"row": cell[0], "column": cell[1], "view": view_stem(*cell),
                                      "verdict": verdicts.FAIL, "status": v.get("status"),
                                      "reasons": [f"not captured (status {v.get('status')})"], "checks": {}})
            continue
        if cell in unreadable:
            views_out.append({"row": cell[0], "column": cell[1], "view": view_stem(*cell), "verdict": verdicts.FAIL,
                              "status": v.get("status"), "file": v.get("file"),
                              "reasons": [f"cannot be read: {unreadable[cell]}"], "checks": {}})
            continue
        entry = grid.judge_view(cell, fit, typical_residual, near_m, gains.get(cell))
        entry["file"] = v.get("file")
        views_out.append(entry)
    # repeatability: the spread of the position errors of the views that fit the grid
    errs = np.array([fit.error_mm[c] for c in fit.error_mm if fit.inlier.get(c)], float).reshape(-1, 2)
    repeat: dict[str, Any]
    if len(errs) >= 5:
        dof = len(errs) / max(len(errs) - 3, 1)           # 3 affine parameters per axis were fitted
        sx, sy = (float(np.sqrt(np.mean(errs[:, i] ** 2) * dof)) * 1000.0 for i in (0, 1))
        repeat = {"x_um": sx, "y_um": sy, "rms_um": float(np.sqrt((sx * sx + sy * sy) / 2)), "views": int(len(errs)),
                  "planned_um": list(g.repeatability_um),
                  "why": "RMS of the measured position errors of the views that fit the grid (global affine "
                         "removed), per axis"}
    else:
        repeat = {"x_um": None, "y_um": None, "rms_um": None, "views": int(len(errs)),
                  "planned_um": list(g.repeatability_um), "why": "too few located views (need 5)"}
    # where the figure compared with comes from, as Geometry.of read it: the plan, the rig's log, else the default
    logged = ((dataset.manifest.get("import") or {}).get("positions") or {}).get("logged_repeatability_um")
    repeat["planned_from"] = ("plan" if (dataset.manifest.get("plan") or {}).get("repeatability_um") is not None
                              else "logged" if g.recorded_positions and logged else "default")
    counts = {k: sum(1 for v in views_out if v["verdict"] == k) for k in (verdicts.PASS, verdicts.WARN, verdicts.FAIL)}
    flagged = [v["view"] for v in views_out if v["verdict"] in (verdicts.WARN, verdicts.FAIL)]
    verdict = verdicts.worst([v["verdict"] for v in views_out] + [depth["verdict"]])
    disparity_doc: dict[str, Any] | None = None
    if disp_map is not None:
        d = disp_map.disparity_px
        fin = d[np.isfinite(d)]
        disparity_doc = {"view": view_stem(*disp_map.cell), "row": disp_map.cell[0], "column": disp_map.cell[1],
                         "unit": "full-resolution px between horizontal neighbours",
                         "valid_fraction": disp_map.valid_fraction(),
                         "median_px": float(np.median(fin)) if fin.size else None,
                         "p1_px": float(np.percentile(fin, 1)) if fin.size else None,
                         "p99_px": float(np.percentile(fin, 99)) if fin.size else None,
                         # the partners are moved back by a known shear: from infinity; else as the views are
                         "reference": "from infinity" if g.zero.known else g.zero.disparity_reference(),
                         "partners": disp_map.partners,
                         "rectified": cal_doc is not None}
    doc = {
        "format": FORMAT, "version": VERSION,
        "created": now_iso(),
        "dataset": str(dataset.root),
        "verdict": verdict,
        "summary": {"views": len(views_out), **counts, "flagged": flagged},
        "thresholds": {**t.as_dict(), "position_warn_mm": limits[0], "position_fail_mm": limits[1]},
        "calibration": {"used": cal_doc is not None,
                        "rotation_deg": cal_doc.get("rotation_deg") if cal_doc else None,
                        "note": None if cal_doc else "no calibration.json: positions and residuals are measured "
                                                     "in the captured (unrectified) images"},
        "deflicker_reference": view_stem(*ref_cell) if ref_cell else None,
        "repeatability": repeat,
        "depth_range": depth,
        "disparity_map": disparity_doc,
        "tracks": {"residual_sigma_px": fit.sigma_px if np.isfinite(fit.sigma_px) else None,
                   "typical_view_residual_px": typical_residual,
                   "count": int(np.count_nonzero(np.isfinite(fit.s_px_per_mm)))},
        "settings": settings,
        "views": views_out,
    }
    return doc


def depth_range(step_disp_full: np.ndarray, step_disp_sigma: np.ndarray, g: Geometry, f_full: float | None,
                t: Thresholds, shear_step_px: float | None = 0.0) -> dict[str, Any]:
    """Measured neighbour-disparity and depth range of the tracks against the plan.

    The range is the 1st to 99th percentile of the tracks' disparities (the better-measured
    :data:`PRECISE_FRACTION` of them), each moved inwards by :data:`RANGE_SIGMAS` of its own standard
    error first, so that measurement noise does not widen it.

    ``shear_step_px``: the views' shear per horizontal step (0: parallel views; None: sheared by an
    amount not stated, when ``step_disp_full`` are the views' own signed disparities and no depth can
    be given). With a known shear ``step_disp_full`` are a parallel capture's disparities; the views'
    own (signed) range is that minus the shear (``views_disparity_min_px``/``_max_px``).
    """
    out: dict[str, Any] = {"planned_near_m": g.near_m, "planned_far_m": g.far_m,
                           "zero_disparity": {"depth_m": g.zero.depth_m, "source": g.zero.source,
                                              "shear_px_per_step": shear_step_px, "about": g.zero.describe(),
                                              "disparity_reference": g.zero.disparity_reference()}}
    if step_disp_full.size >= 20 and shear_step_px is None:
        v_lo = float(np.percentile(step_disp_full + RANGE_SIGMAS * step_disp_sigma, 1.0))
        v_hi = float(np.percentile(step_disp_full - RANGE_SIGMAS * step_disp_sigma, 99.0))
        out.update({"views_disparity_min_px": v_lo, "views_disparity_max_px": v_hi,
                    "disparity_unit": "full-resolution px between horizontal neighbours",
                    "tracks": int(step_disp_full.size), "verdict": verdicts.NA,
                    "why": f"no depths: {g.zero.describe()}"})
        return out
    if step_disp_full.size < 20 or not f_full or shear_step_px is None:     # (None with 20 tracks: above)
        out.update({"verdict": verdicts.NA, "why": "too few tracks (or no focal length) to measure depth"})
        return out
    d_lo = float(np.percentile(step_disp_full + RANGE_SIGMAS * step_disp_sigma, 1.0))
    d_hi = float(np.percentile(step_disp_full - RANGE_SIGMAS * step_disp_sigma, 99.0))
    out.update({"views_disparity_min_px": d_lo - shear_step_px, "views_disparity_max_px": d_hi - shear_step_px})
    # depth = f · b / (1000 · d) with f in full-resolution px and b the horizontal spacing
    fb = f_full * g.spacing_mm[0] / 1000.0
    near = fb / d_hi if d_hi > 0 else None
    far = fb / d_lo if d_lo > 0 else None
    hist, edges = np.histogram(step_disp_full, bins=40, range=(min(0.0, d_lo), d_hi * 1.25 if d_hi > 0 else 1.0))
    out.update({"near_m": near, "far_m": far, "disparity_min_px": d_lo, "disparity_max_px": d_hi,
                "disparity_unit": "full-resolution px between horizontal neighbours",
                "histogram": {"counts": [int(c) for c in hist], "edges_px": [float(e) for e in edges]},
                "tracks": int(step_disp_full.size)})
    problems = []
    if near is not None and g.near_m and near < g.near_m * (1 - t.depth_tolerance):
        problems.append(f"the scene comes to {near:.2f} m, nearer than the planned {g.near_m:.2f} m: the depth "
                        "of field and the repositioning budget were planned for the plan's range")
    if far is not None and g.far_m and far > g.far_m * (1 + t.depth_tolerance):
        problems.append(f"the scene reaches {far:.2f} m, beyond the planned {g.far_m:.2f} m")
    if problems:
        out.update({"verdict": verdicts.WARN, "why": "; ".join(problems)})
    else:
        span = f"{near:.2f} – {far:.2f} m" if near and far else "measured"
        plan = f" (planned {g.near_m:.2f} – {g.far_m:.2f} m)" if g.near_m and g.far_m else ""
        zero = f"; zero disparity at {g.zero.depth_m:.2f} m" if shear_step_px and g.zero.depth_m else ""
        out.update({"verdict": verdicts.PASS, "why": f"scene depth {span}{plan}{zero}"})
    if shear_step_px and g.zero.depth_m and near and far:
        out["zero_disparity"]["inside_range"] = bool(near <= g.zero.depth_m <= far)
    return out


def write_report(dataset, report: QualityReport) -> Path:
    """Write the pictures into ``DATASET/quality/`` and ``DATASET/quality.json`` (atomically)."""
    from lfstudio.quality.pictures import write_pictures

    root = Path(dataset.root)
    # the path guard at the moment of writing (a symlink made after the dataset was opened)
    pictures = write_pictures(folder_inside(root, PICTURES_FOLDER, what="quality folder"), report, dataset)
    report.document["pictures"] = {k: f"{PICTURES_FOLDER}/{Path(p).name}" for k, p in pictures.items()}
    path = atomic_write_json(resolve_inside(root, QUALITY_NAME), report.document)
    return path


def load_quality(dataset_or_root) -> dict[str, Any] | None:
    """The dataset's ``quality.json`` or None when it has none."""
    import json

    from lfstudio.dataset import Dataset

    path = Dataset.root_of(dataset_or_root) / QUALITY_NAME
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot be read ({exc}); run 'lfstudio check' again") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise DatasetError(f"{path}: not a quality report; run 'lfstudio check' again")
    return doc
