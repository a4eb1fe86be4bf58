"""``lfstudio calibrate DATASET``: self-calibrate the camera orientation from the images alone."""

from __future__ import annotations

import argparse
import json
import sys

from lfstudio.cli.args import number_option, path_option
from lfstudio.errors import InputError
from lfstudio.numbers import Number

HELP = "self-calibrate the camera orientation (and principal point) from the dataset's images"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", metavar="DATASET", type=path_option("DATASET"), help="dataset folder (holds dataset.json)")
    p.add_argument("--views", metavar="SPEC", default="default",
                   help="views to use: 'default' (array:4ex10: the first two and last two columns x ten rows "
                        "spread over the grid, capped by its size), an array array:COLUMNSxROWS such as array:3x2 "
                        "(the paper's) or array:5x5 (an 'e' after a count puts those columns/rows at the ends), "
                        "'all', rows/columns like r0-8,c10-18, or names like r00_c000,r00_c050,r20_c000")
    p.add_argument("--pairs", choices=("all", "spanning", "neighbours"), default="spanning",
                   help="which pairs within each row and column of the views: neighbours plus every pair with an "
                        "end view ('spanning', default), every pair ('all'), or adjacent views only ('neighbours': "
                        "short baselines, warned about on a wide grid)")
    p.add_argument("--neighbours-only", action="store_true", help="the same as --pairs neighbours")
    p.add_argument("--principal-point", choices=("auto", "centre"), default="auto",
                   help="'auto' (default): estimate the principal point only when the views determine it (the "
                        "report says which and why); 'centre': hold it at the image centre")
    p.add_argument("--estimate-principal-point", action="store_true",
                   help="the same as --principal-point auto (the default; kept for older scripts)")
    p.add_argument("--position-sigma-um", metavar="SX,SY",
                   help="the rig's repeatability in micrometres, horizontal,vertical: the prior of each view's "
                        "position error (default: the dataset's rig, else the reference gantry's 80,50)")
    p.add_argument("--focal-length-px", type=number_option(Number("px", 0, 1e6, low_open=True), "--focal-length-px"),
                   metavar="F",
                   help="focal length in full-resolution pixels (default: from the dataset's camera and lens)")
    p.add_argument("--work-width-px", type=number_option(Number("px", 0, 100_000, integer=True), "--work-width-px"),
                   default=None, metavar="PX",
                   help="width at which features are detected (default 1400, "
                        "lfstudio.calibration.features.DEFAULT_WORK_WIDTH_PX; 0 = full resolution)")
    p.add_argument("--threads", type=number_option(Number("", 1, 256, integer=True), "--threads"), default=2,
                   help="threads for feature detection and matching (default 2)")
    p.add_argument("--no-save", action="store_true", help="print the result but do not write calibration.json")
    p.add_argument("--json", action="store_true", help="print the calibration document as JSON instead of text")


def run(args: argparse.Namespace) -> int:
    from lfstudio.calibration.calibrate import calibrate_dataset
    from lfstudio.calibration.features import DEFAULT_WORK_WIDTH_PX
    from lfstudio.calibration.model import save_calibration
    from lfstudio.calibration.report import format_report
    from lfstudio.cli.args import number_pair
    from lfstudio.dataset import Dataset
    from lfstudio.jobs import TerminalProgress

    if args.focal_length_px is not None and not args.focal_length_px > 0:
        raise InputError("--focal-length-px", f"{args.focal_length_px} must be positive", "> 0 pixels")
    if args.work_width_px is None:
        args.work_width_px = DEFAULT_WORK_WIDTH_PX
    if args.work_width_px < 0:
        raise InputError("--work-width-px", f"{args.work_width_px} must not be negative", "0 (full) or ≥ 200")
    if 0 < args.work_width_px < 200:
        raise InputError("--work-width-px", f"{args.work_width_px} is too small for reliable features",
                         "0 (full) or ≥ 200")
    sigma = None
    if args.position_sigma_um is not None:
        sigma = number_pair(args.position_sigma_um, "--position-sigma-um", example="80,50")
        if not all(0 <= s <= 100_000 for s in sigma):
            raise InputError("--position-sigma-um", f"{args.position_sigma_um} out of range", "0 … 100000 µm each")
    ds = Dataset.open(args.dataset)
    if args.focal_length_px is None:         # before any detection work, not after it
        from lfstudio.errors import DatasetError

        try:
            ds.focal_length_px()
        except DatasetError:
            raise InputError("--focal-length-px", f"{ds.root} does not record its focal length (imported images "
                             "without EXIF): give it in pixels",
                             "the focal length in mm ÷ the pixel pitch in mm, e.g. --focal-length-px 11111 "
                             "for 50 mm and 4.5 µm pixels") from None
    run_ = calibrate_dataset(ds, args.views, principal_point="auto" if args.estimate_principal_point
                             else args.principal_point, focal_length_px=args.focal_length_px,
                             max_width_px=args.work_width_px or None,
                             pair_set="neighbours" if args.neighbours_only else args.pairs, position_sigma=sigma,
                             threads=max(1, args.threads), progress=TerminalProgress("calibrate"))
    doc = run_.document
    if not args.no_save:
        path = save_calibration(ds, doc)
        print(f"wrote {path}", file=sys.stderr)
    if args.json:
        json.dump(doc, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        print(format_report(doc))
        if not args.no_save:
            print(f"\nsaved {path}")
    return 0
