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

from lfstudio.dataset import images
from lfstudio.dataset.atomic import atomic_write_with
from lfstudio.dataset.manifest import MANIFEST_NAME, ViewRecord, file_of, is_done

log = logging.getLogger(__name__)

THUMB_WIDTH_PX = 160
#: where generated thumbnails are cached, relative to the dataset folder
GENERATED_DIR = "thumbs/generated"


def make_thumbnail(files: Sequence[Path], out_path: Path, width_px: int = THUMB_WIDTH_PX,
                   preview: np.ndarray | None = None) -> Path | None:
    """Write a JPEG thumbnail of a capture to ``out_path`` (atomically); None if nothing decodable.

    ``files``: the capture's files (RAW first, sidecars after). ``preview``: an RGB array the
    camera (or a decoded frame) already has, uint8 or 16-bit at any size (used first when given).
    Otherwise the first sidecar that is an ordinary image, then the capture itself
    (:func:`lfstudio.dataset.images.thumbnail_array`).
    """
    img = None
    if preview is not None:
        img = images.thumbnail_from_array(preview, width_px)
    if img is None:
        for f in list(files)[1:]:
            if _is_image(Path(f)):
                img = images.thumbnail_array(Path(f), width_px)
                if img is not None:
                    break
    if img is None and files:
        img = images.thumbnail_array(Path(files[0]), width_px)
    if img is None:
        return None
    return _write_jpeg(out_path, img)


def _is_image(path: Path) -> bool:
    try:
        return images.kind(path) == "image"
    except images.NotACapture:
        return False


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


class _Versions:
    """The cached thumbnails in a dataset's ``thumbs/generated/``, by the prefix every version of one
    capture's thumbnail shares: listed once, then kept up to date as thumbnails are written (finding
    a capture's stale thumbnail by listing the folder each time costs O(views) per view)."""

    def __init__(self, folder: Path):
        self._lock = threading.Lock()
        self._names: dict[str, set[str]] = {}
        try:
            entries = os.listdir(folder)
        except OSError:
            entries = []
        for name in entries:
            parts = name.rsplit(".", 2)               # FLAT.KEY.jpg
            if len(parts) == 3 and parts[2] == "jpg":
                self._names.setdefault(parts[0] + ".", set()).add(name)

    def replace(self, prefix: str, name: str) -> list[str]:
        """``name`` is now the prefix's one version; the others (stale, to delete) are returned."""
        with self._lock:
            old = self._names.get(prefix, set()) - {name}
            self._names[prefix] = {name}
        return sorted(old)


def _make_cached(root: Path, path: Path, width_px: int, versions: _Versions | None = None) -> np.ndarray | None:
    """Read the cached thumbnail of ``path``, or make it from the file and cache it (and delete the
    thumbnail of an earlier version of the capture)."""
    where = cache_path(root, path, width_px)
    if where is None:
        return None
    target, prefix = where
    if target.is_file():
        img = images.read_picture(target)
        if img is not None:
            return img
    img = images.thumbnail_array(path, width_px)
    if img is None:
        return None
    try:
        _write_jpeg(target, img)
        if versions is None:
            versions = _Versions(target.parent)
        for old in versions.replace(prefix, target.name):
            (target.parent / old).unlink(missing_ok=True)    # the capture changed: its old thumbnail goes
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
        self._versions = _Versions(root / GENERATED_DIR)
        self._cancelled = False
        self._pool = ThreadPoolExecutor(max_workers=workers or os.cpu_count() or 1,
                                        thread_name_prefix="thumb-cache")
        self._jobs = [self._pool.submit(self._fill, p) for p in self._files()]

    def _files(self) -> list[Path]:
        try:
            manifest = json.loads((self.root / MANIFEST_NAME).read_text(encoding="utf-8"))
            views: list[ViewRecord] = manifest.get("views", [])
        except (OSError, ValueError, AttributeError):
            return []
        return [self.root / file_of(v) for v in views
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
            img = _make_cached(self.root, path, self.width_px, self._versions)
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
        return images.thumbnail_array(path, width_px)
    cache_width = max(THUMB_WIDTH_PX, width_px)
    with _filler_lock:
        if _filler is None or _filler.root != root or _filler.width_px != cache_width:
            if _filler is not None:
                _filler.cancel()
            _filler = CacheFiller(root, cache_width)
        filler = _filler
    img = filler.get(path)
    return None if img is None else images.shrink(img, width_px)
