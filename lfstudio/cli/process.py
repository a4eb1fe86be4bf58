"""``lfstudio process DATASET``: RAW captures → rectified 16-bit views in DATASET/processed/."""

from __future__ import annotations

import argparse
import sys

from lfstudio.numbers import WORKERS, as_option
from lfstudio.dataset.paths import path_option

HELP = "process the captured views (debayer, lens, colour, shading, de-flicker, rectify, downsample)"


def _cluster_address(text: str) -> str:
    from lfstudio.processing.executors import check_cluster_address

    check_cluster_address(text)
    return text.strip()


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", metavar="DATASET", type=path_option("DATASET"), help="the dataset folder (holding dataset.json)")
    p.add_argument("--profile", metavar="FILE", type=path_option("--profile"),
                   help="processing profile (TOML); default: DATASET/processing.toml, or built-in defaults. "
                        "The profile used is saved as DATASET/processing.toml")
    p.add_argument("--cluster", metavar="ADDR", type=as_option("--cluster", _cluster_address),
                   help="Dask scheduler address, e.g. tcp://10.0.0.5:8786 (workers must see the dataset "
                        "folder at the same path); default: a local process pool")
    p.add_argument("--workers", metavar="N", type=WORKERS.option("--workers"),
                   help="local worker processes (default: one per core; 0: run in this process)")
    p.add_argument("--force", action="store_true",
                   help="process every view again, even those already done with the same profile")
    p.add_argument("--write-profile", metavar="FILE", type=path_option("--write-profile"),
                   help="write the effective profile (defaults or --profile) to FILE and exit")


def run(args: argparse.Namespace) -> int:
    from lfstudio.errors import InputError
    from lfstudio.jobs import TerminalProgress
    from lfstudio.processing.pipeline import process_dataset
    from lfstudio.dataset.profile import Profile

    if args.workers is not None and args.workers < 0:
        raise InputError("--workers", f"{args.workers} is negative", "0 (in this process) or more")
    if args.cluster and args.workers is not None:
        raise InputError("--workers", "cannot be combined with --cluster (the cluster has its own workers)")
    profile = Profile.load(args.profile) if args.profile else Profile.for_dataset(args.dataset)
    if args.write_profile:
        profile.save(args.write_profile)
        print(f"profile written to {args.write_profile}")
        return 0
    bar = TerminalProgress("process")
    report = process_dataset(args.dataset, profile, workers=args.workers, cluster=args.cluster,
                             force=args.force, progress=bar)
    print(report.summary())
    for row, column, error in report.failed:
        print(f"FAILED row {row}, column {column}: {error}", file=sys.stderr)
    return 1 if report.failed else 0
