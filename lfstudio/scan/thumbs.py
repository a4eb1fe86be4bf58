"""Small preview images for the grid view, made cheaply from what a capture produced.

Preference: a JPEG/PNG/TIFF sidecar the camera delivered (decoded at reduced size), then the
preview embedded in a RAW file (its JPEG decoded at reduced size), then a strided decode of the RAW
mosaic (no demosaicing: each 2 x 2 Bayer block becomes one RGB pixel, only every n-th block read).
Images are made small first and only then measured (the 8-bit scaling's percentile). Thumbnails
are JPEG, at most ``width_px`` wide.

Views without a stored thumbnail (datasets imported or rendered rather than scanned) get one made
from their file by :func:`cached_thumbnail`, which keeps it in the dataset's
``thumbs/generated/`` folder, named after the file and its size and modification time: a changed
capture gets a new thumbnail, the stale one is deleted. The first such request in a dataset starts
making the others in the background on every core (:class:`CacheFiller`), so a large imported
dataset fills its grid in parallel and opens instantly the next time.
"""

from __future__ import annotations

import glob
import hashlib
import json
import logging
import os
import threading
from concurrent.futures import CancelledError, Future, ThreadPoolExecutor
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from lfstudio.dataset.atomic import atomic_write_with
from lfstudio.dataset.manifest import MANIFEST_NAME, is_done

log = logging.getLogger(__name__)

THUMB_WIDTH_PX = 160
_IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp"}
#: where generated thumbnails are cached, relative to the dataset folder
GENERATED_DIR = "thumbs/generated"
_JPEG_REDUCED = ((8, cv2.IMREAD_REDUCED_COLOR_8), (4, cv2.IMREAD_REDUCED_COLOR_4), (2, cv2.IMREAD_REDUCED_COLOR_2))


def _resize(rgb_or_bgr: np.ndarray, width_px: int) -> np.ndarray:
    h, w = rgb_or_bgr.shape[:2]
    if w <= width_px:
        return rgb_or_bgr
    height = max(1, round(h * width_px / w))
    return cv2.resize(rgb_or_bgr, (width_px, height), interpolation=cv2.INTER_AREA)


def _to_uint8(img: np.ndarray) -> np.ndarray:
    if img.dtype == np.uint8:
        return img
    a = img.astype(np.float32)
    hi = float(np.percentile(a, 99.5)) or 1.0
    return np.clip(a * (255.0 / hi), 0, 255).astype(np.uint8)


def _reduced_jpeg(read, width_px: int) -> np.ndarray | None:
    """A JPEG decoded at the smallest of 1/8, 1/4, 1/2 that is still ``width_px`` wide (libjpeg
    scales while decoding); ``read(flags)`` decodes with OpenCV's flags."""
    try:
        small = read(cv2.IMREAD_REDUCED_COLOR_8)
    except cv2.error:
        return None
    if small is None:
        return None
    if small.shape[1] >= width_px:
        return small
    full_w = small.shape[1] * 8
    for factor, flags in _JPEG_REDUCED[1:]:
        if full_w // factor >= width_px:
            return read(flags)
    return read(cv2.IMREAD_COLOR)


def _from_image_file(path: Path, width_px: int) -> np.ndarray | None:
    """BGR uint8, decoded at reduced size where the format allows it, made small before measuring."""
    if path.suffix.lower() in (".jpg", ".jpeg"):
        img = _reduced_jpeg(lambda flags: cv2.imread(str(path), flags), width_px)
        if img is not None:
            return img
    img = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
    if img is None:
        return None
    return _to_uint8(_resize(img, width_px))


