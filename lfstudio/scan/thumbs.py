"""Small preview images for the grid view, made cheaply from what a capture produced.

Preference: a JPEG/PNG/TIFF sidecar the camera delivered (decoded at reduced size), then the
preview embedded in a RAW file, then a strided decode of the RAW mosaic (no demosaicing: each
2 x 2 Bayer block becomes one RGB pixel). Thumbnails are JPEG, at most ``width_px`` wide.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from lfstudio.dataset.atomic import atomic_write_with

THUMB_WIDTH_PX = 160
_IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp"}


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


def _from_image_file(path: Path, width_px: int) -> np.ndarray | None:
    """BGR uint8, decoded at reduced size where the format allows it."""
    flags = cv2.IMREAD_COLOR
    if path.suffix.lower() in (".jpg", ".jpeg"):
        try:
            h_w = cv2.imread(str(path), cv2.IMREAD_REDUCED_COLOR_8)
            if h_w is not None and h_w.shape[1] >= width_px:
                return h_w
        except cv2.error:
            pass
    img = cv2.imread(str(path), flags | cv2.IMREAD_ANYDEPTH)
    if img is None:
        return None
    return _to_uint8(img)


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
                img = cv2.imdecode(np.frombuffer(thumb.data, np.uint8), cv2.IMREAD_COLOR)
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
    img = _resize(img, width_px)

    def write(tmp: Path) -> None:
        if not cv2.imwrite(str(tmp), img, [cv2.IMWRITE_JPEG_QUALITY, 85]):
            raise OSError(f"could not write thumbnail {out_path}")

    return atomic_write_with(out_path, write)
