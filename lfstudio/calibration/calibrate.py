"""Self-calibrate a dataset: pick views and pairs, detect and match features, fit, report, save.

``calibrate_dataset(dataset, ...)`` is a long job (``progress``, ``cancel``); it returns a
:class:`CalibrationRun` whose ``document`` is what :func:`lfstudio.calibration.model.save_calibration`
writes to ``DATASET/calibration.json`` (the model module reads and writes that file). Detection runs on ``threads`` threads, matching too
(:func:`lfstudio.calibration.features.match_pairs`); the views' position errors enter the fit with
the rig's repeatability (:func:`position_sigma_um`) as their prior.
"""

from __future__ import annotations

import logging
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike

from lfstudio.calibration.features import DEFAULT_MAX_FEATURES, DEFAULT_WORK_WIDTH_PX, FeatureCache, Features, match_pairs
from lfstudio.calibration.fit import DEFAULT_POSITION_SIGMA_UM, CalibrationError, FitResult, PairMatches, fit_rectification
from lfstudio.calibration.pairs import DEFAULT_PAIR_SET, DEFAULT_VIEWS, Pair, make_pairs
from lfstudio.calibration.lens import lens_fingerprint, lens_model, undistort_points
from lfstudio.calibration.report import build_report
from lfstudio.dataset import Dataset
from lfstudio.dataset.grid import View
from lfstudio.dataset.profile import Profile
from lfstudio.dataset.manifest import now_iso
from lfstudio.dataset.paths import view_stem
from lfstudio.errors import DatasetError, words
from lfstudio.jobs import CancelToken, Progress, no_progress

log = logging.getLogger(__name__)

__all__ = ["CalibrationRun", "calibrate_dataset", "position_sigma_um", "recorded_positions",
           "with_recorded_positions"]


@dataclass
class CalibrationRun:
    document: dict[str, Any]
    fit: FitResult
    matches: list[PairMatches]
    pairs: list[Pair]
    views: list[View]


def position_sigma_um(dataset) -> tuple[float, float]:
    """The rig's repeatability (horizontal, vertical) in µm: the manifest's ``rig.repeatability_um``
    (a number or a pair) when it has one, else the reference gantry's (80, 50)."""
    value = (dataset.manifest.get("rig") or {}).get("repeatability_um")
    try:
        if isinstance(value, (int, float)):
            return float(value), float(value)
        if isinstance(value, (list, tuple)) and len(value) == 2:
            return float(value[0]), float(value[1])
    except (TypeError, ValueError):
        pass
    return DEFAULT_POSITION_SIGMA_UM


def shear_remover(dataset, views: Sequence[tuple[int, int]], image_size: Sequence[int]):
    """``f(view, xy) -> xy`` taking sheared views' shear off their points (a shear is not a rotation:
    it must neither bias the fit nor be corrected away; :mod:`lfstudio.dataset.zero_plane`): each
    view's points move back by ``shear · (position − the views' mean position)``. Identity for
    parallel views. For views sheared by an amount nobody stated, the least shear the import measured
    (:func:`assumed_shear`) is taken off; without a measurement the fit is refused, naming what works."""
    from lfstudio.dataset.zero_plane import zero_plane

    zp = zero_plane(dataset)
    if zp.parallel:
        return lambda view, xy: xy
    if zp.known:
        shear = zp.shear_at(image_size[0])
    else:
        assumed = assumed_shear(dataset)
        if assumed is None:
            raise CalibrationError(
                f"{dataset.root.name}'s views are sheared by an amount nobody stated (negative disparities) and "
                "no disparities were measured when they were imported, so the shear cannot be told from a rotation; "
                "import them again (the import measures them), or state the plane "
                f"({words('--zero-disparity-depth-m', 'Zero disparity: at a depth')}). Without it: "
                f"{WORKS_WITHOUT_PLANE}")
        shear = assumed * float(image_size[0]) / float(zp.width_px or image_size[0])
    recorded = dataset.positions_recorded

    def where(v):
        rec = dataset.view(*v)
        pos = (rec.get("reported_mm") if recorded else None) or rec.get("commanded_mm") or (0.0, 0.0)
        return np.asarray(pos, float)

    ref = np.mean([where(v) for v in views], axis=0)
    return lambda view, xy: np.asarray(xy, float) - shear * (where(view) - ref)


#: what works on views sheared by an amount nobody stated (messages of calibrate, depth, export)
WORKS_WITHOUT_PLANE = ("calibration (the farthest tracked point taken at infinity), the quality check, "
                       "disparities in px (depth), the PNG and HEVC exports")


