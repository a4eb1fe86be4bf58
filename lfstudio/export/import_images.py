"""Import another rig's images (PNG, TIFF, JPEG, camera RAW) as an lfstudio dataset.

A folder of images, one per view, becomes a dataset folder (``docs/dataset-format.md``) that
calibrates, processes and exports like one captured here:

- the images are listed (``pattern`` glob or every supported image), **sorted naturally**
  (``img2`` before ``img10``) and assigned to the grid in ``order``: ``row-major`` (every row left
  to right) or ``meander`` (odd rows right to left, as a gantry scans);
- every file's size is read from its header (one size for all, else an error naming the file);
- the intrinsics come from ``focal_length_mm`` + ``pixel_pitch_um``, from ``focal_length_px``, or
  from the first image's EXIF; without any, the import still works and says calibration will need a
  focal length;
- the files are hard-linked (same file system) or copied into ``raw/`` under the dataset's names
  (``raw/r00_c000.png``), their sha256 recorded, every view ``done``, commanded positions from the
  grid spacing; each gets its grid thumbnail (``thumbs/r00_c000.jpg``) while it is being read, on
  every core, so the imported dataset opens with all its thumbnails;
- ``out`` follows the rule of every new dataset (:func:`lfstudio.dataset.paths.check_new_dataset_folder`):
  missing or empty; an existing dataset only with ``overwrite`` (it is replaced); a folder holding
  other files never (a new sub-folder is suggested), so no file of the operator's is deleted;
- the dataset is built in a temporary sibling folder ``.NAME.partial-XXXX`` and renamed at the end:
  a cancel or an error leaves nothing under ``out`` (and removes the temporary folder).
"""

from __future__ import annotations

import dataclasses
import fnmatch
import hashlib
import io
import json
import logging
import math
import os
import re
import shutil
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from lfstudio.dataset import images
from lfstudio.dataset.grid import grid_order
from lfstudio.dataset.manifest import ViewRecord, now_iso
from lfstudio.dataset.paths import RENAME_UTF8_FIX, is_utf8_name, shown_name, view_stem
from lfstudio.dataset.store import sha256_file
from lfstudio.dataset.thumbs import make_thumbnail
from lfstudio.errors import DatasetError, InputError, words
from lfstudio.jobs import CancelToken, Progress, no_progress
from lfstudio.numbers import WIDTH_PX, Number, check_grid

log = logging.getLogger(__name__)

ORDERS = ("row-major", "meander")
#: the manifest's ``grid.order`` for each import order (see docs/dataset-format.md)
GRID_ORDER = {"row-major": "raster", "meander": "row-meander"}
SUPPORTED_TEXT = "PNG, TIFF, JPEG or camera RAW (any format LibRaw reads)"


@dataclass
class ImportOptions:
    folder: Path
    out: Path
    grid: tuple[int, int] | None            # (columns, rows); None: from an HCI folder's parameters.cfg
    spacing_mm: tuple[float, float] | None  # (horizontal, vertical); None: from --positions or parameters.cfg
    order: str = "row-major"                # "row-major" | "meander"
    pattern: str | None = None              # glob; None = every supported image in the folder
    focal_length_mm: float | None = None
    pixel_pitch_um: float | None = None
    focal_length_px: float | None = None
    overwrite: bool = False
    link: bool = True                       # hard-link when on the same file system (else copy)
    zero_disparity_depth_m: float | None = None   # the views are sheared: zero disparity at this depth
    parallel_views: bool = False            # the views are parallel: zero disparity at infinity
    positions: str | None = None            # recorded positions: "names" or a CSV file (file,x_mm,y_mm)
    #: measures the views' disparities before anything is written (:func:`lfstudio.quality.shear.measure_shear`,
    #: passed in by the caller: the quality layer sits above this one); None: not measured
    measure: Callable[..., Any] | None = None


@dataclass
class ImportPlan:
    """What an import will do, found before anything is written (:func:`plan_import`)."""

    files: list[Path]                       # in natural order
    cells: list[tuple[int, int]]            # (row, column) of each file
    image_size_px: tuple[int, int]          # (width, height) shared by every file
    camera: dict[str, Any]
    lens: dict[str, Any]
    intrinsics: str                         # where the focal length comes from (or "none")
    warnings: list[str] = field(default_factory=list)
    bytes_total: int = 0
    positions_mm: dict[tuple[int, int], tuple[float, float]] | None = None   # recorded, per cell
    positions_record: dict[str, Any] | None = None
    spacing_mm: tuple[float, float] = (0.0, 0.0)
    raw_positions: list[tuple[float, float]] | None = None
    zero_plane: dict[str, Any] | None = None
    hci: "HciFolder | None" = None


# -- listing ------------------------------------------------------------------------------------------
def natural_key(name: str) -> list:
    """Sort key that orders digit runs by value: ``img2`` < ``img10``; case-insensitive otherwise."""
    return [int(t) if i % 2 else t.lower() for i, t in enumerate(re.split(r"(\d+)", name))]


