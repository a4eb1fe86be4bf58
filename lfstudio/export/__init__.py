"""Export a dataset as files other tools read, and import an exported HEVC stream back.

Formats (``FORMATS``):

- ``png``: a folder with one 16-bit RGB PNG per view (``rRR_cCCC.png``) and ``manifest.json``
  (grid, spacing, commanded/reported positions, calibration, intrinsics), views row-major.
- ``hevc``: one x265 stream (12-bit 4:4:4, CRF 8 by default) with the views in meander order
  (first row left→right, next right→left, …) and a sidecar ``FILE.json`` mapping frame → view;
  :func:`import_hevc` restores the views as 16-bit PNGs in a new dataset.
- ``hci``: the HCI 4D light-field benchmark layout of a sub-array (``parameters.cfg``,
  ``input_Cam000.png`` … row-major).
- ``colmap``: a COLMAP text model (``sparse/0/cameras.txt``, ``images.txt``, ``points3D.txt``)
  with the rig's known poses (reported positions, calibrated rotation) beside ``images/``.
- ``nerfstudio``: ``transforms.json`` (nerfstudio / instant-ngp) with the same poses, a hold-out
  split, beside ``images/``.

Every export is a long job (``progress(done, total, message)``, ``cancel``: a
:class:`lfstudio.jobs.CancelToken`). It writes into a temporary sibling ``.NAME.partial-XXXX`` and
renames it at the end, so nothing ever appears half-written under the final name; an existing
output is refused unless ``overwrite``. Qt-free.

Paths are taken as given: the front ends read what the operator typed (``~``, ``$VARIABLES``) with
:func:`lfstudio.dataset.paths.expand_path` (the CLI's ``path_option``, the GUI's path fields), so
every path reaches the library already expanded, like every other stage's.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from lfstudio.dataset import Dataset, images
from lfstudio.errors import InputError
from lfstudio.export import common
from lfstudio.jobs import CancelToken, Progress, no_progress

log = logging.getLogger(__name__)

FORMATS = ("png", "hevc", "hci", "colmap", "nerfstudio")
POSED_FORMATS = ("colmap", "nerfstudio")
HEVC_SUFFIXES = (".mp4", ".mkv", ".hevc", ".mov")


@dataclass
class ExportOptions:
    format: str                      # one of FORMATS
    out: Path                        # png/hci: a folder to create; hevc: the .mp4/.mkv/.hevc file to create
    views: str | Sequence[tuple[int, int]] | None = None   # None = all available; str: "all", "r0-8,c10-18",
                                     # "array:3x2", "r00_c000,r00_c050" (see Dataset.select)
    source: str = "auto"             # "raw" | "processed" | "auto" (processed when every chosen view has it)
    crf: int = 8                     # hevc
    bit_depth: int = 12              # hevc: 10 or 12
    hci_size: tuple[int, int] = (9, 9)        # hci sub-array (columns, rows)
    hci_center: tuple[int, int] | None = None # hci (row, column) of the centre view; None = grid centre
    overwrite: bool = False          # False: an existing `out` raises InputError("out", ...)
    hci_bit_depth: int = 8           # hci: 8 (sRGB, like the benchmark) or 16 (linear)
    image_bit_depth: int = 8         # colmap/nerfstudio images: 8 (sRGB, what their tools expect) or 16 (linear)
    holdout: str = "none"            # nerfstudio: "none", "centre" or "every-K" (held out of training)
    authors: str = ""                # hci: [meta] authors (default: the manifest's "authors", else empty)
    points: bool = True              # colmap/nerfstudio: the sparse point cloud (points3D.txt, PLY)
    depth: bool = False              # nerfstudio: depth maps (depth_file_path); hci: estimated disparity maps


@dataclass
class ExportEstimate:
    views: list[tuple[int, int]]     # in export order (meander for hevc, row-major for hci/png)
    source: str                      # resolved "raw" | "processed"
    image_size_px: tuple[int, int]   # (width, height) of the exported frames
    bytes_estimate: int              # predicted size of the output
    warnings: list[str] = field(default_factory=list)


@dataclass
class ExportReport:
    out: Path
    views: int
    bytes_written: int
    seconds: float
    format: str = ""
    source: str = ""
    compression_ratio_vs_png: float | None = None   # hevc: 16-bit PNG bytes / HEVC bytes
    psnr_db: float | None = None                    # hevc: decoded frames vs the source, 16-bit scale
    files: list[Path] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    details: dict = field(default_factory=dict)     # hevc: encode_s, verify_s, video_bytes, png_bytes, frames

    def summary(self) -> str:
        text = (f"exported {self.views} view{'' if self.views == 1 else 's'} ({self.source}) as {self.format} to {self.out}: "
                f"{_fmt_bytes(self.bytes_written)} in {self.seconds:.1f} s")
        ratio = self.compression_ratio_vs_png
        if ratio is not None:
            text += f"; {ratio:.1f}x smaller than 16-bit PNG" if ratio >= 1 else \
                f"; {1 / ratio:.1f}x larger than 16-bit PNG (tiny frames)"
        if self.psnr_db is not None:
            text += f"; PSNR {self.psnr_db:.1f} dB (16-bit scale)"
        cloud = self.details.get("point_cloud")
        if isinstance(cloud, dict):
            text += "\n" + describe_points(cloud)
        return text


def describe_points(cloud: dict) -> str:
    """One line on an export's sparse point cloud: how many points, from how many tracks, and why
    the others were dropped (each track counted under the first test it failed)."""
    dropped = {k: int(v) for k, v in (cloud.get("dropped") or {}).items() if v}
    text = f"sparse points: {cloud.get('points', 0)}"
    if cloud.get("tracks") is not None:
        text += f" from {cloud['tracks']} feature tracks"
    if dropped:
        text += "; dropped: " + ", ".join(f"{n} {reason}" for reason, n in sorted(dropped.items(), key=lambda kv: -kv[1]))
    return text


def _fmt_bytes(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} GB"


def _check_options(options: ExportOptions) -> ExportOptions:
    fmt = str(options.format).lower()
    if fmt not in FORMATS:
        raise InputError("format", f"unknown format {options.format!r}", ", ".join(FORMATS))
    if options.out is None or str(options.out).strip() == "":
        raise InputError("out", "no output path given",
                         "a folder (png, hci, colmap, nerfstudio) or a .mp4/.mkv/.hevc file (hevc)")
    out = Path(options.out)
    if fmt == "hevc":
        if out.suffix.lower() not in HEVC_SUFFIXES:
            raise InputError("out", f"{out.name}: an HEVC export is a video file", ", ".join(HEVC_SUFFIXES))
        if options.bit_depth not in (10, 12):
            raise InputError("bit_depth", f"{options.bit_depth} is not supported", "10 or 12")
        if not 0 <= int(options.crf) <= 51:
            raise InputError("crf", f"{options.crf} is out of range", "0..51 (lower is better; 8 default)")
    if fmt == "hci":
        cols, rows = options.hci_size
        if int(cols) < 1 or int(rows) < 1:
            raise InputError("hci_size", f"{cols}x{rows} must be at least 1x1", "e.g. 9x9")
        if int(options.hci_bit_depth) not in (8, 16):
            raise InputError("hci_bit_depth", f"{options.hci_bit_depth} is not supported",
                             "8 (sRGB, like the benchmark) or 16 (linear)")
    if fmt in POSED_FORMATS and int(options.image_bit_depth) not in (8, 16):
        raise InputError("image_bit_depth", f"{options.image_bit_depth} is not supported",
                         "8 (sRGB, what view-synthesis tools expect) or 16 (linear)")
    if options.depth and fmt not in ("nerfstudio", "hci"):
        raise InputError("depth", f"the {fmt} export carries no depth maps", "nerfstudio (depth_file_path) or hci "
                         "(estimated disparity maps)")
    if fmt == "nerfstudio":
        from lfstudio.export import nerfstudio

        nerfstudio.parse_holdout(options.holdout)
    return dataclasses.replace(options, format=fmt, out=out)   # the caller's options stay as they were


def _plan(ds: Dataset, options: ExportOptions) -> tuple[list[common.View], str, tuple[int, int]]:
    """(views in export order, resolved source, view size (w, h))."""
    common.refuse_out_over_inputs(options.out, common.dataset_entries(ds), "the dataset being exported",
                                  "a path outside the dataset, e.g. next to it")
    if options.format == "hci":
        from lfstudio.export import hci

        views = hci.sub_array(ds, options)
    else:
        views = ds.select(options.views)
    if options.format in ("hci", *POSED_FORMATS):
        common.require_zero_plane(ds, {"hci": "an HCI export (focus_distance_m, disp_min/disp_max)"}.get(
            options.format, f"a {options.format} export (each view's principal point)"))
    if (options.source or "").lower() == "hdr" and options.format not in POSED_FORMATS:
        exc = InputError("source", f"hdr (the merged float radiance) is not exported as {options.format}",
                         f"--format {' or '.join(POSED_FORMATS)} with --source hdr; --source tonemap for "
                         f"{options.format}")
        shown = {"hevc": "HEVC", "hci": "HCI", "png": "PNG"}.get(options.format, options.format)
        exc.window_text = (f"Source: HDR radiance (float) is exported as a COLMAP model or for nerfstudio only; "
                           f"for {shown} choose Source: HDR tone map.")
        raise exc
    source = common.resolve_source(ds, views, options.source)
    if source == "hdr":        # float files the image readers do not open: the merge's recorded size
        recorded = (ds.manifest.get("hdr") or {}).get("output_size_px") or (0, 0)
        size = (int(recorded[0]), int(recorded[1])) if len(recorded) == 2 else (0, 0)
        if min(size) <= 0:
            raise InputError("source", f"{ds.manifest_path} records no size of the merged HDR views",
                             "process the dataset again ('lfstudio process --force')")
    else:
        size = images.full_size_px(common.source_path(ds, views[0], source))
    if options.format == "hevc":
        views = common.meander(views)
    return views, source, size


def _posed_warnings(ds: Dataset, views, source: str, size, options: ExportOptions) -> list[str]:
    """What a COLMAP / nerfstudio export should say about its poses (and checks they can be made)."""
    from lfstudio.export import poses

    cam = poses.camera_for(ds, size, common.is_rectified(ds, source))
    out = list(cam.warnings) + poses.position_warnings(ds, views)
    if options.format == "nerfstudio":
        from lfstudio.export import nerfstudio

        n = len(nerfstudio.held_out(views, options.holdout))
        if n:
            out.append(f"{n} view{'' if n == 1 else 's'} held out of training (val/test_filenames)")
    return out


def estimate_export(dataset, options: ExportOptions) -> ExportEstimate:
    """What an export would write (views, order, source, frame size, bytes) without writing; fast."""
    ds = Dataset.of(dataset)
    options = _check_options(options)
    views, source, size = _plan(ds, options)
    warnings: list[str] = []
    if source == "raw":
        warnings.append("raw views are exported without processing (linear 16-bit decode, no lens/colour/"
                        "rectification); process the dataset first for finished views")
    out = options.out
    frame_size = size
    if options.format == "png":
        from lfstudio.export import png

        nbytes = png.estimate_png_bytes(ds, views, source, size)
    elif options.format == "hevc":
        from lfstudio.export import hevc

        frame_size, pad = hevc.even_size(size)
        if pad != (0, 0):
            warnings.append(f"x265 needs even frame sizes of at least {hevc.MIN_FRAME_PX} px: {size[0]} x {size[1]} px "
                            f"views are padded to {frame_size[0]} x {frame_size[1]} px (edge pixels repeated; "
                            "import removes them)")
        nbytes = hevc.estimate_bytes(len(views), frame_size, options.crf, options.bit_depth)
    elif options.format == "hci":
        from lfstudio.export import hci

        nbytes = hci.estimate_bytes(len(views), size, options.hci_bit_depth)
        warnings += hci.warnings(ds, views, size, source)
    else:
        nbytes = (sum(common.source_path(ds, v, source).stat().st_size for v in views) if source == "hdr" else
                  common.images_bytes_estimate(len(views), size, options.image_bit_depth)) + 200 * len(views) + 8192
        warnings += _posed_warnings(ds, views, source, size, options)
        if options.format in POSED_FORMATS and options.points:
            nbytes += 60_000 + 30 * min(len(views), 45) * 200      # the sparse cloud: a few thousand points
    if options.depth and options.format in ("nerfstudio", "hci"):
        from lfstudio.export import depthmaps

        per_px = depthmaps.NERFSTUDIO_BYTES_PER_PX if options.format == "nerfstudio" else depthmaps.HCI_BYTES_PER_PX
        nbytes += int(len(views) * size[0] * size[1] * per_px)
        missing = depthmaps.missing_maps(ds, views)
        if missing:
            warnings.append(f"{len(missing)} of {len(views)} views have no depth map yet: the export computes them "
                            "first in this process (for many views run 'lfstudio depth DATASET --cluster ...' before)")
    if (out.exists() or out.is_symlink()) and not options.overwrite:
        warnings.append(f"{out} already exists and will only be replaced if you allow overwriting")
    return ExportEstimate(views=list(views), source=source, image_size_px=(frame_size[0], frame_size[1]),
                          bytes_estimate=int(nbytes), warnings=warnings)


def export_dataset(dataset, options: ExportOptions, *, progress: Progress | None = None,
                   cancel: CancelToken | None = None) -> ExportReport:
    """Export ``dataset`` as ``options`` say; see the module docstring. Raises
    :class:`lfstudio.jobs.Cancelled` (nothing left behind), InputError, DatasetError."""
    t0 = time.monotonic()
    progress = progress or no_progress
    cancel = cancel or CancelToken()
    ds = Dataset.of(dataset)
    options = _check_options(options)
    out = options.out
    views, source, size = _plan(ds, options)
    report = ExportReport(out=out, views=len(views), bytes_written=0, seconds=0.0, format=options.format,
                          source=source)
    log.info("export of %s started: %d views (%s) as %s to %s", ds.root, len(views), source, options.format, out)
    if options.format == "png":
        from lfstudio.export import png

        common.check_out(out, options.overwrite)
        progress(0, len(views), "exporting 16-bit PNG")
        report.files = png.export_png(ds, views, source, size, out, options.overwrite, progress, cancel)
    elif options.format == "hevc":
        from lfstudio.export import hevc

        sidecar = hevc.sidecar_path(out)
        common.check_out(out, options.overwrite, also=[sidecar])
        result = hevc.export_hevc(ds, views, source, size, out, options, progress, cancel)
        report.files = [out, sidecar]
        report.compression_ratio_vs_png = result["compression_ratio_vs_png"]
        report.psnr_db = result["psnr_db"]
        report.details = result
    elif options.format == "hci":
        from lfstudio.export import hci

        common.check_out(out, options.overwrite)
        report.files, notes = hci.export_hci(ds, views, source, size, out, options, progress, cancel)
        report.warnings += notes
    elif options.format == "colmap":
        from lfstudio.export import colmap

        common.check_out(out, options.overwrite)
        report.warnings += _posed_warnings(ds, views, source, size, options)
        report.files = colmap.export_colmap(ds, views, source, size, out, options, progress, cancel)
    else:
        from lfstudio.export import nerfstudio

        common.check_out(out, options.overwrite)
        report.warnings += _posed_warnings(ds, views, source, size, options)
        report.files = nerfstudio.export_nerfstudio(ds, views, source, size, out, options, progress, cancel)
    report.bytes_written = sum(common.folder_bytes(p) for p in report.files if p.exists())
    report.seconds = time.monotonic() - t0
    if options.format == "colmap":
        import json

        from lfstudio.export.colmap import MANIFEST_NAME
        try:
            cloud = json.loads((out / MANIFEST_NAME).read_text(encoding="utf-8")).get("point_cloud")
        except (OSError, ValueError):
            cloud = None
        if isinstance(cloud, dict):
            report.details["point_cloud"] = cloud
    log.info("export to %s finished: %d files, %d bytes in %.1f s", out, len(report.files), report.bytes_written,
             report.seconds)
    return report


def import_hevc(file, out, *, progress: Progress | None = None, cancel: CancelToken | None = None,
                overwrite: bool = False) -> Path:
    """Restore the views of an HEVC export (``file`` + ``file.json``) as 16-bit PNGs in a new
    dataset at ``out``; returns the dataset root."""
    from lfstudio.export import hevc

    return hevc.import_hevc(Path(file), Path(out), progress=progress or no_progress,
                            cancel=cancel or CancelToken(), overwrite=overwrite)


__all__ = ["FORMATS", "POSED_FORMATS", "ExportOptions", "ExportEstimate", "ExportReport", "estimate_export", "export_dataset",
           "import_hevc"]
