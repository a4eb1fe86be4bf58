"""Process a dataset: every captured view through the profile's steps, on an executor.

:func:`process_dataset` computes the reference statistics once (colour levels, de-flicker
reference, shading coefficients), then sends one task per view to a local process pool or a Dask
cluster (:mod:`lfstudio.processing.executors`). Views already processed with the same effective
profile (same hash) whose output exists are skipped, so a crashed or cancelled run resumes. A view
that fails is reported and the others go on. Results are recorded per view in the manifest
(``view["processed"]``) and the run in ``manifest["processing"]``; the views finished so far are
made durable every few seconds (:meth:`lfstudio.dataset.Dataset.checkpoint`: appended to the
journal) and the manifest is saved atomically at the end.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import logging
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from lfstudio.calibration.model import CALIBRATION_NAME, load_calibration
from lfstudio.dataset import Dataset, images, view_stem
from lfstudio.dataset.grid import View
from lfstudio.dataset.manifest import ViewRecord, file_of, now_iso, processed_file_name
from lfstudio.dataset.paths import folder_inside
from lfstudio.dataset.profile import PROFILE_NAME, Profile
from lfstudio.dataset.storage import StorageError, storage_error
from lfstudio.dataset.store import clean_temporary_files
from lfstudio.errors import DatasetError, InputError, words
from lfstudio.jobs import CancelToken, Cancelled, Progress, no_progress
from lfstudio.processing import executors
from lfstudio.processing.worker import RunPlan, ViewResult, ViewTask, process_view, render, warm_up

log = logging.getLogger(__name__)

SAVE_EVERY_S = 3.0


@dataclass
class ProcessReport:
    processed: int = 0
    skipped: int = 0
    failed: list[tuple[int, int, str]] = field(default_factory=list)
    gains: dict[tuple[int, int], float] = field(default_factory=dict)
    elapsed_s: float = 0.0
    executor: str = ""
    output_folder: str = ""
    profile_sha256: str = ""
    notes: list[str] = field(default_factory=list)      # what the run decided (e.g. not to rotate the views)

    @property
    def ok(self) -> bool:
        return not self.failed

    def summary(self) -> str:
        text = (f"{self.processed} processed, {self.skipped} already done (skipped), {len(self.failed)} failed "
                f"in {self.elapsed_s:.1f} s on {self.executor}; output in {self.output_folder}")
        for note in self.notes:
            text += f"\n{note}"
        if self.gains:
            g = np.array(list(self.gains.values()))
            text += f"\nde-flicker gains: {g.min():.4f} .. {g.max():.4f} (median {np.median(g):.4f})"
        return text


def reference_view(ds: Dataset, profile: Profile) -> ViewRecord:
    views = ds.done_views()
    if not views:
        raise DatasetError(f"{ds.manifest_path}: no captured views to process; scan or import images first")
    ref = profile.reference
    if ref.row >= 0 or ref.column >= 0:
        for v in views:
            if v["row"] == ref.row and v["column"] == ref.column:
                return v
        raise InputError("processing.toml: [reference] row/column",
                         f"no captured view at row {ref.row}, column {ref.column}",
                         "a captured view, or -1/-1 for the middle of the grid")
    rows, cols = ds.grid.rows, ds.grid.columns
    r0, c0 = (rows - 1) / 2.0, (cols - 1) / 2.0
    return min(views, key=lambda v: ((v["row"] - r0) ** 2 + (v["column"] - c0) ** 2, v["row"], v["column"]))


def output_name(profile: Profile, row: int, column: int) -> str:
    ext = ".png" if profile.output.format == "png" else ".tif"
    return f"{profile.output.folder.strip('/') or 'processed'}/{view_stem(row, column)}{ext}"


def split_demosaic(ref_path: Path, profile: Profile, full_size_wh, out_size_wh) -> bool:
    """Whether views are demosaiced at the output size (luminance at full resolution, colour
    differences at half; see :mod:`lfstudio.processing.worker`): demosaic ``auto``, an RGB Bayer
    RAW, and an output at most half the capture's size."""
    step = profile.debayer
    if step.demosaic != "auto" or step.half_size or not images.is_raw(ref_path):
        return False
    (fw, fh), (ow, oh) = full_size_wh, out_size_wh
    if 2 * ow > fw + 1 or 2 * oh > fh + 1:
        return False
    return images.read_bayer(ref_path, step) is not None


