"""Render a whole dataset from the virtual studio straight to disk (no rig, no scan engine).

The result is a real :class:`lfstudio.dataset.Dataset` folder (``raw/r00_c000.dng`` or 16-bit
linear PNG per view, every view ``done``, its grid thumbnail ``thumbs/r00_c000.jpg`` made from the
rendered image in memory) plus ``ground_truth.json`` at its root with the true
orientation, intrinsics, rectifying homography, per-view true positions and layer depths (see
:mod:`lfstudio.sim.studio` for the conventions). Used by tests, benchmarks and demos.

Ground-truth maps (``truth_maps``, on by default), one per rendered view, float32 TIFF (deflate),
the views' full size, read back with :func:`read_truth_map`:

- ``truth/depth/rRR_cCCC.tif``: depth in **metres** (z of the visible surface) of the view as
  captured (the pixels of ``raw/rRR_cCCC.*``);
- ``truth/depth_rectified/rRR_cCCC.tif``: the same for the rectified view (the ideal camera: the
  pixels of a processed view rectified at full size);
- ``truth/disparity_rectified/rRR_cCCC.tif``: disparity in **pixels between horizontal
  neighbours** of the rectified view, ``f · spacing_x / (1000 · Z)`` (the HCI convention; zero at
  infinity).

``root`` must be missing or empty (:func:`lfstudio.dataset.paths.check_new_dataset_folder`): a
virtual dataset is never rendered into another dataset or among other files.

``faults`` (:class:`lfstudio.sim.studio.ViewFault`) spoil chosen views (blur, luminance step,
displacement, a skipped move); ``ground_truth.json`` lists them under ``faults`` and each view's
``true_mm`` is where the camera really stood.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import cv2
import numpy as np

from lfstudio.dataset import Dataset
from lfstudio.dataset.atomic import atomic_write_json, atomic_write_with
from lfstudio.dataset.grid import DEFAULT_ORDER, Grid, grid_order
from lfstudio.dataset.manifest import ViewRecord, camera_problems, now_iso
from lfstudio.dataset.paths import check_new_dataset_folder, view_stem
from lfstudio.dataset.store import sha256_file
from lfstudio.dataset.thumbs import make_thumbnail
from lfstudio.errors import InputError
from lfstudio.jobs import CancelToken
from lfstudio.optics import REFERENCE
from lfstudio.sim.dng import DEFAULT_NEUTRAL, mosaic_from_rgb, write_dng
from lfstudio.sim.sensor import SensorModel
from lfstudio.sim.studio import DEFAULT_WIDTH_PX, ViewFault, VirtualStudio

GROUND_TRUTH_NAME = "ground_truth.json"
TRUTH_DIR = "truth"
#: the kinds of ground-truth map (``truth/KIND/rRR_cCCC.tif``): see the module docstring
TRUTH_MAPS = ("depth", "depth_rectified", "disparity_rectified")
BLACK_LEVEL = 512
WHITE_LEVEL = 16383
SIM_CAMERA_NAME = "Simulated studio camera"


def camera_dict(studio: VirtualStudio) -> dict[str, Any]:
    """The manifest's ``camera`` entry for a studio (so ``Dataset.focal_length_px()`` is right)."""
    return {"name": SIM_CAMERA_NAME, "sensor_px": [studio.width_px, studio.height_px],
            "sensor_mm": [studio.sensor_width_mm, studio.sensor_width_mm * studio.height_px / studio.width_px],
            "pixel_pitch_um": studio.sensor_width_mm / studio.width_px * 1000.0,
            "raw_format": "DNG", "bits": 14, "simulated": True}


def lens_dict(studio: VirtualStudio) -> dict[str, Any]:
    return {"name": f"{studio.focal_length_mm:g} mm (simulated)", "focal_length_mm": studio.focal_length_mm}


