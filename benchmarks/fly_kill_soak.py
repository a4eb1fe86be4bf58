"""kill -9 of ``lfstudio scan --fly`` (issue #40) at random moments, then ``--resume --fly``.

Each trial starts a fly scan of the simulated studio (GRBL simulator + simulated camera, 1 ms exposure,
20 frames/s; ``--trigger``: the hardware trigger on the controller's spindle output by default) in its
own process, kills it with SIGKILL after a random delay (rows being flown, frames being stored, or
before the dataset exists), then resumes it and checks the dataset:

- every view done exactly once, each done view's file on disk with its checksum (``verify_files``), no
  view done without its file: 0 views lost;
- every done view either flown (``fly.recorded_mm``, the same as its ``reported_mm``, within the
  tolerance of its commanded position) or taken standing still (``fly.retaken``/``standing_still``);
- never a wrong position: each flown view's recorded position against the truth the simulated camera
  wrote (less the rig's repeatability draw, which no scan sees) within ``--max-error-mm``.

A flown view off the truth by more than ``--max-error-mm`` is counted apart ("off"), with how far and
against the uncertainty the manifest states for it: the software trigger's positions are interpolated
from position reports, off by up to ~0.1 mm on this loaded machine whether or not the scan was
killed, so they are an accuracy figure, not a view lost; such a view off by more than its own stated
uncertainty too is a wrong position. A trial fails ("FAIL") on a view lost, a file failing its
checksum, a view done without its file, or a wrong position: a flown view not where its reports and
its commanded position say, off the truth beyond both ``--max-error-mm`` and its stated uncertainty,
or neither flown nor flagged. The exit code is 1 on a FAIL or an off view.

``--port``: the simulated studio's GRBL controller (``sim``, by default) or the emulated CiA 402 drive
pair (``sim-dryve``: Modbus TCP, ``sim-canopen``: a virtual CAN bus), both in the scan's process (so
killed with it: the resume starts them again, unhomed, and homes). The kill window: the CLI takes
~10 s to start and home the GRBL simulator and ~20 s for the drives (at ``--time-scale 0.5``), then the
12 × 5 grid is flown in ~5–10 s; choose ``--kill-min-s``/``--kill-max-s`` around that (the summary
says how many kills landed before the first view was stored, with views done, or after the end).

    python benchmarks/fly_kill_soak.py [--trials 20] [--grid 6x3] [--trigger auto|hardware|software]
                                       [--port sim|sim-dryve|sim-canopen] [--seed 1]
"""

from __future__ import annotations

import argparse
import json
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def trial(k: int, rng: random.Random, args: argparse.Namespace, base: Path) -> str:
    import os

    from lfstudio.dataset import Dataset

    out = base / f"fly-{k}"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "lfstudio", "scan", "--port", args.port, "--camera", "sim", "--grid", args.grid,
           "--out", str(out), "--fly", "--trigger", args.trigger, "--time-scale", str(args.time_scale),
           "--sim-width-px", "48", "--exposure-s", "0.001", "--transfer-s", "0.05"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    delay = rng.uniform(args.kill_min_s, args.kill_max_s)
    try:
        proc.wait(delay)
        killed = False
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        killed = True
    before = Dataset.open(out).status_counts()["done"] if (out / "dataset.json").exists() else 0
    again = cmd + ["--resume"] if (out / "dataset.json").exists() else cmd
    res = subprocess.run(again, env=env, capture_output=True, text=True, timeout=900)
    ds = Dataset.open(out)
    counts = ds.status_counts()
    cols, rows = (int(v) for v in args.grid.lower().split("x"))
    lost = cols * rows - counts["done"]
    bad = ds.verify_files()
    no_file = [v for v in ds.done_views() if not ds.path_of(v).is_file()]
    tolerance = 0.25 * float(ds.manifest["grid"]["spacing_mm"][0])
    flown = standing = wrong = off = 0
    worst = ratio = 0.0
    for v in ds.done_views():
        fly = v.get("fly") or {}
        if "recorded_mm" in fly:
            flown += 1
            rec = fly["recorded_mm"]
            if v.get("reported_mm") != rec or abs(rec[0] - v["commanded_mm"][0]) > tolerance + 1e-9:
                wrong += 1
                continue
            truth = json.loads((ds.root / v["sidecars"][1]).read_text())
            rep = truth.get("repeatability_error_mm", [0.0, 0.0])
            err = max(abs(rec[0] - (truth["true_position_mm"][0] - rep[0])),
                      abs(rec[1] - (truth["true_position_mm"][1] - rep[1])))
            worst = max(worst, err)
            if err > args.max_error_mm:
                off += 1
                stated = float(fly.get("uncertainty_mm") or 0.0)
                ratio = max(ratio, err / max(stated, 1e-6))
                wrong += err > stated       # beyond what the manifest says of it: a wrong position
        elif "retaken" in fly or "standing_still" in fly:
            standing += 1
        else:
            wrong += 1                          # done in a fly scan, neither flown nor flagged
    ok = res.returncode == 0 and lost == 0 and not bad and not no_file and wrong == 0
    when = ("finished" if not killed else "killed before the first view" if before == 0
            else "killed after the end" if before == cols * rows else "killed mid-scan")
    line = (f"fly trial {k}: {when}: after {delay:.1f} s with {before} done; resume exit "
            f"{res.returncode}: {counts['done']} done ({flown} flown, {standing} standing still), {lost} lost, "
            f"{len(bad)} bad files, {len(no_file)} done without a file, {wrong} wrong positions; {off} flown views "
            f"off the truth by > {1000 * args.max_error_mm:g} µm (worst {1000 * worst:.1f} µm"
            + (f"; up to {ratio:.2f} x their stated uncertainty" if off else "")
            + f") -> {'FAIL' if not ok else 'off' if off else 'ok'}")
    if not ok:
        line += f"\n  {res.stderr.strip().splitlines()[-1:]}"
    return line


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--grid", default="6x3")
    ap.add_argument("--trigger", default="auto", choices=("auto", "hardware", "software"))
    ap.add_argument("--port", default="sim", choices=("sim", "sim-dryve", "sim-canopen"),
                    help="the simulated GRBL controller or the emulated CiA 402 drive pair")
    ap.add_argument("--time-scale", type=float, default=0.5)
    ap.add_argument("--kill-min-s", type=float, default=2.0)
    ap.add_argument("--kill-max-s", type=float, default=12.0)
    ap.add_argument("--max-error-mm", type=float, default=0.05,
                    help="a flown view's recorded position this far from the truth counts as wrong")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    failed = off = 0
    when = {"killed before the first view": 0, "killed mid-scan": 0, "killed after the end": 0, "finished": 0}
    with tempfile.TemporaryDirectory(prefix="fly-soak-") as tmp:
        for k in range(args.trials):
            line = trial(k, rng, args, Path(tmp))
            failed += line.endswith("FAIL") or "-> FAIL\n" in line
            off += line.endswith("-> off")
            for w in when:
                when[w] += f": {w}:" in line
            print(line, flush=True)
    print(f"{args.trials} trials ({when['killed mid-scan']} killed mid-scan with views done, "
          f"{when['killed before the first view']} before the first view, {when['killed after the end']} after "
          f"the last view, {when['finished']} finished first), {failed} failed, {off} with flown views off the truth "
          f"by > {1000 * args.max_error_mm:g} µm")
    return 1 if failed or off else 0


if __name__ == "__main__":
    t0 = time.monotonic()
    code = main()
    print(f"{time.monotonic() - t0:.0f} s")
    sys.exit(code)
