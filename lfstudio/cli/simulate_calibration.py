"""``lfstudio simulate-calibration``: the paper's synthetic evaluation of the self-calibration."""

from __future__ import annotations

import argparse
import json
import sys

from lfstudio.errors import InputError

HELP = "reproduce the paper's synthetic calibration experiment (Figure 3) with known ground truth"


def _radii(text: str) -> list[float]:
    """'0:50:5' (start:stop:step, inclusive) or '0,10,25,50'."""
    try:
        if ":" in text:
            a, b, step = (float(x) for x in text.split(":"))
            if step <= 0 or b < a:
                raise ValueError
            n = int(round((b - a) / step))
            return [a + i * step for i in range(n + 1)]
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise InputError("--sweep", f"cannot read {text!r}", "START:STOP:STEP like 0:50:5, or a list 0,25,50") from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--trials", type=int, default=100, help="random trials per principal-point shift (default 100)")
    p.add_argument("--pp-shift-px", type=float, default=0.0, metavar="R",
                   help="principal-point shift radius in full-resolution pixels, at a random angle (default 0)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--points-per-pair", type=int, default=300, help="3-D points seen by each pair (default 300)")
    p.add_argument("--mode", choices=("both", "fixed", "estimated"), default="both",
                   help="principal point fixed at the centre (the paper), estimated, or both (default)")
    p.add_argument("--outliers", type=float, default=0.0, metavar="FRACTION",
                   help="share of matches replaced by random wrong ones (default 0)")
    p.add_argument("--sweep", metavar="RADII", help="run for several shifts, e.g. 0:50:5 (Figure 3)")
    p.add_argument("--plot", metavar="FILE.png", help="with --sweep: draw Figure 3 into this PNG")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def _row(label: str, s: dict) -> str:
    return (f"{label:24} {s['residual_px']['mean']:8.3f} {s['residual_px']['p1']:8.3f} {s['residual_px']['p99']:8.3f}"
            f" {s['residual_mean_abs_px']['mean']:9.3f} {s['true_residual_px']['mean']:9.3f}"
            f" {s['true_residual_px']['p99']:9.3f} {s['rotation_error_deg']['median']:9.4f}"
            f" {s['rotation_error_deg']['p99']:9.4f}")


HEADER = (f"{'':24} {'res mean':>8} {'res p1':>8} {'res p99':>8} {'mean|r|':>9} {'true mean':>9} "
          f"{'true p99':>9} {'rot med°':>9} {'rot p99°':>9}")


def run(args: argparse.Namespace) -> int:
    from lfstudio.calibration.simulate import SimulationConfig, simulate, sweep
    from lfstudio.jobs import TerminalProgress

    if args.trials < 1:
        raise InputError("--trials", f"{args.trials} must be at least 1", "≥ 1")
    if args.pp_shift_px < 0:
        raise InputError("--pp-shift-px", f"{args.pp_shift_px} must not be negative", "≥ 0 px")
    if args.points_per_pair < 10:
        raise InputError("--points-per-pair", f"{args.points_per_pair} is too few", "≥ 10")
    if not 0 <= args.outliers < 0.6:
        raise InputError("--outliers", f"{args.outliers} out of range", "0 … 0.6")
    if args.plot and not args.sweep:
        raise InputError("--plot", "needs --sweep (the figure plots several shifts)")
    modes = {"both": (False, True), "fixed": (False,), "estimated": (True,)}[args.mode]
    cfg = SimulationConfig(points_per_pair=args.points_per_pair, outlier_fraction=args.outliers)
    progress = TerminalProgress("simulate")
    if args.sweep:
        radii = _radii(args.sweep)
        results = sweep(radii, args.trials, args.seed, cfg, modes, progress)
        if args.plot:
            from lfstudio.calibration.plot import plot_sweep
            plot_sweep(results, args.plot)
            print(f"wrote {args.plot}", file=sys.stderr)
        if args.json:
            json.dump({"sweep": results}, sys.stdout, indent=1)
            sys.stdout.write("\n")
            return 0
        print("residuals: RMS per trial in full-resolution px (mean|r| = mean absolute); rotation error in degrees")
        print(f"{'pp shift':>8} " + HEADER)
        for res in results:
            for key, label in (("without_principal_point", "PP fixed"), ("with_principal_point", "PP estimated")):
                if key in res:
                    print(f"{res['pp_shift_px']:8.1f} " + _row(label, res[key]))
        return 0
    result = simulate(args.trials, args.pp_shift_px, args.seed, cfg, modes, progress)
    if args.json:
        json.dump(result, sys.stdout, indent=1)
        sys.stdout.write("\n")
        return 0
    print(f"{args.trials} trials, principal-point shift {args.pp_shift_px:g} px, seed {args.seed}; "
          "residuals: RMS per trial in full-resolution px (mean|r| = mean absolute), "
          f"before calibration {result['residual_before_px']['mean']:.1f} px")
    print(HEADER)
    for key, label in (("without_principal_point", "PP fixed (paper)"), ("with_principal_point", "PP estimated")):
        if key in result:
            print(_row(label, result[key]))
    if result["failures"]:
        print(f"{result['failures']} fits failed")
    return 0