def find_images(folder: str | os.PathLike, pattern: str | None = None) -> list[Path]:
    """Image files of ``folder`` (``pattern``: a glob relative to it; without a ``/`` it matches
    names case-insensitively, so ``*.jpg`` takes ``IMG_0001.JPG``) in natural order.

    Hidden files are skipped. What a file is, is found by reading it (:mod:`lfstudio.dataset.images`),
    not from its name: without a pattern, text files (notes, XMP sidecars) are ignored and every
    other file is taken (one that is neither an image nor a RAW LibRaw reads is refused by name when
    the import reads it); with a pattern, a matched text file is an error (the pattern should say
    what to take).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("folder", f"{folder} is not a folder", "a folder holding the other rig's images")
    if pattern:
        try:
            if "/" in pattern or os.sep in pattern:
                candidates = list(folder.glob(pattern))
            else:   # case-insensitive, as cameras write IMG_0001.JPG and operators type '*.jpg'
                candidates = [p for p in folder.iterdir() if fnmatch.fnmatchcase(p.name.lower(), pattern.lower())]
            matched = [p for p in candidates if p.is_file() and not p.name.startswith(".")]
        except (ValueError, NotImplementedError) as exc:
            raise InputError("--pattern", f"{pattern!r} is not a usable glob ({exc})", "e.g. '*.png' or 'cam_*.tif'")
        bad = [p for p in matched if images.is_text(p)]
        if bad:
            raise InputError("--pattern", f"{pattern!r} also matches {bad[0].name}, which is not a {SUPPORTED_TEXT} "
                             "image; narrow the pattern", "e.g. '*.png'")
        files = matched
    else:
        files = [p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".") and not images.is_text(p)]
    for p in files:     # the libraries cannot open such a name (OpenCV crashes on it): refused before any is read
        if not is_utf8_name(p.relative_to(folder)):       # a sub-folder's name too (a pattern with a '/')
            raise InputError("folder", f"{shown_name(p.relative_to(folder))} in {shown_name(folder)} has a name that is not valid "
                             f"UTF-8; {RENAME_UTF8_FIX}, or leave it out with " + words("--pattern", "the Files (pattern) field"))
    return sorted(files, key=lambda p: natural_key(p.relative_to(folder).as_posix()))


def grid_cells(columns: int, rows: int, order: str = "row-major") -> list[tuple[int, int]]:
    """(row, column) of the i-th image: ``row-major`` or ``meander`` (odd rows right to left)."""
    if order not in ORDERS:
        raise InputError("--order", f"unknown order {order!r}", " | ".join(ORDERS))
    return grid_order(columns, rows, GRID_ORDER[order])


def describe_selection(folder: Path, pattern: str | None) -> str:
    return f"in {folder} matching {pattern!r}" if pattern else f"in {folder} (every PNG, TIFF, JPEG and RAW file)"


def count_message(files: Sequence[Path], grid: tuple[int, int], folder: Path, pattern: str | None) -> str | None:
    """None when the number of files fills the grid; else the operator's explanation and fix."""
    cols, rows = grid
    need = cols * rows
    if len(files) == need:
        return None
    what = f"found {len(files)} image{'s' if len(files) != 1 else ''} {describe_selection(folder, pattern)}, " \
           f"but a {cols}x{rows} grid needs {need}"
    by_suffix: dict[str, int] = {}
    for p in files:
        by_suffix[p.suffix.lower()] = by_suffix.get(p.suffix.lower(), 0) + 1
    if len(by_suffix) > 1:
        kinds = ", ".join(f"{n} {s}" for s, n in sorted(by_suffix.items()))
        match = [s for s, n in by_suffix.items() if n == need]
        hint = f"; choose one kind with --pattern '*{match[0]}'" if match else "; choose one kind with --pattern"
        return f"{what} (the folder mixes {kinds}){hint}"
    return f"{what}; check --grid (columns x rows) or select the files with --pattern"


# -- recorded positions ---------------------------------------------------------------------------
POSITIONS_FROM_NAMES = "names"
#: Stanford light field archive: out_RR_CC_<a>_<b>_.png (row, column, the gantry's recorded position)
STANFORD_NAME = re.compile(r"^out_(\d+)_(\d+)_(-?\d+(?:\.\d*)?(?:[eE]-?\d+)?)_(-?\d+(?:\.\d*)?(?:[eE]-?\d+)?)_?$")
POSITIONS_FIX = "give the positions in a CSV file instead (--positions FILE.csv with the columns file,x_mm,y_mm)"
#: a recorded position (mm): finite and within 100 m of the origin (1e308 overflowed the grid fit)
RECORDED_MM = Number("mm", -100_000, 100_000)
#: the least step between recorded positions along the grid (mm; the least spacing lfstudio takes)
MIN_STEP_MM = 0.001
#: the smallest view an import takes (px, either side: lfstudio's smallest working width)
MIN_VIEW_PX = 16


def positions_from_names(files: Sequence[Path], grid: tuple[int, int]) -> tuple[list[tuple[int, int]], list[tuple[float, float]]]:
    """Cells and recorded positions from Stanford's ``out_RR_CC_<a>_<b>`` names (rows and columns
    counted from the smallest); raises :class:`InputError` naming the first file that does not fit."""
    parsed = []
    for p in files:
        m = STANFORD_NAME.match(p.stem)
        if not m:
            raise InputError("--positions", f"{p.name} does not follow the name pattern out_RR_CC_<a>_<b> "
                             f"(row, column, recorded position); {POSITIONS_FIX}")
        parsed.append((int(m[1]), int(m[2]), float(m[3]), float(m[4])))
        problem = RECORDED_MM.problem(parsed[-1][2]) or RECORDED_MM.problem(parsed[-1][3])
        if problem:
            raise InputError("--positions", f"{p.name}: the recorded position {problem}; {POSITIONS_FIX}",
                             RECORDED_MM.valid())
    r0 = min(t[0] for t in parsed)
    c0 = min(t[1] for t in parsed)
    cols, rows = grid
    cells = [(t[0] - r0, t[1] - c0) for t in parsed]
    seen: dict[tuple[int, int], Path] = {}
    for p, cell in zip(files, cells):
        if not (0 <= cell[0] < rows and 0 <= cell[1] < cols):
            raise InputError("--positions", f"{p.name} is row {cell[0]}, column {cell[1]} counted from the smallest "
                             f"numbers in the names, outside the {cols}x{rows} grid; check --grid or select the "
                             "files with --pattern")
        if cell in seen:
            raise InputError("--positions", f"{p.name} and {seen[cell].name} name the same row and column; "
                             "leave one out with --pattern")
        seen[cell] = p
    return cells, [(t[2], t[3]) for t in parsed]


def positions_from_csv(files: Sequence[Path], folder: Path, csv_path: Path) -> list[tuple[float, float]]:
    """Recorded (x, y) mm of every file from a CSV with the columns file,x_mm,y_mm."""
    import csv

    try:
        with open(csv_path, newline="", encoding="utf-8-sig") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputError("--positions", f"{csv_path}: cannot be read ({exc}); save it as UTF-8 CSV with the "
                         "columns file,x_mm,y_mm") from None
    if not rows or not {"file", "x_mm", "y_mm"} <= set(rows[0]):
        raise InputError("--positions", f"{csv_path}: needs the header columns file,x_mm,y_mm (one row per image)")
    table: dict[str, tuple[float, float]] = {}
    lines: dict[str, int] = {}
    for i, row in enumerate(rows, start=2):
        try:
            x, y = float(row["x_mm"]), float(row["y_mm"])
        except (TypeError, ValueError):
            raise InputError("--positions", f"{csv_path} line {i}: x_mm/y_mm {row.get('x_mm')!r}, {row.get('y_mm')!r} "
                             "are not numbers; write the position in mm") from None
        problem = RECORDED_MM.problem(x) or RECORDED_MM.problem(y)
        if problem:
            raise InputError("--positions", f"{csv_path} line {i}: the position {problem}", RECORDED_MM.valid())
        name = str(row["file"]).strip()
        if name in table and table[name] != (x, y):     # the last row must not silently win
            raise InputError("--positions", f"{csv_path} lines {lines[name]} and {i} give {name} two positions "
                             f"({table[name][0]:g}, {table[name][1]:g}) and ({x:g}, {y:g}) mm; keep one row per image")
        table[name] = (x, y)
        lines.setdefault(name, i)
    out = []
    for p in files:
        rel = p.relative_to(folder).as_posix()
        hit = table.get(rel, table.get(p.name))
        if hit is None:
            raise InputError("--positions", f"{csv_path} has no row for {rel}; add one (file,x_mm,y_mm) for every "
                             "image imported")
        out.append(hit)
    return out


