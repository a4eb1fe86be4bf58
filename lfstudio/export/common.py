"""What every export format shares: ordering views (chosen by :meth:`lfstudio.dataset.Dataset.select`),
describing the light field (grid, positions, calibration, intrinsics), and the atomic output
(a temporary sibling ``.NAME.partial-XXXX`` renamed into place at the end)."""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Generator, Iterator, Literal, Sequence

import cv2
import numpy as np

from lfstudio.dataset import Dataset, images
from lfstudio.dataset.grid import View
from lfstudio.dataset.manifest import ViewRecord, hdr_merged, now_iso
from lfstudio.dataset.paths import (DATASET_ENTRIES, IN_USE_FIX, check_new_dataset_folder, check_not_in_use,
                                    view_stem)
from lfstudio.errors import DatasetError, InputError, LfError, words
from lfstudio.support.locks import DATASET_LOCK_NAME, Lock, dataset_lock

EXPORT_FORMAT = "lfstudio-export"
EXPORT_VERSION = 1
PARTIAL_MARK = ".partial-"


# -- views ------------------------------------------------------------------------------------------
def meander(views: Sequence[View]) -> list[View]:
    """Meander order: the first chosen row left→right, the next right→left, and so on, so that
    neighbouring frames are neighbouring views (alternation counts the chosen rows, so a sub-array
    starting at an odd grid row still starts left→right)."""
    by_row: dict[int, list[int]] = {}
    for r, c in views:
        by_row.setdefault(r, []).append(c)
    out: list[View] = []
    for i, r in enumerate(sorted(by_row)):
        cols = sorted(by_row[r], reverse=bool(i % 2))
        out += [View(r, c) for c in cols]
    return out


# -- sources ----------------------------------------------------------------------------------------
def _merge_output(ds: Dataset, view: ViewRecord, key: Literal["file", "preview"]) -> Path | None:
    """The file ``key`` (``file`` or ``preview``) of a view's done HDR merge, when it is there."""
    hdr = hdr_merged(view)
    name = None if hdr is None else hdr.get(key)
    if not name:
        return None
    try:
        path = ds.path_of(name)
    except DatasetError:
        return None
    return path if path.is_file() else None


def tonemap_file(ds: Dataset, view: ViewRecord) -> Path | None:
    """The tone-mapped 16-bit picture of a bracketed view's merged radiance (``lfstudio process``)."""
    return _merge_output(ds, view, "preview")


def hdr_file(ds: Dataset, view: ViewRecord) -> Path | None:
    """The merged linear radiance of a bracketed view (OpenEXR or float TIFF, ``lfstudio process``)."""
    return _merge_output(ds, view, "file")


#: the sources an export can show ("hdr": the merged radiance files as they are, float)
SOURCES = "raw, processed, tonemap, hdr or auto"


def resolve_source(ds: Dataset, views: Sequence[View], source: str) -> str:
    source = (source or "auto").lower()
    if source not in ("auto", "raw", "processed", "tonemap", "hdr"):
        raise InputError("source", f"unknown source {source!r}", SOURCES)
    if source == "raw":
        return "raw"
    if source in ("tonemap", "hdr"):
        find = tonemap_file if source == "tonemap" else hdr_file
        missing = [view_stem(*v) for v in views if find(ds, ds.view(*v)) is None]
        if missing:
            shown = ", ".join(missing[:6]) + (f" and {len(missing) - 6} more" if len(missing) > 6 else "")
            raise InputError("source", f"{'tone-mapped ' if source == 'tonemap' else 'merged '}HDR views missing "
                             f"for {shown}", "scan with --bracket and process the dataset ('lfstudio process'), "
                             "or export --source processed (the bracket's reference exposure)")
        if source == "hdr":
            suffixes = {p.suffix for v in views if (p := hdr_file(ds, ds.view(*v))) is not None}   # none missing
            if len(suffixes) > 1:
                raise InputError("source", f"the merged HDR views are in {' and '.join(sorted(suffixes))} files",
                                 "process the dataset again with one --hdr format (lfstudio process --hdr exr --force)")
        return source
    if source == "tonemap":
        missing = [view_stem(*v) for v in views if tonemap_file(ds, ds.view(*v)) is None]
        if missing:
            shown = ", ".join(missing[:6]) + (f" and {len(missing) - 6} more" if len(missing) > 6 else "")
            raise InputError("source", f"tone-mapped HDR views missing for {shown}",
                             "scan with --bracket and process the dataset ('lfstudio process'), or export "
                             "--source processed (the bracket's reference exposure)")
        return "tonemap"
    missing = [view_stem(*v) for v in views if ds.processed_path(ds.view(*v)) is None]
    if source == "processed" and missing:
        shown = ", ".join(missing[:6]) + (f" and {len(missing) - 6} more" if len(missing) > 6 else "")
        raise InputError("source", f"processed views missing for {shown}",
                         "process the dataset first ('lfstudio process'), or export --source raw")
    return "raw" if missing else "processed"


