"""HEVC export through PyAV (its wheels bundle FFmpeg with libx265) and the import back.

One stream, views in meander order, 4:4:4 at 10 or 12 bits, CRF 8 by default. RGB → Y'CbCr with
the BT.709 matrix at full range (the 12-bit code values keep ~12 bits of the 16-bit RGB);
``psy-rd=0``/``psy-rdoq=0`` because x265's psycho-visual tuning trades fidelity for "texture"
(and halves chroma quality at 4:4:4): we want the frames back as close as possible. Frame sizes
must be even for x265: odd sizes are padded by repeating the last column/row (recorded in the
sidecar, removed on import). The sidecar ``FILE.json`` (e.g. ``scene.mp4.json``) maps frame index
→ (row, column) and carries grid, spacing, positions, calibration and intrinsics.
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import math
import os
import time
from fractions import Fraction
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from lfstudio.dataset import Dataset, images
from lfstudio.dataset.grid import Grid
from lfstudio.dataset.manifest import ViewRecord, now_iso
from lfstudio.dataset.paths import view_stem
from lfstudio.dataset.storage import STORAGE_ERRNOS, storage_error
from lfstudio.dataset.store import sha256_file
from lfstudio.errors import DatasetError, InputError
from lfstudio.export import common
from lfstudio.jobs import CancelToken, Progress

CONTAINERS = {".mp4": "mp4", ".mkv": "matroska", ".mov": "mov", ".hevc": "hevc"}
FRAME_RATE = 25
COLORSPACE = "ITU709"
COLOR_RANGE = "JPEG"          # full range
X265_PARAMS = "psy-rd=0:psy-rdoq=0:log-level=error"
X265_PRESET = "medium"
#: streams this short are encoded without B-frames: x265 derives the first frames' DTS from a
#: reorder history that a stream shorter than its B-frame delay never fills, and FFmpeg then
#: refuses the garbage DTS ("pts (0) < dts (1024...)", EINVAL) now and then
SHORT_STREAM_FRAMES = 16
VERIFY_FRAMES = 8             # PSNR is measured on up to this many frames, spread over the stream
PNG_SAMPLES = 4               # frames encoded as PNG to estimate the 16-bit PNG size (raw sources)
#: HEVC bytes per frame pixel at CRF 8, 12-bit 4:4:4 (measured on virtual-studio views; each +6 CRF
#: roughly halves it): 0.089 at 2000 px with sensor noise 0.002 (benchmarks/export_hevc.py)
BYTES_PER_PX_CRF8 = 0.1


def sidecar_path(video: Path) -> Path:
    return Path(video).with_name(Path(video).name + ".json")


MIN_FRAME_PX = 16             # x265 refuses smaller frames


def even_size(size: Sequence[int]) -> tuple[tuple[int, int], tuple[int, int]]:
    """((width, height) x265 accepts: even and at least 16 px, (pad right, pad bottom))."""
    w, h = int(size[0]), int(size[1])
    fw, fh = max(w + w % 2, MIN_FRAME_PX), max(h + h % 2, MIN_FRAME_PX)
    return (fw, fh), (fw - w, fh - h)


def estimate_bytes(frames: int, frame_size: Sequence[int], crf: int, bit_depth: int) -> int:
    px = int(frame_size[0]) * int(frame_size[1])
    per_px = BYTES_PER_PX_CRF8 * 2.0 ** (-(int(crf) - 8) / 6.0) * (0.85 if bit_depth == 10 else 1.0)
    return int(frames * px * per_px) + 4096


def pix_fmt(bit_depth: int) -> str:
    return "yuv444p12le" if int(bit_depth) == 12 else "yuv444p10le"


def psnr_db(mse: float, peak: float = 65535.0) -> float:
    return math.inf if mse <= 0 else 10.0 * math.log10(peak * peak / mse)


def _spread(n: int, k: int) -> list[int]:
    if n <= 0:
        return []
    if n <= k:
        return list(range(n))
    return sorted({round(i * (n - 1) / (k - 1)) for i in range(k)})


def export_hevc(ds: Dataset, views: Sequence[common.View], source: str, size: tuple[int, int], out: Path,
                options, progress: Progress, cancel: CancelToken) -> dict[str, Any]:
    """Encode ``views`` (already in meander order) into ``out`` + sidecar; returns the figures."""
    import av
    import av.error

    _ffmpeg_errors_in_exceptions()
    n = len(views)
    x265_params = X265_PARAMS + (":bframes=0" if n <= SHORT_STREAM_FRAMES else "")
    frame_size, pad = even_size(size)
    fmt = pix_fmt(options.bit_depth)
    container_fmt = CONTAINERS[out.suffix.lower()]
    debayer = common.debayer_step(ds) if source == "raw" else None
    verify_idx = set(_spread(n, VERIFY_FRAMES))
    png_idx = set(_spread(n, PNG_SAMPLES))
    png_sample_bytes: list[int] = []
    known_png = source == "processed" and all(common.is_png16_rgb(common.source_path(ds, v, source)) for v in views)
    png_bytes = sum(common.source_path(ds, v, source).stat().st_size for v in views) if known_png else None
    sidecar = sidecar_path(out)
    steps = n + len(verify_idx)

    def load(v: common.View) -> np.ndarray:
        rgb = images.develop(common.source_path(ds, v, source), debayer or images.DEFAULT_DEBAYER)
        if (rgb.shape[1], rgb.shape[0]) != tuple(size):
            raise DatasetError(f"{view_stem(*v)}: {rgb.shape[1]} x {rgb.shape[0]} px, the other views are "
                               f"{size[0]} x {size[1]} px; export views of one camera setting")
        return rgb

    def load_for_encode(i: int) -> tuple[np.ndarray, int | None]:
        rgb = load(views[i])   # the PNG size sample is taken here, on the reader thread, beside x265
        return rgb, (common.png16_bytes(rgb) if i in png_idx and png_bytes is None else None)

    progress(0, steps, "encoding HEVC")
    t0 = time.monotonic()
    with common.partial_files([out, sidecar], options.overwrite) as (tmp_video, tmp_sidecar):
        container = av.open(str(tmp_video), "w", format=container_fmt)
        try:
            stream = container.add_stream("libx265", rate=FRAME_RATE)
            time_base = Fraction(1, FRAME_RATE)
            stream.width, stream.height = frame_size
            stream.pix_fmt = fmt
            stream.options = {"crf": str(int(options.crf)), "preset": X265_PRESET, "x265-params": x265_params}
            cc = stream.codec_context
            cc.color_range = 2      # AVCOL_RANGE_JPEG (full)
            cc.colorspace = 1       # AVCOL_SPC_BT709
            cc.color_primaries = 1
            cc.color_trc = 8        # AVCOL_TRC_LINEAR: the samples are linear light
            with cf.ThreadPoolExecutor(1) as reader:   # read/decode the next view while x265 encodes
                ahead = [reader.submit(load_for_encode, 0)] if n else []   # one view ahead: 250 MB at full size
                for i, v in enumerate(views):
                    cancel.check()
                    rgb, sample = ahead.pop(0).result()
                    if i + 1 < n:
                        ahead.append(reader.submit(load_for_encode, i + 1))
                    if sample is not None:
                        png_sample_bytes.append(sample)
                    if pad != (0, 0):
                        rgb = np.pad(rgb, ((0, pad[1]), (0, pad[0]), (0, 0)), mode="edge")
                    frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb48le")
                    frame = frame.reformat(format=fmt, dst_colorspace=COLORSPACE, dst_color_range=COLOR_RANGE)
                    frame.pts = i
                    frame.time_base = time_base
                    for packet in stream.encode(frame):
                        container.mux(packet)
                    progress(i + 1, steps, f"frame {i + 1}/{n} {view_stem(*v)}")
                cancel.check()
                for packet in stream.encode():
                    container.mux(packet)
        except av.error.FFmpegError as exc:
            errno_ = getattr(exc, "errno", None)
            if isinstance(errno_, int) and errno_ in STORAGE_ERRNOS:   # the disk, not the encoder (no --crf advice)
                raise storage_error(OSError(errno_, os.strerror(errno_)), out, doing="writing",
                                    then="export again") or exc from None
            raise DatasetError(f"{out.name}: the HEVC encoder failed on {frame_size[0]} x {frame_size[1]} px "
                               f"{fmt} frames ({exc}); check the disk space and the options (--crf, --bit-depth)") \
                from None
        finally:
            container.close()
        video_bytes = tmp_video.stat().st_size
        t_encoded = time.monotonic()

        # verify: decode frames spread over the stream and compare them with their views read again
        # (not kept from the encode: a full-size 16-bit frame is 250 MB)
        mses = []
        last = max(verify_idx) if verify_idx else -1
        done = n
        todo = set(verify_idx)
        for i, rgb in _decode(tmp_video, size, upto=last, cancel=cancel, want=set(verify_idx)):
            if i in todo:
                src = load(views[i])
                d = rgb.astype(np.float32) - src.astype(np.float32)
                mses.append(float(np.mean(np.square(d), dtype=np.float64)))
                todo.discard(i)
                done += 1
                progress(done, steps, f"verified frame {i}")
        if todo:
            raise DatasetError(f"{out.name}: frame {min(todo)} does not decode back; the encoder failed (disk full?)")
        psnr = psnr_db(float(np.mean(mses))) if mses else None
        t_verified = time.monotonic()
        if png_bytes is None:
            png_bytes = int(np.mean(png_sample_bytes) * n) if png_sample_bytes else None
        ratio = png_bytes / video_bytes if png_bytes and video_bytes else None

        doc = common.describe(ds, views, source, size)
        doc["kind"] = "hevc"
        doc["video_file"] = out.name
        for i, e in enumerate(doc["views"]):
            e["frame"] = i
        doc["frame_order"] = "meander (first row left to right, next row right to left, ...)"
        doc["frames"] = [[r, c] for r, c in views]
        doc["frame_size_px"] = list(frame_size)
        doc["pad_px"] = list(pad)
        doc["encoding"] = {"codec": "hevc", "encoder": "libx265", "container": container_fmt, "crf": int(options.crf),
                           "bit_depth": int(options.bit_depth), "pix_fmt": fmt, "x265_params": x265_params, "preset": X265_PRESET,
                           "frame_rate": FRAME_RATE, "colorspace": "bt709", "color_range": "full",
                           "transfer": "linear", "rgb_scale": 65535}
        doc["figures"] = {"video_bytes": video_bytes, "png16_bytes": png_bytes,
                          "png16_bytes_estimated": not known_png,
                          "compression_ratio_vs_png": ratio, "psnr_db": psnr, "psnr_frames": len(mses)}
        tmp_sidecar.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return {"compression_ratio_vs_png": ratio, "psnr_db": psnr, "video_bytes": video_bytes, "png_bytes": png_bytes,
            "png_bytes_estimated": not known_png, "frames": n, "frame_size_px": list(frame_size),
            "encode_s": t_encoded - t0, "verify_s": t_verified - t_encoded, "psnr_frames": len(mses)}


def _ffmpeg_errors_in_exceptions() -> None:
    """Let PyAV keep FFmpeg's error-level log lines, so its exceptions say what went wrong ("last
    error log: [libx265] ...") instead of only an errno (PyAV keeps FFmpeg's log off by default)."""
    import av.logging

    if av.logging.get_level() is None:
        av.logging.set_level(av.logging.ERROR)