def normalise_positions(cells: Sequence[tuple[int, int]], raw: Sequence[tuple[float, float]]
                        ) -> tuple[dict[tuple[int, int], tuple[float, float]], tuple[float, float], dict[str, Any]]:
    """The recorded positions in the dataset's frame: x along the columns, y along the rows (the
    recorded coordinate that follows each, its sign turned so that it grows with the index), from the
    least-squares grid's (0, 0) cell; also the mean spacing and how the axes were mapped."""
    rc = np.array(cells, float).reshape(-1, 2)
    uv = np.array(raw, float).reshape(-1, 2)

    def slope(values: np.ndarray, index: np.ndarray) -> tuple[float, float]:
        """Least-squares fit values ≈ intercept + slope·index (slope 0 when the index is constant)."""
        if np.ptp(index) == 0:
            return float(np.mean(values)), 0.0
        k, b = np.polyfit(index, values, 1)
        return float(b), float(k)

    def score(a: int) -> float:     # how well coordinate a follows the columns and the other the rows
        return abs(slope(uv[:, a], rc[:, 1])[1]) + abs(slope(uv[:, 1 - a], rc[:, 0])[1])

    ax = 0 if score(0) >= score(1) else 1
    b_x, k_x = slope(uv[:, ax], rc[:, 1])
    b_y, k_y = slope(uv[:, 1 - ax], rc[:, 0])
    sx, sy = (1.0 if k_x >= 0 else -1.0), (1.0 if k_y >= 0 else -1.0)
    # the (0, 0) of the fitted grid: a plane fit of each coordinate over row and column
    A = np.column_stack([np.ones(len(rc)), rc[:, 1], rc[:, 0]])
    cx = np.linalg.lstsq(A, uv[:, ax], rcond=None)[0][0]
    cy = np.linalg.lstsq(A, uv[:, 1 - ax], rcond=None)[0][0]
    pos = {(int(cell[0]), int(cell[1])): (float(sx * (uv[i, ax] - cx)), float(sy * (uv[i, 1 - ax] - cy)))
           for i, cell in enumerate(cells)}
    # the rig's own scatter about its best regular grid (an affine fit over row and column): the
    # repeatability it logged, which the check judges the positions by
    dev = [uv[:, ax] - A @ np.linalg.lstsq(A, uv[:, ax], rcond=None)[0],
           uv[:, 1 - ax] - A @ np.linalg.lstsq(A, uv[:, 1 - ax], rcond=None)[0]]
    dof = len(rc) / max(len(rc) - 3, 1)
    logged_um = [float(np.sqrt(np.mean(d * d) * dof)) * 1000.0 for d in dev]
    names = ("first", "second")
    mapping = {"x": f"{'+' if sx > 0 else '-'}{names[ax]} recorded coordinate",
               "y": f"{'+' if sy > 0 else '-'}{names[1 - ax]} recorded coordinate",
               "origin": [float(cx), float(cy)],
               "logged_repeatability_um": [round(v, 2) for v in logged_um]}
    return pos, (abs(k_x), abs(k_y)), mapping


# -- EXIF ---------------------------------------------------------------------------------------------
def _rational(value: Any) -> float | None:
    try:
        if isinstance(value, (tuple, list)):
            num, den = value[0], value[1]
            return float(num) / float(den) if den else None
        return float(value)
    except (TypeError, ValueError, IndexError):
        return None


def _exif_from_tiff(tif) -> dict[str, Any]:
    page = tif.pages[0]
    out: dict[str, Any] = {}
    for key in ("Make", "Model"):
        tag = page.tags.get(key)
        if tag is not None and isinstance(tag.value, str):
            out[key] = tag.value.strip("\x00 ")
    tag = page.tags.get("ExifTag")
    if tag is not None and isinstance(tag.value, dict):
        out.update(tag.value)
    return out


def read_exif(path: str | os.PathLike) -> dict[str, Any]:
    """The EXIF tags of a JPEG or a TIFF-based file (TIFF, DNG, ARW, NEF, ...); {} when there are none."""
    import tifffile

    path = Path(path)
    try:
        if images.is_jpeg(path):
            data = path.read_bytes()[:1 << 20]
            i = data.find(b"Exif\x00\x00")
            if i < 0:
                return {}
            quiet = logging.getLogger("tifffile")   # an EXIF block has no image data: tifffile warns
            level = quiet.level
            quiet.setLevel(logging.CRITICAL)
            try:
                with tifffile.TiffFile(io.BytesIO(data[i + 6:])) as tif:
                    return _exif_from_tiff(tif)
            finally:
                quiet.setLevel(level)
        if images.png_header(path) is not None:
            return {}
        with tifffile.TiffFile(path) as tif:
            return _exif_from_tiff(tif)
    except Exception:  # no EXIF, or a format tifffile cannot parse (CR3, RAF, ...): not an error
        return {}


def intrinsics_from_exif(exif: dict[str, Any], width_px: int) -> tuple[float | None, float | None, float | None]:
    """(focal_length_mm, pixel_pitch_um, focal_length_px) as far as EXIF tells them (None: unknown)."""
    f_mm = _rational(exif.get("FocalLength"))
    f_mm = f_mm if f_mm and f_mm > 0 else None
    pitch_um = None
    res = _rational(exif.get("FocalPlaneXResolution"))
    unit_mm = {2: 25.4, 3: 10.0, 4: 1.0}.get(int(exif.get("FocalPlaneResolutionUnit", 2) or 2))
    if res and res > 0 and unit_mm:
        pitch_um = unit_mm / res * 1000.0
        if not 2.0 <= width_px * pitch_um / 1000.0 <= 80.0:
            pitch_um = None   # stale after resizing (an implausible sensor width): not for these pixels
    f_px = None
    if f_mm and pitch_um:
        f_px = f_mm / (pitch_um / 1000.0)
    else:
        f35 = _rational(exif.get("FocalLengthIn35mmFilm"))
        if f35 and f35 > 0:
            f_px = f35 / 36.0 * width_px   # 35 mm equivalent: a 36 mm wide frame
    return f_mm, pitch_um, f_px


