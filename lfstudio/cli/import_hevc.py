"""``lfstudio import-hevc FILE --out DATASET``: restore an HEVC export's views as 16-bit PNGs."""

from __future__ import annotations

import argparse
from lfstudio.cli.args import path_option

HELP = "restore the views of an HEVC export (FILE + FILE.json) as 16-bit PNGs in a new dataset"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE", type=path_option("FILE"), help="the .mp4/.mkv/.hevc file written by 'lfstudio export --format hevc' "
                                                "(its sidecar FILE.json must lie next to it)")
    p.add_argument("--out", required=True, metavar="DATASET", type=path_option("--out"), help="the new dataset folder (missing or empty)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace DATASET if it holds a dataset (default: refuse; a folder of other files is never replaced)")


def run(args: argparse.Namespace) -> int:
    from lfstudio.dataset import Dataset
    from lfstudio.errors import InputError
    from lfstudio.export import import_hevc
    from lfstudio.jobs import TerminalProgress

    try:
        root = import_hevc(args.file, args.out, progress=TerminalProgress("import"), overwrite=args.overwrite)
    except InputError as exc:
        option = {"file": "FILE", "out": "--out"}.get(exc.field)
        if option:
            raise InputError(option, str(exc).split(": ", 1)[1]) from None
        raise
    ds = Dataset.open(root)
    counts = ds.status_counts()
    print(f"restored {counts['done']} views into {root}")
    return 0
