"""GenICam through aravis on aravis's fake GigE Vision camera over loopback (issue 39's figures).

1. frames per second sustained with software trigger, at 512 x 512 and at the sensor's largest size
   (2048 x 2048), Mono8, through :class:`lfstudio.rig.genicam.GenicamCamera.grab`;
2. the share of frames lost with the fake camera dropping 1 % of its packets (``-r 10``), at the packet
   size aravis negotiates and at 8000 bytes (every lost frame is taken again and counted);
3. the scan's per-view overhead: a real ``lfstudio scan`` (instant rig, no settle) with ``genicam:`` and with the
   virtual studio's camera (``sim``, time scale 0, 512 px): wall seconds per view, the store stage's
   seconds per view (write + sha256 + thumbnail + journal) from the dataset's timings, minus what the
   camera itself takes per frame (measured in 1).

Needs ``arv-fake-gv-camera-0.8`` (aravis-tools) and aravis's binding; prints figures, asserts nothing.

    ./.venv/bin/python benchmarks/genicam.py [--frames 100] [--grid 6x4]
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from _measure import Timer, load_text  # noqa: E402

from lfstudio.rig.genicam import GenicamCamera, aravis_available, list_cameras  # noqa: E402

DEVICE = "Aravis-Fake-GV01"


@contextmanager
def fake_camera(lost_per_thousand: int = 0):
    exe = shutil.which("arv-fake-gv-camera-0.8")
    if exe is None or not aravis_available():
        sys.exit("genicam benchmark: needs arv-fake-gv-camera-0.8 (apt-get install aravis-tools) and aravis's "
                 "binding (gir1.2-aravis-0.8 python3-gi)")
    args = [exe, "-i", "127.0.0.1"] + (["-r", str(lost_per_thousand)] if lost_per_thousand else [])
    lock = open(Path(tempfile.gettempdir()) / "lfstudio-fake-gv-camera.lock", "a+")   # as tests/fakegv.py: one at a time
    fcntl.flock(lock, fcntl.LOCK_EX)
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 20
        while DEVICE not in list_cameras():
            if time.monotonic() > deadline or proc.poll() is not None:
                sys.exit("genicam benchmark: the fake camera did not start (is another one running?)")
        yield
    finally:
        proc.terminate()
        proc.wait(10)
        lock.close()


def fps(frames: int, width: int, height: int) -> tuple[float, float]:
    cam = GenicamCamera(DEVICE, timeout_s=5)
    cam.connect()
    try:
        cam.set_setting("width", width)
        cam.set_setting("height", height)
        cam.grab()                                    # the acquisition starts
        with Timer() as span:
            for _ in range(frames):
                cam.grab()
        return frames / span.wall_s, span.cpu_s / frames
    finally:
        cam.set_setting("width", 512)                # the fake camera keeps its settings: the scan's 512 px
        cam.set_setting("height", 512)
        cam.disconnect()


def lost_share(frames: int, packet_size: int | None) -> tuple[float, int, int, int | None]:
    cam = GenicamCamera(DEVICE, timeout_s=2, retries=50, packet_size=packet_size)
    cam.connect()
    try:
        got = [cam.grab() for _ in range(frames)]
        size = cam._need().gv_get_packet_size()
        lost = sum(f.lost for f in got)
        return lost / (lost + frames), lost, frames, size
    finally:
        cam.disconnect()


def scan(word: str, grid: str, out: Path, extra: list[str]) -> tuple[float, float, float, int]:
    env = dict(os.environ, PYTHONPATH=str(HERE.parent) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "lfstudio", "scan", "--port", "instant", "--camera", word, "--grid", grid,
                        "--settle-s", "0", "--out", str(out), *extra], capture_output=True, text=True, env=env, timeout=900)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        sys.exit(f"genicam benchmark: scan with {word} failed:\n{r.stderr[-2000:]}")
    views = json.loads((out / "dataset.json").read_text())["views"]
    periods = [v["timings_s"]["period"] for v in views if "period" in v.get("timings_s", {})]
    stores = [v["timings_s"]["store"] for v in views]
    return wall, statistics.median(periods), statistics.median(stores), len(views)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--grid", default="6x4")
    args = p.parse_args()
    print(f"genicam benchmark ({load_text()})")
    with fake_camera():
        small, small_cpu = fps(args.frames, 512, 512)
        large, large_cpu = fps(max(10, args.frames // 4), 2048, 2048)
        print(f"  software trigger, Mono8  512 x  512: {small:6.1f} frames/s sustained ({small_cpu * 1e3:.1f} ms CPU "
              "per frame)")
        print(f"  software trigger, Mono8 2048 x 2048: {large:6.1f} frames/s sustained ({large_cpu * 1e3:.1f} ms CPU "
              "per frame)")
        with tempfile.TemporaryDirectory(prefix="lfstudio-genicam-bench-") as tmp:
            g_wall, g_period, g_store, n = scan(f"genicam:{DEVICE}", args.grid, Path(tmp) / "genicam", [])
            s_wall, s_period, s_store, _ = scan("sim", args.grid, Path(tmp) / "sim",
                                                ["--time-scale", "0", "--sim-width-px", "512"])
        grab_s = 1 / small
        print(f"  scan {args.grid} ({n} views), instant rig: genicam:{DEVICE} 512 px Mono8 -> 16-bit PNG: "
              f"median period {g_period * 1e3:.0f} ms/view, store stage {g_store * 1e3:.0f} ms/view, "
              f"period minus the camera's frame time {max(0.0, g_period - grab_s) * 1e3:.0f} ms; "
              f"{g_wall:.1f} s in all")
        print(f"  scan {args.grid} ({n} views), instant rig: virtual studio (sim, 512 px DNG + JPEG, time scale 0): "
              f"median period {s_period * 1e3:.0f} ms/view, store stage {s_store * 1e3:.0f} ms/view; "
              f"{s_wall:.1f} s in all (rendering included)")
    for packet_size in (None, 8000):
        with fake_camera(lost_per_thousand=10):
            share, lost, frames, size = lost_share(args.frames, packet_size)
        print(f"  -r 10 (1 % of packets dropped), packets of {size} B ({'negotiated' if packet_size is None else 'set'}):"
              f" {lost} frames lost for {frames} good ones = {share * 100:.1f} % of the frames sent "
              "(each taken again, none stored)")


if __name__ == "__main__":
    main()
