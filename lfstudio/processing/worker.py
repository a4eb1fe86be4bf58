"""The per-view task: one capture in, one processed 16-bit view out.

Everything a task needs travels in a small, picklable :class:`RunPlan` (reference statistics are
computed once up front by the pipeline). Heavy derived data (remap maps, the shading map in the
output frame) is built on first use in each worker process and cached there, keyed by the
profile hash, so a process pool or a Dask worker pays for it once per run.

Order of work (intensity steps are per-pixel and linear, so they commute with the warp and the
area resampling and are done last, on the small image): decode → de-flicker gain (measured on
the decoded view) → ONE remap (lens + rectification) → area resample → shading factor, gain,
black/white levels in one pass → encode.

When the plan demosaics at the output size (``RunPlan.split_demosaic``: demosaic ``auto``, a Bayer
RAW, output at most half the capture): the mosaic (:func:`lfstudio.dataset.images.read_bayer`) → OpenCV's
edge-aware demosaic; its green plane (the luminance) is warped at full resolution and area-averaged
to the output size; the colour differences R − G and B − G are taken at the R and B sites (a
half-resolution grid each) and warped there, each with its own sub-pixel position folded into the
warp; R = G + (R − G), B = G + (B − G); then the camera's colour matrix, shading, gain and levels in
one pass. Warping the full image after downsampling instead measured 2.7 dB worse against the
ground truth, so only the smooth colour differences are warped at the small size
(``benchmarks/processing_quality.py`` prints every candidate).

Work arrays are reused from view to view (:class:`Buffers`): allocating and first touching tens of
MB per view cost more than the arithmetic on them. The image :func:`render` returns lives in such a
buffer until the next view of the run in this process (copy it to keep it). PNG output uses zlib's
Huffman-only strategy when it makes files at most 2 % larger than the configured level on the first
view a process writes (it is 2-3× faster; on noisy 16-bit photographs it is usually smaller too).
"""

from __future__ import annotations

import os
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lfstudio.dataset import images
from lfstudio.dataset.grid import View
from lfstudio.dataset.profile import Profile
from lfstudio.dataset.storage import disk_problem, storage_error
from lfstudio.errors import DatasetError, LfError

if TYPE_CHECKING:
    from lfstudio.processing.steps.rectify import HomographyWarp

#: per-process cache: profile hash -> _Prepared
_CACHE: dict[str, "_Prepared"] = {}