def image_suffix(ds: Dataset, views: Sequence[View], source: str) -> str:
    """The exported images' suffix: the merged radiance files' own (``.exr``, ``.tif``) for ``hdr``,
    else ``.png``."""
    if source == "hdr" and views:
        path = hdr_file(ds, ds.view(*views[0]))
        if path is not None:
            return path.suffix
    return ".png"


def source_path(ds: Dataset, view: View, source: str) -> Path:
    v = ds.view(*view)
    if source == "hdr":
        path = hdr_file(ds, v)
        if path is None:
            raise DatasetError(f"{ds.root}: {view_stem(*view)} has no merged HDR file; process the dataset again")
        return path
    if source == "tonemap":
        path = tonemap_file(ds, v)
        if path is None:
            raise DatasetError(f"{ds.root}: {view_stem(*view)} has no tone-mapped HDR picture; process the dataset again")
        return path
    if source == "processed":
        path = ds.processed_path(v)
        if path is None:
            raise DatasetError(f"{ds.root}: {view_stem(*view)} has no processed file; process the dataset again")
        return path
    path = ds.path_of(v)
    if not path.is_file():
        raise DatasetError(f"{path}: missing (row {view[0]}, column {view[1]}); re-capture the view or leave it out")
    return path


def is_png16_rgb(path: Path) -> bool:
    """A 16-bit truecolour PNG without alpha (what every export writes)."""
    hdr = images.png_header(path)
    return hdr is not None and hdr[2] == 16 and hdr[3] == 2


def debayer_step(ds: Dataset):
    """The dataset's debayer settings (its processing.toml, else the defaults), full size."""
    import dataclasses

    from lfstudio.dataset.profile import Profile

    try:
        step = Profile.for_dataset(ds.root).debayer
    except Exception:   # an unreadable profile must not block an export of raw views
        step = images.DEFAULT_DEBAYER
    return dataclasses.replace(step, half_size=False)


def write_png16(path: Path, rgb: np.ndarray, compression: int = 1) -> None:
    """Write (h, w, 3) uint16 RGB as a 16-bit PNG (not atomic: callers write into a temporary folder)."""
    bgr = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)
    if not cv2.imwrite(str(path), bgr, [cv2.IMWRITE_PNG_COMPRESSION, int(compression)]):
        raise OSError(f"{path}: cannot write the PNG (disk full or folder not writable?)")


def png16_bytes(rgb: np.ndarray, compression: int = 1) -> int:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR),
                           [cv2.IMWRITE_PNG_COMPRESSION, int(compression)])
    if not ok:
        raise OSError("cannot encode a PNG")
    return int(buf.size)


_SRGB_LUT: np.ndarray | None = None


def to_srgb8(rgb16: np.ndarray) -> np.ndarray:
    """Linear 16-bit → 8-bit sRGB through a 65536-entry table."""
    global _SRGB_LUT
    if _SRGB_LUT is None:
        x = np.arange(65536, dtype=np.float64) / 65535.0
        s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
        _SRGB_LUT = np.clip(np.rint(s * 255.0), 0, 255).astype(np.uint8)
    return _SRGB_LUT[rgb16]


def write_png8_srgb(path: Path, rgb16: np.ndarray) -> None:
    """Write (h, w, 3) linear uint16 RGB as an 8-bit sRGB PNG (not atomic, like :func:`write_png16`)."""
    if not cv2.imwrite(str(path), cv2.cvtColor(to_srgb8(rgb16), cv2.COLOR_RGB2BGR)):
        raise OSError(f"{path}: cannot write the PNG (disk full or folder not writable?)")