def make_plan(ds: Dataset, profile: Profile, single_thread: bool = False) -> RunPlan:
    """Reference statistics and everything the tasks share (decodes the reference view once)."""
    from lfstudio.processing.steps import color, debayer, deflicker, rectify, resample, shading

    ref = reference_view(ds, profile)
    ref_path = ds.path_of(ref)
    full_size = images.full_size_px(ref_path)
    scale = debayer.processing_scale(ref_path, profile.debayer)
    out_size = resample.output_size(full_size, profile.resample.scale if profile.resample.enabled else scale)
    homography = None
    extra: dict[str, Any] = {}
    if profile.rectify.enabled:
        cal = load_calibration(ds)
        if cal is None:
            raise InputError(words("processing.toml: [rectify]", "6 Rectification (calibration)"),
                             words(f"{ds.root / CALIBRATION_NAME} not found", f"{ds.root.name} is not calibrated")
                             + "; calibrate the dataset first ("
                             + words(f"lfstudio calibrate {ds.root}", "Dataset → Calibrate…")
                             + ") or process without rectification ("
                             + words("--no-rectify, or enabled = false in processing.toml",
                                     "untick 6 Rectification (calibration) in this dialog") + ")")
        if list(cal["image_size_px"]) != list(full_size):
            raise DatasetError(f"{ds.root / CALIBRATION_NAME}: image_size_px {cal['image_size_px']} does not "
                               f"match the captures ({full_size[0]} x {full_size[1]} px); re-run the calibration")
        recorded = cal.get("lens_model")
        if isinstance(recorded, dict):      # files written before it was recorded: not checked
            from lfstudio.calibration.lens import lens_fingerprint
            current = lens_fingerprint(profile.lens)
            if recorded.get("sha256") != current["sha256"]:
                raise InputError(words("processing.toml: [lens]", "2 Lens distortion and lateral CA"),
                                 f"{words(str(ds.root / CALIBRATION_NAME), 'the calibration')} was fitted with lens "
                                 f"model {recorded.get('model')!r}, but processing applies {current['model']!r}: "
                                 f"calibrate again ({words(f'lfstudio calibrate {ds.root}', 'Dataset → Calibrate…')}) "
                                 "so both use the same lens model")
        homography = np.asarray(cal["homography"], float).tolist()
        extra["homography"] = [round(v, 12) for row in homography for v in row]
    flat_path = None
    if profile.shading.enabled and profile.shading.flat_file:
        p = Path(profile.shading.flat_file)
        flat_path = p if p.is_absolute() else ds.root / p
        if not flat_path.is_file():
            raise InputError("processing.toml: [shading] flat_file",
                             f"{flat_path} not found; capture a flat image (uniformly lit white card) and give its path")
        extra["flat_mtime"] = flat_path.stat().st_mtime_ns
    extra["reference"] = [ref["row"], ref["column"], ref.get("sha256")]
    sha = profile.sha256(extra)

    refusal = None
    if homography is not None:
        inside = rectify.inside_fraction(np.asarray(homography), full_size)
        if inside < rectify.MIN_INSIDE_FRACTION:
            refusal = (f"the rectified view would be {100 * (1 - inside):.0f} % black (outside the captured image): "
                       f"the likely cause is the calibration ({ds.root / CALIBRATION_NAME}); calibrate again "
                       "('lfstudio calibrate') or process without rectification ([rectify] enabled = false)")
    plan = RunPlan(root=str(ds.root), profile=profile.to_dict(), profile_sha256=sha, full_size_wh=(full_size[0], full_size[1]),
                   processing_scale=scale, output_size_wh=(out_size[0], out_size[1]), homography=homography,
                   camera=dict(ds.camera), lens=dict(ds.lens), flat_path=str(flat_path) if flat_path else None,
                   single_thread=single_thread, split_demosaic=split_demosaic(ref_path, profile, full_size, out_size),
                   rectify_refusal=refusal)
    needs_reference = profile.color.enabled or profile.deflicker.enabled or \
        (profile.shading.enabled and profile.shading.mode == "model" and not profile.shading.coefficients)
    if not needs_reference:
        return plan
    bayer = images.read_bayer(ref_path, profile.debayer) if plan.split_demosaic else None
    # the reference's statistics from the same demosaic the views get
    img = images.develop(ref_path, profile.debayer) if bayer is None else \
        debayer.output_rgb(debayer.demosaic_ea(bayer), bayer.rgb_cam)
    if profile.deflicker.enabled:
        plan.reference_small = deflicker.small_luminance(img, profile.deflicker.size_px)
    if profile.shading.enabled:
        flat = images.develop(flat_path, profile.debayer) if flat_path else None
        factor, coeffs = shading.correction(profile.shading, (img.shape[1], img.shape[0]), flat)
        plan.shading_coefficients = coeffs
        if profile.color.enabled:
            img = np.clip(img.astype(np.float32) * factor, 0, 65535).astype(np.uint16)
    if profile.color.enabled:
        plan.black_rgb, plan.white_rgb = color.levels(img, profile.color, scale)
    return plan