# -- options ------------------------------------------------------------------------------------------
def _positive(value: float | None, name: str) -> float | None:
    if value is None:
        return None
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(name, f"{value!r} is not a number", "a positive number") from None
    if not (math.isfinite(v) and v > 0):
        raise InputError(name, f"{value!r} must be a positive number", "> 0")
    return v


def _grid(options: ImportOptions) -> tuple[int, int]:
    """(columns, rows) of checked options (:func:`check_options` refuses a grid that is not given or
    read from an HCI folder's parameters.cfg)."""
    if options.grid is None:
        raise InputError("--grid", "is needed (columns x rows)", "e.g. 9x5")
    return int(options.grid[0]), int(options.grid[1])


def check_options(options: ImportOptions) -> None:
    """Raise :class:`InputError` for an option that cannot work (nothing is read or written)."""
    if options.grid is None:
        if read_hci_folder(options.folder) is None:
            raise InputError("--grid", f"is needed (columns x rows): {options.folder} is not an HCI folder "
                             f"(no {HCI_PARAMETERS})", "e.g. 9x5")
        options = apply_hci_folder(options)[0]
    try:
        cols, rows = (int(v) for v in options.grid or ())
    except (TypeError, ValueError):
        raise InputError("--grid", f"{options.grid!r} is not columns x rows", "e.g. 9x5") from None
    if cols < 1 or rows < 1:
        raise InputError("--grid", f"needs at least one column and one row, got {cols}x{rows}", "e.g. 9x5")
    if options.spacing_mm is None:
        if not options.positions:
            raise InputError("--spacing-mm", "is needed (the distance between neighbouring views) unless the "
                             "positions are recorded (--positions names or FILE.csv)", "e.g. 4x6")
    else:
        try:
            h, v = (float(x) for x in options.spacing_mm)
        except (TypeError, ValueError):
            raise InputError("--spacing-mm", f"{options.spacing_mm!r} is not HxV in mm", "e.g. 4x6") from None
        if not (math.isfinite(h) and math.isfinite(v) and h >= 0 and v >= 0) or (cols > 1 and h == 0) \
                or (rows > 1 and v == 0):
            raise InputError("--spacing-mm", f"{h:g}x{v:g} mm: the spacing between neighbouring views must be "
                             "positive", "e.g. 4x6")
    z0 = _positive(options.zero_disparity_depth_m, "--zero-disparity-depth-m")
    if z0 is not None and options.parallel_views:
        raise InputError("--parallel-views", "contradicts --zero-disparity-depth-m: parallel views have zero "
                         "disparity at infinity, sheared ones at the stated depth; give one of them")
    if options.positions and options.positions != POSITIONS_FROM_NAMES:
        csv_path = Path(options.positions)
        if not csv_path.is_file():
            raise InputError("--positions", f"{csv_path} is not a file", f"'{POSITIONS_FROM_NAMES}' or a CSV file "
                             "with the columns file,x_mm,y_mm")
    if options.order not in ORDERS:
        raise InputError("--order", f"unknown order {options.order!r}", " | ".join(ORDERS))
    f_mm = _positive(options.focal_length_mm, "--focal-length-mm")
    _positive(options.pixel_pitch_um, "--pixel-pitch-um")
    f_px = _positive(options.focal_length_px, "--focal-length-px")
    if f_mm is not None and f_px is not None:
        raise InputError("--focal-length-px", "give the focal length either in mm (with --pixel-pitch-um) "
                         "or in pixels, not both")
    if f_mm is not None and options.pixel_pitch_um is None:
        raise InputError("--pixel-pitch-um", "is needed with --focal-length-mm (the sensor's pixel size in µm), "
                         "or give --focal-length-px instead", "e.g. 4.5")
    out = Path(options.out)
    folder = Path(options.folder)
    if not folder.is_dir():
        raise InputError("folder", f"{folder} is not a folder", "a folder holding the other rig's images")
    try:
        folder.resolve().relative_to(out.resolve())
        contains = True
    except ValueError:
        contains = False
    if contains:
        raise InputError("--out", f"{out} holds the images being imported; choose another folder for the dataset")
    from lfstudio.export.common import check_new_dataset_out

    check_new_dataset_out(out, options.overwrite, field="--out")


def plan_import(options: ImportOptions, *, progress: Progress = no_progress,
                cancel: CancelToken | None = None) -> ImportPlan:
    """List and check the files (count, readable, one size) and resolve the intrinsics; writes nothing."""
    options, hci = apply_hci_folder(options)
    check_options(options)
    folder = Path(options.folder)
    cols, rows = _grid(options)
    files = find_images(folder, options.pattern)
    msg = count_message(files, (cols, rows), folder, options.pattern)
    if msg:
        raise InputError("--grid", msg)
    size: tuple[int, int] | None = None
    first: Path | None = None
    total_bytes = 0
    for i, path in enumerate(files):
        if cancel is not None:
            cancel.check()
        try:
            s = images.full_size_px(path)
            images.check_raw_data(path)          # a RAW cut short opens by its headers: unpack it
            total_bytes += path.stat().st_size
        except (OSError, ValueError, DatasetError) as exc:
            why = exc.reason if isinstance(exc, images.NotACapture) else "damaged or truncated"
            raise InputError("folder", f"{path.name}: cannot be read as an image ({why}); re-copy it or leave it "
                             "out with --pattern") from None
        if size is None or first is None:
            size, first = s, path
        elif s != size:
            raise InputError("folder", f"{path.name} is {s[0]}x{s[1]} px but {first.name} is {size[0]}x{size[1]} "
                             "px; every view must have one size (re-export the images at one size or leave the "
                             "odd one out with --pattern)")
        progress(i + 1, len(files), f"checked {path.name}")
    assert size is not None and first is not None
    if min(size) < MIN_VIEW_PX:        # 1-px views imported, then 'check' asked for exabytes
        raise InputError("folder", f"{first.name} is {size[0]}x{size[1]} px: too small to calibrate, check or "
                         "process a light field", f"views of at least {MIN_VIEW_PX}x{MIN_VIEW_PX} px")
    camera, lens, source, warnings = _intrinsics(options, first, size)
    cells = grid_cells(cols, rows, options.order)
    raw_positions: list[tuple[float, float]] | None = None
    positions_record: dict[str, Any] | None = None
    if options.positions == POSITIONS_FROM_NAMES:
        cells, raw_positions = positions_from_names(files, (cols, rows))
        positions_record = {"source": "file names (out_RR_CC_<a>_<b>: row, column, recorded position)"}
    elif options.positions:
        raw_positions = positions_from_csv(files, folder, Path(options.positions))
        positions_record = {"source": str(Path(options.positions).absolute())}
    if hci is not None:
        if tuple(size) != hci.image_size_px:
            raise InputError("folder", f"{hci.path} says {hci.image_size_px[0]}x{hci.image_size_px[1]} px but "
                             f"{first.name} is {size[0]}x{size[1]} px; the views and parameters.cfg do not belong "
                             "together")
        source = f"{hci.path.name} (focal_length_mm / sensor_size_mm · max(w, h))"
        lens["focal_length_mm"] = hci.focal_length_mm
    plan = ImportPlan(files=files, cells=cells, image_size_px=size, camera=camera, lens=lens, intrinsics=source,
                      warnings=warnings, bytes_total=total_bytes, positions_record=positions_record,
                      raw_positions=raw_positions, hci=hci)
    _place(plan, options, (cols, rows))
    if options.zero_disparity_depth_m is not None and plan_focal_px(plan) is None:
        raise InputError("--zero-disparity-depth-m", "needs the focal length in pixels to turn the depth into "
                         "the views' shear; give --focal-length-px (or --focal-length-mm with --pixel-pitch-um)")
    return plan