def _decode(video: Path, size: Sequence[int], *, upto: int | None = None, cancel: CancelToken | None = None,
            colorspace: str = COLORSPACE, color_range: str = COLOR_RANGE, want: set[int] | None = None):
    """Yield (frame index, (h, w, 3) uint16 RGB cropped to ``size``) in stream order (only the
    frames in ``want`` when given)."""
    import av
    import av.error

    _ffmpeg_errors_in_exceptions()
    w, h = int(size[0]), int(size[1])
    try:
        container = av.open(str(video))
    except (av.error.FFmpegError, OSError) as exc:
        raise DatasetError(f"{video}: cannot be opened as a video ({exc})") from None
    try:
        for i, frame in enumerate(container.decode(video=0)):
            if cancel is not None:
                cancel.check()
            if want is not None and i not in want:
                if upto is not None and i >= upto:
                    break
                continue
            rgb = frame.reformat(format="rgb48le", src_colorspace=colorspace, src_color_range=color_range).to_ndarray()
            yield i, rgb[:h, :w]
            if upto is not None and i >= upto:
                break
    except av.error.FFmpegError as exc:
        raise DatasetError(f"{video}: cannot be decoded ({exc}); the file is damaged or incomplete") from None
    finally:
        container.close()


# -- import -----------------------------------------------------------------------------------------
def read_sidecar(video: Path) -> dict[str, Any]:
    side = sidecar_path(video)
    if not video.is_file():
        raise InputError("file", f"{video} not found", "an HEVC file written by 'lfstudio export --format hevc'")
    if not side.is_file():
        raise InputError("file", f"{side.name} (the sidecar next to {video.name}) not found; it maps frames to "
                         "views and is written by the export; copy it along with the video")
    try:
        doc = json.loads(side.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DatasetError(f"{side}: cannot be read as JSON ({exc})") from None
    problems = []
    if doc.get("format") != common.EXPORT_FORMAT or doc.get("kind") != "hevc":
        problems.append(f"{side.name}: format/kind: expected {common.EXPORT_FORMAT!r}/'hevc'")
    if not isinstance(doc.get("frames"), list) or not doc.get("frames"):
        problems.append(f"{side.name}: frames: missing or empty")
    if not isinstance(doc.get("grid"), dict):
        problems.append(f"{side.name}: grid: missing")
    if not isinstance(doc.get("image_size_px"), list):
        problems.append(f"{side.name}: image_size_px: missing")
    if int(doc.get("version", 1)) > common.EXPORT_VERSION:
        problems.append(f"{side.name}: version {doc.get('version')} is newer than this lfstudio; update lfstudio")
    if problems:
        raise DatasetError(f"{side}: not an lfstudio HEVC sidecar", problems)
    return doc


def import_hevc(video: Path, out: Path, *, progress: Progress, cancel: CancelToken,
                overwrite: bool = False) -> Path:
    from lfstudio.calibration.model import calibration_problems, save_calibration
    from lfstudio.dataset.manifest import MANIFEST_NAME
    from lfstudio.dataset.thumbs import make_thumbnail

    video, out = Path(video), Path(out)        # expanded by the front end (dataset.paths.expand_path)
    doc = read_sidecar(video)
    common.refuse_out_over_inputs(out, [video, sidecar_path(video)], "the video being imported",
                                  "a new folder for the dataset")
    common.check_new_dataset_out(out, overwrite, field="out")
    try:
        frames = [(int(r), int(c)) for r, c in doc["frames"]]
        size = [int(v) for v in doc["image_size_px"]][:2]
        grid = Grid.from_manifest(doc["grid"])
    except (TypeError, ValueError, KeyError, AttributeError, IndexError) as exc:
        raise DatasetError(f"{sidecar_path(video)}: frames/image_size_px/grid cannot be read ({exc}); "
                           "the sidecar is damaged: export again") from None
    if len(set(frames)) != len(frames):
        raise DatasetError(f"{sidecar_path(video)}: frames: a view appears twice; the sidecar is damaged")
    by_frame = {e.get("frame", i): e for i, e in enumerate(doc.get("views", [])) if isinstance(e, dict)}
    enc = doc.get("encoding", {})
    colorspace = {"bt709": "ITU709", "bt601": "ITU601"}.get(enc.get("colorspace", "bt709"), COLORSPACE)
    color_range = "JPEG" if enc.get("color_range", "full") == "full" else "MPEG"
    processed = doc.get("source") == "processed"
    folder = "processed" if processed else "raw"
    n = len(frames)
    progress(0, n, f"decoding {video.name}")
    with common.partial_folder(out, overwrite) as tmp:
        (tmp / folder).mkdir(parents=True, exist_ok=True)
        (tmp / "thumbs").mkdir(exist_ok=True)
        records: dict[tuple[int, int], ViewRecord] = {}
        count = 0
        for i, rgb in _decode(video, size, cancel=cancel, colorspace=colorspace, color_range=color_range):
            if i >= n:
                raise DatasetError(f"{video}: more frames than the sidecar lists ({n}); the video and "
                                   f"{sidecar_path(video).name} do not belong together")
            r, c = frames[i]
            rel = f"{folder}/{view_stem(r, c)}.png"
            common.write_png16(tmp / rel, rgb)
            thumb = f"thumbs/{view_stem(r, c)}.jpg"
            if make_thumbnail([], tmp / thumb, preview=rgb) is None:
                thumb = None
            e = by_frame.get(i, {})
            rec: ViewRecord = {"row": r, "column": c, "commanded_mm": e.get("commanded_mm"),
                               "reported_mm": e.get("reported_mm"), "captured_at": e.get("captured_at"),
                               "exposure_s": e.get("exposure_s"), "file": rel, "sha256": sha256_file(tmp / rel),
                               "status": "done", "thumb": thumb, "restored_from": {"video": video.name, "frame": i}}
            if processed:
                rec["processed"] = {"status": "done", "file": rel, "restored_from_hevc": True}
            records[(r, c)] = rec
            count += 1
            progress(count, n, f"frame {i + 1}/{n} → {rel}")
        if count < n:
            raise DatasetError(f"{video}: {count} frames decoded, the sidecar lists {n}; the video is truncated")
        views: list[ViewRecord] = [
            records.get((r, c)) or {"row": r, "column": c, "commanded_mm": None, "reported_mm": None,
                                    "captured_at": None, "exposure_s": None, "file": None, "sha256": None,
                                    "status": "skipped", "note": "not in the HEVC export"}
            for r, c in grid.views()]
        extra: dict[str, Any] = {"imported_from": {"kind": "hevc", "file": video.name, "at": now_iso(),
                                                   "source": doc.get("source"), "encoding": enc,
                                                   "figures": doc.get("figures")}}
        if isinstance(doc.get("zero_disparity"), dict) and doc["zero_disparity"].get("source") != "scan":
            extra["zero_disparity"] = doc["zero_disparity"]       # the views' shear comes back with them
        if processed:
            extra["processing"] = {"restored_from_hevc": True, "rectified": bool(doc.get("rectified")),
                                   "output_size_px": list(size)}
        cal = doc.get("calibration")
        if cal and calibration_problems(cal):
            raise DatasetError(f"{sidecar_path(video)}: calibration: cannot be used; the sidecar is damaged: "
                               "export again", calibration_problems(cal))
        if (tmp / MANIFEST_NAME).exists():
            raise DatasetError(f"{tmp}: unexpected existing manifest")
        ds = Dataset.create(tmp, camera=doc.get("camera") or {}, lens=doc.get("lens") or {},
                            grid=grid.to_manifest(), rig={"name": "imported from HEVC", "origin_mm": None
                                                          if grid.origin_mm is None else list(grid.origin_mm)},
                            plan=doc.get("plan") or {}, views=views, **extra)
        if cal:
            save_calibration(ds, cal)        # calibration.json's one writer (and the manifest's note of it)
        ds.close()
        common.check_new_dataset_out(out, overwrite, field="out")     # again: files may have been put there meanwhile
    return out

