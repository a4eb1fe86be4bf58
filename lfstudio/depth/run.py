"""Dense disparity and depth of a dataset's views, stored in the dataset: a long job, resumable.

``estimate_depth(dataset, views, ...)`` computes every chosen view's disparity and confidence with
the light-field sweep (:mod:`lfstudio.depth.dense`) over its 2-D neighbourhood (:func:`neighbours_of`),
one task per view on the executor it is given (the processing pool or a Dask cluster:
:func:`lfstudio.processing.executors.open_executor`; none: in this process), and writes

    DATASET/depth/disparity/rRR_cCCC.pfm    px between horizontal neighbours (HCI convention)
    DATASET/depth/confidence/rRR_cCCC.pfm   0 … 1
    DATASET/depth/records/rRR_cCCC.json     what it was computed from (settings, source files), figures

each atomically, the record last. A worker keeps the views it prepared (decoded, rectified, grey) for
the next views it computes, whose neighbourhoods overlap (:data:`IMAGE_CACHE_MB`; the record counts
``images_read`` and ``images_cached``). A view whose record matches the settings and its source files
is skipped, so a cancelled or crashed run resumes where it stopped (``force``: compute again).
Workers must see the dataset at the same path (as processing's).

**Images**: the processed views when every view needed has one (rectified when processing
rectified them), else the captures rectified with the calibration's homography, else the captures
as they are (a warning: disparities of unrectified views are only approximately along the rows).

**Neighbour offsets**: from the positions the rig recorded when the import has them, else from the
grid; where the rig's repeatability is not negligible against a spacing (the reference gantry's
80 × 50 µm of 4 mm), each neighbour's offset is also measured from the images (SIFT matches with
the reference, the dataset's feature cache) and combined with the rig's by their uncertainties
(:mod:`lfstudio.depth.positions`; the record's ``offsets_measured``). An HCI folder's are exact.

**Disparity range** searched, from the best source there is (printed with its origin): a range
stated by the user (``--disparity-range``, the Depth dialog), the format's own (an imported HCI
folder's ``disp_min``/``disp_max``), the scene plan's near/far, the quality check's tracks over the
grid (``quality.json``), the import's tracks, else tracks measured now over a block of views around
the chosen ones; a margin is added to measured ranges (:data:`RANGE_MARGINS`). Never one pair.

**Depth** from a map: ``Z = f · spacing_x / (1000 · (d + shear · spacing_x))`` m, ``f`` the focal length
in px at the map's size, ``shear`` the views' zero-disparity shear in px per mm (0 for a scan;
an archive's record, :mod:`lfstudio.dataset.zero_plane`); refused when the shear is not known.
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import json
import logging
import os
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from lfstudio.dataset import Dataset
from lfstudio.dataset.atomic import atomic_write_text, atomic_write_with
from lfstudio.dataset.grid import View
from lfstudio.dataset.manifest import now_iso
from lfstudio.dataset.paths import view_stem
from lfstudio.depth import dense, positions
from lfstudio.depth.files import read_pfm, write_pfm
from lfstudio.errors import DatasetError, InputError, words
from lfstudio.jobs import Cancelled, CancelToken, Progress, no_progress

log = logging.getLogger(__name__)

DEPTH_DIR = "depth"
#: the method's version, part of every view's key: raised when its maps change, so that maps of an
#: earlier version are computed again (2: row/column lines, colour at silhouettes, plane fit; 3: a
#: view recorded a little off its row stays on it; 4: the neighbours' offsets measured from the
#: images; 5: ... a measurement that contradicts the rig not believed)
METHOD = "light-field-sgm-5"
#: search margin around the plan's near/far disparities
RANGE_MARGIN = 0.08
#: the neighbourhood: views up to this many columns and rows away, on the lines through the view
#: (its row, its column and the two diagonals), every direction there is
STEPS_H = 4
STEPS_V = 4


@dataclass(frozen=True)
class DepthSettings:
    steps_h: int = STEPS_H                # neighbours up to this many columns away
    steps_v: int = STEPS_V                # ... and rows away
    window_px: int = dense.WINDOW_PX
    step_px: float = dense.SWEEP_STEP_PX

    def describe(self) -> dict[str, Any]:
        return {"method": METHOD, "steps_h": self.steps_h, "steps_v": self.steps_v, "window_px": self.window_px,
                "step_px": self.step_px}


@dataclass
class DepthReport:
    computed: int = 0
    skipped: int = 0                      # up to date from an earlier run
    failed: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0
    cpu_s: float = 0.0                    # the views' own CPU in their workers
    source: str = ""
    warnings: list[str] = field(default_factory=list)
    range_text: str = ""                  # the disparity range searched and where it came from

    def summary(self) -> str:
        text = (f"depth: {self.computed} view{'' if self.computed == 1 else 's'} computed, {self.skipped} up to date"
                f"{f', {len(self.failed)} failed' if self.failed else ''} ({self.source}) in {self.seconds:.1f} s")
        if self.computed:
            text += f"; {self.cpu_s / self.computed:.1f} CPU s per view"
        return text


def map_path(root: str | os.PathLike, kind: str, view: Sequence[int]) -> Path:
    """``DATASET/depth/KIND/rRR_cCCC.pfm`` (``disparity``, ``confidence``) or ``records/….json``."""
    suffix = ".json" if kind == "records" else ".pfm"
    return Path(root) / DEPTH_DIR / kind / f"{view_stem(int(view[0]), int(view[1]))}{suffix}"


def read_disparity(dataset, view: Sequence[int]) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """(disparity px, confidence, record) of a view computed earlier; DatasetError naming the fix."""
    root = Dataset.root_of(dataset)
    rec_path = map_path(root, "records", view)
    if not rec_path.is_file():
        raise DatasetError(f"{root}: {view_stem(*view)} has no depth map; run 'lfstudio depth {root}' first")
    record = json.loads(rec_path.read_text(encoding="utf-8"))
    return read_pfm(map_path(root, "disparity", view)), read_pfm(map_path(root, "confidence", view)), record


def has_disparity(dataset, view: Sequence[int]) -> bool:
    root = Dataset.root_of(dataset)
    return all(map_path(root, k, view).is_file() for k in ("records", "disparity", "confidence"))


def zero_shear_px_per_mm(ds: Dataset, width_px: float) -> float | None:
    """The views' shear in px per mm at ``width_px`` (0: parallel, a scan; None: sheared by an
    unknown amount)."""
    from lfstudio.dataset.zero_plane import zero_plane

    return zero_plane(ds).shear_at(width_px)


def depth_from_disparity(disparity_px: np.ndarray, focal_length_px: float, spacing_x_mm: float,
                         shear_px_per_mm: float | None = 0.0) -> np.ndarray:
    """Depth in metres (NaN where the disparity is unknown or at/behind infinity; module docstring)."""
    if shear_px_per_mm is None:
        raise InputError("zero_disparity", "the views are sheared by an amount nobody stated: disparities have no "
                         "depth (the disparity maps in px are computed all the same)",
                         "import them again with " + words("--zero-disparity-depth-m",
                                                           "Zero disparity set to a depth in the Import dialog"))
    d = np.asarray(disparity_px, np.float64) + float(shear_px_per_mm) * float(spacing_x_mm)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = float(focal_length_px) * float(spacing_x_mm) / (1000.0 * d)
    z[~(np.isfinite(z) & (d > 0))] = np.nan
    return z.astype(np.float32)


# -- where the images come from -----------------------------------------------------------------------
def _processed_path(ds: Dataset, view: Sequence[int]) -> Path | None:
    return ds.processed_path(ds.view(*view))


def _image_path(ds: Dataset, view: Sequence[int], source: str) -> Path:
    """The view's processed image (``source`` "processed") or its capture; refused by name when the
    processed one is missing."""
    if source != "processed":
        return ds.path_of(ds.view(*view))
    path = _processed_path(ds, view)
    if path is None:
        raise DatasetError(f"{ds.root}: no processed image of {view_stem(*view)}; process the dataset first "
                           "('lfstudio process') or use --source raw")
    return path


@dataclass(frozen=True)
class Geometry:
    source: str                           # "processed" | "raw"
    rectified: bool
    homography: list | None               # raw views rectified with this (full resolution)
    size_px: tuple[int, int]              # the maps' size (w, h)
    focal_length_px: float                # at that size
    spacing_mm: tuple[float, float]
    shear_px_per_mm: float | None         # at that size
    d_range_px: tuple[float, float]       # searched (px between horizontal neighbours, as the views show it)
    warnings: tuple[str, ...] = ()
    range_found_px: tuple[float, float] = (0.0, 0.0)   # the source's range before the search margin
    range_source: str = ""                # where the range came from (one phrase, printed)

    def describe_range(self) -> str:
        lo, hi = self.range_found_px
        return (f"disparity range {lo:+.2f} … {hi:+.2f} px from {self.range_source}; searched "
                f"{self.d_range_px[0]:+.2f} … {self.d_range_px[1]:+.2f} px")


#: where a range comes from, best first (:func:`disparity_range`)
RANGE_SOURCES = ("stated", "format", "plan", "check", "import", "tracks")
#: margins around a range, by source: (share of the span, px) on each side. A stated or declared
#: range is taken nearly as it is; a measured one (1st-99th percentile of tracks pulled inwards by
#: their errors) is widened
RANGE_MARGINS = {"stated": (0.0, 0.0), "format": (0.03, 0.05), "plan": (RANGE_MARGIN, 0.05),
                 "check": (0.12, 0.2), "import": (0.12, 0.2), "tracks": (0.15, 0.25)}


def check_disparity_range(field: str, value) -> tuple[float, float]:
    """A stated range (MIN, MAX) in px between horizontal neighbours, or InputError naming ``field``."""
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(field, f"{value!r} is not two numbers", "MIN,MAX in px between horizontal neighbours, "
                         "e.g. -3.5,3") from None
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise InputError(field, f"{lo:g} … {hi:g} is not a finite range", "MIN,MAX, e.g. -3.5,3")
    if not lo < hi:
        raise InputError(field, f"the minimum {lo:g} is not below the maximum {hi:g}", "MIN,MAX with MIN < MAX, "
                         "e.g. -3.5,3")
    if hi - lo > 2000:
        raise InputError(field, f"{lo:g} … {hi:g} px spans more than 2000 px between neighbours",
                         "the disparity between two neighbouring views, e.g. -3.5,3")
    return lo, hi


def parse_disparity_range(field: str, text: str) -> tuple[float, float]:
    """``MIN,MAX`` typed as text (the CLI option, the Depth dialog's field)."""
    import re

    parts = [p.strip() for p in re.split(r"[,;]|\s+\.\.\.?\s+|\s*…\s*", str(text).strip()) if p.strip()]
    if len(parts) != 2:
        raise InputError(field, f"cannot read {text!r}", "two numbers MIN,MAX in px between horizontal neighbours, "
                         "e.g. -3.5,3")
    try:
        values = [float(p.replace("−", "-")) for p in parts]
    except ValueError:
        raise InputError(field, f"cannot read {text!r} as two numbers", "MIN,MAX, e.g. -3.5,3") from None
    return check_disparity_range(field, values)


def _full_width(ds: Dataset) -> float | None:
    """Width of the full-size images the manifest's ranges are given for."""
    from lfstudio.dataset.zero_plane import zero_plane

    zp = zero_plane(ds)
    if zp.width_px:
        return float(zp.width_px)
    sensor = (ds.manifest.get("camera") or {}).get("sensor_px")
    return float(sensor[0]) if isinstance(sensor, list) and sensor and sensor[0] else None


def _pair(value) -> tuple[float, float] | None:
    if isinstance(value, (list, tuple)) and len(value) == 2 and all(isinstance(v, (int, float)) for v in value) \
            and all(np.isfinite(v) for v in value) and value[0] < value[1]:
        return float(value[0]), float(value[1])
    return None


def disparity_range(ds: Dataset, views: Sequence[View], source: str, H, width_px: float, f_px: float,
                    stated: tuple[float, float] | None = None) -> tuple[tuple[float, float], str, str]:
    """((min, max) px between horizontal neighbours at ``width_px``, source key, phrase) from the best
    source there is: a stated range, the format's own (an HCI folder's ``disp_min``/``disp_max``,
    recorded at import), the scene plan's near/far, the quality check's tracks over the grid
    (``quality.json``), the import's tracks, else tracks measured now over a block of views. Never
    from one pair of views."""
    if stated is not None:
        return check_disparity_range("disparity_range", stated), "stated", "the range stated"
    full = _full_width(ds)
    scale = float(width_px) / full if full else 1.0
    hci = (ds.manifest.get("import") or {}).get("hci") or {}
    zrec = ds.manifest.get("zero_disparity") or {}
    declared = _pair(hci.get("disparity_px")) or _pair(zrec.get("declared_step_disparity_px"))
    if declared is not None:
        name = Path(str(hci.get("parameters") or "parameters.cfg")).name
        return (declared[0] * scale, declared[1] * scale), "format", f"{name} (disp_min/disp_max of the HCI folder)"
    sx = float(ds.grid.step_mm[0])
    plan = ds.manifest.get("plan") or {}
    near, far = plan.get("near_m"), plan.get("far_m")
    if isinstance(near, (int, float)) and isinstance(far, (int, float)) and 0 < near < far:
        shear = zero_shear_px_per_mm(ds, width_px)
        k = f_px * sx / 1000.0
        d_lo, d_hi = k / far, k / near
        if shear:
            d_lo, d_hi = d_lo - shear * sx, d_hi - shear * sx
        return (d_lo, d_hi), "plan", f"the scene plan (far {far:g} m, near {near:g} m)"
    try:
        quality = json.loads((Path(ds.root) / "quality.json").read_text(encoding="utf-8"))
        depth = quality.get("depth_range") or {}
        checked = _pair([depth.get("views_disparity_min_px"), depth.get("views_disparity_max_px")])
    except (OSError, ValueError, AttributeError):
        checked = None
    if checked is not None:
        return (checked[0] * scale, checked[1] * scale), "check", \
            f"the quality check's tracks ({depth.get('tracks')} tracks over the grid, quality.json)"
    measured = _pair((zrec.get("measured") or {}).get("step_disparity_px"))
    if measured is not None:
        m = zrec["measured"]
        return (measured[0] * scale, measured[1] * scale), "import", \
            f"the import's tracks ({m.get('tracks')} tracks of {m.get('views')} views)"
    lo, hi, detail = measured_range(ds, views, source, H, width_px)
    return (lo, hi), "tracks", detail


def widen(found: tuple[float, float], key: str) -> tuple[float, float]:
    """The searched range: ``found`` with its source's margin (:data:`RANGE_MARGINS`)."""
    share, px = RANGE_MARGINS.get(key, (RANGE_MARGIN, 0.05))
    lo, hi = found
    span = hi - lo
    return lo - share * span - px, hi + share * span + px


def geometry_of(ds: Dataset, views: Sequence[View], needed: Sequence[View], source: str = "auto",
                stated_range: tuple[float, float] | None = None) -> Geometry:
    """How the chosen views' maps are made (module docstring: images, range, focal length)."""
    from lfstudio.calibration.model import load_calibration
    from lfstudio.dataset import images

    source = (source or "auto").lower()
    if source not in ("auto", "raw", "processed"):
        raise InputError("source", f"unknown source {source!r}", "raw, processed or auto")
    missing = [v for v in needed if _processed_path(ds, v) is None]
    if source == "processed" and missing:
        raise InputError("source", f"processed views missing for {', '.join(view_stem(*v) for v in missing[:6])}",
                         "process the dataset first ('lfstudio process'), or --source raw")
    use = "processed" if source == "processed" or (source == "auto" and not missing) else "raw"
    w, h = images.full_size_px(_image_path(ds, views[0], use))
    cal = load_calibration(ds)
    warnings: list[str] = []
    rectified = bool(use == "processed" and (ds.manifest.get("processing") or {}).get("rectified"))
    H = None
    if use == "raw" and cal and cal.get("homography"):
        H = np.asarray(cal["homography"], float).tolist()
        rectified = True
    if not rectified and not (ds.manifest.get("import") or {}).get("hci"):
        warnings.append("the views are not rectified (no calibration): disparities along the rows are approximate; "
                        "calibrate (and process) first")
    f_full = float(cal["focal_length_px"]) if cal and cal.get("focal_length_px") else None
    if f_full and cal and cal.get("image_size_px"):
        f_px = f_full * w / float(cal["image_size_px"][0])
    else:
        f_px = ds.focal_length_px(w)
    sx, sy = (float(v) for v in ds.grid.step_mm)
    shear = zero_shear_px_per_mm(ds, w)
    found, key, phrase = disparity_range(ds, views, use, H, float(w), float(f_px), stated_range)
    d_range = widen(found, key)
    return Geometry(use, rectified, H, (int(w), int(h)), float(f_px), (sx, sy), shear, d_range, tuple(warnings),
                    found, phrase)


#: what to do when the range cannot be found: in the command line's words and the Depth dialog's
STATE_THE_RANGE = (f"state it ({words('lfstudio depth --disparity-range MIN,MAX', 'Disparity range field: MIN, MAX')}) "
                   "or give the dataset a scene plan")


def measured_range(ds: Dataset, views: Sequence[View], source: str, H, width_px: float) -> tuple[float, float, str]:
    """Disparity range (px per horizontal step at ``width_px``, 1st-99th percentile) from SIFT
    matches pooled over the pairs of a star of views around the chosen views' centre: its nearest and
    farthest neighbours (up to 4 steps) left, right, up and down (never one pair)."""
    from lfstudio.calibration.features import detect, match_pairs
    from lfstudio.calibration.model import apply_homography

    captured = set(ds.captured_views())
    usable = {v for v in captured if source != "processed" or _processed_path(ds, v) is not None}
    rows = sorted({r for r, _ in views})
    cols = sorted({c for _, c in views})
    r0, c0 = rows[len(rows) // 2], cols[len(cols) // 2]
    centre = min(usable, key=lambda v: (abs(v[0] - r0) + abs(v[1] - c0), v)) if usable else None
    sx, sy = (float(v) for v in ds.grid.step_mm)
    pairs: list[tuple[View, View, str, float]] = []   # (a, b, direction, b's offset from a in horizontal spacings)
    if centre is not None:
        r, c = centre
        for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            steps = [k for k in range(1, 5) if (r + dr * k, c + dc * k) in usable]
            for k in sorted({steps[0], steps[-1]}) if steps else ():
                other = View(r + dr * k, c + dc * k)
                a, b = (View(*centre), other) if dr + dc > 0 else (other, View(*centre))
                pairs.append((a, b, "h" if dc else "v", k * (1.0 if dc else sy / sx)))
    if len(pairs) < 2:
        raise InputError("views", "too few views around the chosen ones and no scene plan: the disparity range is "
                         "unknown", STATE_THE_RANGE)
    needed = sorted({v for p in pairs for v in p[:2]})
    features = {v: detect(_image_path(ds, v, source)) for v in needed}
    results = match_pairs(features, [(a, b, d) for a, b, d, _ in pairs], threads=1)
    found = []
    full_w = None
    for (a, b, direction, offset), m in zip(pairs, results):
        xa, xb = m.xy_a, m.xy_b
        if len(xa) < 8:
            continue
        if H is not None:
            xa, xb = apply_homography(np.asarray(H), xa), apply_homography(np.asarray(H), xb)
        axis = 0 if direction == "h" else 1
        found.append((xa[:, axis] - xb[:, axis]) / offset)
        full_w = full_w or features[a].image_size_px[0]
    d = np.concatenate(found) if found else np.zeros(0)
    if len(found) < 2 or len(d) < 20:
        raise InputError("views", "too few feature matches to measure the disparity range and no scene plan",
                         STATE_THE_RANGE)
    scale = float(width_px) / float(full_w) if full_w else 1.0
    lo, hi = (float(v) * scale for v in np.percentile(d, [1, 99]))
    assert centre is not None                   # pairs come only from around it
    return lo, hi, f"feature matches of {len(found)} pairs around {view_stem(*centre)} ({len(d)} matches)"


def neighbours_of(ds: Dataset, view: View, settings: DepthSettings, captured: set,
                  recorded: dict[tuple[int, int], tuple[float, float]] | None = None
                  ) -> list[tuple[View, float, float]]:
    """(view, dx, dy) of the neighbours used: the captured views up to ``steps_h`` columns and
    ``steps_v`` rows away on the lines through the view (its row, its column, the diagonals), near
    and far, in every direction the grid has; offsets in horizontal spacings, from the positions
    the rig recorded when the import has them, else from the grid. An edge or corner view has the
    directions that stay inside the grid. ``recorded``: :func:`_recorded_positions` of ``ds`` when the
    caller has it (``{}``: none; one pass over the views for all of them), None: read here."""
    r, c = view
    sx, sy = (float(v) for v in ds.grid.step_mm)
    ratio = sy / sx if sx else 1.0
    if recorded is None:
        recorded = _recorded_positions(ds)
    out = []
    for dr in range(-settings.steps_v, settings.steps_v + 1):
        for dc in range(-settings.steps_h, settings.steps_h + 1):
            if (dr, dc) == (0, 0) or not (dr == 0 or dc == 0 or abs(dr) == abs(dc)):
                continue
            if (r + dr, c + dc) not in captured:
                continue
            if recorded and (r, c) in recorded and (r + dr, c + dc) in recorded and sx:
                (x0, y0), (x1, y1) = recorded[(r, c)], recorded[(r + dr, c + dc)]
                out.append((View(r + dr, c + dc), (x1 - x0) / sx, (y1 - y0) / sx))
            else:
                out.append((View(r + dr, c + dc), float(dc), float(dr) * ratio))
    return out


def _recorded_positions(ds: Dataset) -> dict[tuple[int, int], tuple[float, float]] | None:
    """The views' positions as the rig recorded them (``reported_mm`` of an import with
    ``--positions`` or of a fly scan: :attr:`Dataset.positions_recorded`), else None (the grid's)."""
    if not ds.positions_recorded:
        return None
    out = {}
    for v in ds.views:
        pos = v.get("reported_mm")
        if isinstance(pos, (list, tuple)) and len(pos) == 2:
            out[(int(v["row"]), int(v["column"]))] = (float(pos[0]), float(pos[1]))
    return out or None


# -- one view (runs in a worker) ----------------------------------------------------------------------
def _read_rgb(path: str, H, size=None) -> np.ndarray:
    """A view developed (RGB), rectified with ``H`` when given (the size checked against ``size``)."""
    import cv2

    from lfstudio.dataset import images

    rgb = images.develop(path)
    if size is not None and (rgb.shape[1], rgb.shape[0]) != tuple(size):
        raise DatasetError(f"{path}: {rgb.shape[1]} x {rgb.shape[0]} px, the other views are {size[0]} x {size[1]} px")
    if H is not None:
        rgb = cv2.warpPerspective(rgb, np.asarray(H, float), (rgb.shape[1], rgb.shape[0]), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_REPLICATE)
    return rgb


def _read(path: str, H, size) -> np.ndarray:
    return dense.prepare(_read_rgb(path, H, size))


#: prepared (decoded, rectified, grey) views a worker process keeps for its next views (MB): the
#: neighbourhoods of views computed one after the other share most of their views (an HCI view has
#: 32 neighbours; without this each view's run decoded and warped them again)
IMAGE_CACHE_MB = 1024
_image_cache: OrderedDict[tuple, np.ndarray] = OrderedDict()
_image_cache_lock = threading.Lock()


def _read_reference(path: str, H, size, counts: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
    """The view whose map is made: (grey as :func:`_read_cached`, colour (:func:`dense.prepare_colour`));
    its grey joins the cache (the next views have it as a neighbour)."""
    rgb = _read_rgb(path, H, size)
    grey = dense.prepare(rgb)
    grey.setflags(write=False)
    _remember(_cache_key(path, H, size), grey)
    counts["read"] = counts.get("read", 0) + 1
    return grey, dense.prepare_colour(rgb)


def _cache_key(path: str, H, size) -> tuple:
    st = os.stat(path)
    return (os.path.abspath(path), st.st_mtime_ns, st.st_size, json.dumps(H), tuple(int(v) for v in size))


def _remember(key: tuple, image: np.ndarray) -> None:
    budget = IMAGE_CACHE_MB * 1024 * 1024
    with _image_cache_lock:
        _image_cache[key] = image
        _image_cache.move_to_end(key)
        total = sum(a.nbytes for a in _image_cache.values())
        while total > budget and len(_image_cache) > 1:
            _, dropped = _image_cache.popitem(last=False)
            total -= dropped.nbytes


def _read_cached(path: str, H, size, counts: dict[str, int] | None = None) -> np.ndarray:
    """:func:`_read` through this process's cache of prepared views (least recently used dropped
    beyond :data:`IMAGE_CACHE_MB`); a file changed since (size, modification time) is read again.
    The array is read-only (shared by the views that use it). ``counts``: "read" / "cached" tallied."""
    key = _cache_key(path, H, size)
    with _image_cache_lock:
        hit = _image_cache.get(key)
        if hit is not None:
            _image_cache.move_to_end(key)
    if counts is not None:
        counts["cached" if hit is not None else "read"] = counts.get("cached" if hit is not None else "read", 0) + 1
    if hit is not None:
        return hit
    image = _read(path, H, size)
    image.setflags(write=False)
    _remember(key, image)
    return image


def depth_view_task(task: dict[str, Any]) -> dict[str, Any]:
    """Compute and store one view's maps (``task``: see :func:`estimate_depth`); returns its record."""
    import cv2

    cv2.setNumThreads(1)
    t_cpu = time.process_time()
    counts: dict[str, int] = {}
    ref, colour = _read_reference(task["reference"], task["homography"], task["size"], counts)
    measured, offsets_record = _measured_neighbours(task)
    nbs = [dense.Neighbour(_read_cached(p, task["homography"], task["size"], counts), dx, dy)
           for p, dx, dy in measured]
    res = dense.light_field_disparity(ref, nbs, *task["d_range"], window_px=task["settings"]["window_px"],
                                      step_px=task["settings"]["step_px"], colour=colour)
    out = {k: Path(v) for k, v in task["out"].items()}
    for kind, data in (("disparity", res.disparity_px), ("confidence", res.confidence)):
        out[kind].parent.mkdir(parents=True, exist_ok=True)
        atomic_write_with(out[kind], lambda tmp, d=data: write_pfm(tmp, d))
    finite = np.isfinite(res.disparity_px)
    record = {"key": task["key"], "view": task["view"], "settings": task["settings"], "source": task["source"],
              "size_px": list(task["size"]), "d_range_px": list(task["d_range"]), "candidates": res.candidates,
              "d_range_source": task.get("range_source"), "d_range_found_px": task.get("range_found"),
              "neighbours": task["neighbour_views"],
              "offsets_measured": offsets_record,
              "images_read": counts.get("read", 0), "images_cached": counts.get("cached", 0),
              "valid_fraction": float(finite.mean()),
              "confident_fraction": float((res.confidence > 0.1).mean()),
              "disparity_px": {"p2": float(np.percentile(res.disparity_px[finite], 2)) if finite.any() else None,
                               "p98": float(np.percentile(res.disparity_px[finite], 98)) if finite.any() else None},
              "cpu_s": time.process_time() - t_cpu, "computed_at": now_iso()}
    out["records"].parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out["records"], json.dumps(record) + "\n")
    return record


def _key(settings: DepthSettings, geometry: Geometry, paths: Sequence[str], offsets: dict | None = None) -> str:
    h = hashlib.sha256(json.dumps([settings.describe(), geometry.source, geometry.homography,
                                   list(geometry.d_range_px)] + ([offsets] if offsets else []),
                                  sort_keys=True).encode())
    for p in paths:
        st = os.stat(p)
        h.update(f"{Path(p).name}:{st.st_size}:{st.st_mtime_ns};".encode())
    return h.hexdigest()[:24]


def plan_tasks(ds: Dataset, views: Sequence[View], settings: DepthSettings, source: str = "auto",
               disparity_range_px: tuple[float, float] | None = None) -> tuple[Geometry, list[dict[str, Any]]]:
    """The geometry and one task per view (nothing computed)."""
    captured = set(ds.captured_views())
    recorded = _recorded_positions(ds)
    nb = {v: neighbours_of(ds, v, settings, captured, recorded or {}) for v in views}
    lonely = [v for v in views if not nb[v]]
    if lonely:
        raise InputError("views", f"{view_stem(*lonely[0])} has no captured neighbour in its row or column",
                         "views of a grid with at least two captured views in a row or a column")
    needed = sorted(set(views) | {n for v in views for n, _, _ in nb[v]})
    geo = geometry_of(ds, views, needed, source, disparity_range_px)
    offsets = offset_measurement(ds, geo)
    path = (lambda v: str(_processed_path(ds, v))) if geo.source == "processed" else \
        (lambda v: str(ds.path_of(ds.view(*v))))
    tasks = []
    for v in views:
        ref = path(v)
        nbp = [(path(n), dx, dy) for n, dx, dy in nb[v]]
        tasks.append({"view": [int(v[0]), int(v[1])], "reference": ref, "neighbours": nbp,
                      "neighbour_views": [[int(n[0]), int(n[1]), dx, dy] for n, dx, dy in nb[v]],
                      "homography": geo.homography, "size": list(geo.size_px), "d_range": list(geo.d_range_px),
                      "range_source": geo.range_source, "range_found": list(geo.range_found_px),
                      "settings": settings.describe(), "source": geo.source, "offsets": offsets,
                      "key": _key(settings, geo, [ref] + [p for p, _, _ in nbp], offsets),
                      "out": {k: str(map_path(ds.root, k, v)) for k in ("disparity", "confidence", "records")}})
    return geo, tasks


def offset_measurement(ds: Dataset, geo: Geometry) -> dict[str, Any] | None:
    """How the workers measure the neighbours' offsets from the images (:mod:`lfstudio.depth.positions`):
    the prior's standard deviation (the rig's repeatability, in spacings) and where the features are
    cached; None where the rig's offsets are good enough (:func:`positions.worth_measuring`) or exact
    (an HCI folder: rendered where its format states)."""
    from lfstudio.calibration.calibrate import position_sigma_um

    sx = float(ds.grid.step_mm[0])
    if sx <= 0 or (ds.manifest.get("import") or {}).get("hci"):
        return None
    sigma = positions.prior_sigma_spacings(position_sigma_um(ds), sx)
    if not positions.worth_measuring(sigma):
        return None
    return {"prior_sigma": list(sigma), "feature_cache": str(ds.root) if geo.source == "raw" else None}


#: SIFT features (rectified keypoints, descriptors) a worker keeps for its next views: path -> ...
FEATURE_CACHE_VIEWS = 256
_feature_cache: OrderedDict[tuple, tuple[np.ndarray, np.ndarray]] = OrderedDict()


def _features(path: str, H, cache_root: str | None) -> tuple[np.ndarray, np.ndarray]:
    """(rectified keypoints, descriptors) of a view: the dataset's feature cache for captured views
    (``cache/features``, shared with calibration), this process's memory for the next views."""
    from lfstudio.calibration.features import FeatureCache, detect
    from lfstudio.calibration.model import apply_homography

    key = _cache_key(path, H, (0, 0))
    with _image_cache_lock:
        hit = _feature_cache.get(key)
        if hit is not None:
            _feature_cache.move_to_end(key)
            return hit
    if cache_root is not None:
        feats, _ = FeatureCache(cache_root).get(Path(path).stem, path)
    else:
        feats = detect(path)
    xy = feats.xy.astype(np.float64)
    if H is not None and len(xy):
        xy = apply_homography(np.asarray(H, float), xy)
    out = (xy, feats.descriptors)
    with _image_cache_lock:
        _feature_cache[key] = out
        while len(_feature_cache) > FEATURE_CACHE_VIEWS:
            _feature_cache.popitem(last=False)
    return out


def _measured_neighbours(task: dict[str, Any]) -> tuple[list[tuple[str, float, float]], dict[str, Any] | None]:
    """The task's neighbours with their offsets measured from the images (:func:`offset_measurement`),
    and what was measured for the record; as they are when the task measures nothing."""
    spec = task.get("offsets")
    nbs = [(p, float(dx), float(dy)) for p, dx, dy in task["neighbours"]]
    if not spec:
        return nbs, None
    H, root = task["homography"], spec.get("feature_cache")
    ref_xy, ref_desc = _features(task["reference"], H, root)
    feats = [_features(p, H, root) for p, _, _ in nbs]
    prior = np.array([(dx, dy) for _, dx, dy in nbs], float)
    m = positions.measure_offsets(ref_xy, ref_desc, feats, prior, spec["prior_sigma"])
    return [(p, float(o[0]), float(o[1])) for (p, _, _), o in zip(nbs, m.offsets)], m.describe(prior)


def _up_to_date(task: dict[str, Any]) -> bool:
    rec = Path(task["out"]["records"])
    if not (rec.is_file() and all(Path(task["out"][k]).is_file() for k in ("disparity", "confidence"))):
        return False
    try:
        return json.loads(rec.read_text(encoding="utf-8")).get("key") == task["key"]
    except (OSError, ValueError):
        return False


def estimate_depth(dataset, views: str | Sequence[tuple[int, int]] | None = None, *,
                   settings: DepthSettings | None = None, source: str = "auto",
                   disparity_range_px: tuple[float, float] | None = None,
                   executor: cf.Executor | None = None, workers: int = 1, force: bool = False,
                   progress: Progress = no_progress, cancel: CancelToken | None = None) -> DepthReport:
    """Compute the chosen views' maps (module docstring); ``executor``: where the views run (a
    bounded window of ``2 · workers`` tasks at a time), None: here, one after the other;
    ``disparity_range_px``: the range to search (px between horizontal neighbours), None: from the
    best source there is (:func:`disparity_range`; the report says which). Raises
    :class:`lfstudio.jobs.Cancelled` (views finished so far are kept: the next run resumes)."""
    t0 = time.monotonic()
    cancel = cancel or CancelToken()
    settings = settings or DepthSettings()
    ds = Dataset.of(dataset)
    chosen = ds.select(views)
    geo, tasks = plan_tasks(ds, chosen, settings, source, disparity_range_px)
    report = DepthReport(source=geo.source + (" (rectified)" if geo.rectified else ""), warnings=list(geo.warnings),
                         range_text=geo.describe_range())
    todo = [t for t in tasks if force or not _up_to_date(t)]
    report.skipped = len(tasks) - len(todo)
    total = len(tasks)
    done = report.skipped
    progress(done, total, f"depth: {len(todo)} to compute, {report.skipped} up to date")
    log.info("depth of %s started: %d views to compute, %d up to date (%s); %s", ds.root, len(todo), report.skipped,
             report.source, report.range_text)

    def finish(task, record: dict[str, Any] | None = None, error: str | None = None) -> None:
        nonlocal done
        done += 1
        name = view_stem(*task["view"])
        if error is not None:
            report.failed[name] = error
            log.warning("depth of %s failed: %s", name, error)
        else:
            assert record is not None           # given a record or an error
            report.computed += 1
            report.cpu_s += float(record.get("cpu_s") or 0.0)
        progress(done, total, f"depth {name}")

    if executor is None:
        for task in todo:
            cancel.check()
            try:
                finish(task, depth_view_task(task))
            except (DatasetError, OSError, ValueError) as exc:
                finish(task, error=str(exc))
    else:
        window = max(2, 2 * int(workers))
        queue = list(todo)
        pending: dict[cf.Future, dict] = {}
        try:
            while queue or pending:
                while queue and len(pending) < window and not cancel.cancelled:
                    task = queue.pop(0)
                    pending[executor.submit(depth_view_task, task)] = task
                if cancel.cancelled:
                    raise Cancelled()
                finished, _ = cf.wait(list(pending), timeout=0.25, return_when=cf.FIRST_COMPLETED)
                for fut in finished:
                    task = pending.pop(fut)
                    try:
                        finish(task, fut.result())
                    except cf.CancelledError:
                        continue
                    except Exception as exc:  # noqa: BLE001 - a worker's failure names the view, the run goes on
                        finish(task, error=f"{type(exc).__name__}: {exc}")
        finally:
            for fut in pending:
                fut.cancel()
    report.seconds = time.monotonic() - t0
    log.info("depth of %s finished: %s", ds.root, report.summary())
    return report