def plan_focal_px(plan: ImportPlan) -> float | None:
    """The focal length in pixels of the full-size images, when the plan knows it."""
    lens, cam = plan.lens, plan.camera
    if lens.get("focal_length_px"):
        return float(lens["focal_length_px"])
    if lens.get("focal_length_mm") and cam.get("pixel_pitch_um"):
        return float(lens["focal_length_mm"]) / (float(cam["pixel_pitch_um"]) / 1000.0)
    return None


def _place(plan: ImportPlan, options: ImportOptions, grid: tuple[int, int]) -> None:
    """The recorded positions in the dataset's frame for ``plan.cells`` and the spacing (given, or
    the recorded positions' mean step)."""
    cols, rows = grid
    raw = plan.raw_positions
    derived = (0.0, 0.0)
    if raw is not None:
        try:
            plan.positions_mm, derived, mapping = normalise_positions(plan.cells, raw)
        except InputError:
            raise
        except (np.linalg.LinAlgError, ValueError) as exc:    # positions no grid fits (they are bounded first)
            raise InputError("--positions", f"the recorded positions fit no grid of the views ({exc}); check the "
                             "file's x_mm/y_mm columns") from None
        plan.positions_record = {**(plan.positions_record or {}), **mapping}
        still = [what for what, n, step in (("columns", cols, derived[0]), ("rows", rows, derived[1]))
                 if n > 1 and not step >= MIN_STEP_MM]      # all equal: a spacing of 0, depth divides by it
        if still:
            raise InputError("--positions", f"the recorded positions do not change along the {' and '.join(still)} "
                             f"(less than {MIN_STEP_MM:g} mm per step); check the file's x_mm/y_mm columns",
                             "one position per view, different for each")
    if options.spacing_mm is not None:
        plan.spacing_mm = (float(options.spacing_mm[0]), float(options.spacing_mm[1]))
    else:
        if (cols > 1 and not derived[0] > 0) or (rows > 1 and not derived[1] > 0):
            raise InputError("--spacing-mm", "cannot be found from the recorded positions (they do not change "
                             "along the grid); give it", "e.g. 4x6")
        plan.spacing_mm = (round(derived[0], 6), round(derived[1], 6))
        if plan.positions_record is not None:
            plan.positions_record["spacing_from_positions"] = True