def assumed_shear(dataset) -> float | None:
    """For views sheared by an amount nobody stated: the least shear their measured negative
    disparities prove (px per mm of baseline, full-size image; the import's ``shear_min_px_per_mm``),
    or None when nothing was measured.

    Taken off, it leaves the farthest tracked point at infinity and every other point at a finite
    depth: a parallel light field of a scene with those depths, which a parallel capture with the same
    camera orientation would have taken. The rotation and the focal length the fit finds do not depend
    on which such scene it is; depths would (they are not what calibration gives). On a virtual capture
    sheared to 3 m and turned (0.5, -0.8, 0.3)°, the fit found (0.40, -0.48, 0.43)° ± (0.40, 1.1, 0.12)
    this way; with the plane stated (0.55, -0.53, 0.30)° ± (0.22, 0.60, 0.09); with no shear taken off
    (-0.89, -1.03, 0.18)°."""
    from lfstudio.dataset.zero_plane import zero_plane

    zp = zero_plane(dataset)
    if zp.known:
        return None
    value = zp.measured.get("shear_min_px_per_mm")
    if isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value) and value > 0:
        return float(value)
    return None


def recorded_positions(dataset, views: Sequence[tuple[int, int]]) -> dict[tuple[int, int], np.ndarray] | None:
    """Each view's position as the rig recorded it (``import-images --positions``: the views'
    ``reported_mm`` in the dataset's frame, x along the columns, y along the rows), or None when the
    dataset has no recorded positions (a step scan, an import on a regular grid; a fly scan has them). A view of a dataset with
    recorded positions that lacks one is refused by name."""
    if not dataset.positions_recorded:
        return None
    out = {}
    for v in views:
        rec = dataset.view(*v).get("reported_mm")
        if not (isinstance(rec, (list, tuple)) and len(rec) == 2):
            raise CalibrationError(f"{view_stem(*v)} has no recorded position although {dataset.root.name} was "
                                   "imported with --positions or fly-scanned; import it again with a position for "
                                   "every view, or scan that view again")
        out[tuple(v)] = np.asarray(rec, float)
    return out


def with_recorded_positions(m: PairMatches, pos_a: ArrayLike, pos_b: ArrayLike) -> PairMatches:
    """The pair with its baseline as the rig recorded it (issue 27: another rig's recorded positions
    are not a perfect grid; Stanford's gantry steps vary by up to 8 %), instead of the grid's spacing:
    the baseline scales how much a view's position error moves the pair's matches (``d / B``).

    Only the baseline: a recorded offset *across* the baseline is not taken off the matches. On the
    real Stanford Chess views (5 × 5, offsets across the rows of 0.1–0.25 mm on 5 mm steps) doing so
    raised the fit's residual from 0.23 to 0.27 px RMS and moved the roll 0.6° away from the rotation
    hidden in the views: the record's across-axis scatter is not where the images were taken from.
    Those offsets stay in the fit as each view's unknown position error."""
    pa, pb = np.asarray(pos_a, float), np.asarray(pos_b, float)
    along = 0 if m.direction == "h" else 1
    base = abs(float(pb[along] - pa[along]))
    if not base > 1e-9:
        raise CalibrationError(f"{view_stem(*m.view_a)} and {view_stem(*m.view_b)} were recorded at the same "
                               f"{'x' if along == 0 else 'y'} ({pa[along]:.3f} mm): no baseline between them; "
                               "check the positions given at import (--positions)")
    return PairMatches(m.view_a, m.view_b, m.direction, m.xy_a, m.xy_b, raw_matches=m.raw_matches, baseline_mm=base)