def _from_raw(path: Path, width_px: int) -> np.ndarray | None:
    """BGR uint8 from a RAW file: the embedded JPEG preview if large enough, else a strided decode."""
    import rawpy

    try:
        raw = rawpy.imread(str(path))
    except Exception:
        return None
    with raw:
        try:
            thumb = raw.extract_thumb()
            if thumb.format == rawpy.ThumbFormat.JPEG:
                data = np.frombuffer(thumb.data, np.uint8)
                img = _reduced_jpeg(lambda flags: cv2.imdecode(data, flags), width_px)
                if img is not None and img.shape[1] >= width_px:
                    return img
            elif thumb.format == rawpy.ThumbFormat.BITMAP and thumb.data.shape[1] >= width_px:
                return cv2.cvtColor(np.ascontiguousarray(thumb.data), cv2.COLOR_RGB2BGR)
        except Exception:
            pass
        try:
            mosaic = raw.raw_image_visible
            colors = raw.raw_colors_visible
            black = float(np.mean(raw.black_level_per_channel))
            white = float(raw.white_level)
        except Exception:
            return None
        h, w = mosaic.shape
        step = max(1, (w // 2) // (width_px * 2)) * 2     # even stride keeps the Bayer phase
        # one RGB pixel per 2x2 block, blocks taken every `step` pixels
        out = np.zeros((len(range(0, h - 1, step)), len(range(0, w - 1, step)), 3), np.float32)
        count = np.zeros_like(out)
        for dy in (0, 1):
            for dx in (0, 1):
                vals = mosaic[dy:h - 1 + dy:step, dx:w - 1 + dx:step][: out.shape[0], : out.shape[1]]
                ch = int(colors[dy, dx])
                ch = 1 if ch == 3 else ch      # second green
                out[..., ch] += vals
                count[..., ch] += 1
        rgb = out / np.maximum(count, 1)
        rgb = (rgb - black) / max(white - black, 1.0)
        # a rough grey-world balance and gamma: this is a thumbnail, not a rendering
        means = rgb.reshape(-1, 3).mean(axis=0) + 1e-6
        rgb = rgb * (means.mean() / means)
        rgb = np.clip(rgb / max(float(np.percentile(rgb, 99)), 1e-6), 0, 1) ** (1 / 2.2)
        return cv2.cvtColor((rgb * 255).astype(np.uint8), cv2.COLOR_RGB2BGR)


def thumbnail_array(path: str | Path, width_px: int = THUMB_WIDTH_PX) -> np.ndarray | None:
    """A BGR uint8 thumbnail of one image or RAW file, at most ``width_px`` wide (None if undecodable).

    For views without a stored thumbnail (datasets rendered or imported rather than scanned)."""
    path = Path(path)
    img = _from_image_file(path, width_px) if path.suffix.lower() in _IMAGE_SUFFIXES else _from_raw(path, width_px)
    return None if img is None else _resize(img, width_px)


def make_thumbnail(files: Sequence[Path], out_path: Path, width_px: int = THUMB_WIDTH_PX,
                   preview: np.ndarray | None = None) -> Path | None:
    """Write a JPEG thumbnail of a capture to ``out_path`` (atomically); None if nothing decodable.

    ``files``: the capture's files (RAW first, sidecars after). ``preview``: an RGB array the
    camera (or a decoded frame) already has, uint8 or 16-bit at any size (used first when given).
    """
    img = None
    if preview is not None:
        small = _resize(np.asarray(preview), width_px)   # first: the 8-bit scaling's percentile is then cheap
        img = cv2.cvtColor(_to_uint8(small), cv2.COLOR_RGB2BGR) if small.ndim == 3 else _to_uint8(small)
    if img is None:
        for f in list(files)[1:]:
            if Path(f).suffix.lower() in _IMAGE_SUFFIXES:
                img = _from_image_file(Path(f), width_px)
                if img is not None:
                    break
    if img is None and files:
        main = Path(files[0])
        img = _from_image_file(main, width_px) if main.suffix.lower() in _IMAGE_SUFFIXES else _from_raw(main, width_px)
    if img is None:
        return None
    return _write_jpeg(out_path, _resize(img, width_px))


def _write_jpeg(out_path: Path, img: np.ndarray) -> Path:
    def write(tmp: Path) -> None:
        if not cv2.imwrite(str(tmp), img, [cv2.IMWRITE_JPEG_QUALITY, 85]):
            raise OSError(f"could not write thumbnail {out_path}")

    return atomic_write_with(out_path, write)


# -- generated thumbnails, cached in the dataset ------------------------------------------------------
_roots: dict[Path, Path | None] = {}


def dataset_root(path: Path) -> Path | None:
    """The dataset folder (holding ``dataset.json``) that ``path`` lies in, or None."""
    folder = path.parent
    root = _roots.get(folder)
    if root is None:
        root = next((p for p in (folder, *folder.parents) if (p / MANIFEST_NAME).is_file()), None)
        if root is not None:
            _roots[folder] = root
    return root


def cache_path(root: Path, path: Path, width_px: int = THUMB_WIDTH_PX) -> tuple[Path, str] | None:
    """(cached thumbnail of ``path`` as it is now, the prefix every version of it shares), or None
    if the file cannot be read."""
    try:
        st = path.stat()
        rel = path.relative_to(root).as_posix()
    except (OSError, ValueError):
        return None
    flat = rel.replace("/", "~")
    key = hashlib.sha1(f"{st.st_size}:{st.st_mtime_ns}:{width_px}".encode()).hexdigest()[:12]
    return root / GENERATED_DIR / f"{flat}.{key}.jpg", f"{flat}."


def _make_cached(root: Path, path: Path, width_px: int) -> np.ndarray | None:
    """Read the cached thumbnail of ``path``, or make it from the file and cache it."""
    where = cache_path(root, path, width_px)
    if where is None:
        return None
    target, prefix = where
    if target.is_file():
        img = cv2.imread(str(target), cv2.IMREAD_COLOR)
        if img is not None:
            return img
    img = thumbnail_array(path, width_px)
    if img is None:
        return None
    try:
        _write_jpeg(target, img)
        for old in glob.glob(os.path.join(glob.escape(str(target.parent)), glob.escape(prefix) + "*.jpg")):
            if Path(old) != target:
                Path(old).unlink(missing_ok=True)      # the capture changed: its old thumbnail goes
    except OSError as exc:                             # a read-only dataset still shows its thumbnails
        log.debug("thumbnail of %s not cached: %s", path, exc)
    return img


class CacheFiller:
    """Makes the cached thumbnails of a dataset's views (those without a stored thumbnail) on a
    pool of threads (OpenCV and libjpeg/libpng release the GIL); :meth:`get` answers one view
    first, or waits for the pool when it is already making that one."""

    def __init__(self, root: Path, width_px: int = THUMB_WIDTH_PX, workers: int | None = None):
        self.root, self.width_px = root, width_px
        self._lock = threading.Lock()
        self._inflight: dict[Path, Future] = {}
        self._cancelled = False
        self._pool = ThreadPoolExecutor(max_workers=workers or os.cpu_count() or 1,
                                        thread_name_prefix="thumb-cache")
        self._jobs = [self._pool.submit(self._fill, p) for p in self._files()]

    def _files(self) -> list[Path]:
        try:
            manifest = json.loads((self.root / MANIFEST_NAME).read_text(encoding="utf-8"))
            views = manifest.get("views", [])
        except (OSError, ValueError, AttributeError):
            return []
        return [self.root / v["file"] for v in views
                if isinstance(v, dict) and is_done(v) and not v.get("thumb")]

    def _claim(self, path: Path) -> tuple[Future, bool]:
        with self._lock:
            fut = self._inflight.get(path)
            if fut is not None:
                return fut, False
            fut = self._inflight[path] = Future()
            return fut, True

    def _make(self, path: Path, fut: Future) -> np.ndarray | None:
        try:
            img = _make_cached(self.root, path, self.width_px)
        except Exception as exc:  # an unreadable file stays a coloured cell
            img = None
            log.debug("no thumbnail for %s: %s", path, exc)
        with self._lock:
            del self._inflight[path]     # from now on the cache answers
        fut.set_result(img)
        return img

    def _fill(self, path: Path) -> None:
        if self._cancelled:
            return
        fut, mine = self._claim(path)
        if mine:
            self._make(path, fut)

    def get(self, path: Path) -> np.ndarray | None:
        fut, mine = self._claim(path)
        if not mine:
            return fut.result()
        return self._make(path, fut)

    def wait(self) -> None:
        """Until every queued view has its thumbnail (or was skipped after :meth:`cancel`)."""
        for job in self._jobs:
            try:
                job.result()
            except CancelledError:
                pass

    def cancel(self) -> None:
        self._cancelled = True
        self._pool.shutdown(wait=False, cancel_futures=True)


_filler: CacheFiller | None = None
_filler_lock = threading.Lock()


def cached_thumbnail(path: str | Path, width_px: int = THUMB_WIDTH_PX) -> np.ndarray | None:
    """A BGR uint8 thumbnail of a view file, at most ``width_px`` wide, from its dataset's cache
    of generated thumbnails (kept at least :data:`THUMB_WIDTH_PX` wide) or made now and cached;
    None if undecodable. The first call for a dataset starts filling its cache in the background
    (a call for another dataset stops that). Files outside a dataset are not cached."""
    global _filler
    path = Path(path)
    root = dataset_root(path)
    if root is None:
        return thumbnail_array(path, width_px)
    cache_width = max(THUMB_WIDTH_PX, width_px)
    with _filler_lock:
        if _filler is None or _filler.root != root or _filler.width_px != cache_width:
            if _filler is not None:
                _filler.cancel()
            _filler = CacheFiller(root, cache_width)
        filler = _filler
    img = filler.get(path)
    return None if img is None else _resize(img, width_px)
