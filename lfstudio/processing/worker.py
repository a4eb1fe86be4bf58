"""The per-view task: one capture in, one processed 16-bit view out.

Everything a task needs travels in a small, picklable :class:`RunPlan` (reference statistics are
computed once up front by the pipeline). Heavy derived data (remap maps, the shading map in the
output frame) is built on first use in each worker process and cached there, keyed by the
profile hash, so a process pool or a Dask worker pays for it once per run.

Order of work (intensity steps are per-pixel and linear, so they commute with the warp and the
area resampling and are done last, on the small image): decode → de-flicker gain (measured on
the decoded view) → ONE remap (lens + rectification) → area resample → shading factor, gain,
black/white levels in one pass → encode.
"""

from __future__ import annotations

import os
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lfstudio.errors import LfError
from lfstudio.processing.profile import Profile

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

    @property
    def processing_size_wh(self) -> tuple[int, int]:
        w, h = self.full_size_wh
        s = self.processing_scale
        return (w, h) if s == 1.0 else ((w + 1) // 2, (h + 1) // 2)  # LibRaw half_size rounds up

    def get_profile(self) -> Profile:
        return Profile.from_dict(self.profile)


@dataclass
class ViewTask:
    row: int
    column: int
    file: str        # capture, relative to the dataset folder
    out_file: str    # processed view, relative to the dataset folder


@dataclass
class ViewResult:
    row: int
    column: int
    out_file: str | None = None
    gain: float = 1.0
    gain_support: float = 0.0    # fraction of the small image the gain was measured on
    stats: dict = field(default_factory=dict)
    timings_s: dict = field(default_factory=dict)
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


@dataclass
class _Prepared:
    profile: Profile
    maps: list | None
    level_map: tuple | None = None  # (per-pixel multiplier, offset): shading folded into the levels


def _factor_map_captured(plan: RunPlan, profile: Profile) -> np.ndarray | None:
    from lfstudio.processing.steps import debayer, shading

    if not profile.shading.enabled:
        return None
    size = plan.processing_size_wh
    if profile.shading.mode == "model":
        return shading.correction_from_model(size, plan.shading_coefficients)
    flat = debayer.decode(plan.flat_path, profile.debayer)
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
    _CACHE.clear()  # one run at a time per process: keep memory bounded
    _CACHE[plan.profile_sha256] = prepared
    return prepared


def render(plan: RunPlan, capture_path: str | Path) -> tuple[np.ndarray, dict[str, Any]]:
    """The processed view of one capture (uint16 RGB, output size) and facts about it."""
    from lfstudio.processing.steps import color, debayer, deflicker, rectify, resample

    t0 = time.perf_counter()
    prep = prepare(plan)
    profile = prep.profile
    t1 = time.perf_counter()
    img = debayer.decode(capture_path, profile.debayer)
    t2 = time.perf_counter()
    expected = plan.processing_size_wh
    if (img.shape[1], img.shape[0]) != tuple(expected):
        raise LfError(f"{capture_path}: image is {img.shape[1]} x {img.shape[0]} px, the reference view is "
                      f"{expected[0]} x {expected[1]} px; all views of a dataset must have the same size")
    gain, support = 1.0, 0.0
    if profile.deflicker.enabled and plan.reference_small is not None:
        small = deflicker.small_luminance(img, plan.reference_small.shape[1])
        gain, support = deflicker.gain(plan.reference_small, small, profile.deflicker)
    img = rectify.apply_maps(img, prep.maps, profile.rectify.interpolation)
    img = resample.apply(img, plan.output_size_wh)
    if prep.level_map is not None:
        img = color.apply_map(img, *prep.level_map, gain=gain)
    else:
        img = color.apply(img, gain=gain, black=plan.black_rgb, white=plan.white_rgb,
                          white_output=profile.color.white_output, enabled=profile.color.enabled)
    t3 = time.perf_counter()
    info = {"gain": gain, "gain_support": support,
            "timings_s": {"prepare": t1 - t0, "decode": t2 - t1, "process": t3 - t2}}
    return img, info


def image_stats(img: np.ndarray) -> dict[str, Any]:
    sample = img[::4, ::4].reshape(-1, img.shape[2] if img.ndim == 3 else 1)
    return {"mean_rgb": [round(float(v), 1) for v in sample.mean(axis=0)],
            "min": int(sample.min()), "max": int(sample.max()),
            "clipped_fraction": round(float((sample >= 65535).mean()), 6),
            "size_px": [int(img.shape[1]), int(img.shape[0])]}


def encode(img: np.ndarray, path: Path, profile: Profile) -> None:
    """Write ``img`` (uint16 RGB) atomically as 16-bit PNG or TIFF."""
    import cv2

    from lfstudio.dataset.atomic import atomic_write_with

    bgr = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    params = [cv2.IMWRITE_PNG_COMPRESSION, int(profile.output.png_compression)] \
        if profile.output.format == "png" else []

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
    result = ViewResult(task.row, task.column)
    try:
        if plan.single_thread:
            _single_thread()
        root = Path(plan.root)
        img, info = render(plan, root / task.file)
        t0 = time.perf_counter()
        encode(img, root / task.out_file, info_profile(plan))
        info["timings_s"]["encode"] = time.perf_counter() - t0
        result.out_file = task.out_file
        result.gain, result.gain_support = info["gain"], info["gain_support"]
        result.timings_s = info["timings_s"]
        result.stats = image_stats(img)
    except LfError as exc:
        result.error = str(exc)
    except MemoryError:
        result.error = f"{task.file}: out of memory; use fewer workers (--workers) or half_size debayering"
    except Exception as exc:  # a bug or a broken file: report it with the view, keep the run going
        result.error = f"{task.file}: {type(exc).__name__}: {exc}"
        traceback.print_exc()
    return result


def info_profile(plan: RunPlan) -> Profile:
    return prepare(plan).profile