def calibrate_dataset(dataset: Dataset, views: str | Sequence[tuple[int, int]] | None = None, *,
                      principal_point: str = "auto", estimate_principal_point: bool | None = None,
                      focal_length_px: float | None = None,
                      max_width_px: int | None = DEFAULT_WORK_WIDTH_PX, max_features: int = DEFAULT_MAX_FEATURES,
                      pair_set: str = DEFAULT_PAIR_SET, neighbours_only: bool = False,
                      position_sigma: Sequence[float] | None = None, ratio: float = 0.8, threads: int = 2,
                      pairs: Sequence[Pair] | None = None, progress: Progress = no_progress,
                      cancel: CancelToken | None = None) -> CalibrationRun:
    """Run the whole self-calibration on ``dataset`` (an open :class:`lfstudio.dataset.Dataset`).

    ``views``: a selection (:meth:`lfstudio.dataset.Dataset.select`; default: the default array,
    :data:`lfstudio.calibration.pairs.DEFAULT_VIEWS`) or (row, column) pairs; ``pair_set``: which pairs
    of them (default :data:`lfstudio.calibration.pairs.DEFAULT_PAIR_SET`; ``neighbours_only`` is the
    older spelling of "neighbours"); ``principal_point``: "auto" (estimated where observable) or
    "centre" (``estimate_principal_point``: the older True/False); ``position_sigma``: the rig's
    repeatability in µm (default :func:`position_sigma_um`).
    """
    if neighbours_only:
        pair_set = "neighbours"
    if estimate_principal_point is not None:
        principal_point = "auto" if estimate_principal_point else "centre"
    chosen = dataset.select(views, default=DEFAULT_VIEWS, field_name="--views")
    spacing = dataset.grid.step_mm
    pair_list = list(pairs) if pairs is not None else make_pairs(chosen, spacing, pair_set=pair_set)
    if not pair_list:
        raise CalibrationError(f"the chosen views ({', '.join(view_stem(*v) for v in chosen)}) form no pair in a "
                               "common row or column; choose at least two views of one row and two of one column")
    needed = sorted({p.a for p in pair_list} | {p.b for p in pair_list})
    log.info("calibration of %s started: %d views, %d pairs", dataset.root, len(needed), len(pair_list))
    total_steps = len(needed) + len(pair_list) + 1
    done = 0
    cache = FeatureCache(dataset.root, max_width_px, max_features)

    def check() -> None:
        if cancel is not None:
            cancel.check()

    feats: dict[tuple[int, int], Features] = {}
    progress(0, total_steps, "detecting features")

    def one(v):
        check()
        return v, cache.get(view_stem(*v), dataset.path_of(dataset.view(*v)))[0]

    with ThreadPoolExecutor(max_workers=max(1, threads)) as pool:
        futures = [pool.submit(one, v) for v in needed]
        try:
            for fut in futures:
                v, f = fut.result()
                feats[v] = f
                done += 1
                progress(done, total_steps, f"features {view_stem(*v)}: {f.count}")
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise
    sizes = {f.image_size_px for f in feats.values()}
    if len(sizes) > 1:
        raise DatasetError(f"{dataset.root}: the chosen views have different image sizes {sorted(sizes)}; "
                           "calibrate views of one camera setting")
    image_size = next(iter(sizes))
    # one coordinate system: the features undistorted with the lens model processing applies
    step = Profile.for_dataset(dataset.root).lens
    model = lens_model(step, image_size, dict(dataset.camera), dict(dataset.lens))
    lens_record = {**lens_fingerprint(step),
                   "description": "" if model is None else str(getattr(model, "description", "") or
                                                                  f"OpenCV coefficients {list(step.dist_coeffs)}")}
    if model is not None:
        progress(done, total_steps, "undistorting features with the lens model")
        feats = {v: Features(undistort_points(model, f.xy).astype(np.float32), f.descriptors, f.image_size_px, f.scale)
                 for v, f in feats.items()}
    if focal_length_px is None:
        focal_length_px = dataset.focal_length_px(image_size[0])

    lock = threading.Lock()

    def matched(i, m) -> None:
        nonlocal done
        p = pair_list[i]
        with lock:
            done += 1
            progress(done, total_steps, f"matched {view_stem(*p.a)}–{view_stem(*p.b)}: {m.inliers}/{m.candidates}")

    results = match_pairs(feats, [(p.a, p.b, p.direction) for p in pair_list], ratio=ratio, threads=threads,
                          on_done=matched, check=check)
    unshear = shear_remover(dataset, needed, image_size)
    matches = [PairMatches(p.a, p.b, p.direction, unshear(p.a, m.xy_a), unshear(p.b, m.xy_b), raw_matches=m.candidates,
                           baseline_mm=p.baseline_mm)
               for p, m in zip(pair_list, results)]
    recorded = recorded_positions(dataset, needed)
    if recorded is not None:
        matches = [with_recorded_positions(m, recorded[m.view_a], recorded[m.view_b]) for m in matches]
    check()
    progress(done, total_steps, "fitting orientation")
    sigma_um = tuple(position_sigma) if position_sigma is not None else position_sigma_um(dataset)
    fit = fit_rectification(matches, focal_length_px, image_size, principal_point=principal_point,
                            position_sigma_um=sigma_um, radial_term="none" if model is not None else "auto")
    settings = {"max_width_px": max_width_px, "max_features": max_features, "ratio": ratio,
                "pair_set": pair_set, "neighbours_only": pair_set == "neighbours",
                "principal_point": principal_point, "estimate_principal_point": principal_point == "auto",
                "position_sigma_um": list(sigma_um),
                "work_scale": float(max(f.scale for f in feats.values())),
                "positions": "recorded" if recorded is not None else "grid"}
    assumed = assumed_shear(dataset)
    if assumed is not None:
        settings["zero_plane"] = {"assumed_shear_px_per_mm": assumed,
                                  "why": "the views are sheared by an amount nobody stated: the least shear their "
                                         "measured disparities prove was taken off (the farthest tracked point at "
                                         "infinity); the orientation and the focal length do not depend on it"}
    doc = build_report(fit, matches, views=needed, feature_counts={v: f.count for v, f in feats.items()},
                       settings=settings, grid_extent_mm=dataset.grid.baselines_mm,
                       created=now_iso())
    doc["lens_model"] = lens_record
    progress(total_steps, total_steps, "done")
    log.info("calibration of %s finished: rotation %s deg ± %s, residual rms %.3f px", dataset.root,
             [round(float(a), 3) for a in doc.get("rotation_deg") or ()],
             [round(float(a), 3) for a in doc.get("rotation_std_deg") or ()],
             doc.get("residual_px", {}).get("after", {}).get("rms", float("nan")))
    return CalibrationRun(doc, fit, matches, pair_list, needed)
