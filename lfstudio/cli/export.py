"""``lfstudio export DATASET --format png|hevc|hci|colmap|nerfstudio --out PATH``: write the views for other tools."""

from __future__ import annotations

import argparse
import sys

from lfstudio.cli.args import grid_position, number_option, numbers_option, path_option, refused_spelling
from lfstudio.errors import InputError
from lfstudio.numbers import Number

BITS = Number("bits", 1, 16, integer=True)   # each format checks its own depths

HELP = ("export the views as 16-bit PNG + manifest, an HEVC stream (meander order), the HCI benchmark layout, "
        "a COLMAP model or a nerfstudio transforms.json (with the rig's known poses)")

#: ExportOptions field -> the option the user typed (error messages name what the user knows)
_OPTION = {"format": "--format", "out": "--out", "views": "--views", "source": "--source", "crf": "--crf",
           "bit_depth": "--bit-depth", "hci_size": "--hci-size", "hci_center": "--hci-centre-view",
           "hci_bit_depth": "--hci-bit-depth", "image_bit_depth": "--image-bit-depth", "holdout": "--holdout", "authors": "--authors"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", metavar="DATASET", type=path_option("DATASET"), help="the dataset folder (holding dataset.json)")
    from lfstudio.export import FORMATS
    from lfstudio.export.nerfstudio import HOLDOUT_HELP

    p.add_argument("--format", required=True, choices=FORMATS, type=str.lower,
                   help="png (16-bit PNG per view + manifest.json), hevc (x265 12-bit 4:4:4, meander order, "
                        "sidecar FILE.json), hci (HCI benchmark layout of a sub-array), colmap (COLMAP text "
                        "model sparse/0/*.txt + images/, known poses, metres) or nerfstudio (transforms.json + "
                        "images/, known poses, train/test split)")
    p.add_argument("--out", required=True, metavar="PATH", type=path_option("--out"),
                   help="png/hci/colmap/nerfstudio: a new folder; hevc: a new .mp4/.mkv/.hevc file "
                        "(its sidecar is PATH.json)")
    p.add_argument("--views", metavar="SUBSET",
                   help="views to export: 'all' (default), rows/columns like r0-8,c10-18, an array like array:5x3 "
                        "(columns x rows) spread over the grid, or names like r00_c000,r00_c001")
    p.add_argument("--source", default="auto", metavar="SRC",
                   help="raw, processed, tonemap, hdr, or auto (default: processed when every chosen view is processed). "
                        "A bracketed dataset: raw and processed show the bracket's reference (0 EV) frame, tonemap "
                        "the tone-mapped merge of every frame (lfstudio process), hdr (colmap, nerfstudio) the merged "
                        "linear radiance as float OpenEXR/TIFF files; the export's manifest names which")
    p.add_argument("--crf", type=number_option(Number("", 0, 51, integer=True), "--crf"), default=8,
                   help="hevc: constant rate factor, lower is better (default 8)")
    p.add_argument("--bit-depth", type=number_option(BITS, "--bit-depth"), default=12, help="hevc: 10 or 12 bits (default 12)")
    p.add_argument("--hci-size", default="9x9", metavar="CxR",
                   type=numbers_option("--hci-size", Number("", 1, integer=True), 2, "9x9"),
                   help="hci: sub-array columns x rows (default 9x9; ignored with --views)")
    p.add_argument("--hci-centre-view", metavar="COLUMN,ROW",
                   help="hci: the sub-array's centre view, grid column,row from 0 (default: the grid centre)")
    refused_spelling(p, "--hci-center", lambda value: (
        f"--hci-center took ROW,COLUMN; the centre view is now --hci-centre-view COLUMN,ROW like every position: "
        f"write --hci-centre-view {','.join(reversed(value.split(',')))}"))
    p.add_argument("--hci-bit-depth", type=number_option(BITS, "--hci-bit-depth"), default=8,
                   help="hci: 8 (sRGB PNG like the benchmark, default) or 16 (linear 16-bit PNG)")
    p.add_argument("--authors", default="", metavar="NAMES",
                   help="hci: the authors written to parameters.cfg (default: the dataset's 'authors', else empty)")
    p.add_argument("--image-bit-depth", type=number_option(BITS, "--image-bit-depth"), default=8,
                   help="colmap/nerfstudio: 8 (sRGB PNG, what view-synthesis tools expect, default) or 16 "
                        "(linear 16-bit PNG)")
    p.add_argument("--holdout", default="none", metavar="SPLIT",
                   help=f"nerfstudio: views held out of training for evaluation: {HOLDOUT_HELP} (default none)")
    p.add_argument("--no-points", dest="points", action="store_false",
                   help="colmap/nerfstudio: leave out the sparse point cloud (points3D.txt stays empty, no PLY); "
                        "by default it is triangulated from the views with the known poses")
    p.add_argument("--depth", action="store_true",
                   help="nerfstudio: depth maps per frame (depth_file_path: 16-bit PNG in mm, beside them float TIFF "
                        "in m and a confidence PFM); hci: estimated disparity maps (estimated_disp_CamNNN.pfm). Views "
                        "without a map ('lfstudio depth') are computed first")
    p.add_argument("--overwrite", action="store_true", help="replace PATH if it exists (default: refuse)")
    p.add_argument("--estimate", action="store_true", help="print the size estimate and exit without writing")


def _centre_view(text: str | None) -> tuple[int, int] | None:
    """``--hci-centre-view COLUMN,ROW`` -> the (row, column) of :class:`ExportOptions`."""
    if not text:
        return None
    column, row = grid_position(text, "--hci-centre-view", example="50,10")
    return row, column


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from lfstudio.dataset import Dataset
    from lfstudio.export import ExportOptions, estimate_export, export_dataset
    from lfstudio.jobs import TerminalProgress

    options = ExportOptions(format=args.format, out=Path(args.out), views=args.views, source=args.source,
                            crf=args.crf, bit_depth=args.bit_depth,
                            hci_size=args.hci_size,
                            hci_center=_centre_view(args.hci_centre_view),
                            overwrite=args.overwrite, hci_bit_depth=args.hci_bit_depth,
                            image_bit_depth=args.image_bit_depth, holdout=args.holdout, authors=args.authors,
                            points=args.points, depth=args.depth)
    root = Path(args.dataset)
    try:
        ds = Dataset.open(root)
        est = estimate_export(ds, options)
        w, h = est.image_size_px
        stream = sys.stdout if args.estimate else sys.stderr   # --estimate: the estimate is the output
        print(f"{len(est.views)} views ({est.source}), {w} x {h} px, about {est.bytes_estimate / 1e6:.1f} MB "
              f"-> {options.out}", file=stream)
        for warning in est.warnings:
            print(f"note: {warning}", file=stream)
        if args.estimate:
            return 0
        report = export_dataset(ds, options, progress=TerminalProgress("export"))
    except InputError as exc:
        if exc.field in _OPTION:
            raise InputError(_OPTION[exc.field], str(exc).split(": ", 1)[1] if ": " in str(exc) else str(exc)) \
                from None
        raise
    print(report.summary())
    return 0