def write_images(ds: Dataset, views: Sequence[View], source: str, size: Sequence[int], folder: Path,
                 names: dict[View, str], bit_depth: int, progress, cancel, *, label: str = "") -> None:
    """Write every view as ``folder / names[view]``: 16-bit linear RGB PNG (processed 16-bit PNGs
    are copied byte for byte) or 8-bit sRGB PNG; on two threads, in order, ``progress(i, n,
    label + name)`` after each; ``cancel`` checked between views. Every view must be ``size``."""
    debayer = debayer_step(ds) if source == "raw" else None
    n = len(views)

    def write(v: View) -> str:
        src = source_path(ds, v, source)
        dst = folder / names[v]
        if source == "hdr":             # the merged radiance as processing wrote it (float; 1.0 = 0 EV white)
            shutil.copyfile(src, dst)
            return names[v]
        hdr = images.png_header(src) if bit_depth == 16 and source == "processed" else None
        if hdr is not None and hdr[2] == 16 and hdr[3] == 2:          # is_png16_rgb: copied as it is
            if (hdr[0], hdr[1]) != tuple(size):
                raise DatasetError(f"{src}: {hdr[0]} x {hdr[1]} px, the other views are {size[0]} x {size[1]} px; "
                                   "process the dataset again so that every view has the same size")
            shutil.copyfile(src, dst)
            return names[v]
        rgb = images.develop(src, debayer or images.DEFAULT_DEBAYER)
        if (rgb.shape[1], rgb.shape[0]) != tuple(size):
            raise DatasetError(f"{src}: {rgb.shape[1]} x {rgb.shape[0]} px, the other views are "
                               f"{size[0]} x {size[1]} px; export views of one camera setting")
        if bit_depth == 16:
            write_png16(dst, rgb)
        else:
            write_png8_srgb(dst, rgb)
        return names[v]

    with contextlib.closing(ordered_map(write, views, cancel)) as results:   # threads end before cleanup
        for i, name in enumerate(results):
            progress(i + 1, n, f"{label}{name}")


#: PNG size / uncompressed size of natural-scene views: 8-bit sRGB, and 16-bit linear (the low bits
#: are noise; measured on virtual-studio views with a little sensor noise: 0.82; noiseless: 0.6)
PNG8_RATIO = 0.45
PNG16_RATIO = 0.8


def images_bytes_estimate(n: int, size: Sequence[int], bit_depth: int) -> int:
    """Bytes of ``n`` PNG views of ``size`` at ``bit_depth`` (8: sRGB, 16: linear)."""
    per_px = 3 * PNG8_RATIO if int(bit_depth) == 8 else 6 * PNG16_RATIO
    return int(n * int(size[0]) * int(size[1]) * per_px)


def ordered_map(fn, items: Sequence, cancel, workers: int = 2, window: int = 4) -> Generator[Any, None, None]:
    """``fn(item)`` for each item on ``workers`` threads (decoding and PNG compression release the
    GIL), yielded in order; at most ``window`` in flight; ``cancel.check()`` between items (the
    ones in flight finish first, then :class:`Cancelled` propagates)."""
    import concurrent.futures as cf

    items = list(items)
    with cf.ThreadPoolExecutor(max(1, workers)) as pool:
        pending: list = []
        nxt = 0
        try:
            while nxt < len(items) or pending:
                while nxt < len(items) and len(pending) < window:
                    cancel.check()
                    pending.append(pool.submit(fn, items[nxt]))
                    nxt += 1
                yield pending.pop(0).result()
                cancel.check()
        finally:
            for f in pending:
                f.cancel()


