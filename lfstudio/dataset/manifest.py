"""``dataset.json``: the versioned manifest of a dataset folder, and its validation.

Layout of the manifest (JSON; every length in mm unless the key says otherwise)::

    {"format": "lfstudio-dataset", "version": 1, "created": "2026-11-21T22:00:00+00:00",
     "rig": {...}, "camera": {"name": ..., "sensor_px": [w, h], "sensor_mm": [w, h],
     "pixel_pitch_um": ...}, "lens": {"name": ..., "focal_length_mm": ...}, "plan": {...},
     "grid": {"columns": C, "rows": R, "spacing_mm": [h, v], "order": "row-meander"},
     "views": [{"row": r, "column": c, "commanded_mm": [x, y], "reported_mm": [x, y] | null,
                "captured_at": iso8601 | null, "exposure_s": float | null,
                "file": "raw/r00_c000.dng" | null, "sha256": hex | null,
                "status": "pending" | "done" | "failed" | "skipped", ...}, ...],
     "devices": {"rig": {"kind": "grbl" | "sim" | "instant", "profile": ..., "port": ..., "firmware": ...},
                 "camera": {"kind": "sim" | "gphoto2" | "folder" | "instant", "spec": ..., "model": ...,
                            "serial": ...}},
     "device_changes": [{"at": iso8601, "devices": {...}, "differences": [...]}, ...]}

``devices`` (optional; datasets made before it existed lack it) records which rig and camera
captured the dataset; a resume opens them again. When a resume continues with other devices (only
when the operator says so), the change is appended to ``device_changes`` and every view captured
with them carries its own ``devices`` record (a view without one was captured with ``devices``).

Stages add their own top-level keys (``processing``, ``calibration`` summary, ...) and per-view keys;
unknown keys are kept as they are.
"""

from __future__ import annotations

import datetime as _dt
import gc
import itertools
import json
import math
import operator
import os
import re
import threading
from pathlib import Path
from typing import Any, Iterable, Literal, Required, Sequence, TypedDict, Unpack

from lfstudio.dataset.atomic import atomic_write_bytes, is_temporary
from lfstudio.dataset.bracket import Bracket
from lfstudio.dataset.grid import Grid, View
from lfstudio.dataset.paths import (InsideChecker, check_dataset_entries, check_path_name, resolve_inside, view_label,
                                    view_stem)
from lfstudio.dataset.store import JOURNAL_NAME, Journal, read_journal, sha256_file
from lfstudio.errors import DatasetError, DatasetNotFound, InputError, words
from lfstudio.numbers import MAX_GRID_SIDE, Number, non_finite_fields
from lfstudio.support.locks import DATASET_LOCK_NAME, Lock, LockBusy, dataset_lock, holder_of, manifest_lock

FORMAT = "lfstudio-dataset"
VERSION = 1
MANIFEST_NAME = "dataset.json"
#: :meth:`Dataset.checkpoint` rewrites the manifest once the journal is larger than half of it, and
#: never for less than this (an open replays the journal: ~10 us per line)
JOURNAL_MIN_BYTES = 1 << 20
VIEW_STATUSES = ("pending", "done", "failed", "skipped")
#: a view a scan does not take again (unless asked to re-capture it): captured, or skipped by the operator
FINISHED_STATUSES = ("done", "skipped")
_SHA256 = re.compile(r"^[0-9a-f]{64}$")
#: top-level keys every save sets anew (never merged: each writer writes its own)
_VOLATILE = ("views", "modified", "journal_seq")
_MISSING = object()


