"""``lfstudio info DATASET``: summarise a dataset (views done / missing / failed, devices, size)."""

from __future__ import annotations

import argparse
import json

from lfstudio.errors import DatasetError
from lfstudio.cli.args import path_option

HELP = "summarise a dataset folder: grid, devices, views done/missing/failed, size"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", metavar="DATASET", type=path_option("DATASET"), help="the dataset folder (holding dataset.json)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--verify", action="store_true",
                   help="also check every captured file exists and matches its sha256 (reads all files)")


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return str(n)


def _files_line(summary: dict) -> str:
    """Size of the views' files by folder, e.g. 'raw/ 83.5 MB' or, for a dataset restored from a
    video, 'processed/ 83.5 MB (restored from bust.mkv); raw/ empty'."""
    by_folder = summary["view_file_bytes"]
    if not by_folder:
        return "none yet (no view captured)"
    text = ", ".join(f"{folder} {_size(n)}" for folder, n in sorted(by_folder.items()))
    if summary.get("imported_from"):
        text += f" (restored from {summary['imported_from']})"
    if "raw/" not in by_folder:
        text += "; raw/ empty"
    return text


def run(args: argparse.Namespace) -> int:
    from lfstudio.dataset import Dataset

    ds = Dataset.open(args.dataset)
    summary = ds.summary()
    problems = ds.verify_files(checksums=True) if args.verify else []
    if args.verify:
        summary["file_problems"] = problems
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        g = summary["grid"]
        spacing = g.get("spacing_mm") or ["?", "?"]
        print(f"dataset   {summary['path']}")
        print(f"format    {summary['format']} v{summary['version']}, created {summary['created']}")
        print(f"rig       {summary['rig'] or '–'}")
        print(f"camera    {summary['camera'] or '–'}; lens {summary['lens'] or '–'}")
        print(f"grid      {g['columns']} x {g['rows']} views, spacing {spacing[0]} x {spacing[1]} mm, "
              f"order {g.get('order') or 'row-meander'}")
        print(f"views     {summary['done']} done, {summary['missing']} missing, {summary['failed']} failed, "
              f"{summary['skipped']} skipped (of {summary['views']})")
        print(f"files     {_files_line(summary)}")
        if summary["journal_replayed"]:
            print(f"journal   {summary['journal_replayed']} view(s) recovered from journal.jsonl "
                  "(the scan was interrupted; resume it with 'lfstudio scan --resume')")
        for p in summary["journal_problems"]:
            print(f"warning   {p}")
        if args.verify:
            print("files     all present and intact" if not problems else f"files     {len(problems)} problem(s):")
            for p in problems:
                print(f"  - {p}")
    if problems:
        raise DatasetError(f"{ds.root}: {len(problems)} file problem(s) found")
    return 0