# -- description --------------------------------------------------------------------------------------
def intrinsics(ds: Dataset, image_size: tuple[int, int], calibration: dict | None = None,
               rectified: bool = False) -> dict[str, Any]:
    """Pinhole intrinsics of the exported images: square pixels; focal length and principal point
    from ``calibration`` (scaled to these images) when given, else from the camera and lens with the
    principal point at the image centre. Rectified views (H = K0·Rᵀ·K_true⁻¹) have the
    calibration's focal length and the principal point at the image centre."""
    w, h = int(image_size[0]), int(image_size[1])
    cam, lens = ds.camera, ds.lens
    out: dict[str, Any] = {"image_size_px": [w, h], "focal_length_mm": lens.get("focal_length_mm"),
                           "sensor_mm": cam.get("sensor_mm"), "sensor_px": cam.get("sensor_px")}
    try:
        f_px = ds.focal_length_px(w)
    except DatasetError:
        f_px = None
    out["focal_length_px"] = f_px
    sensor_px = cam.get("sensor_px")
    scale = w / float(sensor_px[0]) if sensor_px else 1.0
    pitch = cam.get("pixel_pitch_um")
    if pitch is None and cam.get("sensor_mm") and sensor_px:
        pitch = float(cam["sensor_mm"][0]) / float(sensor_px[0]) * 1000.0
    out["pixel_pitch_um"] = float(pitch) / scale if pitch else None
    out["principal_point_px"] = [(w - 1) / 2.0, (h - 1) / 2.0]
    out["principal_point_from"] = "image centre"
    cal = calibration
    try:
        if cal and cal.get("image_size_px") and cal.get("principal_point_px"):
            # the calibration's K at full resolution, scaled with x_s = s·(x + 0.5) − 0.5 (OpenCV centres)
            sx = w / float(cal["image_size_px"][0])
            sy = h / float(cal["image_size_px"][1])
            cx, cy = (float(v) for v in cal["principal_point_px"])
            if rectified:
                out["principal_point_from"] = "rectified (image centre)"
            else:
                out["principal_point_px"] = [sx * (cx + 0.5) - 0.5, sy * (cy + 0.5) - 0.5]
                out["principal_point_from"] = ("calibration (estimated)" if cal.get("principal_point_estimated")
                                               else "calibration (nominal centre)")
            if cal.get("focal_length_px"):
                out["focal_length_px"] = float(cal["focal_length_px"]) * sx
    except (TypeError, ValueError, IndexError, ZeroDivisionError):
        pass
    return out


def is_rectified(ds: Dataset, source: str) -> bool:
    """The exported views are rectified: processed views of a run that rectified them."""
    if source in ("tonemap", "hdr"):
        return bool((ds.manifest.get("hdr") or {}).get("rectified"))
    return bool(source == "processed" and (ds.manifest.get("processing") or {}).get("rectified"))


def exposure_of(ds: Dataset, source: str) -> dict[str, Any] | None:
    """Which exposure of a bracketed dataset the exported pictures show: the bracket's reference
    frame (raw, processed) or the tone map of the merged radiance (tonemap); None without a bracket."""
    bracket = ds.manifest.get("bracket")
    if not isinstance(bracket, dict):
        return None
    if source == "hdr":
        return {"kind": "merged radiance", "of": "every frame of the bracket", "unit":
                (ds.manifest.get("hdr") or {}).get("weights", {}).get("unit"), "bracket": dict(bracket)}
    if source == "tonemap":
        tone = (ds.manifest.get("hdr") or {}).get("tone_map") or {}
        return {"kind": "tone map", "operator": tone.get("operator"), "key_radiance": tone.get("key_radiance"),
                "of": "the merged linear radiance of every frame of the bracket", "bracket": dict(bracket)}
    ref = bracket.get("reference_frame", 0)
    times = bracket.get("frame_shutter_s") or []
    return {"kind": "one exposure", "frame": ref, "shutter_s": times[ref] if ref < len(times) else None,
            "ev": (bracket.get("ev") or [None] * (ref + 1))[ref] if bracket.get("ev") else None,
            "bracket": dict(bracket)}


def describe(ds: Dataset, views: Sequence[View], source: str, image_size: tuple[int, int],
             files: dict[View, str] | None = None) -> dict[str, Any]:
    """The manifest part every format writes: grid, spacing, positions, calibration, intrinsics."""
    from lfstudio.calibration.model import load_calibration

    calibration = load_calibration(ds)
    grid, rig = ds.grid, ds.manifest.get("rig", {}) or {}
    if grid.origin_mm is None and rig.get("origin_mm") is not None:     # older scans kept it with the rig
        grid = dataclasses.replace(grid, origin_mm=(float(rig["origin_mm"][0]), float(rig["origin_mm"][1])))
    entries = []
    for v in views:
        rec = ds.view(*v)
        e = {"row": v[0], "column": v[1], "commanded_mm": rec.get("commanded_mm"),
             "reported_mm": rec.get("reported_mm"), "captured_at": rec.get("captured_at"),
             "exposure_s": rec.get("exposure_s")}
        if files is not None:
            e["file"] = files[v]
        entries.append(e)
    rectified = is_rectified(ds, source)
    return {"format": EXPORT_FORMAT, "version": EXPORT_VERSION, "created": now_iso(),
            "dataset": {"path": str(ds.root), "created": ds.manifest.get("created")},
            "source": source,
            "rectified": rectified,
            "color": "sRGB-encoded tone map of the merged HDR radiance (16-bit)" if source == "tonemap"
            else hdr_color(ds) if source == "hdr" else "linear RGB (16-bit, 65535 = white)",
            **({"exposure": exposure_of(ds, source)} if exposure_of(ds, source) is not None else {}),
            "grid": grid.to_manifest(), "camera": dict(ds.camera), "lens": dict(ds.lens),
            "plan": dict(ds.manifest.get("plan") or {}),
            "image_size_px": [int(image_size[0]), int(image_size[1])],
            "intrinsics": intrinsics(ds, image_size, calibration, rectified),
            "calibration": calibration,
            "zero_disparity": zero_disparity_of(ds),
            "views": entries}