def _file_signature(path: Path) -> tuple | None:
    """What changes whenever another process writes ``path`` (atomic rename: a new inode)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns


def _apply_journal(views: list[dict[str, Any]], records: list[dict[str, Any]], after_seq: int) -> int:
    """Apply the journal ``records`` after ``after_seq`` to ``views`` (plain dicts); the last seq applied."""
    by_key = {(v.get("row"), v.get("column")): v for v in views if isinstance(v, dict)}
    seq = after_seq
    for rec in records:
        if rec["seq"] <= after_seq:
            continue
        view = by_key.get((rec["row"], rec["column"]))
        if view is None:
            continue
        if "view" in rec:
            view.clear()
            view.update(rec["view"])
        else:
            view.update(rec["set"])
        seq = max(seq, rec["seq"])
    return seq


def now_iso(at_s: float | None = None) -> str:
    """Every timestamp lfstudio writes: UTC, ISO 8601 with milliseconds; now, or the POSIX time ``at_s``."""
    when = _dt.datetime.now(_dt.timezone.utc) if at_s is None else _dt.datetime.fromtimestamp(at_s, _dt.timezone.utc)
    return when.isoformat(timespec="milliseconds")


class FrameRecord(TypedDict, total=False):
    """One frame of a bracketed view (``views[].frames[]``; the scan's store stage writes it)."""

    index: Required[int]
    file: Required[str]                   # dataset-relative, e.g. raw/r00_c000.f1.dng
    sha256: str
    shutter_s: float | None               # the shutter time the scan set for it
    exposure_s: float | None              # what the camera reported
    captured_at: str
    sidecars: list[str]
    camera_settings: dict[str, Any]
    camera_frame: dict[str, Any]


class ProcessedRecord(TypedDict, total=False):
    """A view's processing (``views[].processed``; :mod:`lfstudio.processing.pipeline` writes it,
    ``import-hevc`` of an export of processed views restores it)."""

    status: Required[str]                 # "done" | "failed"
    file: str
    profile_sha256: str
    gain: float
    gain_support: float
    stats: dict[str, Any]
    processed_at: str
    timings_s: dict[str, float]
    error: str
    restored_from_hevc: bool              # import-hevc: the view is a processed view decoded from the video


class HdrClipped(TypedDict):
    """The clipped share of a merge's frames and of its result (``views[].hdr.clipped_fraction``)."""

    frames: list[float]                   # per frame, capture order
    merged: float


class HdrMerged(TypedDict):
    """A bracketed view's HDR merge (``views[].hdr`` when done; :mod:`lfstudio.processing.hdr` writes it)."""

    status: Literal["done"]
    file: str                             # the radiance (OpenEXR / float TIFF), dataset-relative
    preview: str | None                   # its tone-mapped 16-bit PNG
    options_sha256: str
    frames: int
    exposures_s: list[float]
    reference_frame: int
    clipped_fraction: HdrClipped
    noise_floor_fraction: float
    misalignment_px: list[list[float] | None]   # each frame's shift to the reference (None: not measured)
    max_misalignment_px: float | None
    radiance: dict[str, float]            # min, median, max of the merged luminance
    timings_s: dict[str, float]
    merged_at: str


class HdrFailed(TypedDict):
    """A view whose HDR merge failed (``views[].hdr``): why."""

    status: Literal["failed"]
    error: str
    options_sha256: str
    merged_at: str


#: ``views[].hdr``: ``status`` tells which
HdrRecord = HdrMerged | HdrFailed


class RestoredFrom(TypedDict):
    """Where ``import-hevc`` decoded a view from (``views[].restored_from``)."""

    video: str
    frame: int


class ViewFields(TypedDict, total=False):
    """The keys of a view record other than ``row``, ``column`` and ``status`` (see :class:`ViewRecord`)."""

    commanded_mm: list[float] | None
    reported_mm: list[float] | None
    captured_at: str | None
    exposure_s: float | None
    file: str | None                      # dataset-relative
    sha256: str | None
    thumb: str | None
    sidecars: list[str]
    attempts: int
    timings_s: dict[str, float]           # move, settle, camera_wait, expose, transfer, store, period
    frames: list[FrameRecord] | None      # an exposure bracket's frames
    reference_frame: int                  # the frame that is the view's file
    error: str                            # why a view failed (recorded when the operator skips it)
    camera: dict[str, Any]                # the driver's record of the camera and its settings
    camera_settings: dict[str, Any]
    camera_frame: dict[str, Any]          # an array camera's frame: pixel format, bits, timestamps, frame id
    on_card: list[str]                    # --keep-on-card: the shot's files still on the camera's card
    fly: dict[str, Any]                   # a fly scan's frame: recorded_mm, uncertainty_mm, offset_mm, speed
                                          # (or retaken: why the view was taken again standing still)
    devices: dict[str, Any] | None        # the devices that took it, when not the dataset's own
    processed: ProcessedRecord
    hdr: HdrRecord                        # a bracketed view's HDR merge
    source_file: str                      # import-images: the file in the imported folder it came from
    restored_from: RestoredFrom           # import-hevc: the video frame it was decoded from
    note: str                             # import-hevc: why a view is skipped ("not in the HEVC export")


class ViewUpdate(ViewFields, total=False):
    """Fields of a view a stage sets (:meth:`Dataset.record_view`'s keywords, its journal's ``set``).
    ``row`` and ``column`` name the view and are never set (declared so that an update is a partial
    :class:`ViewRecord`: a TypedDict without them could hold them as anything)."""

    row: int
    column: int
    status: str                           # VIEW_STATUSES


class ViewRecord(ViewFields, total=False):
    """One view of ``dataset.json`` (``views[]``), as the stages write it: created pending, then the
    scan's store stage (or an import) records the capture, processing adds ``processed``, the HDR
    merge ``hdr``. Unknown keys a later stage adds are kept (the manifest is read as plain JSON); the
    known ones are these (``tests/scan/test_view_records.py`` checks a scan, processing, the HDR merge
    and the importers write no other)."""

    row: Required[int]
    column: Required[int]
    status: Required[str]                 # VIEW_STATUSES


def is_done(view: ViewRecord) -> bool:
    """A view record that has been captured: status ``done`` and a file (the one test of it)."""
    file = view.get("file")
    return view.get("status") == "done" and isinstance(file, str) and bool(file)


def is_finished(view: ViewRecord) -> bool:
    """A view record a scan does not take again: status in :data:`FINISHED_STATUSES` (the one test of it)."""
    return view.get("status") in FINISHED_STATUSES


def processed_status(view: ViewRecord) -> str | None:
    """A captured view's processing: ``"done"``, ``"failed"`` or None (not processed), from its
    ``processed`` record (:mod:`lfstudio.processing.pipeline` writes it)."""
    record = view.get("processed")
    return record.get("status") if isinstance(record, dict) else None


def processed_file_name(view: ViewRecord) -> str | None:
    """The dataset-relative file of a processed view (status ``done`` with a file), else None (the one
    test of a processed view)."""
    record = view.get("processed")
    file = record.get("file") if isinstance(record, dict) and processed_status(view) == "done" else None
    return file if isinstance(file, str) and file else None


def hdr_merged(view: ViewRecord) -> HdrMerged | None:
    """A bracketed view's done HDR merge record (``views[].hdr`` with status ``done``), else None
    (not merged, or failed; the one test of a merged view)."""
    hdr = view.get("hdr")
    return hdr if isinstance(hdr, dict) and "status" in hdr and hdr["status"] == "done" else None


def file_of(view: ViewRecord) -> str:
    """The dataset-relative file of a captured view (:func:`is_done` says it has one);
    :class:`DatasetError` naming the view when it has none."""
    file = view.get("file")
    if not isinstance(file, str) or not file:
        raise DatasetError(f"{MANIFEST_NAME}: view {view_label(view['row'], view['column'])} has no file; "
                           "capture it first")
    return file


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _is_pair(x: Any) -> bool:
    return isinstance(x, (list, tuple)) and len(x) == 2 and all(_is_number(v) for v in x)


#: camera and lens numbers the stages compute with: (number, how many)
_CAMERA_NUMBERS = {("camera", "sensor_px"): (Number("px", 1, 1_000_000, integer=True), 2),
                   ("camera", "sensor_mm"): (Number("mm", 0, 1000, low_open=True), 2),
                   ("camera", "pixel_pitch_um"): (Number("µm", 0, 1000, low_open=True), 1),
                   ("lens", "focal_length_mm"): (Number("mm", 0, 100_000, low_open=True), 1),
                   ("lens", "focal_length_px"): (Number("px", 0, 1e9, low_open=True), 1)}


def _constant(seen: list[str]) -> Any:
    """A ``json.loads`` hook for ``NaN``/``Infinity``/``-Infinity``: parsed, and noted in ``seen``
    (checking costs nothing when a manifest has none)."""
    def parse(name: str) -> float:
        seen.append(name)
        return float(name.replace("Infinity", "inf"))
    return parse


def camera_problems(manifest: dict) -> list[str]:
    """The camera and lens numbers of ``manifest`` (its ``camera`` and ``lens`` objects; each number
    optional) the stages could not compute with, worded as :func:`validate_manifest` words them: a
    writer checks them before it writes any view."""
    problems = []
    for (obj, key), (number, count) in _CAMERA_NUMBERS.items():    # optional, but numbers when given
        value = manifest.get(obj, {}).get(key) if isinstance(manifest.get(obj), dict) else None
        if value is None:
            continue
        values = [value] if count == 1 else value if isinstance(value, list) and len(value) == count else None
        problem = f"must be {count} numbers" if values is None else \
            next((p for p in map(number.problem, values) if p), None)
        if problem:
            problems.append(f"{MANIFEST_NAME}: {obj}.{key}: {problem} "
                            f"(valid: {number.valid()}{' each' if count > 1 else ''})")
    return problems


def validate_manifest(manifest: Any, root: str | Path | None = None) -> list[str]:
    """Every problem in ``manifest`` as ``"dataset.json: <field>: <what is wrong>"``; empty if valid.

    With ``root``, file names are also checked to stay inside the folder.
    """
    f = MANIFEST_NAME
    if not isinstance(manifest, dict):
        return [f"{f}: top level must be a JSON object"]
    problems: list[str] = []
    if manifest.get("format") != FORMAT:
        problems.append(f"{f}: format: must be {FORMAT!r}, found {manifest.get('format')!r}")
    version = manifest.get("version")
    if not isinstance(version, int) or version < 1:
        problems.append(f"{f}: version: must be a positive integer, found {version!r}")
    elif version > VERSION:
        problems.append(f"{f}: version: {version} is newer than this lfstudio understands ({VERSION}); update lfstudio")
    for key in ("rig", "camera", "lens", "grid"):
        if not isinstance(manifest.get(key), dict):
            problems.append(f"{f}: {key}: missing or not an object")
    for key in ("plan", "processing", "calibration"):           # written by the stages; optional
        if manifest.get(key) is not None and not isinstance(manifest[key], dict):
            problems.append(f"{f}: {key}: must be an object")
    problems += camera_problems(manifest)
    devices = manifest.get("devices")
    if devices is not None and not (isinstance(devices, dict) and all(isinstance(devices.get(k), dict)
                                                                       for k in ("rig", "camera"))):
        problems.append(f"{f}: devices: must be an object with 'rig' and 'camera' objects")
    if not isinstance(manifest.get("device_changes", []), list):
        problems.append(f"{f}: device_changes: must be a list")
    grid_obj = manifest.get("grid")
    grid: dict[str, Any] = grid_obj if isinstance(grid_obj, dict) else {}
    cols, rows = grid.get("columns"), grid.get("rows")
    for name, val in (("grid.columns", cols), ("grid.rows", rows)):
        if isinstance(manifest.get("grid"), dict) and (not isinstance(val, int) or isinstance(val, bool) or val < 1):
            problems.append(f"{f}: {name}: must be a positive integer, found {val!r}")
        elif isinstance(val, int) and val > MAX_GRID_SIDE:
            problems.append(f"{f}: {name}: {val} is more than lfstudio handles (valid: 1 … {MAX_GRID_SIDE})")
    if grid and "spacing_mm" in grid and not _is_pair(grid["spacing_mm"]):
        problems.append(f"{f}: grid.spacing_mm: must be [horizontal, vertical] numbers")
    if grid.get("origin_mm") is not None and not _is_pair(grid["origin_mm"]):   # what Grid.from_manifest reads
        problems.append(f"{f}: grid.origin_mm: must be [x, y] numbers or null")
    if grid.get("order") is not None and not isinstance(grid["order"], str):
        problems.append(f"{f}: grid.order: must be a string or null")
    if grid.get("settle_s") is not None and not (_is_number(grid["settle_s"]) and grid["settle_s"] >= 0):
        problems.append(f"{f}: grid.settle_s: must be a non-negative number or null")
    bracket_frames = None
    if manifest.get("bracket") is not None:
        try:
            bracket_frames = Bracket.from_manifest(manifest["bracket"], f"{f}: bracket").frames
        except InputError as exc:
            problems.append(str(exc))
    views = manifest.get("views")
    if not isinstance(views, list):
        problems.append(f"{f}: views: missing or not a list")
        return problems
    seen: set[tuple[int, int]] = set()
    files: set[str] = set()
    inside = InsideChecker(root) if root is not None else None
    for i, v in enumerate(views):
        where = f"{f}: views[{i}]"
        if not isinstance(v, dict):
            problems.append(f"{where}: must be an object")
            continue
        r, c = v.get("row"), v.get("column")
        if not isinstance(r, int) or not isinstance(c, int) or r < 0 or c < 0:
            problems.append(f"{where}: row/column: must be non-negative integers, found {r!r}/{c!r}")
            continue
        where = f"{f}: views[{i}] (row {r}, column {c})"
        if isinstance(rows, int) and isinstance(cols, int) and (r >= rows or c >= cols):
            problems.append(f"{where}: outside the {cols} x {rows} grid")
        if (r, c) in seen:
            problems.append(f"{where}: appears more than once")
        seen.add((r, c))
        status = v.get("status")
        if status not in VIEW_STATUSES:
            problems.append(f"{where}: status: must be one of {', '.join(VIEW_STATUSES)}, found {status!r}")
        if "commanded_mm" in v and v["commanded_mm"] is not None and not _is_pair(v["commanded_mm"]):
            problems.append(f"{where}: commanded_mm: must be [x, y] in mm")
        if v.get("reported_mm") is not None and not _is_pair(v["reported_mm"]):
            problems.append(f"{where}: reported_mm: must be [x, y] in mm or null")
        file = v.get("file")
        if file is not None:
            if not isinstance(file, str) or not file:
                problems.append(f"{where}: file: must be a relative path string or null")
            else:
                if inside is not None:
                    try:
                        inside.check(file, what="file")
                    except DatasetError as exc:
                        problems.append(f"{where}: file: {exc}")
                if file in files:
                    problems.append(f"{where}: file: {file!r} is used by another view too")
                files.add(file)
        if status == "done" and not file:
            problems.append(f"{where}: file: a view with status 'done' needs a file")
        sha = v.get("sha256")
        if sha is not None and not (isinstance(sha, str) and _SHA256.match(sha)):
            problems.append(f"{where}: sha256: must be 64 lowercase hex digits or null, found {sha!r}")
        if v.get("exposure_s") is not None and not (_is_number(v["exposure_s"]) and v["exposure_s"] >= 0):
            problems.append(f"{where}: exposure_s: must be a non-negative number or null")
        if v.get("captured_at") is not None and not isinstance(v["captured_at"], str):
            problems.append(f"{where}: captured_at: must be an ISO 8601 time string or null")
        if v.get("devices") is not None and not isinstance(v["devices"], dict):
            problems.append(f"{where}: devices: must be an object or null")
        problems += _frame_problems(v, where, bracket_frames, inside)
        thumb = v.get("thumb")
        if thumb is not None and inside is not None:
            try:
                inside.check(thumb, what="thumb")
            except DatasetError as exc:
                problems.append(f"{where}: thumb: {exc}")
        processed = v.get("processed")
        if processed is not None and not isinstance(processed, dict):
            problems.append(f"{where}: processed: must be an object or null")
        elif processed is not None and processed.get("file") is not None and inside is not None:
            try:
                inside.check(processed["file"], what="processed.file")
            except DatasetError as exc:
                problems.append(f"{where}: processed.file: {exc}")
    seq = manifest.get("journal_seq", 0)
    if not isinstance(seq, int) or isinstance(seq, bool) or seq < 0:
        problems.append(f"{f}: journal_seq: must be a non-negative integer, found {seq!r}")
    return problems


def _frame_problems(v: dict, where: str, bracket_frames: int | None, inside: Any) -> list[str]:
    """Problems of a view's exposure-bracket ``frames`` (each {index, file, sha256, exposure_s, ...});
    a done view of a bracketed dataset needs every frame, and its ``file`` is one of them."""
    frames = v.get("frames")
    if frames is None:
        if bracket_frames is not None and v.get("status") == "done":
            return [f"{where}: frames: the dataset is bracketed ({bracket_frames} frames a view) but the view "
                    "lists none; re-capture this view"]
        return []
    if not isinstance(frames, list) or not all(isinstance(fr, dict) for fr in frames):
        return [f"{where}: frames: must be a list of objects"]
    problems = []
    for k, fr in enumerate(frames):
        file = fr.get("file")
        if not isinstance(file, str) or not file:
            problems.append(f"{where}: frames[{k}].file: must be a relative path string")
        elif inside is not None:
            try:
                inside.check(file, what=f"frames[{k}].file")
            except DatasetError as exc:
                problems.append(f"{where}: frames[{k}].file: {exc}")
        sha = fr.get("sha256")
        if sha is not None and not (isinstance(sha, str) and _SHA256.match(sha)):
            problems.append(f"{where}: frames[{k}].sha256: must be 64 lowercase hex digits or null")
        for key in ("exposure_s", "shutter_s"):
            if fr.get(key) is not None and not (_is_number(fr[key]) and fr[key] > 0):
                problems.append(f"{where}: frames[{k}].{key}: must be a positive number or null")
    if v.get("status") == "done":
        if bracket_frames is not None and len(frames) != bracket_frames:
            problems.append(f"{where}: frames: {len(frames)} frame(s), the dataset's bracket has {bracket_frames}; "
                            "re-capture this view")
        if v.get("file") not in [fr.get("file") for fr in frames]:
            problems.append(f"{where}: file: must be one of its frames' files")
    return problems


class ManifestWriter:
    """``dataset.json``'s text: compact JSON (the C encoder; ``indent`` would force the pure-Python
    one, 3x slower), the top-level keys on the first line, then one view per line::

        {"format":"lfstudio-dataset","version":1,...,
        "views":[
        {"row":0,"column":0,...},
        {"row":0,"column":1,...}
        ]}

    A view that is the same object as at the last :meth:`encode` and still equal to what was
    written then keeps its text (one C-level comparison per view); only changed views are encoded
    again. The file read on open is adopted the same way (:meth:`adopt`), so the first save after
    opening encodes only what changed too. (Equality is Python's: a value replaced by an equal one
    of another JSON type, 1 by 1.0 or True, keeps its former spelling until the view changes
    otherwise; readers see an equal value.)
    """

    _VIEWS_LINE = '"views":['
    #: top-level keys every save changes (not a reason to rewrite the file)
    _VOLATILE = ("views", "modified", "journal_seq")

    def __init__(self) -> None:
        self._encoder = json.JSONEncoder(separators=(",", ":"), allow_nan=False)
        self._views: list = []       # the view objects at the last encode...
        self._written: list = []     # ...what the disk holds for each, file or journal (JSON types)...
        self._texts: list = []       # ...and its text in the file (None: the journal has a newer one)
        self._where: dict[int, int] | None = None   # id(view) -> its index in _views
        self._head: dict | None = None              # the top-level keys as last written
        self._adopted: str | None = None

    def adopt(self, text: str) -> None:
        """The manifest's file as it was read: its view lines are reused by the next encode for
        the views still equal to them (a file in another layout is simply encoded anew)."""
        self._adopted = text

    def _take_adopted(self, views: list) -> None:
        text, self._adopted = self._adopted, None
        if not text:
            return
        lines = text.split("\n")
        if len(lines) != len(views) + 4 or lines[1] != self._VIEWS_LINE or lines[-2] != "]}" or lines[-1]:
            return
        written = json.loads(text).get("views")
        if not isinstance(written, list) or len(written) != len(views):
            return
        self._views, self._written, self._where = list(views), written, None
        self._texts = [line[:-1] if line.endswith(",") else line for line in lines[2:-2]]

    def _paired(self, views: list) -> tuple[list, list]:
        """(written, texts) of each of ``views``, paired with the last encode's by identity."""
        if self._adopted is not None:
            self._take_adopted(views)
        if len(self._views) == len(views) and all(map(operator.is_, views, self._views)):
            return list(self._written), list(self._texts)
        where = {id(v): i for i, v in enumerate(self._views)}   # views added, removed or replaced
        pos = [where.get(id(v)) for v in views]
        return [None if i is None else self._written[i] for i in pos], \
            [None if i is None else self._texts[i] for i in pos]

    def encode(self, manifest: dict[str, Any]) -> bytes:
        encode = self._encoder.encode
        views = manifest.get("views")
        head_obj = {k: v for k, v in manifest.items() if k != "views"}
        head = encode(head_obj)
        self._head = json.loads(encode({k: v for k, v in head_obj.items() if k not in self._VOLATILE}))
        if not isinstance(views, list):
            return (head + "\n").encode("utf-8")
        written, texts = self._paired(views)
        n = len(views)
        stale = map(operator.or_, map(operator.ne, views, written), map(operator.not_, texts))
        for i in itertools.compress(range(n), stale):
            texts[i] = encode(views[i])
            written[i] = json.loads(texts[i])
        self._views, self._written, self._texts, self._where = list(views), written, texts, None
        body = ",\n".join(texts)
        sep = "," if head != "{}" else ""
        return f'{head[:-1]}{sep}\n{self._VIEWS_LINE}\n{body}\n]}}\n'.encode("utf-8")

    def changed_views(self, manifest: dict[str, Any]) -> list[ViewRecord] | None:
        """The views that differ from what the disk holds (file or journal), or None when only a
        full write can record the change (top-level keys changed, views added, removed or replaced,
        or nothing written yet)."""
        views = manifest.get("views")
        if self._head is None or not isinstance(views, list):
            return None
        head = {k: v for k, v in manifest.items() if k not in self._VOLATILE}
        if head != self._head:
            return None
        written, _ = self._paired(views)
        if len(self._views) != len(views) or any(w is None for w in written):
            return None
        return [views[i] for i in itertools.compress(range(len(views)), map(operator.ne, views, written))]

    def journaled(self, view: ViewRecord, fields: ViewUpdate | None = None) -> None:
        """``fields`` of ``view`` (all of it when None) are now in the journal: the disk holds them,
        the file's text of the view is stale."""
        if self._adopted is not None:
            return                     # nothing paired yet: the next save compares everything
        if self._where is None:
            self._where = {id(v): i for i, v in enumerate(self._views)}
        i = self._where.get(id(view))
        if i is None or self._views[i] is not view or self._written[i] is None:
            return
        done = json.loads(self._encoder.encode(view if fields is None else fields))
        self._written[i] = done if fields is None else {**self._written[i], **done}
        self._texts[i] = None


class Dataset:
    """A dataset folder on disk. Construct with :meth:`create` or :meth:`open`.

    ``manifest`` is the parsed ``dataset.json`` (plain JSON types); change it, then :meth:`save`.
    """

    def __init__(self, root: str | Path, manifest: dict[str, Any]):
        self.root = Path(root).resolve()
        self.manifest = manifest
        self.journal_problems: list[str] = []   # torn/corrupt journal lines found on open
        self.replayed = 0                       # journal records applied on open (0: clean shutdown)
        self._lock = threading.RLock()
        self._seq = int(manifest.get("journal_seq", 0) or 0)
        self._journal = Journal(self.root / JOURNAL_NAME)
        self._index: dict[tuple[int, int], ViewRecord] = {}
        self._index_of: list | None = None
        self._writer = ManifestWriter()
        self._manifest_bytes = 0                # the size of dataset.json as last written or read
        #: :meth:`checkpoint` rewrites the manifest when the journal is longer than this (None: half
        #: the manifest, at least JOURNAL_MIN_BYTES; 0: at every checkpoint)
        self.journal_limit_bytes: int | None = None
        #: the device record of views captured from now on when they are not the dataset's own
        #: ``devices`` (None: they are); :meth:`record_view` stores it with every view marked done
        self.capture_devices: dict[str, Any] | None = None
        #: the held ``dataset.lock`` that makes this object the journal's owner (a scan's), or None
        self.journal_lock: Lock | None = None
        self._own_lock: Lock | None = None      # held by record_view for one append when no scan owns it
        # what this object last read from or wrote to the disk: the base of the next merge (see save)
        self._base_source: tuple[bytes | str, list] | None = None
        self._base_parsed: tuple[dict, dict] | None = None
        self._disk_signature: tuple | None = None
        self._journal_signature: tuple | None = None
        self._swept = False                     # the manifest's crash leftovers removed (first save)

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def create(cls, root: str | Path, *, camera: dict, lens: dict, grid: dict, rig: dict | None = None,
               plan: dict | None = None, views: Iterable[ViewRecord] | None = None, exist_ok: bool = False,
               **extra: Any) -> "Dataset":
        """Make a new dataset folder with ``raw/`` and ``thumbs/`` and write its manifest.

        Without ``views``, one pending view per grid cell is listed (row-major).
        """
        root = Path(root)
        check_path_name(root, "dataset folder")
        check_dataset_entries(root)
        if (root / MANIFEST_NAME).exists() and not exist_ok:
            raise DatasetError(f"{root}: already holds a dataset ({MANIFEST_NAME} exists); "
                               "open it to resume, or choose another folder")
        root.mkdir(parents=True, exist_ok=True)
        made = []
        for sub in ("raw", "thumbs"):
            if not (root / sub).exists():
                (root / sub).mkdir()
                made.append(root / sub)
        if views is None:
            views = [{"row": r, "column": c, "commanded_mm": None, "reported_mm": None,
                      "captured_at": None, "exposure_s": None, "file": None, "sha256": None,
                      "status": "pending"}
                     for r in range(int(grid["rows"])) for c in range(int(grid["columns"]))]
        manifest = {"format": FORMAT, "version": VERSION, "created": now_iso(),
                    "rig": dict(rig or {}), "camera": dict(camera), "lens": dict(lens),
                    "plan": dict(plan or {}), "grid": dict(grid), **extra, "views": list(views)}
        ds = cls(root, manifest)
        problems = validate_manifest(manifest, ds.root)
        if problems:
            raise DatasetError(f"{root}: cannot create dataset", problems)
        try:
            ds.save()
        except BaseException:          # e.g. a full disk: no half-made dataset keeps the folder from a re-run
            for folder in made:
                try:
                    folder.rmdir()
                except OSError:
                    pass
            raise
        holder = holder_of(root / DATASET_LOCK_NAME)
        if ds._journal.size_bytes() and (holder is None or holder.pid == os.getpid()):
            ds._journal.clear()        # an old dataset's journal does not belong to this new manifest
        return ds

    @classmethod
    def of(cls, dataset_or_root: "Dataset | str | os.PathLike[str]") -> "Dataset":
        """``dataset_or_root`` itself when it is a Dataset, else the dataset opened from that folder."""
        return dataset_or_root if isinstance(dataset_or_root, Dataset) else cls.open(dataset_or_root)

    @staticmethod
    def root_of(dataset_or_root: "Dataset | str | os.PathLike[str]") -> Path:
        """The folder of a Dataset or a folder given as it is (a Path's own ``.root`` is "/")."""
        return dataset_or_root.root if isinstance(dataset_or_root, Dataset) else Path(dataset_or_root)

    @classmethod
    def open(cls, root: str | os.PathLike[str]) -> "Dataset":
        """Read and validate ``root/dataset.json``; raise :class:`DatasetError` listing every problem."""
        root = Path(root)
        path = root / MANIFEST_NAME
        check_path_name(root, "dataset folder")
        if not root.is_dir():
            raise DatasetNotFound(f"{root}: not a folder; choose the dataset folder (the one holding {MANIFEST_NAME})")
        if not path.is_file():
            raise DatasetNotFound(f"{path}: not found; {root} is not an lfstudio dataset "
                                  "(import a folder of images with 'lfstudio import-images')")
        check_dataset_entries(root)
        with manifest_lock(root, shared=True):     # not between another writer's manifest and journal
            signature = _file_signature(path)
            try:
                text = path.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as exc:
                raise DatasetError(f"{path}: cannot be read as JSON ({exc})") from None
            records, journal_problems = read_journal(root / JOURNAL_NAME)
            journal_signature = _file_signature(root / JOURNAL_NAME)
        return cls._from_text(root, path, text, records, journal_problems, signature, journal_signature)

    @classmethod
    def _from_text(cls, root: Path, path: Path, text: str, records: list, journal_problems: list[str],
                   signature: tuple | None, journal_signature: tuple | None) -> "Dataset":
        constants: list[str] = []
        try:
            gc_was_on = gc.isenabled()
            gc.disable()     # parsing makes ~25 objects per view: no collector passes over them meanwhile
            try:
                manifest = json.loads(text, parse_constant=_constant(constants))
            finally:
                if gc_was_on:
                    gc.enable()
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise DatasetError(f"{path}: cannot be read as JSON ({exc})") from None
        except RecursionError:
            raise DatasetError(f"{path}: cannot be read: nested too deeply to be an lfstudio manifest") from None
        if constants:                            # NaN/Infinity: not JSON, and no stage can use them
            fields = non_finite_fields(manifest)
            raise DatasetError(f"{path}: {', '.join(fields[:3])}{' and more' if len(fields) > 3 else ''}: "
                               f"not a finite number (NaN or infinite); correct {'it' if len(fields) == 1 else 'them'}"
                               " in the file")
        problems = validate_manifest(manifest, root)
        if problems:
            raise DatasetError(f"{path}: invalid manifest", problems)
        ds = cls(root, manifest)
        ds._writer.adopt(text)
        ds._manifest_bytes = len(text)
        ds._replay_journal(records, journal_problems)
        ds._base_source = (text, records)
        ds._disk_signature, ds._journal_signature = signature, journal_signature
        problems = validate_manifest(ds.manifest, root) if ds.replayed else []
        if problems:
            raise DatasetError(f"{path}: invalid after replaying {JOURNAL_NAME}", problems)
        return ds

    def _replay_journal(self, records: list, problems: list[str]) -> None:
        self.journal_problems = list(problems)
        base = self._seq
        views: list[dict[str, Any]] = self.manifest["views"]     # as read: JSON objects, replaced whole below
        by_key = {(v["row"], v["column"]): v for v in views}
        for rec in records:
            if rec["seq"] <= base:
                continue   # already folded into the manifest
            view = by_key.get((rec["row"], rec["column"]))
            if view is None:
                self.journal_problems.append(f"{JOURNAL_NAME}: seq {rec['seq']}: no view at row {rec['row']}, "
                                             f"column {rec['column']} in the manifest; ignored")
                continue
            if "view" in rec:          # a whole view, journaled by a checkpoint
                view.clear()
                view.update(rec["view"])
            else:
                view.update(rec["set"])
            self._seq = max(self._seq, rec["seq"])
            self.replayed += 1

    # -- access -----------------------------------------------------------------------------------
    @property
    def manifest_path(self) -> Path:
        return self.root / MANIFEST_NAME

    @property
    def views(self) -> list[ViewRecord]:
        return self.manifest["views"]

    @property
    def grid(self) -> Grid:
        """The typed grid (:class:`lfstudio.dataset.grid.Grid`) of ``dataset.json`` → ``grid``."""
        raw = self.manifest["grid"]
        cached = getattr(self, "_grid", None)
        if cached is None or cached[0] is not raw:
            cached = self._grid = (raw, Grid.from_manifest(raw))
        return cached[1]

    @property
    def positions_recorded(self) -> bool:
        """True when each view's ``reported_mm`` is where it was really taken and the stages use it
        instead of the grid: an import with recorded positions, or a fly scan (``acquisition``)."""
        if (self.manifest.get("import") or {}).get("positions"):
            return True
        return (self.manifest.get("acquisition") or {}).get("positions") == "recorded"

    @property
    def camera(self) -> dict[str, Any]:
        return self.manifest["camera"]

    @property
    def lens(self) -> dict[str, Any]:
        return self.manifest["lens"]

    def view(self, row: int, column: int) -> ViewRecord:
        views = self.views
        if self._index_of is not views or len(self._index) != len(views):
            self._index = {(w["row"], w["column"]): w for w in views}
            self._index_of = views
        v = self._index.get((row, column))
        if v is not None and v.get("row") == row and v.get("column") == column:
            return v
        self._index = {(w["row"], w["column"]): w for w in views}
        try:
            return self._index[(row, column)]
        except KeyError:
            raise KeyError(f"no view at row {row}, column {column}") from None

    def status_counts(self) -> dict[str, int]:
        """Number of views per status (every status listed, zeros included)."""
        counts = {s: 0 for s in VIEW_STATUSES}
        for v in self.views:
            counts[v.get("status", "pending")] = counts.get(v.get("status", "pending"), 0) + 1
        return counts

    def summary(self) -> dict[str, Any]:
        """What ``lfstudio info`` prints: grid, devices, counts per status, size on disk."""
        counts = self.status_counts()
        folder_bytes: dict[str, int] = {}     # the captured views' files by the folder they are in
        for v in self.done_views():
            try:
                size = self.path_of(v).stat().st_size
            except (OSError, DatasetError):
                continue
            parts = Path(v.get("file") or "").parts        # a done view has a file (is_done)
            folder = parts[0] + "/" if len(parts) > 1 else "./"
            folder_bytes[folder] = folder_bytes.get(folder, 0) + size
        grid = self.manifest["grid"]
        return {"path": str(self.root), "format": self.manifest.get("format"), "version": self.manifest.get("version"),
                "created": self.manifest.get("created"), "modified": self.manifest.get("modified"),
                "rig": self.manifest.get("rig", {}).get("name"), "camera": self.camera.get("name"),
                "lens": self.lens.get("name"), "grid": {"columns": grid.get("columns"), "rows": grid.get("rows"),
                                                       "spacing_mm": grid.get("spacing_mm"), "order": grid.get("order")},
                "views": len(self.views), **counts, "missing": counts["pending"],
                "complete": self.finished(),
                "raw_bytes": folder_bytes.get("raw/", 0), "view_file_bytes": folder_bytes,
                "imported_from": (self.manifest.get("imported_from") or {}).get("file"),
                "journal_replayed": self.replayed, "journal_problems": list(self.journal_problems)}

    def verify_files(self, checksums: bool = True) -> list[str]:
        """Problems with the files of done views (every frame of a bracketed one), by file: missing,
        empty, checksum mismatch."""
        problems = []
        entries = []
        for v in self.done_views():
            entries.append(v)
            entries += [{**f, "row": v["row"], "column": v["column"]} for f in (v.get("frames") or ())
                        if isinstance(f, dict) and f.get("file") != v.get("file")]
        for v in entries:
            where = f"{v.get('file')} (row {v['row']}, column {v['column']})"
            try:
                path = self.path_of(v)
            except DatasetError as exc:
                problems.append(f"{where}: {exc}")
                continue
            if not path.is_file():
                problems.append(f"{where}: file is missing; re-capture this view")
                continue
            if path.stat().st_size == 0:
                problems.append(f"{where}: file is empty; re-capture this view")
                continue
            if checksums and v.get("sha256") and sha256_file(path) != v["sha256"]:
                problems.append(f"{where}: sha256 does not match the manifest (file changed or corrupt); "
                                "re-capture this view")
        return problems

    def done_views(self) -> list[ViewRecord]:
        """The captured views' records (:func:`is_done`), in manifest order."""
        return [v for v in self.views if is_done(v)]

    def finished(self) -> bool:
        """Every view is finished (:func:`is_finished`): a scan has nothing left to take."""
        return all(is_finished(v) for v in self.views)

    def captured_views(self) -> list[View]:
        """The captured views (:func:`is_done`) as grid cells, row-major."""
        return sorted(View(int(v["row"]), int(v["column"])) for v in self.done_views())

    def select(self, spec: str | Iterable[Sequence[int]] | None, *, default: str = "all",
               field_name: str = "views") -> list[View]:
        """The captured views a selection chooses (:meth:`lfstudio.dataset.grid.Grid.select`:
        ``"all"``, ``"r0-8,c10-18"``, ``"array:3x2"``, ``"r00_c000,r00_c050"`` or (row, column) pairs),
        row-major; :class:`DatasetError` when nothing is captured yet."""
        captured = self.captured_views()
        if not captured:
            raise DatasetError(f"{self.root}: no captured views yet; scan or import images first")
        return self.grid.select(spec, captured, default=default, field_name=field_name)

    def path_of(self, view_or_relative: ViewRecord | FrameRecord | str) -> Path:
        """Absolute path of a view's (or a frame's) file, or of a relative name, refused if outside the folder."""
        rel = view_or_relative.get("file") if isinstance(view_or_relative, dict) else view_or_relative
        if not rel:
            raise DatasetError(f"{self.manifest_path}: view has no file yet")
        return resolve_inside(self.root, rel)

    def processed_path(self, view: ViewRecord) -> Path | None:
        """The view's processed image when its record names one inside the folder and the file is
        there, else None (not processed, processed with another profile's name gone, or deleted)."""
        name = processed_file_name(view)
        if name is None:
            return None
        try:
            path = self.path_of(name)
        except DatasetError:
            return None
        return path if path.is_file() else None

    def raw_name(self, row: int, column: int, suffix: str) -> str:
        """Relative name for a view's raw file, e.g. ``raw/r07_c042.dng``."""
        return f"raw/{view_stem(row, column)}{suffix}"

    def focal_length_px(self, image_width_px: int | None = None) -> float:
        """Focal length in pixels of an image ``image_width_px`` wide (default: the full sensor)."""
        cam, lens = self.camera, self.lens
        try:
            f_mm = float(lens["focal_length_mm"])
            sensor_w_px = float(cam["sensor_px"][0])
            pitch_mm = float(cam["pixel_pitch_um"]) / 1000.0 if cam.get("pixel_pitch_um") else \
                float(cam["sensor_mm"][0]) / sensor_w_px
        except (KeyError, TypeError, ValueError, IndexError):
            # imported datasets may know only the focal length in pixels of the full-size image
            if lens.get("focal_length_px") and cam.get("sensor_px"):
                scale = 1.0 if image_width_px is None else image_width_px / float(cam["sensor_px"][0])
                return float(lens["focal_length_px"]) * scale
            raise DatasetError(f"{self.manifest_path}: camera.sensor_px, camera.pixel_pitch_um (or sensor_mm) "
                               "and lens.focal_length_mm are needed for the focal length in pixels; "
                               "add them, or give the focal length in pixels ("
                               + words("lfstudio calibrate --focal-length-px F; for imported images: lens.focal_length_px",
                                       "the Calibrate dialog's Focal length, or Focal length (px) when importing")
                               + ")") from None
        scale = 1.0 if image_width_px is None else image_width_px / sensor_w_px
        return f_mm / pitch_mm * scale

    # -- writing ----------------------------------------------------------------------------------
    def owns_journal(self) -> bool:
        """True while this object holds the dataset's ``dataset.lock`` (a scan's): then it alone
        appends to and empties ``journal.jsonl``. Any other writer merges into the manifest only."""
        lock = self.journal_lock or self._own_lock
        return lock is not None and lock.held

    def save(self) -> None:
        """Write the manifest atomically (temporary file, fsync, rename), merged with what other
        processes wrote meanwhile (docs/dataset-format.md, "Two commands at once").

        Under the dataset's short lock (:func:`lfstudio.support.locks.manifest_lock`): when the
        manifest on disk (or, for a writer that does not own the journal, the journal) changed since
        this object last read or wrote it, it is read again and the other writers' changes are
        merged in, field by field (:meth:`_merge_from_disk`): each writer keeps what it changed
        itself and takes what the others changed, so a stage running beside a scan never loses the
        scan's views and the scan never loses the stage's records. The journal's owner (the scan)
        then empties the journal, whose records the written manifest holds.

        Compact JSON, one view per line, by the C encoder; the text of a view that did not change
        since the last save is reused (:class:`ManifestWriter`), so a save costs little more than
        writing the file: < 50 ms at 8241 views (``benchmarks/manifest_save.py``)."""
        with self._lock, manifest_lock(self.root):
            if not self._swept:
                self._sweep_manifest_leftovers()
            owner = self.owns_journal()
            folding = None
            if not owner and self._journal_has_records():
                try:                       # no scan runs: this save may fold the journal in and empty it
                    folding = dataset_lock(self.root, "saving its manifest").acquire()
                except LockBusy:
                    folding = None
            try:
                if self._base_source is not None and self._disk_changed(owner):
                    self._merge_from_disk()
                self.manifest["modified"] = now_iso()
                self.manifest["journal_seq"] = self._seq
                data = self._writer.encode(self.manifest)
                atomic_write_bytes(self.manifest_path, data)
                self._manifest_bytes = len(data)
                self._base_source, self._base_parsed = (data, []), None
                self._disk_signature = _file_signature(self.manifest_path)
                if owner or folding is not None:
                    self._journal.clear()
                self._journal_signature = _file_signature(self._journal.path)
            finally:
                if folding is not None:
                    folding.release()

    def _journal_has_records(self) -> bool:
        try:
            return os.path.getsize(self._journal.path) > 0
        except OSError:
            return False

    def _sweep_manifest_leftovers(self) -> None:
        """Remove the manifest's temporary files a killed writer left (``.dataset.XXXXXXXX.tmp.json``):
        safe under the manifest lock, which every writer of the manifest holds while its own exists."""
        self._swept = True
        try:
            names = [n for n in os.listdir(self.root) if n.startswith(".dataset.") and is_temporary(n)]
        except OSError:
            return
        for name in names:
            try:
                os.unlink(self.root / name)
            except OSError:
                pass

    def _disk_changed(self, owner: bool) -> bool:
        if _file_signature(self.manifest_path) != self._disk_signature:
            return True
        return not owner and _file_signature(self._journal.path) != self._journal_signature

    def _base(self) -> tuple[dict, dict]:
        """(top-level keys, views by (row, column)) as this object last read or wrote them."""
        if self._base_parsed is None:
            assert self._base_source is not None, "a merge needs what was read or written last"   # save() checks
            text, records = self._base_source
            base = json.loads(text)
            views = base.get("views") if isinstance(base.get("views"), list) else []
            _apply_journal(views, records, int(base.get("journal_seq", 0) or 0))
            head = {k: v for k, v in base.items() if k not in _VOLATILE}
            self._base_parsed = (head, {(v.get("row"), v.get("column")): v for v in views if isinstance(v, dict)})
        return self._base_parsed

    def _merge_from_disk(self) -> None:
        """Take into this manifest what other processes changed since this object's base: a
        top-level key or a view's field that differs between the disk (manifest + journal) and the
        base, and that this object did not change itself. Views keep their objects (a scan holds them)."""
        path = self.manifest_path
        try:
            text = path.read_text(encoding="utf-8")
            disk = json.loads(text)
        except FileNotFoundError:
            return                       # removed meanwhile: ours is all there is
        except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
            raise DatasetError(f"{path}: changed by another program into something unreadable ({exc}); "
                               "nothing was written over it: look at it, then run the command again") from None
        disk_views = disk.get("views") if isinstance(disk, dict) else None
        if not isinstance(disk_views, list):
            raise DatasetError(f"{path}: changed by another program into something that is no dataset; "
                               "nothing was written over it: look at it, then run the command again")
        records, _ = read_journal(self._journal.path)
        disk_seq = _apply_journal(disk_views, records, int(disk.get("journal_seq", 0) or 0))
        base_head, base_views = self._base()
        ours = self.manifest
        for key in set(disk) | set(base_head) | set(ours):
            if key in _VOLATILE:
                continue
            if ours.get(key, _MISSING) != base_head.get(key, _MISSING):
                continue                  # we changed it: ours is newer
            if key in disk:
                ours[key] = disk[key]
            else:
                ours.pop(key, None)
        our_views = {(v["row"], v["column"]): v for v in ours["views"]}
        for dv in disk_views:
            if not isinstance(dv, dict):
                continue
            key = (dv.get("row"), dv.get("column"))
            bv = base_views.get(key, {})
            ov = our_views.get(key)
            if ov is None:
                if key not in base_views:          # added by another writer
                    ours["views"].append(dv)
                continue
            if dv == bv:
                continue                            # nobody else changed this view
            for field in set(dv) | set(bv):
                theirs = dv.get(field, _MISSING)
                if theirs == bv.get(field, _MISSING) or ov.get(field, _MISSING) != bv.get(field, _MISSING):
                    continue                        # not changed by them, or changed by us too (ours wins)
                if theirs is _MISSING:
                    ov.pop(field, None)
                else:
                    ov[field] = theirs
        self._seq = max(self._seq, disk_seq)

    def checkpoint(self) -> None:
        """Make every change so far durable, cheaply. The journal's owner (a scan): views that
        changed since the last save or checkpoint (beyond what :meth:`record_view` journaled) are
        appended whole to the journal (one write, one fsync); the manifest itself is rewritten
        (:meth:`save`) only when a top-level key changed, views were added or removed, or the
        journal has grown past half the manifest (at least :data:`JOURNAL_MIN_BYTES`), which bounds
        what an open replays: the rewrites cost the same per view at any grid size. Any other
        writer (processing beside a scan) saves, merged, when something changed.

        What a scan calls every few seconds: at 8241 views it costs the comparison of the views
        with what was written (a few ms of CPU) instead of rewriting 3.6 MB
        (``benchmarks/manifest_save.py``)."""
        with self._lock:
            changed = self._writer.changed_views(self.manifest)
            if not self.owns_journal():
                if changed is None or changed:
                    self.save()
                return
            limit = self.journal_limit_bytes
            if limit is None:
                limit = max(JOURNAL_MIN_BYTES, self._manifest_bytes // 2)
            if changed is None or self._journal.size_bytes() > limit:
                self.save()
                return
            if not changed:
                return
            records = []
            for view in changed:
                self._seq += 1
                records.append({"seq": self._seq, "row": view["row"], "column": view["column"], "view": view})
            self._journal.append_many(records)
            for view in changed:
                self._writer.journaled(view)

    def record_view(self, row: int, column: int, /, **fields: Unpack[ViewUpdate]) -> ViewRecord:
        """Update a view and append the change to the fsync'd journal (durable when this returns).

        Cheap (one short line and an fsync); call :meth:`save` now and then to fold the journal in.
        Only the journal's owner appends: without ``journal_lock`` this takes the dataset's lock for
        the append, and is refused (:class:`LockBusy` naming the holder) while a scan holds it.
        """
        if "row" in fields or "column" in fields:
            raise ValueError("record_view: row and column name the view; they are not fields to set")
        with self._lock:
            if self.owns_journal():
                return self._append_view(row, column, fields)
            with dataset_lock(self.root, "writing its journal") as lock:
                self._own_lock = lock
                try:
                    if self._base_source is not None and self._disk_changed(False):
                        self.save()        # what others wrote meanwhile merged first, the journal folded
                    return self._append_view(row, column, fields)
                finally:
                    self._own_lock = None

    def _append_view(self, row: int, column: int, fields: ViewUpdate) -> ViewRecord:
        view = self.view(row, column)
        if fields.get("status") == "done" and "devices" not in fields and (
                self.capture_devices is not None or view.get("devices") is not None):
            fields = fields.copy()
            fields["devices"] = self.capture_devices
        self._seq += 1
        self._journal.append({"seq": self._seq, "row": row, "column": column, "set": fields})
        view.update(fields)
        self._writer.journaled(view, fields)
        self._journal_signature = _file_signature(self._journal.path)
        return view

    def close(self) -> None:
        with self._lock:
            self._journal.close()
