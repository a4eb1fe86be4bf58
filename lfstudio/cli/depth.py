"""``lfstudio depth DATASET``: dense disparity and depth of the views, stored in DATASET/depth/."""

from __future__ import annotations

import argparse
import sys
from lfstudio.cli.args import number_option, path_option
from lfstudio.numbers import WORKERS, Number

HELP = "estimate each view's disparity, depth and confidence from its 2-D neighbourhood (resumable)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", metavar="DATASET", type=path_option("DATASET"), help="the dataset folder (holding dataset.json)")
    p.add_argument("--views", metavar="SUBSET", default=None,
                   help="which views (default all captured): all, r0-8,c10-18, array:3x2, r00_c000,r00_c050")
    p.add_argument("--source", default="auto", choices=("auto", "raw", "processed"),
                   help="processed views (default when every needed view has one) or the captures rectified with "
                        "the calibration")
    p.add_argument("--disparity-range", metavar="MIN,MAX", default=None,
                   help="the disparities to search, in px between horizontal neighbours (write "
                        "--disparity-range=-3.5,3 when MIN is negative); default: the HCI folder's disp_min/disp_max, "
                        "the scene plan, else the tracks of the check or the import (printed with its origin)")
    p.add_argument("--steps", metavar="H,V", default=None,
                   help="the neighbourhood: views up to H columns and V rows away, along the view's row, column and "
                        "diagonals (default 4,4)")
    p.add_argument("--cluster", metavar="ADDR",
                   help="Dask scheduler address, e.g. tcp://10.0.0.5:8786 (workers must see the dataset folder at "
                        "the same path); default: a local process pool")
    p.add_argument("--workers", metavar="N", type=number_option(WORKERS, "--workers"),
                   help="local worker processes (default: one per core; 0: run in this process)")
    p.add_argument("--force", action="store_true", help="compute every view again, even those up to date")
    p.epilog = CONFIDENCE_MEANING


#: what the confidence map is, in the words of the help (and docs/how-to/depth.md)
CONFIDENCE_MEANING = (
    "The confidence map (DATASET/depth/confidence/rRR_cCCC.pfm, 0 ... 1) is 1 - (the matching cost at the "
    "answer) / (the lowest cost 3 or more candidate disparities away): 0 where another disparity matches as well "
    "(flat or repeated texture, the end of the searched range), near 1 where nothing else does. It ranks the pixels "
    "of one map (higher: fewer wrong) but is no probability and means different things on different scenes: of "
    "the pixels with confidence 0.3-0.5, 0.4-1.6 % are more than 0.07 px off on the HCI benchmark's scenes, "
    "5 % on the virtual studio.")


def run(args: argparse.Namespace) -> int:
    from lfstudio.depth.run import DepthSettings, estimate_depth, parse_disparity_range
    from lfstudio.errors import InputError
    from lfstudio.jobs import TerminalProgress
    from lfstudio.numbers import parse_numbers
    from lfstudio.processing.executors import open_executor

    if args.workers is not None and args.workers < 0:
        raise InputError("--workers", f"{args.workers} is negative", "0 (in this process) or more")
    if args.cluster and args.workers is not None:
        raise InputError("--workers", "cannot be combined with --cluster (the cluster has its own workers)")
    settings = DepthSettings()
    if args.steps:
        h, v = parse_numbers("--steps", args.steps, Number("", 0, 50, integer=True), 2, "4,4")
        if h + v < 1:
            raise InputError("--steps", "needs at least one neighbour", "e.g. 4,4")
        settings = DepthSettings(steps_h=int(h), steps_v=int(v))
    stated = parse_disparity_range("--disparity-range", args.disparity_range) if args.disparity_range else None
    from lfstudio.dataset import Dataset

    ds = Dataset.open(args.dataset)          # a bad folder is named before any worker starts
    with open_executor(args.workers, args.cluster) as info:
        executor = None if args.workers == 0 and not args.cluster else info.executor
        print(f"depth on {info.description}", file=sys.stderr)
        report = estimate_depth(ds, args.views, settings=settings, source=args.source, disparity_range_px=stated,
                                executor=executor, workers=info.workers, force=args.force, progress=TerminalProgress("depth"))
    print(report.range_text.replace("the range stated", "--disparity-range"))
    for warning in report.warnings:
        print(f"note: {warning}", file=sys.stderr)
    print(report.summary())
    for name, error in report.failed.items():
        print(f"FAILED {name}: {error}", file=sys.stderr)
    return 1 if report.failed else 0