def _export_manifest_focal_px(folder: Path, size: tuple[int, int]) -> float | None:
    """The focal length (px) an lfstudio PNG export recorded for these images, or None (not such an
    export, another image size, or unknown)."""
    from lfstudio.export.common import EXPORT_FORMAT
    from lfstudio.export.png import MANIFEST_NAME

    try:
        doc = json.loads((folder / MANIFEST_NAME).read_text(encoding="utf-8"))
        intr = doc["intrinsics"]
        if doc.get("format") != EXPORT_FORMAT or tuple(int(v) for v in intr["image_size_px"]) != tuple(size):
            return None
        f_px = float(intr["focal_length_px"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return f_px if math.isfinite(f_px) and f_px > 0 else None


def _intrinsics(options: ImportOptions, first: Path, size: tuple[int, int]):
    w, h = size
    exif = read_exif(first)
    make, model = str(exif.get("Make", "")).strip(), str(exif.get("Model", "")).strip()
    name = model if model.lower().startswith(make.lower()) else f"{make} {model}".strip()
    kind = first.suffix.lower().lstrip(".").upper()
    camera: dict[str, Any] = {"name": name or f"imported ({kind})", "sensor_px": [w, h], "raw_format": kind,
                              "imported": True}
    lens: dict[str, Any] = {"name": str(exif.get("LensModel", "")).strip() or "unknown (imported)"}
    e_mm, e_pitch, e_px = intrinsics_from_exif(exif, w)
    pitch = options.pixel_pitch_um if options.pixel_pitch_um is not None else e_pitch
    warnings: list[str] = []
    if options.focal_length_px is not None:
        source = "--focal-length-px"
        lens["focal_length_px"] = float(options.focal_length_px)
        if pitch:
            lens["focal_length_mm"] = float(options.focal_length_px) * pitch / 1000.0
    elif options.focal_length_mm is not None:
        source = "--focal-length-mm and --pixel-pitch-um"
        lens["focal_length_mm"] = float(options.focal_length_mm)
    elif (exported := _export_manifest_focal_px(first.parent, size)) is not None:
        source = "manifest.json of the lfstudio PNG export"
        lens["focal_length_px"] = exported
    elif e_mm and e_pitch:
        source = f"EXIF of {first.name} (FocalLength, FocalPlaneXResolution)"
        lens["focal_length_mm"] = e_mm
    elif e_px:
        source = f"EXIF of {first.name} (FocalLengthIn35mmFilm)"
        lens["focal_length_px"] = e_px
        if e_mm:
            lens["focal_length_mm"] = e_mm
    else:
        source = "none"
        if e_mm:
            lens["focal_length_mm"] = e_mm
        warnings.append(NO_FOCAL_LENGTH_WARNING + " (no --focal-length-mm/--pixel-pitch-um, no "
                        "--focal-length-px, nothing usable in EXIF): calibration will need one "
                        "('lfstudio calibrate DATASET --focal-length-px F'), or import again with it")
    if pitch:
        camera["pixel_pitch_um"] = float(pitch)
        camera["sensor_mm"] = [w * pitch / 1000.0, h * pitch / 1000.0]
    return camera, lens, source, warnings


#: how the warning of an import without a focal length starts (the window says it in its own words)
NO_FOCAL_LENGTH_WARNING = "no focal length in pixels is known"


# -- HCI benchmark folders ----------------------------------------------------------------------------
HCI_PARAMETERS = "parameters.cfg"
HCI_PATTERN = "input_Cam*.png"
#: focus_distance_m at or beyond this is a parallel light field (lfstudio writes 1e9 m for its own)
HCI_PARALLEL_FROM_M = 1e6


@dataclass
class HciFolder:
    """What an HCI benchmark folder's ``parameters.cfg`` says (Honauer et al. 2016; the toolkit's
    ``file_io.read_parameters``)."""

    path: Path
    grid: tuple[int, int]                  # (num_cams_x, num_cams_y)
    spacing_mm: tuple[float, float]        # (baseline_mm, baseline_y_mm or baseline_mm)
    image_size_px: tuple[int, int]
    focal_length_px: float
    focal_length_mm: float
    focus_distance_m: float | None         # None: parallel (focus_distance_m at infinity)
    disparity_px: tuple[float, float] | None   # (disp_min, disp_max)
    files: list[str]


def read_hci_folder(folder: Path) -> HciFolder | None:
    """The HCI folder ``folder`` (None when it has no parameters.cfg); raises :class:`InputError`
    naming parameters.cfg and the field when it cannot be used, or the first missing view."""
    import configparser

    path = Path(folder) / HCI_PARAMETERS
    if not path.is_file():
        return None
    cfg = configparser.ConfigParser(interpolation=None)     # '%' is a character in a value, never a reference
    try:
        cfg.read_string(path.read_text(encoding="utf-8", errors="replace"))
    except configparser.Error as exc:
        raise InputError("folder", f"{path}: cannot be read as INI ({str(exc).splitlines()[0]}); fix or remove it") from None

    def number(section: str, key: str, default: float | None = None, positive: bool = True) -> float:
        raw = cfg.get(section, key, fallback=None)
        if raw is None:
            if default is not None:
                return default
            raise InputError("folder", f"{path}: [{section}] {key} is missing; the HCI benchmark's parameters.cfg has it")
        try:
            v = float(raw)
        except ValueError:
            raise InputError("folder", f"{path}: [{section}] {key} = {raw!r} is not a number") from None
        if not math.isfinite(v) or (positive and v <= 0):
            raise InputError("folder", f"{path}: [{section}] {key} = {raw!r} must be a positive number")
        return v

    cols, rows = int(number("extrinsics", "num_cams_x")), int(number("extrinsics", "num_cams_y"))
    w, h = int(number("intrinsics", "image_resolution_x_px")), int(number("intrinsics", "image_resolution_y_px"))
    f_mm, sensor = number("intrinsics", "focal_length_mm"), number("intrinsics", "sensor_size_mm")
    b = number("extrinsics", "baseline_mm")
    b_y = number("extrinsics", "baseline_y_mm", b)
    focus = number("extrinsics", "focus_distance_m")
    d = None
    if cfg.has_option("meta", "disp_min") and cfg.has_option("meta", "disp_max"):
        d = (number("meta", "disp_min", positive=False), number("meta", "disp_max", positive=False))
    check_grid(f"{path}: [extrinsics] num_cams_x, num_cams_y", cols, rows)    # before a name is built per view
    for key, value in (("image_resolution_x_px", w), ("image_resolution_y_px", h)):
        problem = WIDTH_PX.problem(value)
        if problem:
            raise InputError("folder", f"{path}: [intrinsics] {key} {problem}", WIDTH_PX.valid())
    n = cols * rows
    digits = max(3, len(str(n - 1)))
    files = [f"input_Cam{i:0{digits}d}.png" for i in range(n)]
    for name in files:
        if not (Path(folder) / name).is_file():
            raise InputError("folder", f"{path} lists {cols}x{rows} views but {name} is missing from {folder}; copy it "
                             f"in (the views are {files[0]} … {files[-1]}, row by row)")
    return HciFolder(path, (cols, rows), (b, b_y), (w, h), f_mm / sensor * max(w, h), f_mm,
                     None if focus >= HCI_PARALLEL_FROM_M else focus, d, files)


def apply_hci_folder(options: ImportOptions) -> tuple[ImportOptions, HciFolder | None]:
    """``options`` completed from the folder's parameters.cfg (grid, spacing, focal length, zero
    plane, the file names); an option given that contradicts the file is refused by name."""
    hci = read_hci_folder(options.folder)
    if hci is None:
        return options, None
    where = f"{hci.path} says"
    if options.grid is not None and tuple(int(v) for v in options.grid) != hci.grid:
        raise InputError("--grid", f"{options.grid[0]}x{options.grid[1]}, but {where} {hci.grid[0]}x{hci.grid[1]}; "
                         "leave --grid out for an HCI folder")
    if options.spacing_mm is not None and not np.allclose(options.spacing_mm, hci.spacing_mm, rtol=1e-6):
        raise InputError("--spacing-mm", f"{options.spacing_mm[0]:g}x{options.spacing_mm[1]:g} mm, but {where} "
                         f"baseline {hci.spacing_mm[0]:g}x{hci.spacing_mm[1]:g} mm; leave --spacing-mm out")
    if options.parallel_views and hci.focus_distance_m is not None:
        raise InputError("--parallel-views", f"contradicts {where} focus_distance_m = {hci.focus_distance_m:g} m (the "
                         "views are sheared to zero disparity there); leave it out")
    if options.zero_disparity_depth_m is not None and (hci.focus_distance_m is None or not math.isclose(
            options.zero_disparity_depth_m, hci.focus_distance_m, rel_tol=1e-6)):
        said = "parallel views (focus_distance_m at infinity)" if hci.focus_distance_m is None else \
            f"focus_distance_m = {hci.focus_distance_m:g} m"
        raise InputError("--zero-disparity-depth-m", f"{options.zero_disparity_depth_m:g} m, but {where} {said}; "
                         "leave it out")
    if options.focal_length_mm is not None or (options.focal_length_px is not None and
                                               not math.isclose(options.focal_length_px, hci.focal_length_px, rel_tol=1e-9)):
        raise InputError("--focal-length-px", f"{where} the focal length ({hci.focal_length_px:.6g} px); leave the "
                         "focal length options out for an HCI folder")
    if options.pattern not in (None, HCI_PATTERN):
        raise InputError("--pattern", f"an HCI folder's views are {HCI_PATTERN} ({where} which); leave --pattern out")
    done = dataclasses.replace(options, grid=hci.grid, spacing_mm=hci.spacing_mm, pattern=HCI_PATTERN,
                               order="row-major", focal_length_px=hci.focal_length_px,
                               zero_disparity_depth_m=hci.focus_distance_m,
                               parallel_views=hci.focus_distance_m is None)
    return done, hci


# -- the zero-disparity plane -------------------------------------------------------------------------
def resolve_zero_plane(plan: ImportPlan, options: ImportOptions, grid: tuple[int, int], *,
                       cancel: CancelToken | None = None, progress: Progress | None = None) -> None:
    """Measure the views (``options.measure``), reverse the rows when the tracks say they run upwards,
    and set ``plan.zero_plane`` (the manifest's ``zero_disparity``) from the options or the
    measurement; refuses a stated zero plane the views contradict. Writes nothing. ``progress(done,
    total, message)``: the measurement's (a view read and tracked at a time, then the solve)."""
    from lfstudio.dataset import zero_plane as zp

    cols, rows = grid
    f_px = plan_focal_px(plan)
    measured = None
    if options.measure is not None:
        positions = plan.positions_mm or {c: (c[1] * plan.spacing_mm[0], c[0] * plan.spacing_mm[1]) for c in plan.cells}
        files = dict(zip(plan.cells, plan.files))
        measured = options.measure(files, positions, plan.spacing_mm, f_px, cancel=cancel, progress=progress)
    info = measured.as_dict() if measured is not None else {}
    if plan.hci is not None:
        # a published layout is read as the format defines it, whatever the image content suggests
        info["rows_reversed"] = False
        info["rows_order"] = "format"
        info["rows_order_why"] = ("the HCI format numbers its views row by row from the top left (input_Cam000 is "
                                  "the top-left view, rows top-down): taken as the format states it")
        if measured is not None and measured.rows_reversed:
            info["rows_content_suggested_reversed"] = True
    elif measured is not None and measured.rows_reversed and rows > 1:
        plan.cells = [(rows - 1 - r, c) for r, c in plan.cells]
        _place(plan, options, grid)
        info["rows_order"] = "reversed"
        info["rows_reversed_why"] = ("the tracks' vertical disparities agree with the horizontal ones only with the "
                                     "rows reversed: row 0 of the files is the bottom row; reversed so that row 0 is "
                                     "the top (columns are taken as given, left to right)")
    elif measured is not None and rows > 1:
        info["rows_order"] = "as numbered"
    width = float(plan.image_size_px[0])
    if options.parallel_views:
        if measured is not None and measured.sheared:
            raise InputError(str(plan.hci.path) if plan.hci else "--parallel-views", f"the views have disparities down to "
                             f"{measured.step_disparity_px[0]:+.2f} px per step, which parallel views cannot have "
                             "(they are sheared); leave --parallel-views out or give --zero-disparity-depth-m")
        plan.zero_plane = zp.record(0.0, None, zp.SOURCE_PARALLEL, width, info)
    elif options.zero_disparity_depth_m is not None:
        assert f_px is not None      # plan_import refused it otherwise
        z0 = float(options.zero_disparity_depth_m)
        shear = zp.shear_for_depth(f_px, z0)
        if measured is not None and measured.sheared and shear < measured.shear_min_px_per_mm:
            raise InputError(str(plan.hci.path) if plan.hci else "--zero-disparity-depth-m",
                             f"{z0:g} m is too far: the views have disparities down to "
                             f"{measured.step_disparity_px[0]:+.2f} px per step, so points would lie beyond infinity; "
                             f"the zero-disparity plane is nearer than {measured.depth_max_m:.2f} m")
        plan.zero_plane = zp.record(shear, z0, zp.SOURCE_HCI if plan.hci else zp.SOURCE_STATED, width, info)
    elif measured is not None:
        if measured.sheared:
            plan.zero_plane = zp.record(None, None, zp.SOURCE_MEASURED_SHEARED, width, info)
        else:
            plan.zero_plane = zp.record(0.0, None, zp.SOURCE_MEASURED_PARALLEL, width, info)
    if plan.hci is not None and plan.zero_plane is not None:
        if plan.zero_plane["source"] == zp.SOURCE_PARALLEL:
            plan.zero_plane["source"] = zp.SOURCE_HCI
        if plan.hci.disparity_px is not None:   # what the benchmark file declares (HCI's disp_min/disp_max)
            plan.zero_plane["declared_step_disparity_px"] = [float(v) for v in plan.hci.disparity_px]


def import_summary(ds) -> str:
    """The zero-disparity plane and the recorded positions of an imported dataset, for the summary;
    options as :func:`lfstudio.errors.words` parts (the command line prints it through
    :func:`~lfstudio.errors.for_cli`, the window through :func:`~lfstudio.errors.for_window`)."""
    from lfstudio.dataset.zero_plane import zero_plane

    zp = zero_plane(ds)
    lines = [f"zero disparity: {zp.describe(front_words=True)}"]
    m = zp.measured
    if m.get("step_disparity_px"):
        lo, hi = m["step_disparity_px"]
        lines.append(f"disparity     : {lo:+.2f} … {hi:+.2f} px between horizontal neighbours, {zp.disparity_reference()}"
                     f" (tracked points, measured on {m.get('views')} views, {m.get('tracks')} tracks)")
    order = m.get("rows_order")
    if m.get("rows_reversed"):
        lines.append("rows          : reversed (the tracks say the files number the rows from the bottom)")
    elif order == "format":
        lines.append("rows          : as the HCI format defines them (input_Cam000 top left, rows top-down)")
    elif order == "as numbered":
        lines.append("rows          : as numbered (the tracks agree: row 0 of the files is the top row)")
    hci = (ds.manifest.get("import") or {}).get("hci")
    if hci:
        lines.append(f"HCI folder    : grid, baseline, focal length and zero plane from {hci.get('parameters')}")
    pos = (ds.manifest.get("import") or {}).get("positions")
    if pos:
        lines.append(f"positions     : recorded, from {pos.get('source')} (x = {pos.get('x')}, y = {pos.get('y')})")
    return "\n".join(lines)


# -- copying ------------------------------------------------------------------------------------------
def _link_or_copy(src: Path, dst: Path, link: bool, cancel: CancelToken | None) -> tuple[str, bool]:
    """Put ``src`` at ``dst`` (hard link if allowed and possible, else a copy); its sha256 and whether linked."""
    if link:
        try:    # the file a symlink leads to: link() would link the symlink itself, which leads outside the dataset
            os.link(os.path.realpath(src), dst)
        except OSError:
            pass
        else:
            return sha256_file(dst), True
    h = hashlib.sha256()   # a copy is hashed while it is written: one read of the source
    with open(src, "rb") as fi, open(dst, "wb") as fo:
        for chunk in iter(lambda: fi.read(1 << 20), b""):
            if cancel is not None:
                cancel.check()
            h.update(chunk)
            fo.write(chunk)
        fo.flush()
        os.fsync(fo.fileno())
    shutil.copystat(src, dst)
    return h.hexdigest(), False


def _iso_mtime(path: Path) -> str:
    return now_iso(path.stat().st_mtime)


def import_images(options: ImportOptions, *, progress: Progress | None = None,
                  cancel: CancelToken | None = None) -> Path:
    """Build a dataset at ``options.out`` from ``options.folder``'s images; returns the dataset root.

    Raises :class:`InputError` naming the option and the fix (count vs grid, mixed sizes, unreadable
    file, ``out`` exists without ``overwrite``); :class:`lfstudio.jobs.Cancelled` when cancelled.
    Nothing is left under ``out`` (nor a temporary folder) unless the import finished.
    """
    from lfstudio.dataset import Dataset
    from lfstudio.dataset.store import free_bytes
    from lfstudio.export.common import check_new_dataset_out, partial_folder

    progress = progress or no_progress
    options = apply_hci_folder(options)[0]
    check_options(options)
    grid_cr = _grid(options)
    n_files = grid_cr[0] * grid_cr[1]
    # checking the files, measuring the views' disparities (when asked: 6-11 s for 25 views, shown in
    # steps of the same weight as a file), linking or copying the files, moving into place
    measuring = n_files if options.measure is not None else 0
    total = 2 * n_files + measuring + 1

    def check_progress(done: int, _total: int, message: str = "") -> None:
        progress(done, total, message)

    def measure_progress(done: int, steps: int, message: str = "") -> None:
        progress(n_files + math.ceil(measuring * done / max(steps, 1)), total, message)

    plan = plan_import(options, progress=check_progress, cancel=cancel)
    if measuring:
        progress(n_files, total, "measuring the disparities between views")
    resolve_zero_plane(plan, options, grid_cr, cancel=cancel,
                       progress=measure_progress)
    out = Path(options.out).absolute()
    out.parent.mkdir(parents=True, exist_ok=True)
    if free_bytes(out.parent) < plan.bytes_total + (64 << 20):
        raise InputError("--out", f"{out.parent} has {free_bytes(out.parent) / 1e9:.1f} GB free, the images need "
                         f"{plan.bytes_total / 1e9:.1f} GB; free space or choose another disk")
    with partial_folder(out, options.overwrite) as tmp:
        (tmp / "raw").mkdir()
        sx, sy = plan.spacing_mm
        recorded = plan.positions_mm or {}
        views: list[ViewRecord] = []
        linked = 0

        def bring(src: Path, rel: str, thumb_rel: str) -> tuple[str, bool, str | None]:
            sha, was_linked = _link_or_copy(src, tmp / rel, options.link, cancel)
            try:    # made while the file is in the page cache: the grid shows it at once
                thumb = make_thumbnail([tmp / rel], tmp / thumb_rel)
            except Exception as exc:  # a thumbnail is a convenience: the grid makes one later
                log.info("no thumbnail of %s: %s", src, exc)
                thumb = None
            return sha, was_linked, thumb_rel if thumb is not None else None

        # each file is linked or copied, hashed and given its thumbnail on a pool of threads (hashing,
        # copying and decoding release the GIL); results are taken in order
        with ThreadPoolExecutor(max_workers=os.cpu_count() or 1, thread_name_prefix="import") as pool:
            jobs = []
            for src, (r, c) in zip(plan.files, plan.cells):
                stem = view_stem(r, c)
                rel = f"raw/{stem}{src.suffix.lower()}"   # = Dataset.raw_name(r, c, suffix)
                jobs.append(pool.submit(bring, src, rel, f"thumbs/{stem}.jpg"))
            try:
                for i, (job, src, (r, c)) in enumerate(zip(jobs, plan.files, plan.cells)):
                    if cancel is not None:
                        cancel.check()
                    sha, was_linked, thumb = job.result()
                    rel = f"raw/{view_stem(r, c)}{src.suffix.lower()}"
                    linked += was_linked
                    views.append({"row": r, "column": c, "commanded_mm": [c * sx, r * sy],
                                  "reported_mm": list(recorded[(r, c)]) if (r, c) in recorded else None,
                                  "captured_at": _iso_mtime(src), "exposure_s": None, "file": rel, "sha256": sha,
                                  "thumb": thumb, "status": "done",
                                  "source_file": src.relative_to(Path(options.folder)).as_posix()})
                    progress(n_files + measuring + i + 1, total, f"{'linked' if was_linked else 'copied'} {src.name} → {rel}")
            except BaseException:
                pool.shutdown(wait=True, cancel_futures=True)
                raise
        views.sort(key=lambda v: (v["row"], v["column"]))
        cols, rows = grid_cr
        grid = {"columns": cols, "rows": rows, "spacing_mm": [sx, sy], "origin_mm": [0.0, 0.0],
                "order": GRID_ORDER[options.order]}
        record = {"folder": str(Path(options.folder).absolute()), "pattern": options.pattern,
                  "order": options.order, "files": len(plan.files), "linked": linked,
                  "intrinsics": plan.intrinsics, "warnings": list(plan.warnings),
                  "imported_at": now_iso()}
        if plan.hci is not None:
            record["hci"] = {"parameters": str(plan.hci.path), "grid": list(plan.hci.grid),
                             "baseline_mm": list(plan.hci.spacing_mm), "focal_length_px": plan.hci.focal_length_px,
                             "focus_distance_m": plan.hci.focus_distance_m,
                             "disparity_px": None if plan.hci.disparity_px is None else list(plan.hci.disparity_px)}
        if plan.positions_record is not None:
            record["positions"] = plan.positions_record
        extra: dict[str, Any] = {"import": record}
        if plan.zero_plane is not None:
            extra["zero_disparity"] = plan.zero_plane
        ds = Dataset.create(tmp, camera=plan.camera, lens=plan.lens, grid=grid,
                            rig={"name": "imported", "imported": True}, views=views, exist_ok=True, **extra)
        ds.close()
        if cancel is not None:
            cancel.check()
        check_new_dataset_out(out, options.overwrite, field="--out")      # again: files may have been put there meanwhile
        progress(total - 1, total, "moving into place")
    progress(total, total, f"imported {len(plan.files)} views into {out}")
    return out