def hdr_color(ds: Dataset) -> str:
    """What the pixels of an ``hdr`` export are."""
    options = (ds.manifest.get("hdr") or {}).get("options") or {}
    kind = "OpenEXR" if options.get("format", "exr") == "exr" else "TIFF"
    bits = "16-bit half" if options.get("half") else "32-bit"
    return (f"linear RGB radiance, {bits} float {kind} (the HDR merge; 1.0 = just clipping in the bracket's "
            "reference frame, values above 1 are highlights beyond it)")


def zero_disparity_of(ds: Dataset) -> dict[str, Any]:
    """The dataset's zero-disparity record for an export's manifest (parallel when it records none)."""
    from lfstudio.dataset.zero_plane import RECORD, record, zero_plane

    rec = ds.manifest.get(RECORD)
    if isinstance(rec, dict):
        return dict(rec)
    zp = zero_plane(ds)
    return record(zp.shear_px_per_mm, zp.depth_m, zp.source, zp.width_px)


def require_zero_plane(ds: Dataset, what: str) -> None:
    """Refuse an export whose geometry needs the zero plane of views sheared by an unstated amount."""
    from lfstudio.dataset.zero_plane import zero_plane

    zp = zero_plane(ds)
    if not zp.known:
        raise InputError(words("--format", "Format"), f"{what} needs the views' zero-disparity plane, and "
                         f"{ds.root.name}'s views are sheared by an amount nobody stated; import them again with "
                         + words("--zero-disparity-depth-m (or --parallel-views if they are not sheared)",
                                 "Zero disparity set to a depth (or to Parallel views if they are not sheared)")
                         + "; the PNG and HEVC exports need no plane")


# -- atomic output ------------------------------------------------------------------------------------
def check_out(out: Path, overwrite: bool, *, also: Sequence[Path] = ()) -> None:
    """Refuse an existing output (and its companions) unless ``overwrite``; with ``overwrite``, still
    refuse a folder that holds anything but an earlier lfstudio export (:func:`export_folder_problem`):
    the same rule as a new dataset's folder, so ``--overwrite`` never deletes the operator's own files."""
    for p in (out, *also):
        if (p.exists() or p.is_symlink()) and not overwrite:
            raise InputError("out", f"{p} already exists; choose another name or allow overwriting (--overwrite)")
        problem = export_folder_problem(p) if overwrite else None
        if problem:
            raise InputError("out", problem, "a new folder name (the export makes it), an empty folder, "
                                             "or the folder of an earlier export to replace")


#: the files that describe an lfstudio export (PNG; HCI, COLMAP, nerfstudio), each with "format": EXPORT_FORMAT
EXPORT_MANIFEST_NAMES = ("manifest.json", "lfstudio_manifest.json")


def export_folder_problem(out: Path) -> str | None:
    """Why ``--overwrite`` may not replace the existing folder ``out`` (None: not a folder, empty, or
    an earlier lfstudio export, recognised by its manifest's ``"format": "lfstudio-export"``)."""
    if out.is_symlink() or not out.is_dir():
        return None
    entries = sorted(p.name for p in out.iterdir())
    if not entries:
        return None
    for name in EXPORT_MANIFEST_NAMES:
        try:
            with open(out / name, encoding="utf-8") as fh:
                doc = json.loads(fh.read(1 << 22))
        except (OSError, ValueError, RecursionError):
            continue
        if isinstance(doc, dict) and doc.get("format") == EXPORT_FORMAT:
            return None
    shown = ", ".join(entries[:3]) + (f" and {len(entries) - 3} more" if len(entries) > 3 else "")
    kind = "a dataset" if "dataset.json" in entries else "no lfstudio export"
    return (f"{out} holds other files ({shown}) and {kind}: --overwrite replaces only an earlier export, "
            "never a folder of other files")


