"""``lfstudio simulate-calibration``: the paper's synthetic evaluation of the self-calibration."""

from __future__ import annotations

import argparse
import json
import sys

from lfstudio.errors import InputError
from lfstudio.cli.args import path_option

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
    p.add_argument("--views", metavar="SPEC", default="array:3x2",
                   help="the calibration's views over the 101 x 21 grid: an array array:COLUMNSxROWS (default "
                        "array:3x2, the paper's), 'default' (what lfstudio calibrate uses: array:4ex10), "
                        "'array:101x2' (two full rows), or view names")
    p.add_argument("--pairs", choices=("all", "spanning", "neighbours"), default="spanning",
                   help="which pairs of those views (default spanning, as lfstudio calibrate; for the paper's array "
                        "the same as all)")
    p.add_argument("--mode", choices=("both", "fixed", "estimated"), default="both",
                   help="principal point held at the centre (the paper), estimated where observable (as lfstudio "
                        "calibrate does), or both (default)")
    p.add_argument("--outliers", type=float, default=0.0, metavar="FRACTION",
                   help="share of matches replaced by random wrong ones (default 0)")
    p.add_argument("--sweep", metavar="RADII", help="run for several shifts, e.g. 0:50:5 (Figure 3)")
    p.add_argument("--plot", metavar="FILE.png", type=path_option("--plot"), help="with --sweep: draw Figure 3 into this PNG")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def _row(label: str, s: dict) -> str:
    cov = s["coverage"]["true_residual"]
    return (f"{label:20} {s['residual_px']['mean']:8.3f} {s['residual_px']['p99']:8.3f}"
            f" {s['true_residual_px']['mean']:9.3f} {s['true_residual_px']['p99']:9.3f}"
            f" {s['rotation_error_deg']['median']:9.4f} {s['rotation_error_deg']['p99']:9.4f}"
            f" {s['stated_true_residual_px']['median_1sigma']:8.3f} {100 * cov[0]:6.0f}% {100 * cov[1]:5.0f}%"
            f" {s['pp_error_px']['estimated_trials']:6d}")


def _linear_row(s: dict) -> str:
    lin = s["linear"]
    return (f"{'linear epipole':20} {'':8} {'':8} {lin['true_residual_px']['mean']:9.3f} "
            f"{lin['true_residual_px']['p99']:9.3f} {lin['rotation_error_deg']['median']:9.4f} "
            f"{lin['rotation_error_deg']['p99']:9.4f}")


HEADER = (f"{'':20} {'res mean':>8} {'res p99':>8} {'true mean':>9} {'true p99':>9} {'rot med°':>9} {'rot p99°':>9} "
          f"{'stated1σ':>8} {'cov1σ':>7} {'cov2σ':>6} {'PP est':>6}")
LEGEND = ("res: RMS residual per trial (px); true: rectification error of the ideal rig on the evaluation set "
          "(every pair of a 3 x 5 array over the grid; px RMS per trial); rot: angle to the true orientation; "
          "stated1σ: median stated 68 % bound of the true error; cov: trials whose true error is within the "
          "stated 1σ / 2σ bounds; PP est: trials where the principal point was estimated (observable)")


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
    modes = {"both": ("centre", "auto"), "fixed": ("centre",), "estimated": ("auto",)}[args.mode]
    cfg = SimulationConfig(points_per_pair=args.points_per_pair, outlier_fraction=args.outliers, views=args.views,
                           pair_set=args.pairs)
    pairs = cfg.pairs()        # reads --views (an InputError naming it when it cannot)
    if not any(p.direction == "h" for p in pairs) or not any(p.direction == "v" for p in pairs):
        raise InputError("--views", f"{args.views!r} gives no pairs in one direction", "views in ≥ 2 rows and ≥ 2 columns")
    progress = TerminalProgress("simulate")
    labels = (("without_principal_point", "PP fixed (paper)"), ("with_principal_point", "PP auto"))
    if args.sweep:
        radii = _radii(args.sweep)
        results = sweep(radii, args.trials, args.seed, cfg, modes, progress, linear=True)
        if args.plot:
            from lfstudio.calibration.plot import plot_sweep
            plot_sweep(results, args.plot)
            print(f"wrote {args.plot}", file=sys.stderr)
        if args.json:
            json.dump({"sweep": results}, sys.stdout, indent=1)
            sys.stdout.write("\n")
            return 0
        print(f"{args.trials} trials per shift, views {args.views} ({len(pairs)} pairs, {args.pairs}); " + LEGEND)
        print(f"{'pp shift':>8} " + HEADER)
        for res in results:
            for key, label in labels:
                if key in res:
                    print(f"{res['pp_shift_px']:8.1f} " + _row(label, res[key]))
            first = res.get("without_principal_point") or res.get("with_principal_point")
            if first is not None and "linear" in first:
                print(f"{res['pp_shift_px']:8.1f} " + _linear_row(first))
        return 0
    result = simulate(args.trials, args.pp_shift_px, args.seed, cfg, modes, progress, linear=True)
    if args.json:
        json.dump(result, sys.stdout, indent=1)
        sys.stdout.write("\n")
        return 0
    print(f"{args.trials} trials, principal-point shift {args.pp_shift_px:g} px, seed {args.seed}, views {args.views} "
          f"({result['views']} views, {result['pairs']} pairs, {args.pairs}); residual before calibration "
          f"{result['residual_before_px']['mean']:.1f} px")
    print(LEGEND)
    print(HEADER)
    for key, label in labels:
        if key in result:
            print(_row(label, result[key]))
    first = result.get("without_principal_point") or result.get("with_principal_point")
    if first is not None and "linear" in first:
        print(_linear_row(first))
    if result["failures"]:
        print(f"{result['failures']} fits failed")
    return 0
