"""``lfstudio check DATASET``: is this capture good enough to publish? Judge every view from its pixels.

Writes ``DATASET/quality.json`` and ``DATASET/quality/`` (heat maps, disparity map, histograms,
report.html) and prints the verdicts. The exit status is 0 whatever the verdicts (scripts read them
from ``--json``); 1 only when the check itself could not run.
"""

from __future__ import annotations

import argparse
import json
import sys

from lfstudio.cli.args import path_option
from lfstudio.errors import InputError

HELP = "check a dataset's views from their pixels (sharpness, exposure, position, residual, depth); write quality.json"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", metavar="DATASET", type=path_option("DATASET"), help="dataset folder (holds dataset.json)")
    p.add_argument("--views", metavar="SPEC", default="all",
                   help="views to judge: 'all' (default) or names like r00_c000,r01_c002 (their neighbours are "
                        "read too, to compare with)")
    p.add_argument("--json", action="store_true",
                   help="print the whole report (quality.json) as one JSON object instead of text")
    p.add_argument("--work-width-px", type=int, default=1000, metavar="PX",
                   help="width at which views are tracked (default 1000)")
    p.add_argument("--threads", type=int, default=2, help="threads reading views (default 2)")
    p.add_argument("--no-disparity", action="store_true", help="skip the disparity map of the centre view")
    p.add_argument("--no-save", action="store_true", help="print the result but write nothing into the dataset")


def format_report(doc: dict) -> str:
    """A readable summary: the dataset checks, then one line per flagged view."""
    s = doc["summary"]
    rep = doc.get("repeatability") or {}
    depth = doc.get("depth_range") or {}
    disp = doc.get("disparity_map") or {}

    def num(x, spec: str) -> str:
        return "–" if x is None else format(x, spec)

    from lfstudio.quality.summaries import disparity_map_summary, disparity_summary, repeatability_summary

    lines = [f"verdict       {doc['verdict'].upper()}   {s['views']} views: {s['pass']} pass, {s['warn']} warn, "
             f"{s['fail']} fail",
             f"repeatability {repeatability_summary(rep)}",
             f"depth         {depth.get('verdict', 'n/a')}: {depth.get('why', '')}",
             f"disparity     {disparity_summary(depth)}"]
    zero = depth.get("zero_disparity") or {}
    if zero.get("about"):
        lines.append(f"zero plane    {zero['about']}")
    if disp:
        lines.append(f"disparity map {disparity_map_summary(disp, depth)}")
    if not doc["calibration"]["used"]:
        lines.append(f"note          {doc['calibration']['note']}")
    flagged = [v for v in doc["views"] if v["verdict"] in ("warn", "fail")]
    lines.append("")
    lines.append("flagged views" if flagged else "no view flagged")
    for v in flagged:
        lines.append(f"  {v['view']}  {v['verdict'].upper():4}  " + "; ".join(v["reasons"]))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from lfstudio.dataset import Dataset
    from lfstudio.jobs import TerminalProgress
    from lfstudio.quality import check_dataset

    if not 200 <= args.work_width_px <= 8000:
        raise InputError("--work-width-px", f"{args.work_width_px} is out of range", "200 .. 8000")
    if args.threads < 1:
        raise InputError("--threads", "must be at least 1")
    ds = Dataset.open(args.dataset)
    report = check_dataset(ds, args.views, work_width_px=args.work_width_px, threads=args.threads,
                           disparity=not args.no_disparity, write=not args.no_save,
                           progress=TerminalProgress("check"))
    if args.json:
        json.dump(report.document, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        print(format_report(report.document))
        if report.path is not None:
            pictures = report.document.get("pictures", {})
            print(f"\nwrote {report.path}" + (f" and {Path(ds.root) / pictures['report']}" if "report" in pictures
                                               else ""))
    return 0
