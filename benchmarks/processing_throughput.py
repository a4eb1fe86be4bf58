"""Processing throughput at about 4000 x 2700 DNG input, and the pipeline's overhead.

Prints views/s with one local worker and with two (target: >= 1.8x scaling on two free cores), and
the pipeline's time over its unavoidable parts, RAW decode + output encode alone, done the same
way (one worker process, one thread each) on the same files (target: <= 15 %).

    ./.venv/bin/python benchmarks/processing_throughput.py [--views 10] [--width 4000]

Takes a few minutes: renders a virtual-studio dataset once (cached in /tmp), then runs each
configuration once. The machine must be otherwise idle for the scaling figure to mean anything.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import multiprocessing
import os
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def cpu_s() -> float:
    """CPU seconds used by this process and its finished children (robust to other load)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def decode_encode(path: str, out: str, half_size: bool) -> float:
    """The unavoidable part of one view: decode the RAW, write a half-resolution 16-bit PNG."""
    import cv2

    from lfstudio.processing.profile import DebayerStep
    from lfstudio.processing.steps import debayer
    from lfstudio.processing.worker import _single_thread

    _single_thread()
    t0 = time.perf_counter()
    img = debayer.decode(path, DebayerStep(half_size=half_size))
    small = img if half_size else img[::2, ::2]
    cv2.imwrite(out, cv2.cvtColor(small, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    return time.perf_counter() - t0


def baseline(paths: list[Path], out_dir: Path, workers: int) -> float:
    from lfstudio.processing.executors import _init_local_worker

    out_dir.mkdir(exist_ok=True)
    t0 = time.perf_counter()
    with cf.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                initializer=_init_local_worker) as pool:
        list(pool.map(decode_encode, map(str, paths), [str(out_dir / (p.stem + ".png")) for p in paths],
                      [False] * len(paths)))
    return time.perf_counter() - t0


def make_dataset(root: Path, n_views: int, width_px: int):
    from lfstudio.dataset import Dataset
    from lfstudio.sim.virtual_dataset import load_ground_truth, make_virtual_dataset

    marker = root / "ready.json"
    if marker.is_file() and json.loads(marker.read_text()) == [n_views, width_px]:
        return Dataset.open(root)
    import shutil

    shutil.rmtree(root, ignore_errors=True)
    print(f"rendering {n_views} views at {width_px} px wide (once; cached in {root}) ...", flush=True)
    ds = make_virtual_dataset(root, columns=n_views, rows=1, width_px=width_px, rotation_deg=(1.0, -1.5, 0.7),
                              seed=3, fmt="dng", flicker=0.03, vignetting=0.2, noise=0.002, workers=1)
    truth = load_ground_truth(root)
    (root / "calibration.json").write_text(json.dumps(
        {"homography": truth["H"].tolist(), "image_size_px": truth["image_size_px"]}))
    marker.write_text(json.dumps([n_views, width_px]))
    return ds


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=10)
    ap.add_argument("--width", type=int, default=4000)
    ap.add_argument("--root", default="/tmp/lfstudio-bench-processing")
    args = ap.parse_args()

    from lfstudio.processing.pipeline import process_dataset
    from lfstudio.processing.profile import Profile

    root = Path(args.root)
    ds = make_dataset(root, args.views, args.width)
    paths = [ds.path_of(v) for v in ds.views]
    size = json.loads((root / "calibration.json").read_text())["image_size_px"]
    profile = Profile()  # every default step: debayer, colour, de-flicker, rectify, half resolution
    profile.shading.enabled = True
    profile.shading.mode = "model"
    profile.shading.coefficients = [-0.2]
    n = len(paths)
    print(f"{n} DNG views of {size[0]} x {size[1]} px; cores: {os.cpu_count()}; profile: debayer AHD, shading, "
          "colour, de-flicker, rectify, half resolution; 16-bit PNG out", flush=True)

    results, step_share, cpu = {}, {}, {}
    for workers in (1, 2):
        c0 = cpu_s()
        t_base = baseline(paths, root / "baseline", workers)
        c1 = cpu_s()
        t0 = time.perf_counter()
        report = process_dataset(root, profile, workers=workers, force=True)
        t_pipe = time.perf_counter() - t0
        cpu[workers] = (c1 - c0, cpu_s() - c1)
        assert report.ok, report.failed
        results[workers] = (t_base, t_pipe)
        views = json.loads((root / "dataset.json").read_text())["views"]
        t = {k: sum(v["processed"]["timings_s"][k] for v in views) for k in ("decode", "process", "encode")}
        step_share[workers] = t["process"] / (t["decode"] + t["encode"])
        print(f"{workers} worker(s): pipeline {t_pipe:6.2f} s = {n / t_pipe:5.2f} views/s; "
              f"decode+encode alone {t_base:6.2f} s = {n / t_base:5.2f} views/s", flush=True)

    (b1, p1), (b2, p2) = results[1], results[2]
    print()
    print(f"scaling 2 workers / 1 worker (pipeline):       {p1 / p2:5.2f}x   (target >= 1.8)")
    print(f"scaling 2 workers / 1 worker (decode+encode):  {b1 / b2:5.2f}x   (what the machine allows)")
    print(f"pipeline overhead over decode+encode, 1 worker: {100 * (p1 / b1 - 1):5.1f} %  (target <= 15 %)")
    print(f"pipeline overhead over decode+encode, 2 workers: {100 * (p2 / b2 - 1):5.1f} %")
    print(f"per view, inside the workers: steps (gain, warp, resample, levels) / (decode + encode): "
          f"{100 * step_share[1]:4.1f} % (1 worker), {100 * step_share[2]:4.1f} % (2 workers)")
    for w in (1, 2):
        cb, cp = cpu[w]
        print(f"CPU time, {w} worker(s): pipeline {cp:6.1f} s, decode+encode {cb:6.1f} s -> overhead "
              f"{100 * (cp / cb - 1):5.1f} % (includes worker start-up and the reference view)")
    print(f"load average during the run: {os.getloadavg()[0]:.1f} (figures mean little above ~{os.cpu_count()})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