def _skip(view: ViewRecord, sha: str, ds: Dataset) -> bool:
    name = processed_file_name(view)
    if name is None or view.get("processed", {}).get("profile_sha256") != sha:
        return False
    return ds.path_of(name).is_file()


def _record(ds: Dataset, view: ViewRecord, result: ViewResult, sha: str) -> None:
    if result.error is None and result.out_file is not None:       # ok: the worker wrote out_file
        view["processed"] = {"status": "done", "file": result.out_file, "profile_sha256": sha,
                             "gain": round(result.gain, 6), "gain_support": round(result.gain_support, 4),
                             "stats": result.stats, "processed_at": now_iso(),
                             "timings_s": {k: round(v, 4) for k, v in result.timings_s.items()}}
    else:
        view["processed"] = {"status": "failed", "error": result.error or "no output file written",
                             "profile_sha256": sha,
                             "processed_at": now_iso()}


def process_dataset(dataset: Dataset | str | Path, profile: Profile | None = None, *, workers: int | None = None,
                    cluster: str | None = None, force: bool = False,
                    progress: Progress = no_progress, cancel: CancelToken | None = None,
                    on_view: Callable[[ViewResult], None] | None = None) -> ProcessReport:
    """Process every captured view of ``dataset``; see the module docstring. Raises :class:`Cancelled`."""
    t_start = time.monotonic()
    cancel = cancel or CancelToken()
    ds = Dataset.of(dataset)
    profile = profile or Profile.for_dataset(ds.root)
    progress(0, len(ds.done_views()), "reading the reference view")
    log.info("processing of %s started (%d captured views)", ds.root, len(ds.done_views()))
    with contextlib.ExitStack() as stack:
        info = stack.enter_context(executors.open_executor(workers, cluster))
        if info.separate_processes:  # workers start and import while this process reads the reference
            for _ in range(info.workers):
                info.executor.submit(warm_up)
        return _process(ds, profile, info, force, progress, cancel, on_view, t_start)


def _refuse_output_over_captures(ds: Dataset, profile: Profile) -> None:
    """A dataset whose captures already sit where processing writes (``import-hevc`` of an export of
    processed views restores them as ``processed/rRR_cCCC.png``) would have them overwritten."""
    for v in ds.done_views():
        out = output_name(profile, v["row"], v["column"])
        if os.path.normpath(str(v.get("file"))) == os.path.normpath(out):
            raise InputError("processing.toml: [output] folder",
                             f"the captures are the files processing would write (e.g. {out}; restored from an "
                             "HEVC export of processed views, they are processed already): export them as they "
                             "are, or set another [output] folder", 'e.g. folder = "reprocessed"')


