"""kill -9 of ``lfstudio scan --keep-on-card`` (issue #40) at random moments, then ``--resume --keep-on-card``:
on libgphoto2's virtual PTP camera (tests/vcamera.py; its card lives in the scan's process, so the
pictures a killed run left on it are gone and those views are taken again) and on the simulated camera
(its card in memory too). Per trial: every view done exactly once, each done view's file on disk with
its checksum (``lfstudio info --verify``), no view done without its file.

    python benchmarks/card_kill_soak.py [--trials 20] [--camera gphoto2|sim|both] [--grid 4x3] [--seed 1]
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def env_for(camera: str, folder: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    if camera == "gphoto2":
        import gphoto2 as gp

        from tests.vcamera import port_libraries, write_vcamera_folder

        write_vcamera_folder(folder)
        env.update(IOLIBS=str(port_libraries(gp, "vusb")), VCAMERADIR=str(folder))
    return env


def trial(camera: str, k: int, rng: random.Random, grid: str, base: Path) -> str:
    out = base / f"{camera}-{k}"
    env = env_for(camera, base / f"vcam-{k}")
    args = [sys.executable, "-m", "lfstudio", "scan", "--port", "sim", "--camera", camera, "--grid", grid,
            "--out", str(out), "--keep-on-card", "--time-scale", "0.2", "--sim-width-px", "64",
            "--exposure-s", "0.2", "--transfer-s", "0.5"]
    proc = subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    delay = rng.uniform(3.0, 14.0)
    try:
        proc.wait(delay)
        killed = False
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        killed = True
    from lfstudio.dataset import Dataset

    before = 0
    if (out / "dataset.json").exists():
        before = Dataset.open(out).status_counts()["done"]
    # killed before the dataset was made (while the simulated rig homed): the scan is started afresh
    again = args + ["--resume"] if (out / "dataset.json").exists() else args
    res = subprocess.run(again, env=env, capture_output=True, text=True, timeout=600)
    ds = Dataset.open(out)
    counts = ds.status_counts()
    bad = ds.verify_files()
    cols, rows = (int(v) for v in grid.split("x"))
    lost = cols * rows - counts["done"]
    no_file = [v for v in ds.done_views() if not ds.path_of(v).is_file()]
    left = sum(1 for v in ds.views if v.get("on_card"))
    ok = res.returncode == 0 and lost == 0 and not bad and not no_file
    return (f"{camera} trial {k}: {'killed' if killed else 'finished'} after {delay:.1f} s with {before} done; "
            f"resume exit {res.returncode}: {counts['done']} done, {lost} lost, {len(bad)} bad files, "
            f"{len(no_file)} done without a file, {left} still marked on the card -> {'ok' if ok else 'FAIL'}"
            + ("" if ok else f"\n  {res.stderr.strip().splitlines()[-1:]}"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--camera", default="both", choices=("gphoto2", "sim", "both"))
    ap.add_argument("--grid", default="4x3")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    cameras = ("gphoto2", "sim") if args.camera == "both" else (args.camera,)
    failed = 0
    with tempfile.TemporaryDirectory(prefix="card-soak-") as tmp:
        for camera in cameras:
            for k in range(args.trials):
                line = trial(camera, k, rng, args.grid, Path(tmp))
                failed += "FAIL" in line
                print(line, flush=True)
    print(f"{args.trials * len(cameras)} trials, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    t0 = time.monotonic()
    code = main()
    print(f"{time.monotonic() - t0:.0f} s")
    sys.exit(code)
