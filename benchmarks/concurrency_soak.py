"""Concurrency soak: N trials of a real ``lfstudio scan`` with ``process``, ``calibrate`` and ``check``
started beside it at random moments (docs/dataset-format.md, "Two commands at once").

Each trial scans a small grid (instant rig, simulated camera, default 4 x 3 views of 160 px) at a fast
time scale in a subprocess. While it runs, each of the three stages is started once (in a random
order) after a random number of captured views (0 to all) and a random extra delay, in its own
process; several may overlap each other and the scan's saves. When everything has ended,
``lfstudio scan --resume`` runs on the dataset (it must find nothing to take), and the trial counts:

* views lost: the views (each counted once) the scan captured (its journal line, or done in any
  snapshot taken during the trial) that the final manifest does not hold as done with the same file and
  checksum, and those not done after the scan said "Finished";
* records lost: a stage that exited 0 whose record is gone at the end: ``process`` (the views it
  reported processed that are not ``processed: done``, or no ``processing`` key), ``calibrate`` (no
  ``calibration`` key), ``check`` (no quality.json);
* captured twice: a view seen captured that the resume captured again (its checksum or capture time
  changed), or a view captured twice within the scan (two journal lines marking it done).

A stage refused by name (e.g. calibrate before a 3 x 3 of views is captured: exit 1 or 2 with one line)
is no failure; a traceback is counted as ``tracebacks``.

Usage (from the repository root)::

    ./.venv/bin/python benchmarks/concurrency_soak.py [--trials 50] [--seed 1] [--grid 4x3] [--time-scale 0.02]

Prints one line per trial and ``N trials: 0 views lost, 0 records lost, 0 captured twice, 0 tracebacks``.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from lfstudio.dataset import Dataset  # noqa: E402
from lfstudio.dataset.store import read_journal  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
PROFILE = "[rectify]\nenabled = false\n[color]\nenabled = false\n"     # processing without a calibration


def cli(*args: object) -> list[str]:
    return [sys.executable, "-m", "lfstudio", *map(str, args)]


def env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def done_views(root: Path) -> dict[tuple[int, int], tuple]:
    try:
        ds = Dataset.open(root)
    except Exception:  # noqa: BLE001 - not created yet
        return {}
    try:
        return {(v["row"], v["column"]): (v["file"], v["sha256"], v["captured_at"]) for v in ds.done_views()}
    finally:
        ds.close()


def journal_done(root: Path) -> list[tuple[int, int]]:
    records, _ = read_journal(root / "journal.jsonl")
    return [(r["row"], r["column"]) for r in records if r.get("set", {}).get("status") == "done"]


def run_stage(name: str, root: Path, profile: Path, results: dict) -> None:
    args = {"process": ("process", root, "--workers", "1", "--profile", profile),
            "calibrate": ("calibrate", root, "--views", "3x3"),
            "check": ("check", root, "--no-disparity", "--threads", "1")}[name]
    proc = subprocess.run(cli(*args), capture_output=True, text=True, env=env(), cwd=REPO, timeout=600)
    processed = None
    for line in proc.stdout.splitlines():
        words = line.split()
        if name == "process" and len(words) > 1 and words[1] == "processed,":
            processed = int(words[0])
    results[name] = (proc.returncode, proc.stderr, processed)


def trial(i: int, rnd: random.Random, work: Path, grid: tuple[int, int], time_scale: float, width: int,
          profile: Path) -> dict:
    root = work / f"t{i:03d}"
    n = grid[0] * grid[1]
    scan = subprocess.Popen(cli("scan", "--port", "instant", "--camera", "sim", "--sim-width-px", width, "--grid",
                                f"{grid[0]}x{grid[1]}", "--time-scale", time_scale, "--out", root),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env(), cwd=REPO)
    stages = ["process", "calibrate", "check"]
    rnd.shuffle(stages)
    moments = sorted(rnd.randint(0, n) for _ in stages)
    results: dict = {}
    threads = []
    seen: dict = {}
    journal_seen: set = set()
    twice = 0
    for name, at in zip(stages, moments):
        while scan.poll() is None and len(done_views(root)) < at:
            journal_seen.update(journal_done(root))
            time.sleep(0.02)            # polling another process's files, not a synchronisation
        time.sleep(rnd.uniform(0, 0.3))
        t = threading.Thread(target=run_stage, args=(name, root, profile, results))
        t.start()
        threads.append(t)
        seen.update(done_views(root))
    while scan.poll() is None:
        lines = journal_done(root)
        journal_seen.update(lines)
        twice = max(twice, len(lines) - len(set(lines)))
        seen.update(done_views(root))
        time.sleep(0.05)
    _, scan_err = scan.communicate()
    for t in threads:
        t.join()
    final = done_views(root)
    lost_cells = {cell for cell, rec in seen.items() if final.get(cell, (None, None))[:2] != rec[:2]}
    lost_cells |= {cell for cell in journal_seen if cell not in final}
    if "Finished" in scan_err:                      # the scan said every view is captured
        lost_cells |= {(r, c) for r in range(grid[1]) for c in range(grid[0])} - set(final)
    lost = len(lost_cells)
    resume = subprocess.run(cli("scan", "--resume", "--out", root, "--time-scale", time_scale,
                                "--sim-width-px", width), capture_output=True, text=True, env=env(), cwd=REPO,
                            timeout=600)
    after = done_views(root)
    before = {**seen, **final}                      # every capture seen: the resume must take none again
    twice += sum(1 for cell, rec in before.items() if cell in after and after[cell][1:] != rec[1:])
    ds = Dataset.open(root)
    records_lost = 0
    tracebacks = sum("Traceback" in r[1] for r in results.values()) + ("Traceback" in scan_err + resume.stderr)
    status = {}
    for name, (rc, err, processed) in results.items():
        status[name] = rc
        if rc != 0:
            continue
        if name == "process":
            have = sum((v.get("processed") or {}).get("status") == "done" for v in ds.views)
            records_lost += max(0, (processed or 0) - have) + ("processing" not in ds.manifest)
        elif name == "calibrate":
            records_lost += "calibration" not in ds.manifest
        else:
            records_lost += not (root / "quality.json").is_file()
    ds.close()
    return {"trial": i, "order": list(zip(stages, moments)), "exit": status, "scan": scan.returncode,
            "views_lost": lost, "records_lost": records_lost, "captured_twice": twice, "tracebacks": tracebacks}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=50)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--grid", default="4x3")
    parser.add_argument("--time-scale", type=float, default=0.02)
    parser.add_argument("--width-px", type=int, default=160)
    args = parser.parse_args()
    grid = tuple(int(x) for x in args.grid.lower().split("x"))
    rnd = random.Random(args.seed)
    totals = {"views_lost": 0, "records_lost": 0, "captured_twice": 0, "tracebacks": 0}
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="lfstudio-concurrency-") as tmp:
        work = Path(tmp)
        profile = work / "plain.toml"
        profile.write_text(PROFILE)
        for i in range(args.trials):
            result = trial(i, rnd, work, grid, args.time_scale, args.width_px, profile)
            for key in totals:
                totals[key] += result[key]
            print(json.dumps(result), flush=True)
    print(f"{args.trials} trials ({grid[0]}x{grid[1]} views, time scale {args.time_scale:g}, "
          f"{time.monotonic() - t0:.0f} s): {totals['views_lost']} views lost, {totals['records_lost']} records lost, "
          f"{totals['captured_twice']} captured twice, {totals['tracebacks']} tracebacks")
    return 0 if not any(totals.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
