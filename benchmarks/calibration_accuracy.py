"""Simulated accuracy of the self-calibration, with the stated uncertainty checked against the truth.

    python benchmarks/calibration_accuracy.py [--trials 25] [--shifts 0,50,100,200] [--seed 0]

The paper's synthetic experiment (section 4.1; :mod:`lfstudio.calibration.simulate`: reference rig
101 × 21 views, 80 µm position noise, 0.5 px feature noise, orientation σ 2.5°), per principal-point
shift and per subsample: the paper's 2 × 3, a 3 × 5, the new default (what ``lfstudio calibrate``
uses), and two full rows paired with neighbours only. The principal point is handled as
``lfstudio calibrate`` does (estimated only where observable). Columns: the true rectification error
on the fixed evaluation set (every pair of a 3 × 5 array; px RMS per trial: mean and p99 over
trials), the rotation error (median, p99), the coverage (trials whose true error is within the stated
1σ / 2σ bound), how many trials estimated the principal point (and the largest error of those), the fit
time (CPU s per fit), and the linear epipole method on the same trials (true error, rotation error).
Prints a Markdown table, the trial count and the time taken.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import argparse

from _measure import Timer, load_text
from lfstudio.calibration.pairs import DEFAULT_VIEWS
from lfstudio.dataset.grid import Grid
from lfstudio.calibration.simulate import SimulationConfig, simulate

SUBSAMPLES = (("2x3", "all", "2 × 3 (paper)"), ("3x5", "all", "3 × 5"), ("default", "all", "default"),
              ("2x101", "neighbours", "2 × 101 neighbours only"))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=25)
    ap.add_argument("--shifts", default="0,50,100,200")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    shifts = [float(r) for r in args.shifts.split(",")]
    d = Grid(101, 21).select(DEFAULT_VIEWS, Grid(101, 21).views())
    print(f"{args.trials} trials per row, seed {args.seed}; {load_text()}; default = {len({r for r, _ in d})} × "
          f"{len({c for _, c in d})} views, every pair\n")
    print("| pp shift | views (pairs) | true error mean | true p99 | rot. median | rot. p99 | coverage 1σ | 2σ "
          "| PP estimated | fit CPU | linear: true mean | true p99 | rot. median | rot. p99 |")
    print("| --- " * 14 + "|")
    with Timer() as span:
        _table(args, shifts)
    print(f"\n{args.trials} trials per row; {span.wall_s:.0f} s wall, {span.cpu_s:.0f} s CPU, {load_text()}; "
          "true error = RMS over the evaluation set per trial (px), coverage against the stated bounds")


def _table(args, shifts) -> None:
    for k, shift in enumerate(shifts):
        for j, (views, pairs, label) in enumerate(SUBSAMPLES):
            cfg = SimulationConfig(views=views, pair_set=pairs)
            out = simulate(args.trials, shift, args.seed + 100 * k + j, cfg, modes=("auto",), linear=True)
            s, lin = out["with_principal_point"], out["with_principal_point"]["linear"]
            cov = s["coverage"]["true_residual"]
            pp = s["pp_error_px"]
            pp_text = f"{pp['estimated_trials']}" + (f" (max {pp['max_estimated']:.0f} px)" if pp["estimated_trials"] else "")
            print(f"| {shift:g} px | {label} ({out['pairs']}) | {s['true_residual_px']['mean']:.3f} | "
                  f"{s['true_residual_px']['p99']:.3f} | {s['rotation_error_deg']['median']:.4f}° | "
                  f"{s['rotation_error_deg']['p99']:.4f}° | {100 * cov[0]:.0f} % | {100 * cov[1]:.0f} % | {pp_text} | "
                  f"{s['fit_cpu_s']['mean']:.2f} s | {lin['true_residual_px']['mean']:.3f} | "
                  f"{lin['true_residual_px']['p99']:.3f} | {lin['rotation_error_deg']['median']:.4f}° | "
                  f"{lin['rotation_error_deg']['p99']:.4f}° |", flush=True)


if __name__ == "__main__":
    main()