def write_view_file(path: Path, sensor_rgb: np.ndarray, fmt: str, exposure_s: float | None = None) -> Path:
    """Store one rendered view: a Bayer DNG (14-bit) or a 16-bit linear RGB PNG, atomically."""
    if fmt == "dng":
        mosaic = mosaic_from_rgb(sensor_rgb, BLACK_LEVEL, WHITE_LEVEL, DEFAULT_NEUTRAL)
        return write_dng(path, mosaic, black_level=BLACK_LEVEL, white_level=WHITE_LEVEL,
                         as_shot_neutral=DEFAULT_NEUTRAL, exposure_s=exposure_s)
    if fmt == "png":
        img16 = np.rint(np.clip(sensor_rgb, 0.0, 1.0) * 65535.0).astype(np.uint16)
        bgr = cv2.cvtColor(img16, cv2.COLOR_RGB2BGR)

        def _write(tmp: Path) -> None:
            if not cv2.imwrite(str(tmp), bgr):
                raise OSError(f"{path}: cv2.imwrite failed")

        return atomic_write_with(path, _write)
    raise InputError("fmt", f"unknown format {fmt!r}", "dng or png")


# -- worker-side rendering (one studio per process) -------------------------------------------------
_WORKER_STUDIO: VirtualStudio | None = None


def _init_worker(studio_kwargs: dict[str, Any]) -> None:
    global _WORKER_STUDIO
    cv2.setNumThreads(1)
    _WORKER_STUDIO = VirtualStudio(**studio_kwargs)


def _render_and_write(studio: VirtualStudio, sensor: SensorModel, job: dict[str, Any]) -> dict[str, Any]:
    rgb = studio.render(*job["true_mm"])
    fault: ViewFault | None = job.get("fault")
    if fault is not None:
        rgb = fault.spoil_image(rgb)
    recorded, gain = sensor.apply(rgb, job["shot"])
    path = Path(job["path"])
    if job.get("truth_root"):
        write_truth_maps(studio, Path(job["truth_root"]), job["row"], job["column"], job["true_mm"],
                         job["spacing_x_mm"])
    write_view_file(path, recorded, job["fmt"], job["exposure_s"])
    # the grid's thumbnail from the image in memory, as a camera's preview (no decoding of the file)
    thumb = make_thumbnail([path], Path(job["thumb_path"]), preview=recorded)
    return {"sha256": sha256_file(path), "gain": gain, "thumb": thumb is not None}


def truth_map_path(root: str | os.PathLike, kind: str, row: int, column: int) -> Path:
    """``root/truth/KIND/rRR_cCCC.tif`` (``kind`` one of :data:`TRUTH_MAPS`)."""
    if kind not in TRUTH_MAPS:
        raise InputError("kind", f"unknown ground-truth map {kind!r}", ", ".join(TRUTH_MAPS))
    return Path(root) / TRUTH_DIR / kind / f"{view_stem(row, column)}.tif"


def _write_tiff(path: Path, data: np.ndarray) -> None:
    import tifffile

    tifffile.imwrite(path, data, compression="zlib")


def write_truth_maps(studio: VirtualStudio, root: Path, row: int, column: int, true_mm: Sequence[float],
                     spacing_x_mm: float) -> list[Path]:
    """Render and store the ground-truth maps of one view (module docstring), each atomically."""
    depth = studio.depth_map(*true_mm)
    depth_rect = studio.depth_map(*true_mm, ideal=True)
    maps = {"depth": depth, "depth_rectified": depth_rect,
            "disparity_rectified": (studio.f_px * float(spacing_x_mm) / (1000.0 * depth_rect)).astype(np.float32)}
    out = []
    for kind, data in maps.items():
        path = truth_map_path(root, kind, row, column)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_with(path, lambda tmp, d=data: _write_tiff(tmp, d))
        out.append(path)
    return out


def read_truth_map(root: str | os.PathLike, kind: str, row: int, column: int) -> np.ndarray:
    """A stored ground-truth map (H x W float32; module docstring); DatasetError when it is missing."""
    import tifffile

    from lfstudio.errors import DatasetError

    path = truth_map_path(root, kind, row, column)
    if not path.is_file():
        raise DatasetError(f"{path}: no ground-truth map; render the dataset with truth maps "
                           "(make_virtual_dataset(truth_maps=True), the default)")
    return np.asarray(tifffile.imread(path), np.float32)


