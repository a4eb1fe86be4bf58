"""``lfstudio import-images``: build a dataset from another rig's folder of images."""

from __future__ import annotations

import argparse
import shlex
import sys
from lfstudio.errors import for_cli
from lfstudio.numbers import SPACING_MM, Number, parse_grid
from lfstudio.cli.args import number_option, numbers_option, path_option

HELP = "import another rig's images (PNG, TIFF, JPEG, camera RAW) as a dataset that calibrates, processes and exports"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", metavar="FOLDER", type=path_option("FOLDER"), help="folder holding the other rig's images, one per view")
    p.add_argument("--grid", metavar="CxR", help="columns x rows of the capture grid, e.g. 9x5 (an HCI benchmark "
                                                "folder's parameters.cfg gives it)")
    p.add_argument("--spacing-mm", type=numbers_option("--spacing-mm", SPACING_MM, 2, "4x6"), metavar="HxV",
                   help="distance between neighbouring views in mm, horizontal x vertical, e.g. 4x6 (needed unless "
                        "--positions records them)")
    p.add_argument("--positions", metavar="names|FILE.csv",
                   help="the rig's recorded position of every view: 'names' reads them from the file names "
                        "(the Stanford archive's out_RR_CC_<a>_<b>), or a CSV with the columns file,x_mm,y_mm; "
                        "check then measures each view against them")
    zero = p.add_argument_group("zero-disparity plane (default: measured from the views' disparities)")
    zero.add_argument("--zero-disparity-depth-m", type=number_option(Number("m", 0, 1e6, low_open=True), "--zero-disparity-depth-m"),
                      metavar="Z", help="the views are sheared so that the plane at Z m has zero disparity (as "
                                        "archive light fields are published); needs the focal length")
    zero.add_argument("--parallel-views", action="store_true",
                      help="the views are parallel (not sheared): zero disparity at infinity, as lfstudio scans")
    p.add_argument("--order", choices=("row-major", "meander"), default="row-major",
                   help="how the sorted files fill the grid: row-major (every row left to right, default) or "
                        "meander (odd rows right to left)")
    p.add_argument("--pattern", metavar="GLOB",
                   help="which files to take, e.g. '*.png' (default: every PNG/TIFF/JPEG/RAW file); files are "
                        "sorted naturally (img2 before img10)")
    p.add_argument("--focal-length-mm", type=number_option(Number("mm", 0, 10_000, low_open=True), "--focal-length-mm"), metavar="F",
                   help="lens focal length in mm (with --pixel-pitch-um)")
    p.add_argument("--pixel-pitch-um", type=number_option(Number("µm", 0, 1000, low_open=True), "--pixel-pitch-um"), metavar="P",
                   help="sensor pixel size in µm")
    p.add_argument("--focal-length-px", type=number_option(Number("px", 0, 1e6, low_open=True), "--focal-length-px"), metavar="F",
                   help="focal length in pixels of these images (instead of --focal-length-mm/--pixel-pitch-um)")
    p.add_argument("--out", required=True, metavar="DATASET", type=path_option("--out"), help="the new dataset folder (missing or empty)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace DATASET if it holds a dataset (a folder of other files is never replaced)")
    p.add_argument("--copy", action="store_true",
                   help="always copy the files (default: hard-link them when on the same file system)")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from lfstudio.dataset import Dataset
    from lfstudio.export.import_images import ImportOptions, import_images
    from lfstudio.jobs import TerminalProgress
    from lfstudio.export.import_images import import_summary
    from lfstudio.quality.shear import measure_shear

    # read after the other options: a grid's size is checked before anything is allocated per view
    grid = parse_grid("--grid", args.grid, "9x5") if args.grid is not None else None
    options = ImportOptions(folder=Path(args.folder), out=Path(args.out), grid=grid,
                            spacing_mm=args.spacing_mm,
                            order=args.order, pattern=args.pattern, focal_length_mm=args.focal_length_mm,
                            pixel_pitch_um=args.pixel_pitch_um, focal_length_px=args.focal_length_px,
                            overwrite=args.overwrite, link=not args.copy,
                            zero_disparity_depth_m=args.zero_disparity_depth_m, parallel_views=args.parallel_views,
                            positions=args.positions, measure=measure_shear)
    root = import_images(options, progress=TerminalProgress("importing"))
    ds = Dataset.open(root)
    record = ds.manifest.get("import", {})
    w, h = ds.camera["sensor_px"]
    print(f"{root}: {len(ds.views)} views ({ds.grid.columns}x{ds.grid.rows}, {args.order}), {w}x{h} px, "
          f"{record.get('linked', 0)} hard-linked, {len(ds.views) - record.get('linked', 0)} copied; "
          + ("focal length not known" if record.get("intrinsics", "none") == "none"
             else f"focal length from {record['intrinsics']}"))
    print(for_cli(import_summary(ds)))
    for warning in record.get("warnings", []):
        print(f"warning: {warning}", file=sys.stderr)
    if record.get("intrinsics", "none") == "none":      # calibrate needs it: the hint that works
        print(f"next: lfstudio calibrate {shlex.quote(str(root))} --focal-length-px F   (F = focal length in mm ÷ pixel pitch "
              "in mm, e.g. 50 ÷ 0.0045 = 11111)")
    else:
        print(f"next: lfstudio calibrate {shlex.quote(str(root))}")
    return 0

