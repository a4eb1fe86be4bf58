"""``lfstudio virtual-dataset``: render a dataset from the virtual studio, with ground truth."""

from __future__ import annotations

import argparse
import sys

from lfstudio.errors import InputError
from lfstudio.numbers import SEED, SPACING_MM, WIDTH_PX, Number, parse_numbers
from lfstudio.cli.args import grid_option, number_option, numbers_option, path_option

DISTANCE_M = Number("m", 0, 10_000, low_open=True)
FRACTION = Number("", 0, 1)

HELP = "render a light-field dataset of the virtual studio directly to disk (DNG or PNG) with ground truth"


def _numbers(text: str, option: str, n: int) -> tuple[float, ...]:
    return parse_numbers(option, text, Number(), n, ",".join(["1"] * n))


def _pair(text: str, option: str) -> tuple[float, float]:
    a, b = _numbers(text, option, 2)
    return a, b


def _triple(text: str, option: str) -> tuple[float, float, float]:
    a, b, c = _numbers(text, option, 3)
    return a, b, c


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", type=path_option("folder"), help="the new dataset folder (missing or empty)")
    p.add_argument("--grid", default=(5, 3), type=grid_option("--grid"), metavar="CxR",
                   help="columns x rows (default 5x3; the reference is 101x21)")
    p.add_argument("--spacing-mm", default="4x6", type=numbers_option("--spacing-mm", SPACING_MM, 2, "4x6"),
                   metavar="HxV", help="spacing in mm, horizontal x vertical (default 4x6)")
    p.add_argument("--width", type=number_option(WIDTH_PX, "--width"), default=2000, metavar="PX",
                   help="image width in pixels (default 2000)")
    p.add_argument("--format", choices=("dng", "png"), default="dng",
                   help="14-bit Bayer DNG or 16-bit linear PNG (default dng)")
    p.add_argument("--rotation-deg", default="1,-1.5,0.7", metavar="RX,RY,RZ",
                   help="true orientation error, degrees (default 1,-1.5,0.7)")
    p.add_argument("--pp-offset-px", default="0,0", metavar="DX,DY", help="true principal-point offset (default 0,0)")
    p.add_argument("--position-noise-um", default="0,0", metavar="SX,SY",
                   help="camera-position error sigma in micrometres (default 0,0; the reference rig: 80,50)")
    p.add_argument("--near-m", type=number_option(DISTANCE_M, "--near-m"), default=1.77,
                   help="nearest scene distance (default 1.77)")
    p.add_argument("--far-m", type=number_option(DISTANCE_M, "--far-m"), default=4.77,
                   help="farthest scene distance (default 4.77)")
    p.add_argument("--flicker", type=number_option(FRACTION, "--flicker"), default=0.0,
                   help="per-shot gain sigma, e.g. 0.01 (default 0)")
    p.add_argument("--vignetting", type=number_option(FRACTION, "--vignetting"), default=0.0,
                   help="corner light loss, e.g. 0.2 (default 0)")
    p.add_argument("--noise", type=number_option(FRACTION, "--noise"), default=0.0,
                   help="read noise, fraction of white, e.g. 0.002 (default 0)")
    p.add_argument("--fault", action="append", default=[], metavar="KIND:VIEW[:VALUE]",
                   help="spoil a view, named like r01_c002 (row 1, column 2) (repeatable): blur:VIEW:PX (motion "
                        "blur, PX[,ANGLE]), luminance:VIEW:FACTOR, displaced:VIEW:DX[,DY] (mm), skipped:VIEW (the "
                        "rig did not move: the view repeats the previous one); ground truth lists them")
    p.add_argument("--seed", type=number_option(SEED, "--seed"), default=0, metavar="N",
                   help="random seed of the scene's texture, the flicker, the noise and the position errors: "
                        "the same seed renders the same dataset (default 0)")
    p.add_argument("--no-truth-maps", dest="truth_maps", action="store_false",
                   help="do not store each view's ground-truth depth (m) and disparity (px) under truth/ "
                        "(docs/conventions.md)")
    p.add_argument("--workers", type=number_option(Number("", 1, 256, integer=True), "--workers"), default=1,
                   help="processes rendering in parallel (default 1)")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from lfstudio.jobs import TerminalProgress
    from lfstudio.studio.simulated import GROUND_TRUTH_NAME, make_virtual_dataset, parse_fault

    cols, rows = args.grid
    if not 16 <= args.width <= 12000:
        raise InputError("--width", f"{args.width} px is out of range", "16 .. 12000")
    if not 0 < args.near_m < args.far_m:
        raise InputError("--near-m", f"must be positive and below --far-m ({args.far_m:g})")
    if args.workers < 1:
        raise InputError("--workers", "must be at least 1")
    try:
        faults = [parse_fault(text) for text in args.fault]
    except ValueError as exc:
        raise InputError("--fault", str(exc)) from None
    folder = Path(args.folder)       # missing or empty: make_virtual_dataset checks it first
    ds = make_virtual_dataset(folder, cols, rows, spacing_mm=args.spacing_mm,
                              width_px=args.width, fmt=args.format,
                              rotation_deg=_triple(args.rotation_deg, "--rotation-deg"),
                              pp_offset_px=_pair(args.pp_offset_px, "--pp-offset-px"),
                              position_noise_um=_pair(args.position_noise_um, "--position-noise-um"),
                              near_m=args.near_m, far_m=args.far_m, flicker=args.flicker,
                              vignetting=args.vignetting, noise=args.noise, seed=args.seed, workers=args.workers,
                              faults=faults, truth_maps=args.truth_maps,
                              progress=TerminalProgress("rendering"))
    print(f"{ds.root}: {len(ds.views)} views ({args.format.upper()}, {args.width} px wide); "
          f"ground truth in {ds.root / GROUND_TRUTH_NAME}", file=sys.stdout)
    return 0