def _worker_job(sensor: SensorModel, job: dict[str, Any]) -> dict[str, Any]:
    assert _WORKER_STUDIO is not None
    return _render_and_write(_WORKER_STUDIO, sensor, job)


def make_virtual_dataset(root: str | os.PathLike, columns: int, rows: int, *,
                         spacing_mm: tuple[float, float] = (4.0, 6.0),
                         origin_mm: tuple[float, float] = (0.0, 0.0),
                         width_px: int = DEFAULT_WIDTH_PX,
                         rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
                         pp_offset_px: tuple[float, float] = (0.0, 0.0),
                         position_noise_um: tuple[float, float] = (0.0, 0.0),
                         seed: int = 0, fmt: str = "dng",
                         near_m: float = REFERENCE.near_m, far_m: float = REFERENCE.far_m,
                         focal_length_mm: float = REFERENCE.focal_length_mm,
                         sensor_width_mm: float = REFERENCE.sensor_mm[0],
                         flicker: float = 0.0, vignetting: float = 0.0, noise: float = 0.0,
                         exposure_s: float = REFERENCE.exposure_s, workers: int = 1,
                         studio: VirtualStudio | None = None,
                         faults: Sequence[ViewFault] = (),
                         only_views: Iterable[Sequence[int]] | None = None,
                         truth_maps: bool = True,
                         progress: Callable[[int, int, str], None] | None = None,
                         cancel: CancelToken | None = None) -> Dataset:
    """Render a ``columns`` x ``rows`` grid into a new dataset folder at ``root`` and return it.

    View (row r, column c) is commanded at ``origin_mm + (c * spacing_mm[0], r * spacing_mm[1])``
    and rendered at that position plus Gaussian noise of ``position_noise_um`` (x, y) sigma.
    ``reported_mm`` equals the commanded position (what a controller reports). ``workers`` > 1
    renders in that many processes. ``studio`` (optional) overrides the scene parameters.
    ``faults``: defects injected into chosen views (at most one per view; see the module docstring).
    ``only_views``: render and record only these (row, column) views of the grid (the others stay
    uncaptured; every view's position error is drawn as if all were, so a view's image does not
    depend on which others are rendered). ``truth_maps``: store each view's ground-truth depth and
    disparity maps under ``truth/`` (module docstring).
    """
    check_new_dataset_folder(Path(root), "folder", stem="lfstudio-virtual")   # never into a dataset or other files
    fmt = fmt.lower()
    if fmt not in ("dng", "png"):
        raise InputError("fmt", f"unknown format {fmt!r}", "dng or png")
    if columns < 1 or rows < 1:
        raise InputError("grid", f"columns and rows must be at least 1, got {columns} x {rows}")
    sx, sy = float(spacing_mm[0]), float(spacing_mm[1])
    ox, oy = float(origin_mm[0]), float(origin_mm[1])
    noise_mm = (position_noise_um[0] / 1000.0, position_noise_um[1] / 1000.0)
    fault_at: dict[tuple[int, int], ViewFault] = {}
    for fault in faults:
        if not (0 <= fault.row < rows and 0 <= fault.column < columns):
            raise InputError("faults", f"fault {fault.kind} at row {fault.row}, column {fault.column} is outside "
                                       f"the {columns} x {rows} grid")
        if fault.cell in fault_at:
            raise InputError("faults", f"two faults at row {fault.row}, column {fault.column}", "one per view")
        fault_at[fault.cell] = fault
    margin_mm = 4 * max(noise_mm) + 0.5      # faults keep the scene: a faulty dataset = the clean one + defects
    region = (ox - margin_mm, ox + (columns - 1) * sx + margin_mm, oy - margin_mm, oy + (rows - 1) * sy + margin_mm)
    studio_kwargs: dict[str, Any] = dict(
        width_px=width_px, focal_length_mm=focal_length_mm, sensor_width_mm=sensor_width_mm, near_m=near_m,
        far_m=far_m, rotation_deg=tuple(rotation_deg), pp_offset_px=tuple(pp_offset_px), view_region_mm=region,
        seed=seed)
    if studio is None:
        studio = VirtualStudio(**studio_kwargs)
    else:
        studio_kwargs = studio.init_kwargs()
    if fmt == "dng" and studio.width_px % 2:
        raise InputError("width_px", f"a Bayer DNG needs an even width, got {studio.width_px}")
    problems = camera_problems({"camera": camera_dict(studio), "lens": lens_dict(studio)})
    if problems:     # refused before any view is written (the manifest would refuse them at the end)
        raise InputError("width_px", f"{studio.width_px} px wide images of a {studio.sensor_width_mm:g} mm "
                         f"sensor cannot be recorded ({problems[0].split(': ', 1)[1]}); render wider images")
    sensor = SensorModel(flicker=flicker, vignetting=vignetting, noise=noise, seed=seed)

    rng = np.random.default_rng([seed, 0x9051])
    root = Path(root)
    suffix = ".dng" if fmt == "dng" else ".png"
    order = grid_order(columns, rows, DEFAULT_ORDER)
    jobs: list[dict[str, Any]] = []
    for shot, (r, c) in enumerate(order):
        commanded = (ox + c * sx, oy + r * sy)
        true = (commanded[0] + noise_mm[0] * rng.standard_normal(),
                commanded[1] + noise_mm[1] * rng.standard_normal())
        fault = fault_at.get((r, c))
        if fault is not None:
            try:
                true = fault.true_position_mm(true, jobs[-1]["true_mm"] if jobs else None)
            except ValueError as exc:
                raise InputError("faults", str(exc), "a view captured after another one") from None
        rel = f"raw/{view_stem(r, c)}{suffix}"
        thumb_rel = f"thumbs/{view_stem(r, c)}.jpg"
        jobs.append({"row": r, "column": c, "shot": shot, "commanded_mm": commanded, "true_mm": true,
                     "rel": rel, "path": str(root / rel), "thumb_rel": thumb_rel, "thumb_path": str(root / thumb_rel),
                     "fmt": fmt, "exposure_s": exposure_s, "fault": fault,
                     "truth_root": str(root) if truth_maps else None, "spacing_x_mm": sx})

    if only_views is not None:
        keep = {(int(r), int(c)) for r, c in only_views}
        jobs = [job for job in jobs if (job["row"], job["column"]) in keep]
        if not jobs:
            raise InputError("only_views", "no view of the grid chosen", f"views inside the {columns} x {rows} grid")
    (root / "raw").mkdir(parents=True, exist_ok=True)
    total = len(jobs)
    results: list[dict[str, Any]] = []
    if progress:
        progress(0, total, "rendering views")
    if workers > 1 and total > 1:
        # spawn, not fork: a forked child inherits OpenCV's thread pool in an unusable state and hangs
        with ProcessPoolExecutor(max_workers=workers, initializer=_init_worker, initargs=(studio_kwargs,),
                                 mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = [pool.submit(_worker_job, sensor, job) for job in jobs]
            try:
                for i, fut in enumerate(futures):
                    if cancel is not None:
                        cancel.check()
                    results.append(fut.result())
                    if progress:
                        progress(i + 1, total, f"rendered {jobs[i]['rel']}")
            except BaseException:
                for fut in futures:
                    fut.cancel()
                raise
    else:
        for i, job in enumerate(jobs):
            if cancel is not None:
                cancel.check()
            results.append(_render_and_write(studio, sensor, job))
            if progress:
                progress(i + 1, total, f"rendered {job['rel']}")

    start_s = time.time()
    views: list[ViewRecord] = []
    for job, res in zip(jobs, results):
        views.append({"row": job["row"], "column": job["column"],
                      "commanded_mm": [round(v, 6) for v in job["commanded_mm"]],
                      "reported_mm": [round(v, 3) for v in job["commanded_mm"]],
                      "captured_at": now_iso(start_s + job["shot"] * (exposure_s + 0.5)), "exposure_s": exposure_s,
                      "file": job["rel"], "sha256": res["sha256"], "thumb": job["thumb_rel"] if res["thumb"] else None,
                      "status": "done"})
    views.sort(key=lambda v: (v["row"], v["column"]))
    grid = Grid(int(columns), int(rows), (sx, sy), order=DEFAULT_ORDER).to_manifest()
    rig = {"name": "virtual studio", "simulated": True, "origin_mm": [ox, oy]}
    plan = {"near_m": near_m, "far_m": far_m, "focal_length_mm": focal_length_mm}
    ds = Dataset.create(root, camera=camera_dict(studio), lens=lens_dict(studio), grid=grid, rig=rig, plan=plan,
                        views=views, exist_ok=True)
    truth = studio.ground_truth()
    truth.update({
        "studio": {k: list(v) if isinstance(v, tuple) else v for k, v in studio_kwargs.items()},
        "format": fmt,
        "black_level": BLACK_LEVEL if fmt == "dng" else 0,
        "white_level": WHITE_LEVEL if fmt == "dng" else 65535,
        "as_shot_neutral": list(DEFAULT_NEUTRAL) if fmt == "dng" else [1.0, 1.0, 1.0],
        "sensor": {"flicker": flicker, "vignetting": vignetting, "noise": noise,
                   "full_well_e": sensor.full_well_e},
        "position_noise_um": list(position_noise_um),
        "faults": [f.describe() for f in faults],
        "truth_maps": ({kind: f"{TRUTH_DIR}/{kind}/rRR_cCCC.tif" for kind in TRUTH_MAPS} | {
            "units": "depth, depth_rectified: metres (z of the visible surface); disparity_rectified: pixels "
                     "between horizontal neighbours of the rectified view, f * spacing_x_mm / (1000 * Z)",
            "format": "float32 TIFF (deflate), the views' full size"}) if truth_maps else None,
        "views": [{"row": j["row"], "column": j["column"], "shot": j["shot"], "file": j["rel"],
                   "commanded_mm": list(j["commanded_mm"]), "true_mm": list(j["true_mm"]), "gain": res["gain"]}
                  for j, res in zip(jobs, results)],
    })
    atomic_write_json(root / GROUND_TRUTH_NAME, truth)
    return ds


def load_ground_truth(root: str | os.PathLike) -> dict[str, Any]:
    """``ground_truth.json`` of a virtual dataset, with R, K_true, K0 and H as numpy arrays."""
    import json

    truth = json.loads((Path(root) / GROUND_TRUTH_NAME).read_text(encoding="utf-8"))
    for key in ("R", "K_true", "K0", "H"):
        truth[key] = np.array(truth[key], float)
    return truth


def true_disparity_px(root: str | os.PathLike, row: int, column: int, size_px: tuple[int, int], *,
                      rectified: bool) -> np.ndarray:
    """Ground-truth disparity map (H x W float32) of view (``row``, ``column``) of a virtual dataset,
    sampled at ``size_px`` (w, h): full-resolution pixels between *horizontal* neighbours, i.e.
    ``f · spacing_x / (1000 · Z)`` of the visible surface, as the view was captured (``rectified``
    False) or after rectification (True: the ideal camera). What a measured disparity map is checked
    against (:mod:`lfstudio.quality.disparity`)."""
    truth = load_ground_truth(root)
    kwargs: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in truth["studio"].items()}
    studio = VirtualStudio(**kwargs)
    view = next((v for v in truth["views"] if v["row"] == row and v["column"] == column), None)
    if view is None:
        raise InputError("row/column", f"the dataset has no view at row {row}, column {column}")
    depth = studio.depth_map(*view["true_mm"], ideal=rectified)
    depth = cv2.resize(depth, (int(size_px[0]), int(size_px[1])), interpolation=cv2.INTER_NEAREST)
    from lfstudio.dataset import Dataset

    spacing_x = Dataset.open(Path(root)).grid.step_mm[0]
    return (studio.f_px * spacing_x / (1000.0 * depth)).astype(np.float32)