def check_new_dataset_out(out: Path, overwrite: bool, *, field: str) -> str:
    """An importer's new dataset folder (import-images, import-hevc) under THE rule of every new
    dataset (:func:`lfstudio.dataset.paths.check_new_dataset_folder`): missing or empty; an existing
    dataset only with ``overwrite`` (it is replaced); a folder holding other files never (their
    deletion is not what ``--overwrite`` means). Returns the folder's kind."""
    return check_new_dataset_folder(out, field, add_to_dataset=overwrite, stem="lfstudio-import",
                                    dataset_fix="add --overwrite to replace it, or choose a new folder")


def _is_or_holds(out: Path, path: Path) -> bool:
    out, path = out.absolute().resolve(), path.absolute().resolve()
    return out == path or out in path.parents


def refuse_out_over_inputs(out: Path, inputs: Sequence[Path], what: str, fix: str) -> None:
    """Refuse an ``out`` that is, or holds, one of ``inputs`` (the first: the whole input, e.g. the
    dataset folder): replacing it (``--overwrite``) would delete what is being read (e.g.
    ``export DATASET --out DATASET``). The message names each path once."""
    for i, p in enumerate(inputs):
        if _is_or_holds(out, p):
            if out.absolute().resolve() != p.absolute().resolve():
                where = f"holds {what} ({p})"
            else:     # the same path: name it once
                where = f"is {what}" if i == 0 else f"is part of {what}"
            raise InputError("out", f"{out} {where}; writing there would delete it", fix)


def dataset_entries(ds: Dataset) -> list[Path]:
    """The dataset folder and everything in it lfstudio reads: its own files and folders
    (:data:`lfstudio.dataset.paths.DATASET_ENTRIES`: manifest, journal, calibration, profile, data
    folders), a virtual dataset's ground truth and every view's capture and processed file."""
    root = ds.root
    entries = [root] + [root / name for name in (*DATASET_ENTRIES, "ground_truth.json")]
    for v in ds.views:
        for rel in (v.get("file"), (v.get("processed") or {}).get("file") if isinstance(v.get("processed"), dict)
                    else None):
            if rel:
                entries.append(root / rel)
    return entries


def partial_name(out: Path) -> str:
    """Prefix of the temporary sibling: ``.NAME.partial-PID-`` (the pid lets a later export tell
    the leftovers of a killed export from those of one still running)."""
    return f".{out.name}{PARTIAL_MARK}{os.getpid()}-"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_partials(out: Path) -> list[Path]:
    """Remove temporary siblings of ``out`` left by exports whose process is gone (killed, power
    cut); those of running exports stay. Returns what was removed."""
    removed = []
    prefix = f".{out.name}{PARTIAL_MARK}"
    try:
        siblings = list(out.parent.iterdir())
    except OSError:
        return removed
    for p in siblings:
        if not p.name.startswith(prefix):
            continue
        pid_text = p.name[len(prefix):].split("-", 1)[0]
        if pid_text.isdigit() and int(pid_text) != os.getpid() and not _pid_alive(int(pid_text)):
            _remove(p)
            removed.append(p)
    return removed


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def _hold_dataset_folder(tmp: Path, final: Path) -> Lock | None:
    """The lock of the dataset folder ``final`` that the folder ``tmp`` is to replace or move into,
    held until the rename is done (so no scan starts in it meanwhile); :class:`LockBusy` naming the
    scan when one runs there now (the rule's :func:`lfstudio.dataset.paths.check_not_in_use`, checked
    again at the last moment). None when ``final`` is no dataset's folder (no ``dataset.json`` nor
    ``dataset.lock``)."""
    if not (tmp.is_dir() and final.is_dir() and not final.is_symlink()):
        return None
    if not any((final / name).exists() for name in (DATASET_LOCK_NAME, "dataset.json")):
        return None
    return dataset_lock(final, f"replacing {final}", hint=IN_USE_FIX).acquire()