def _process(ds: Dataset, profile: Profile, info: executors.ExecutorInfo, force: bool, progress: Progress,
             cancel: CancelToken, on_view, t_start: float) -> ProcessReport:
    _refuse_output_over_captures(ds, profile)
    # every processed view is written in this folder: refused when it (a symlink) leads outside the dataset
    folder = profile.output.folder.strip("/") or "processed"
    folder_inside(ds.root, folder, what="processing.toml: [output] folder", create=False)
    clean_temporary_files(ds.root, (folder,))        # left by a run that was killed
    plan = make_plan(ds, profile, single_thread=info.separate_processes)
    folder_inside(ds.root, folder, what="processing.toml: [output] folder")   # made once the run can start
    sha = plan.profile_sha256
    profile.save(ds.root / PROFILE_NAME)

    views = ds.done_views()
    todo = [v for v in views if force or not _skip(v, sha, ds)]
    report = ProcessReport(skipped=len(views) - len(todo), profile_sha256=sha,
                           output_folder=str(ds.root / profile.output.folder))
    if plan.homography is not None:
        from lfstudio.calibration.model import rectification_decision

        decided = rectification_decision(load_calibration(ds) or {})
        if decided:
            report.notes.append(f"rectification: {decided}")
    ref = reference_view(ds, profile)
    ds.manifest["processing"] = {
        "profile_file": PROFILE_NAME, "profile_sha256": sha, "profile": profile.to_dict(),
        "reference": {"row": ref["row"], "column": ref["column"],
                      "black_rgb": plan.black_rgb, "white_rgb": plan.white_rgb},
        "shading_coefficients": plan.shading_coefficients,
        "rectified": plan.homography is not None,
        "output_size_px": list(plan.output_size_wh), "started_at": now_iso(), "finished_at": None,
    }
    ds.save()
    total = len(views)
    done = report.skipped
    progress(done, total, f"{report.skipped} already processed" if report.skipped else "starting workers")
    by_index = {(v["row"], v["column"]): v for v in todo}
    last_save = time.monotonic()

    def finish(result: ViewResult) -> None:
        nonlocal done, last_save
        if result.disk:             # stop, keep what is processed (recorded below), run again later
            raise StorageError(result.error or "disk problem", kind="disk")
        _record(ds, by_index[result.view], result, sha)
        done += 1
        stem = result.view.name
        if result.ok:
            report.processed += 1
            report.gains[result.view] = result.gain
            progress(done, total, f"{stem} gain {result.gain:.4f}")
        else:
            report.failed.append((result.view.row, result.view.column, result.error or "failed"))
            progress(done, total, f"{stem} FAILED")
        if on_view is not None:
            on_view(result)
        if time.monotonic() - last_save > SAVE_EVERY_S:  # batch the manifest writes (journal-first)
            try:
                ds.checkpoint()
            except OSError as exc:
                raise storage_error(exc, ds.manifest_path, doing="saving",
                                    then="run 'lfstudio process' again (views already processed are kept)") or exc
            last_save = time.monotonic()

    try:
        if todo:
            report.executor = info.description
            _run(info, plan, profile, todo, finish, cancel)
        else:
            report.executor = "nothing to do"
    finally:
        ds.manifest["processing"]["finished_at"] = now_iso()
        ds.manifest["processing"]["summary"] = {"processed": report.processed, "skipped": report.skipped,
                                                "failed": len(report.failed)}
        try:
            ds.save()
        except OSError as exc:      # a full disk: the run's own error (if any) is the one to tell
            if sys.exc_info()[1] is None:
                raise
            log.info("saving %s after the run stopped failed: %s", ds.manifest_path, exc)
    report.elapsed_s = time.monotonic() - t_start
    log.info("processing of %s finished: %s", ds.root, report.summary().replace("\n", "; "))
    return report


def _run(info: executors.ExecutorInfo, plan: RunPlan, profile: Profile, todo: list[ViewRecord],
         finish: Callable[[ViewResult], None], cancel: CancelToken) -> None:
    """Submit a bounded window of tasks, collect results as they come, stop early on cancel."""
    window = max(2, 2 * info.workers)
    queue = list(todo)
    pending: dict[cf.Future, ViewRecord] = {}
    cancelled = False
    try:
        while queue or pending:
            while queue and len(pending) < window and not cancel.cancelled:
                v = queue.pop(0)
                task = ViewTask(View(v["row"], v["column"]), file_of(v), output_name(profile, v["row"], v["column"]))
                pending[info.executor.submit(process_view, plan, task)] = v
            if cancel.cancelled:
                cancelled = True
                queue.clear()
                for f in list(pending):
                    if f.cancel():
                        del pending[f]
            if not pending:
                break
            finished, _ = cf.wait(list(pending), timeout=0.25, return_when=cf.FIRST_COMPLETED)
            for f in finished:
                v = pending.pop(f)
                try:
                    result = f.result()
                except cf.CancelledError:
                    continue
                except Exception as exc:  # the worker process died (e.g. killed, out of memory)
                    result = ViewResult(View(v["row"], v["column"]), error=f"{v.get('file')}: worker failed "
                                        f"({type(exc).__name__}: {exc})")
                finish(result)
    finally:
        for f in pending:
            f.cancel()
    if cancelled or cancel.cancelled:
        raise Cancelled()


def preview(dataset: Dataset | str | Path, profile: Profile, row: int | None = None,
            column: int | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """(before, after, info) of one view without writing anything: ``before`` is the decoded capture
    resized to the output size, ``after`` the processed view (both uint16 RGB)."""
    from lfstudio.processing.steps import resample

    ds = Dataset.of(dataset)
    plan = make_plan(ds, profile)
    if row is None or column is None:
        if row is not None or column is not None:
            raise ValueError("preview: give the view's row and column, or neither (the reference view)")
        view = reference_view(ds, profile)
    else:
        view = ds.view(row, column)
    path = ds.path_of(view)
    after, info = render(plan, path)
    after = after.copy()   # render's image lives in a buffer the next render reuses
    before = resample.apply(images.develop(path, profile.debayer), plan.output_size_wh)
    info["row"], info["column"] = view["row"], view["column"]
    return before, after, info
