"""The exposure-bracket merge: every bracketed view's frames → one linear radiance image.

After debayering (LibRaw with the profile's ``[debayer]`` settings: linear, black subtracted, white
balanced) each frame ``k`` is a linear image ``z_k`` (0 … 1 of full scale) taken with exposure
``t_k`` (the shutter time the camera *reported* for that frame: ``views[i].frames[k].exposure_s``).
A frame's pixel is left out of the merge when it is

* **clipped**: any channel of the developed pixel at or above ``clip_fraction`` of full scale, or the
  sensor's own mosaic saturated within one pixel of it (the demosaic spreads a clipped site);
* **in the noise floor**: its brightest channel below ``noise_floor`` of full scale.

What is left is merged as ``L = Σ z_k / Σ t_k`` over the frames that keep the pixel (the maximum
likelihood radiance for photon noise: each frame weighted by its exposure time), in units of the
reference frame's full scale per reference exposure (1.0 = just clipping in the reference frame).
A pixel every frame clips takes its shortest frame's value (a lower bound: counted as clipped in the
merge); one below the noise floor in every frame takes the longest frame's. The weights are the same
function of the same thresholds and the same recorded exposures at every view, so the light field
stays consistent from view to view (no per-view normalisation, no tone curve in the radiance).

The radiance then goes through the processing's geometry (lens model, rectification, the output size:
:func:`lfstudio.processing.worker.prepare`), so it lines up pixel for pixel with ``processed/``; it is
not de-flickered, shaded or levelled (those are display normalisations). Outputs per view:
``hdr/rRR_cCCC.exr`` (OpenEXR, ZIP; or ``.tif`` float TIFF; 32-bit float, or 16-bit half with
``half``) and ``hdr/preview/rRR_cCCC.png``: a 16-bit tone-mapped picture (Reinhard's global operator
with one key for the whole dataset, sRGB-encoded).

Frames of a view come from one stop of the rig, so they should line up; their misalignment is
measured (phase correlation of each frame's radiance against the reference frame's, on the pixels
both keep) and recorded per frame in full-size pixels; a view with a frame further off than
``max_shift_px`` is named in the report (it is merged all the same: a static scene needs no
de-ghosting).
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import json
import logging
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lfstudio.dataset import Dataset, images, view_stem
from lfstudio.dataset.atomic import atomic_write_with
from lfstudio.dataset.bracket import Bracket
from lfstudio.dataset.manifest import HdrFailed, HdrMerged, ViewRecord, hdr_merged, now_iso
from lfstudio.dataset.paths import folder_inside
from lfstudio.dataset.profile import Profile
from lfstudio.dataset.store import clean_temporary_files
from lfstudio.errors import DatasetError, InputError
from lfstudio.jobs import CancelToken, Cancelled, Progress, no_progress
from lfstudio.numbers import Number, check_described, described, params_of
from lfstudio.processing import executors

log = logging.getLogger(__name__)

FORMATS = ("exr", "tiff")
FULL_SCALE = 65535.0


_FORMAT, _CLIP, _NOISE = "hdr format", "clipped", "noise"


@dataclass(frozen=True)
class MergeOptions:
    """How brackets are merged (the same for every view of a run), each setting described once
    (:func:`lfstudio.numbers.described`): ``lfstudio process``'s ``--hdr*`` options are made from these
    descriptions and :meth:`__post_init__` checks by them."""

    format: str = described("exr", choices=FORMATS, label="HDR format", option="--hdr", group=_FORMAT,
                            tip="exr: OpenEXR (ZIP); tiff: float TIFF")
    half: bool = described(False, flag=True, label="Half floats", option="--hdr-half", group=_FORMAT,
                           tip="16-bit half floats instead of 32-bit in the HDR files")
    clip_fraction: float = described(
        0.97, number=Number("", 0.5, 1.0), label="Clipped at", option="--hdr-clip", metavar="F", group=_CLIP,
        tip="a developed channel at or above this share of full scale counts as clipped")
    noise_floor: float = described(
        0.002, number=Number("", 0.0, 0.25), label="Noise floor", option="--hdr-noise-floor", metavar="F",
        group=_NOISE, tip="a pixel whose brightest channel is below this share of full scale counts as noise")
    max_shift_px: float = described(
        0.5, number=Number("px", 0, 1000), label="Largest frame shift", group=_CLIP,
        tip="frames further apart than this (full-size px) are reported")
    folder: str = "hdr"
    preview: bool = True             # the 16-bit tone-mapped PNG beside each radiance file

    def __post_init__(self) -> None:
        check_described(self, lambda name: MERGE_PARAMS[name].option or name)

    @property
    def suffix(self) -> str:
        return ".exr" if self.format == "exr" else ".tif"

    def sha256(self) -> str:
        return hashlib.sha256(json.dumps(asdict(self), sort_keys=True).encode()).hexdigest()


#: every described merge setting, by field
MERGE_PARAMS = params_of(MergeOptions)


# -- the merge itself (pure arrays) ---------------------------------------------------------------
@dataclass
class Merged:
    radiance: np.ndarray                    # (h, w, 3) float32
    clipped_frames: list[float]             # share of pixels clipped in each frame
    clipped_merged: float                   # share clipped in every frame
    noise_merged: float                     # share below the noise floor in every frame
    shifts_px: list[list[float] | None]     # each frame against the reference frame (processing px)


def clipped_mask(developed: np.ndarray, saturated: np.ndarray | None, clip_fraction: float) -> np.ndarray:
    """Pixels of a developed frame (uint16 or 0…1 float) that carry no radiance: a channel at or above
    ``clip_fraction`` of full scale, or (``saturated``: the sensor's saturated sites at the developed
    size) a saturated site within one pixel."""
    scale = FULL_SCALE if developed.dtype == np.uint16 else 1.0
    mask = np.asarray((developed >= clip_fraction * scale).any(axis=2))
    if saturated is not None:
        mask |= saturated
    return cv2.dilate(mask.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)


def merge_frames(frames: list[np.ndarray], clipped: list[np.ndarray], exposures: list[float], reference: int,
                 noise_floor: float) -> Merged:
    """``L = Σ z_k / Σ t_k`` over the frames that keep each pixel (see the module docstring).
    ``frames``: linear (h, w, 3) float32 0…1; ``exposures``: seconds; result in reference full scale
    per reference exposure."""
    t_ref = float(exposures[reference])
    rel = [float(t) / t_ref for t in exposures]
    h, w = frames[0].shape[:2]
    num = np.zeros((h, w, 3), np.float32)
    den = np.zeros((h, w), np.float32)
    all_clipped = np.ones((h, w), bool)
    all_dark = np.ones((h, w), bool)
    clipped_share = []
    for z, clip, t in zip(frames, clipped, rel):
        dark = z.max(axis=2) < noise_floor
        keep = ~clip & ~dark
        num += z * keep[..., None]
        den += keep * np.float32(t)
        all_clipped &= clip
        all_dark &= dark & ~clip
        clipped_share.append(float(clip.mean()))
    with np.errstate(invalid="ignore", divide="ignore"):
        radiance = num / den[..., None]
    shortest, longest = int(np.argmin(rel)), int(np.argmax(rel))
    none = den == 0
    if none.any():
        fallback = np.where(all_clipped[..., None] | ~all_dark[..., None],
                            frames[shortest] / np.float32(rel[shortest]), frames[longest] / np.float32(rel[longest]))
        radiance[none] = fallback[none]
    shifts = [[0.0, 0.0] if k == reference else frame_shift_px(frames[k] / np.float32(rel[k]),
                                                              frames[reference], clipped[k] | clipped[reference])
              for k in range(len(frames))]
    return Merged(radiance.astype(np.float32, copy=False), clipped_share, float(all_clipped.mean()),
                  float((all_dark & ~all_clipped).mean()), shifts)


def frame_shift_px(a: np.ndarray, b: np.ndarray, masked: np.ndarray, size_px: int = 512) -> list[float] | None:
    """(dx, dy) of ``a`` against ``b`` (both radiance, the same scale) by phase correlation of their log
    luminance, pixels either clips set to ``b``'s (so they agree there); in ``a``'s pixels, good to about
    0.3 px (the correlation peak's sub-pixel centroid). None for an image too small to tell (under 16 px)."""
    if min(a.shape[:2]) < 16:
        return None
    la = a.mean(axis=2)
    lb = b.mean(axis=2)
    la = np.where(masked, lb, la)
    scale = min(1.0, size_px / max(la.shape))
    if scale < 1.0:
        size = (max(8, int(la.shape[1] * scale)), max(8, int(la.shape[0] * scale)))
        la = cv2.resize(la, size, interpolation=cv2.INTER_AREA)
        lb = cv2.resize(lb, size, interpolation=cv2.INTER_AREA)
    la = np.log(np.maximum(la, 1e-4)).astype(np.float32)
    lb = np.log(np.maximum(lb, 1e-4)).astype(np.float32)
    window = cv2.createHanningWindow((la.shape[1], la.shape[0]), cv2.CV_32F)
    (dx, dy), _ = cv2.phaseCorrelate(lb, la, window)
    return [round(float(dx) / scale, 3), round(float(dy) / scale, 3)]


def tone_map(radiance: np.ndarray, key_radiance: float) -> np.ndarray:
    """16-bit sRGB picture of ``radiance``: Reinhard's global operator L·a/key / (1 + L·a/key) with
    a = 0.18 (``key_radiance``: the dataset's log-average luminance, one for every view)."""
    lum = radiance.mean(axis=2, keepdims=True)
    scaled = lum * np.float32(0.18 / max(key_radiance, 1e-9))
    mapped = radiance * (scaled / (1.0 + scaled) / np.maximum(lum, 1e-9))
    x = np.clip(mapped, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(srgb * 65535.0).astype(np.uint16)


def log_average(radiance: np.ndarray) -> float:
    lum = radiance.mean(axis=2)
    return float(np.exp(np.mean(np.log(np.maximum(lum[::4, ::4], 1e-4)))))


# -- files ---------------------------------------------------------------------------------------------
def write_radiance(path: Path, radiance: np.ndarray, half: bool) -> None:
    """``radiance`` (h, w, 3) as OpenEXR (by the ``.exr`` suffix) or float TIFF, atomically."""
    data = np.ascontiguousarray(radiance.astype(np.float16 if half else np.float32))

    def write(tmp: Path) -> None:
        if path.suffix == ".exr":
            import OpenEXR

            header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
            with OpenEXR.File(header, {"RGB": data}) as f:
                f.write(str(tmp))
        else:
            import tifffile

            tifffile.imwrite(tmp, data, photometric="rgb", compression="zlib")

    atomic_write_with(path, write)


def read_radiance(path: str | os.PathLike) -> np.ndarray:
    """A radiance file written by :func:`write_radiance` as (h, w, 3) float32."""
    path = Path(path)
    if path.suffix == ".exr":
        import OpenEXR

        with OpenEXR.File(str(path)) as f:
            channels = f.channels()
            if "RGB" in channels:
                return np.asarray(channels["RGB"].pixels, np.float32)
            return np.dstack([np.asarray(channels[c].pixels, np.float32) for c in "RGB"])
    import tifffile

    return np.asarray(tifffile.imread(path), np.float32)


def _write_png16(path: Path, rgb16: np.ndarray) -> None:
    bgr = cv2.cvtColor(rgb16, cv2.COLOR_RGB2BGR)

    def write(tmp: Path) -> None:        # (the temporary name keeps the .png suffix)
        if not cv2.imwrite(str(tmp), bgr):
            raise OSError(f"{path}: cannot write the preview (disk full or no permission?)")

    atomic_write_with(path, write)


# -- one view (runs in a worker process) ------------------------------------------------------------
@dataclass
class HdrTask:
    row: int
    column: int
    files: list[str]                 # every frame's file, in frame order
    exposures_s: list[float]
    reference: int
    out_file: str
    preview_file: str | None
    key_radiance: float | None = None


@dataclass
class HdrResult:
    row: int
    column: int
    record: HdrMerged | None = None       # the view's ``hdr`` record, or None and the error
    error: str | None = None


def saturated_pixels(sites: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The developed image's saturated pixels (``shape``) from the sensor's saturated sites: a pixel
    made from several sites (half-size debayering, a smaller processing size) is saturated when any
    of them is (averaged with unsaturated neighbours it no longer looks clipped, yet is wrong)."""
    if sites.shape == tuple(shape):
        return sites.astype(bool)
    return cv2.resize(sites.astype(np.float32), (shape[1], shape[0]), interpolation=cv2.INTER_AREA) > 0


def develop_frame(plan: Any, path: Path, clip_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """(linear float32 0…1 at the processing size, its clipped mask) of one frame."""
    profile = plan.get_profile()
    img = images.develop(path, profile.debayer)
    if (img.shape[1], img.shape[0]) != tuple(plan.processing_size_wh):
        raise DatasetError(f"{path}: image is {img.shape[1]} x {img.shape[0]} px, the dataset's views are "
                           f"{plan.processing_size_wh[0]} x {plan.processing_size_wh[1]} px")
    saturated = None
    if images.is_raw(path):
        bayer = images.read_bayer(path, profile.debayer)
        if bayer is not None:
            saturated = saturated_pixels(bayer.mosaic >= clip_fraction * FULL_SCALE, img.shape[:2])
    scale = FULL_SCALE if img.dtype == np.uint16 else float(np.iinfo(img.dtype).max) if img.dtype.kind == "u" else 1.0
    mask = clipped_mask(img if img.dtype == np.uint16 else (img / scale).astype(np.float32), saturated, clip_fraction)
    return (img.astype(np.float32) / np.float32(scale)), mask


def merge_view(plan: Any, options: MergeOptions, task: HdrTask) -> HdrResult:
    """Merge, warp to the processing's geometry, write; the view's ``hdr`` record (or the error)."""
    from lfstudio.processing.steps import rectify, resample
    from lfstudio.processing.worker import prepare

    t0, c0 = time.perf_counter(), time.process_time()
    try:
        root = Path(plan.root)
        developed = [develop_frame(plan, root / f, options.clip_fraction) for f in task.files]
        t1 = time.perf_counter()
        merged = merge_frames([d[0] for d in developed], [d[1] for d in developed], task.exposures_s,
                              task.reference, options.noise_floor)
        prep = prepare(plan)
        warped = rectify.apply_maps(merged.radiance, prep.maps, prep.profile.rectify.interpolation)
        out = resample.apply(warped, plan.output_size_wh)
        out = np.ascontiguousarray(np.maximum(out, 0), np.float32)
        t2 = time.perf_counter()
        write_radiance(root / task.out_file, out, options.half)
        if task.preview_file:
            _write_png16(root / task.preview_file, tone_map(out, task.key_radiance or log_average(out)))
        scale = 1.0 / plan.processing_scale
        shifts = [None if s is None else [round(v * scale, 3) for v in s] for s in merged.shifts_px]
        measured = [float(np.hypot(*s)) for s in shifts if s is not None]
        lum = out.mean(axis=2)
        record: HdrMerged = {"status": "done", "file": task.out_file, "preview": task.preview_file,
                  "options_sha256": options.sha256(), "frames": len(task.files),
                  "exposures_s": [float(t) for t in task.exposures_s], "reference_frame": task.reference,
                  "clipped_fraction": {"frames": [round(v, 6) for v in merged.clipped_frames],
                                       "merged": round(merged.clipped_merged, 6)},
                  "noise_floor_fraction": round(merged.noise_merged, 6),
                  "misalignment_px": shifts,
                  "max_misalignment_px": round(max(measured), 3) if measured else None,
                  "radiance": {"min": float(lum.min()), "median": float(np.median(lum)), "max": float(lum.max())},
                  "timings_s": {"decode": round(t1 - t0, 4), "merge": round(t2 - t1, 4),
                                "total": round(time.perf_counter() - t0, 4),
                                "cpu": round(time.process_time() - c0, 4)},
                  "merged_at": now_iso()}
        return HdrResult(task.row, task.column, record)
    except Exception as exc:           # one view's problem is reported; the others go on
        return HdrResult(task.row, task.column, error=f"{task.files[task.reference]}: {type(exc).__name__}: {exc}"
                         if not isinstance(exc, (DatasetError, InputError, OSError)) else str(exc))


# -- the dataset -------------------------------------------------------------------------------------
@dataclass
class MergeReport:
    merged: int = 0
    skipped: int = 0
    failed: list[tuple[int, int, str]] = field(default_factory=list)
    misaligned: list[tuple[int, int, float]] = field(default_factory=list)
    clipped_reference: float = 0.0             # mean share clipped in the reference frames
    clipped_merged: float = 0.0                # mean share clipped in every frame
    elapsed_s: float = 0.0
    cpu_s_per_view: float = 0.0
    folder: str = ""
    executor: str = ""                         # where the views were merged (processes here, a Dask cluster)

    def summary(self) -> str:
        text = (f"HDR: {self.merged} views merged, {self.skipped} already merged, {len(self.failed)} failed in "
                f"{self.elapsed_s:.1f} s{f' on {self.executor}' if self.executor else ''} "
                f"({self.cpu_s_per_view:.2f} s CPU per view); clipped "
                f"{100 * self.clipped_reference:.2f} % in the reference frames, {100 * self.clipped_merged:.2f} % "
                f"after the merge; output in {self.folder}")
        if self.misaligned:
            worst = max(self.misaligned, key=lambda m: m[2])
            text += (f"\nframes misaligned by more than the limit in {len(self.misaligned)} view(s) (worst r{worst[0]:02d} "
                     f"c{worst[1]:03d}: {worst[2]:.2f} px): check the rig's settle time and vibration")
        return text


def bracket_of(ds: Dataset) -> Bracket:
    recorded = ds.manifest.get("bracket")
    if not recorded:
        raise DatasetError(f"{ds.manifest_path}: the dataset has no exposure bracket (scan with --bracket); "
                           "nothing to merge")
    return Bracket.from_manifest(recorded, f"{ds.manifest_path}: bracket")


def _task(ds: Dataset, v: ViewRecord, options: MergeOptions, bracket: Bracket) -> HdrTask:
    frames = v.get("frames") or []
    if len(frames) != bracket.frames:
        raise DatasetError(f"{ds.manifest_path}: view r{v['row']:02d} c{v['column']:03d} has {len(frames)} frame(s), "
                           f"the bracket {bracket.frames}; re-capture it")
    exposures = []
    for k, f in enumerate(frames):
        t = f.get("exposure_s") or f.get("shutter_s")
        if not isinstance(t, (int, float)) or not t > 0:
            raise DatasetError(f"{ds.manifest_path}: view r{v['row']:02d} c{v['column']:03d} frame {k}: no exposure "
                               "recorded; the merge needs each frame's exposure")
        exposures.append(float(t))
    for f in frames:
        ds.path_of(f["file"])             # refused when it leads outside the folder
    stem = view_stem(v["row"], v["column"])
    folder = options.folder.strip("/")
    return HdrTask(v["row"], v["column"], [f["file"] for f in frames], exposures,
                   int(v.get("reference_frame", bracket.reference_index)), f"{folder}/{stem}{options.suffix}",
                   f"{folder}/preview/{stem}.png" if options.preview else None)


def _merged_already(ds: Dataset, view: ViewRecord, options_sha256: str) -> bool:
    """The view's radiance is merged with these options and its file is there (nothing to do)."""
    hdr = hdr_merged(view)
    return hdr is not None and hdr.get("options_sha256") == options_sha256 and (ds.root / hdr["file"]).is_file()


def merge_dataset(dataset: Dataset | str | Path, options: MergeOptions | None = None, profile: Profile | None = None,
                  *, workers: int | None = None, cluster: str | None = None, force: bool = False,
                  progress: Progress = no_progress, cancel: CancelToken | None = None) -> MergeReport:
    """Merge every captured view's bracket (see the module docstring); records ``views[i].hdr`` and
    ``dataset.json`` → ``hdr``. Views merged before with the same options whose file exists are skipped.
    ``workers``/``cluster`` as for :func:`lfstudio.processing.pipeline.process_dataset` (a Dask
    scheduler's workers must see the dataset at the same path: they read the frames and write the
    merged files; the manifest is written here). Raises :class:`Cancelled`."""
    from lfstudio.processing.pipeline import make_plan

    t_start = time.monotonic()
    cancel = cancel or CancelToken()
    options = options or MergeOptions()
    ds = Dataset.of(dataset)
    bracket = bracket_of(ds)
    profile = profile or Profile.for_dataset(ds.root)
    folder = folder_inside(ds.root, options.folder.strip("/") or "hdr", what="--hdr folder")
    folder.mkdir(exist_ok=True)
    if options.preview:
        (folder / "preview").mkdir(exist_ok=True)
    clean_temporary_files(ds.root, (options.folder.strip("/"),))
    views = ds.done_views()
    tasks = [_task(ds, v, options, bracket) for v in views]
    sha = options.sha256()
    todo = [t for t, v in zip(tasks, views) if force or not _merged_already(ds, v, sha)]
    report = MergeReport(skipped=len(tasks) - len(todo), folder=str(folder))
    progress(0, len(tasks), "reading the reference view")
    plan = make_plan(ds, profile)
    if plan.rectify_refusal:
        raise DatasetError(f"{ds.root}: {plan.rectify_refusal}")
    # one tone-map key for the whole dataset: the reference view's merged log-average luminance
    key_task = next((t for t in tasks if (t.row, t.column) == tuple(ds.manifest.get("processing", {}).get(
        "reference", {}).get(k) for k in ("row", "column"))), tasks[len(tasks) // 2] if tasks else None)
    key = None
    if key_task is not None and options.preview:
        probe = merge_view(plan, MergeOptions(**{**asdict(options), "preview": False, "folder": options.folder}),
                           HdrTask(key_task.row, key_task.column, key_task.files, key_task.exposures_s,
                                   key_task.reference, key_task.out_file, None))
        if probe.record is not None:
            key = max(1e-6, probe.record["radiance"]["median"])
    for t in todo:
        t.key_radiance = key
    ds.manifest["hdr"] = {"options": asdict(options), "options_sha256": sha, "bracket": bracket.to_manifest(),
                          "weights": {"rule": "L = sum(z_k) / sum(t_k) over frames neither clipped nor in the "
                                              "noise floor (each frame weighted by its exposure time)",
                                      "clip_fraction": options.clip_fraction, "noise_floor": options.noise_floor,
                                      "unit": "reference frame's full scale per reference exposure"},
                          "tone_map": {"operator": "reinhard-global", "key_radiance": key},
                          "output_size_px": list(plan.output_size_wh), "rectified": plan.homography is not None,
                          "started_at": now_iso(), "finished_at": None}
    ds.save()
    done = report.skipped
    cpu = []
    with executors.open_executor(workers, cluster) as info:
        report.executor = info.description
        pending = {}
        queue = list(todo)
        window = max(2, 2 * info.workers)
        try:
            while queue or pending:
                while queue and len(pending) < window and not cancel.cancelled:
                    t = queue.pop(0)
                    pending[info.executor.submit(merge_view, plan, options, t)] = t
                if cancel.cancelled:
                    for f in list(pending):
                        f.cancel()
                    raise Cancelled()
                finished, _ = cf.wait(list(pending), timeout=0.25, return_when=cf.FIRST_COMPLETED)
                for f in finished:
                    t = pending.pop(f)
                    try:
                        result = f.result()
                    except Exception as exc:       # the worker process died
                        result = HdrResult(t.row, t.column, error=f"worker failed ({type(exc).__name__}: {exc})")
                    view = ds.view(result.row, result.column)
                    if result.record is None:
                        error = result.error or "the merge returned nothing"
                        report.failed.append((result.row, result.column, error))
                        failed: HdrFailed = {"status": "failed", "error": error, "options_sha256": sha,
                                             "merged_at": now_iso()}
                        view["hdr"] = failed
                    else:
                        report.merged += 1
                        view["hdr"] = result.record
                        cpu.append(result.record["timings_s"]["cpu"])
                        shift = result.record["max_misalignment_px"]
                        if shift is not None and shift > options.max_shift_px:
                            report.misaligned.append((result.row, result.column, shift))
                    done += 1
                    progress(done, len(tasks), f"merged r{result.row:02d} c{result.column:03d}")
        finally:
            for f in pending:
                f.cancel()
            ds.manifest["hdr"]["finished_at"] = now_iso()
            ds.save()
    records = [hdr for v in ds.done_views() if (hdr := hdr_merged(v)) is not None]
    if records:
        report.clipped_reference = float(np.mean([r["clipped_fraction"]["frames"][r["reference_frame"]]
                                                  for r in records]))
        report.clipped_merged = float(np.mean([r["clipped_fraction"]["merged"] for r in records]))
    report.cpu_s_per_view = float(np.mean(cpu)) if cpu else 0.0
    report.elapsed_s = time.monotonic() - t_start
    ds.manifest["hdr"]["summary"] = {"merged": report.merged, "skipped": report.skipped, "failed": len(report.failed),
                                     "misaligned": len(report.misaligned)}
    ds.save()
    log.info("%s", report.summary().replace("\n", "; "))
    return report