def _replace(tmp: Path, final: Path, overwrite: bool) -> None:
    lock = _hold_dataset_folder(tmp, final)
    try:
        _replace_unlocked(tmp, final, overwrite, lock)
    finally:
        if lock is not None:
            lock.release()


def _replace_unlocked(tmp: Path, final: Path, overwrite: bool, lock: Lock | None) -> None:
    if not overwrite and tmp.is_dir() and final.is_dir() and not final.is_symlink():
        # an empty folder (a new dataset's, chosen beforehand) takes the new one in one rename; the
        # system refuses the rename if anything is in it now, and nothing in it is replaced. A lock
        # file left by a scan that is gone (now ours) is no file of the folder: it goes first.
        if lock is not None:
            lock.remove()
        try:
            os.replace(tmp, final)
            return
        except OSError as exc:
            if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                raise
            check_not_in_use(final)          # a scan started there meanwhile: name it
            raise InputError("out", f"{final} is not empty (files were put there meanwhile); nothing was "
                             "replaced", "an empty or new folder") from None
    if final.exists() or final.is_symlink():
        if not overwrite:
            raise InputError("out", f"{final} appeared meanwhile; choose another name or allow overwriting")
        if final.is_dir() and not final.is_symlink():
            # move the old folder aside first: the new one takes its name in one rename
            old = Path(tempfile.mkdtemp(prefix=f".{final.name}.old-", dir=final.parent))
            os.replace(final, old / final.name)
            try:
                os.replace(tmp, final)
            except BaseException:
                os.replace(old / final.name, final)   # the rename failed: put the old folder back
                shutil.rmtree(old, ignore_errors=True)
                raise
            shutil.rmtree(old, ignore_errors=True)
            return
        if tmp.is_dir():      # a file (or symlink) where the new folder goes
            final.unlink()
    os.replace(tmp, final)


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _chmod_default(path: Path, folder: bool) -> None:
    """mkdtemp/mkstemp create private (0700/0600) entries; exports get the usual permissions."""
    with contextlib.suppress(OSError):
        os.chmod(path, (0o777 if folder else 0o666) & ~_umask())


@contextlib.contextmanager
def partial_folder(out: Path, overwrite: bool) -> Iterator[Path]:
    """Yield a temporary sibling folder of ``out``; on success it becomes ``out`` (replacing an
    old one when ``overwrite``), on any exception (cancel included) it is removed."""
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_partials(out)
    tmp = Path(tempfile.mkdtemp(prefix=partial_name(out), dir=out.parent))
    _chmod_default(tmp, True)
    try:
        yield tmp
        for p in tmp.iterdir():
            if p.is_file():
                with open(p, "rb") as fh:
                    os.fsync(fh.fileno())
        _replace(tmp, out, overwrite)
        _fsync_dir(out.parent)
    except BaseException as exc:
        _remove(tmp)
        _name_the_destination(exc, tmp, out)
        raise


def _name_the_destination(exc: BaseException, tmp: Path, out: Path) -> None:
    """An operator's error raised while building ``tmp`` names ``out`` instead: the hidden temporary
    folder is gone by the time the message is read, and is no name the operator knows."""
    if not isinstance(exc, LfError):
        return
    exc.args = tuple(a.replace(str(tmp), str(out)) if isinstance(a, str) else a for a in exc.args)
    if exc.window_text:
        exc.window_text = exc.window_text.replace(str(tmp), str(out))


@contextlib.contextmanager
def partial_files(outs: Sequence[Path], overwrite: bool) -> Iterator[list[Path]]:
    """Temporary sibling names for several files written together (e.g. a video and its sidecar);
    renamed into place in order at the end, all removed on any exception."""
    tmps: list[Path] = []
    try:
        for out in outs:
            out.parent.mkdir(parents=True, exist_ok=True)
            remove_stale_partials(out)
            fd, name = tempfile.mkstemp(prefix=partial_name(out), dir=out.parent)
            os.close(fd)
            tmps.append(Path(name))
            _chmod_default(Path(name), False)
        yield tmps
        for t in tmps:
            with open(t, "rb") as fh:
                os.fsync(fh.fileno())
        for t, out in zip(tmps, outs):
            _replace(t, out, overwrite)
        _fsync_dir(outs[0].parent)
    except BaseException:
        for t in tmps:
            _remove(t)
        raise


def folder_bytes(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