@dataclass
class RunPlan:
    """What every task of one run shares (small: sent with each task)."""

    root: str
    profile: dict
    profile_sha256: str
    full_size_wh: tuple[int, int]
    processing_scale: float
    output_size_wh: tuple[int, int]
    homography: list | None = None
    camera: dict = field(default_factory=dict)
    lens: dict = field(default_factory=dict)
    black_rgb: list = field(default_factory=lambda: [0.0, 0.0, 0.0])
    white_rgb: list = field(default_factory=lambda: [65535.0] * 3)
    reference_small: np.ndarray | None = None
    shading_coefficients: list = field(default_factory=list)
    flat_path: str | None = None
    single_thread: bool = False
    split_demosaic: bool = False   # luminance at full resolution, colour differences at half (see module doc)
    rectify_refusal: str | None = None   # why every view would come out mostly black (the calibration)

    @property
    def processing_size_wh(self) -> tuple[int, int]:
        w, h = self.full_size_wh
        s = self.processing_scale
        return (w, h) if s == 1.0 else ((w + 1) // 2, (h + 1) // 2)  # LibRaw half_size rounds up

    def get_profile(self) -> Profile:
        return Profile.from_dict(self.profile)


@dataclass
class ViewTask:
    view: View       # the grid cell
    file: str        # capture, relative to the dataset folder
    out_file: str    # processed view, relative to the dataset folder


@dataclass
class ViewResult:
    view: View
    out_file: str | None = None
    gain: float = 1.0
    gain_support: float = 0.0    # fraction of the small image the gain was measured on
    stats: dict = field(default_factory=dict)
    timings_s: dict = field(default_factory=dict)
    error: str | None = None
    disk: bool = False           # the error is the disk's (full, read-only, ...): the run stops, it is not the view's

    @property
    def ok(self) -> bool:
        return self.error is None


class Buffers:
    """Arrays reused across the views of a run, by name (a new one only when shape or type change)."""

    def __init__(self) -> None:
        self._arrays: dict[str, np.ndarray] = {}

    def get(self, name: str, shape: tuple[int, ...], dtype: type[np.generic] = np.uint16) -> np.ndarray:
        a = self._arrays.get(name)
        if a is None or a.shape != tuple(shape) or a.dtype != np.dtype(dtype):
            a = self._arrays[name] = np.empty(shape, dtype)
        return a

    def __len__(self) -> int:
        return len(self._arrays)


@dataclass
class _Prepared:
    profile: Profile
    maps: list | HomographyWarp | None
    level_map: tuple | None = None  # (per-pixel multiplier, offset): shading folded into the levels
    luma_warp: Any = None           # split demosaic: the warp of the green plane (full resolution)
    chroma_warps: dict = field(default_factory=dict)   # Bayer pattern -> [R warp, B warp] (half resolution)
    buffers: Buffers = field(default_factory=Buffers)
    png_params: list | None = None  # decided on the first PNG this process writes for the run


def _factor_map_captured(plan: RunPlan, profile: Profile) -> np.ndarray | None:
    from lfstudio.processing.steps import shading

    if not profile.shading.enabled:
        return None
    size = plan.processing_size_wh
    if profile.shading.mode == "model":
        return shading.correction_from_model(size, plan.shading_coefficients)
    flat = images.develop(plan.flat_path, profile.debayer) if plan.flat_path else None
    factor, _ = shading.correction(profile.shading, size, flat)
    return factor


def prepare(plan: RunPlan) -> _Prepared:
    """Maps and shading map for ``plan`` (cached per process)."""
    cached = _CACHE.get(plan.profile_sha256)
    if cached is not None:
        return cached
    from lfstudio.processing.steps import lens as lens_step
    from lfstudio.processing.steps import rectify, resample

    profile = plan.get_profile()
    H = np.asarray(plan.homography, float) if (profile.rectify.enabled and plan.homography is not None) else None
    model = lens_step.lens_model(profile.lens, plan.full_size_wh, plan.camera, plan.lens)
    maps = rectify.build_maps(plan.processing_size_wh, plan.processing_scale, H, model)
    factor = _factor_map_captured(plan, profile)
    if factor is not None:
        if maps is not None:
            if factor.shape[2] == 1 and (isinstance(maps, rectify.HomographyWarp) or len(maps) == 1):
                factor = rectify.apply_maps(factor[:, :, 0], maps, profile.rectify.interpolation)[:, :, None]
            else:
                if factor.shape[2] == 1:
                    factor = np.repeat(factor, 3, axis=2)
                factor = rectify.apply_maps(factor, maps, profile.rectify.interpolation)
        factor = resample.apply(factor, plan.output_size_wh)
        if factor.ndim == 2:
            factor = factor[:, :, None]
        factor = np.ascontiguousarray(factor, np.float32)
    levels = None
    if factor is not None:
        from lfstudio.processing.steps import color
        levels = color.level_map(factor, plan.black_rgb, plan.white_rgb, profile.color.white_output,
                                 profile.color.enabled)
    prepared = _Prepared(profile, maps, levels)
    if plan.split_demosaic:
        # the green plane: the lens model's green channel (lateral CA is relative to green)
        prepared.luma_warp = maps[1:2] if isinstance(maps, list) and len(maps) == 3 else maps
    _CACHE.clear()  # one run at a time per process: keep memory bounded
    _CACHE[plan.profile_sha256] = prepared
    return prepared


def render(plan: RunPlan, capture_path: str | Path) -> tuple[np.ndarray, dict[str, Any]]:
    """The processed view of one capture (uint16 RGB, output size) and facts about it. The image
    lives in a buffer of this process that the next view of the run overwrites."""
    from lfstudio.processing.steps import color, debayer, rectify, resample

    t0 = time.perf_counter()
    prep = prepare(plan)
    profile = prep.profile
    buf = prep.buffers
    t1 = time.perf_counter()
    bayer = None
    if plan.split_demosaic:
        w, h = plan.full_size_wh
        bayer = images.read_bayer(capture_path, profile.debayer, out=buf.get("mosaic", (h, w)))
    if bayer is not None:
        _check_size(capture_path, bayer.mosaic.shape, plan.full_size_wh)
        img = debayer.demosaic_ea(bayer, dst=buf.get("demosaic", bayer.mosaic.shape + (3,)))
        t2 = time.perf_counter()
        gain, support = _deflicker_gain(plan, profile, img, bayer.rgb_cam)
        out = _render_split(plan, prep, bayer, img, gain)
    else:
        img = images.develop(capture_path, profile.debayer)
        t2 = time.perf_counter()
        _check_size(capture_path, img.shape, plan.processing_size_wh)
        gain, support = _deflicker_gain(plan, profile, img, None)
        out_w, out_h = plan.output_size_wh
        warped = rectify.apply_maps(img, prep.maps, profile.rectify.interpolation,
                                    dst=buf.get("warped", img.shape) if prep.maps is not None else None)
        small = warped if (warped.shape[1], warped.shape[0]) == (out_w, out_h) else \
            resample.apply(warped, plan.output_size_wh, dst=buf.get("resampled", (out_h, out_w, 3)))
        if prep.level_map is not None:
            out = color.apply_map(small, *prep.level_map, gain=gain, dst=buf.get("out", (out_h, out_w, 3)))
        else:
            out = color.apply(small, gain=gain, black=plan.black_rgb, white=plan.white_rgb,
                              white_output=profile.color.white_output, enabled=profile.color.enabled)
    t3 = time.perf_counter()
    info = {"gain": gain, "gain_support": support,
            "timings_s": {"prepare": t1 - t0, "decode": t2 - t1, "process": t3 - t2}}
    return out, info


def _check_size(capture_path, shape: tuple[int, ...], expected_wh: tuple[int, int]) -> None:
    if (shape[1], shape[0]) != tuple(expected_wh):
        raise LfError(f"{capture_path}: image is {shape[1]} x {shape[0]} px, the reference view is "
                      f"{expected_wh[0]} x {expected_wh[1]} px; all views of a dataset must have the same size")


def _deflicker_gain(plan: RunPlan, profile: Profile, img: np.ndarray, rgb_cam) -> tuple[float, float]:
    from lfstudio.processing.steps import deflicker

    if not (profile.deflicker.enabled and plan.reference_small is not None):
        return 1.0, 0.0
    small = deflicker.small_luminance(img, plan.reference_small.shape[1], rgb_cam)
    return deflicker.gain(plan.reference_small, small, profile.deflicker)


def chroma_offsets(bayer) -> list[tuple[float, float]]:
    """Where the R and B samples of a Bayer block sit relative to the block's centre, in pixels of
    the half-resolution grid (x, y): e.g. RGGB: R at (-0.25, -0.25), B at (+0.25, +0.25)."""
    out = []
    for colour in ("R", "B"):
        dy, dx = bayer.site(colour)
        out.append(((dx - 0.5) / 2.0, (dy - 0.5) / 2.0))
    return out


def _render_split(plan: RunPlan, prep: _Prepared, bayer, rgb: np.ndarray, gain: float) -> np.ndarray:
    import cv2

    from lfstudio.processing.steps import color, lens as lens_step, rectify, resample

    profile, buf = prep.profile, prep.buffers
    h, w = bayer.mosaic.shape
    hh, hw = h // 2, w // 2
    out_w, out_h = plan.output_size_wh
    inter = profile.rectify.interpolation
    # luminance: the green plane, warped at full resolution, then area-averaged to the output size
    green = cv2.extractChannel(rgb, 1, dst=buf.get("green", (h, w)))
    warped = green if prep.luma_warp is None else \
        rectify.apply_maps(green, prep.luma_warp, inter, dst=buf.get("green_warped", (h, w)))
    luma = resample.apply(warped, (out_w, out_h), dst=buf.get("luma", (out_h, out_w)))
    # colour differences at the R and B sites, warped on their half-resolution grid
    warps = prep.chroma_warps.get(bayer.pattern)
    if warps is None:
        H = np.asarray(plan.homography, float) if (profile.rectify.enabled and plan.homography is not None) else None
        model = lens_step.lens_model(profile.lens, plan.full_size_wh, plan.camera, plan.lens)
        r_off, b_off = chroma_offsets(bayer)
        built = rectify.build_maps((hw, hh), 0.5, H, model, offsets_px=[r_off, (0.0, 0.0), b_off])
        assert isinstance(built, list), "build_maps with offsets gives one warp per channel"
        r_warp, _, b_warp = built
        warps = prep.chroma_warps[bayer.pattern] = [r_warp, b_warp]
    mosaic_pairs = bayer.mosaic.reshape(h, w // 2, 2)   # (even column, odd column) as two channels
    green_pairs = green.reshape(h, w // 2, 2)
    planes = []
    for name, colour, warp in (("r", "R", warps[0]), ("b", "B", warps[1])):
        dy, dx = bayer.site(colour)
        sites = cv2.extractChannel(mosaic_pairs[dy::2], dx, dst=buf.get(f"{name}_sites", (hh, hw)))
        green_there = cv2.extractChannel(green_pairs[dy::2], dx, dst=buf.get("green_sites", (hh, hw)))
        diff = cv2.subtract(sites, green_there, dst=buf.get(f"{name}_diff", (hh, hw), np.float32), dtype=cv2.CV_32F)
        diff = rectify.apply_maps(diff, warp, inter, dst=buf.get(f"{name}_diff_warped", (hh, hw), np.float32))
        diff = resample.apply(diff, (out_w, out_h), dst=buf.get(f"{name}_diff_out", (out_h, out_w), np.float32))
        planes.append(cv2.add(luma, diff, dst=buf.get(f"{name}_out", (out_h, out_w), np.float32),
                              dtype=cv2.CV_32F))
    luma_f = buf.get("g_out", (out_h, out_w), np.float32)
    np.copyto(luma_f, luma)
    x = cv2.merge([planes[0], luma_f, planes[1]], dst=buf.get("camera_rgb", (out_h, out_w, 3), np.float32))
    return color.apply_camera(x, bayer.rgb_cam, gain=gain, level_map=prep.level_map, black=plan.black_rgb,
                              white=plan.white_rgb, white_output=profile.color.white_output,
                              enabled=profile.color.enabled, dst=buf.get("out", (out_h, out_w, 3)))


def image_stats(img: np.ndarray) -> dict[str, Any]:
    sample = img[::4, ::4].reshape(-1, img.shape[2] if img.ndim == 3 else 1)
    return {"mean_rgb": [round(float(v), 1) for v in sample.mean(axis=0)],
            "min": int(sample.min()), "max": int(sample.max()),
            "clipped_fraction": round(float((sample >= 65535).mean()), 6),
            "size_px": [int(img.shape[1]), int(img.shape[0])]}


def png_params(level: int, strategy: str) -> list[int]:
    """OpenCV's PNG options: ``deflate`` is zlib at ``level`` with libpng's adaptive filters;
    ``huffman`` is zlib's Huffman-only strategy (no string matching) with the Average filter."""
    import cv2

    if strategy == "huffman":
        return [cv2.IMWRITE_PNG_COMPRESSION, max(1, int(level)), cv2.IMWRITE_PNG_STRATEGY,
                cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_AVG]
    return [cv2.IMWRITE_PNG_COMPRESSION, int(level)]


#: Huffman-only is chosen (``png_strategy = "auto"``) when its sample is at most this much larger
HUFFMAN_MAX_GROWTH = 1.02


def choose_png_strategy(bgr: np.ndarray, level: int, rows_per_strip: int = 16, strips: int = 8) -> str:
    """``huffman`` or ``deflate`` for images like ``bgr``: both encode the same strips of rows (one
    in the middle of each of ``strips`` bands, ~10 % of a 2000 px high image), the smaller wins,
    Huffman-only (2-3× faster) also when it is at most 2 % larger."""
    import cv2

    if level == 0:
        return "deflate"   # stored, uncompressed: nothing is faster
    h = bgr.shape[0]
    if h <= 2 * rows_per_strip * strips:
        sample = bgr      # small: all of it (repeated rows would flatter zlib's string matching)
    else:
        starts = [int((i + 0.5) * h / strips) - rows_per_strip // 2 for i in range(strips)]
        sample = np.ascontiguousarray(np.concatenate([bgr[y:y + rows_per_strip] for y in starts]))
    sizes = {s: len(cv2.imencode(".png", sample, png_params(level, s))[1]) for s in ("deflate", "huffman")}
    return "huffman" if sizes["huffman"] <= HUFFMAN_MAX_GROWTH * sizes["deflate"] else "deflate"


def encode(img: np.ndarray, path: Path, profile: Profile, prep: _Prepared | None = None) -> None:
    """Write ``img`` (uint16 RGB) atomically as 16-bit PNG or TIFF. With ``prep`` (the run's
    prepared state in this process) the PNG strategy is decided once and buffers are reused."""
    import cv2

    from lfstudio.dataset.atomic import atomic_write_with

    bgr = cv2.cvtColor(img, cv2.COLOR_RGB2BGR, dst=prep.buffers.get("bgr", img.shape) if prep else None)
    params: list[int] = []
    if profile.output.format == "png":
        level, strategy = int(profile.output.png_compression), profile.output.png_strategy
        if strategy == "auto":
            if prep is None:
                strategy = choose_png_strategy(bgr, level)
            else:
                if prep.png_params is None:
                    prep.png_params = png_params(level, choose_png_strategy(bgr, level))
                params = prep.png_params
        if not params:
            params = png_params(level, strategy)

    def write(tmp: Path) -> None:
        if not cv2.imwrite(str(tmp), bgr, params):
            raise LfError(f"{path}: could not be written (disk full or no permission?)")

    atomic_write_with(path, write)


def _single_thread() -> None:
    if "rawpy" not in sys.modules:
        os.environ.setdefault("OMP_NUM_THREADS", "1")  # LibRaw's OpenMP: one process per core instead
    import cv2

    cv2.setNumThreads(1)


def warm_up() -> None:
    """Load the heavy modules in a fresh worker (submitted while the pipeline reads the reference)."""
    _single_thread()
    import rawpy  # noqa: F401

    from lfstudio.processing.steps import color, debayer, deflicker, rectify, resample  # noqa: F401


def process_view(plan: RunPlan, task: ViewTask) -> ViewResult:
    """Process one view and write it; never raises (errors come back in ``ViewResult.error``)."""
    result = ViewResult(task.view)
    cpu0 = time.thread_time()
    try:
        if plan.single_thread:
            _single_thread()
        if plan.rectify_refusal:
            raise DatasetError(f"{task.file}: {plan.rectify_refusal}")
        root = Path(plan.root)
        img, info = render(plan, root / task.file)
        t0 = time.perf_counter()
        encode(img, root / task.out_file, info_profile(plan), prepare(plan))
        info["timings_s"]["encode"] = time.perf_counter() - t0
        info["timings_s"]["cpu"] = time.thread_time() - cpu0      # this view's own CPU, whatever the load
        result.out_file = task.out_file
        result.gain, result.gain_support = info["gain"], info["gain_support"]
        result.timings_s = info["timings_s"]
        result.stats = image_stats(img)
    except (LfError, OSError) as exc:
        out = Path(plan.root) / task.out_file
        disk = storage_error(exc, out, then="run 'lfstudio process' again (views already processed are kept)") \
            or disk_problem(out.parent, 2**20)
        result.disk = disk is not None
        result.error = str(disk) if disk is not None else \
            str(exc) if isinstance(exc, LfError) else f"{task.file}: {type(exc).__name__}: {exc}"
    except MemoryError:
        result.error = f"{task.file}: out of memory; use fewer workers (--workers) or half_size debayering"
    except Exception as exc:  # a bug or a broken file: report it with the view, keep the run going
        result.error = f"{task.file}: {type(exc).__name__}: {exc}"
        traceback.print_exc()
    return result


def info_profile(plan: RunPlan) -> Profile:
    return prepare(plan).profile
