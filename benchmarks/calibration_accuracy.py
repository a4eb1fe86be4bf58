"""Simulated accuracy of the self-calibration (the paper's section 4.1 / Figure 3) as a table.

    python benchmarks/calibration_accuracy.py [--trials 200] [--radii 0,25,50] [--seed 0]

Prints a Markdown table (the one in README "Self-calibration"): per principal-point shift and mode
(principal point fixed = the paper's method, or estimated), the RMS residual per trial (mean, p1,
p99 over trials), the mean absolute residual, the true rectification error (mean, p99) and the
rotation error against the truth (median, p99), plus the time per trial.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import argparse
import time

from lfstudio.calibration.simulate import simulate


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=200)
    ap.add_argument("--radii", default="0,25,50")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    radii = [float(r) for r in args.radii.split(",")]
    print(f"{args.trials} trials per row, seed {args.seed}; residuals in full-resolution px, rotation in degrees\n")
    print("| pp shift r | principal point | residual RMS mean | p1 | p99 | mean abs | true mean | true p99 "
          "| rot. error median | rot. p99 |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    t_total, n_fits = 0.0, 0
    for k, r in enumerate(radii):
        t0 = time.perf_counter()
        out = simulate(args.trials, r, args.seed + k)
        t_total += time.perf_counter() - t0
        n_fits += 2 * args.trials
        for key, label in (("without_principal_point", "fixed (paper)"), ("with_principal_point", "estimated")):
            s = out[key]
            print(f"| {r:g} px | {label} | {s['residual_px']['mean']:.3f} | {s['residual_px']['p1']:.3f} | "
                  f"{s['residual_px']['p99']:.3f} | {s['residual_mean_abs_px']['mean']:.3f} | "
                  f"{s['true_residual_px']['mean']:.3f} | {s['true_residual_px']['p99']:.3f} | "
                  f"{s['rotation_error_deg']['median']:.4f}° | {s['rotation_error_deg']['p99']:.4f}° |")
    print(f"\n{1000 * t_total / n_fits:.0f} ms per simulated calibration (incl. drawing the trial)")


if __name__ == "__main__":
    main()
