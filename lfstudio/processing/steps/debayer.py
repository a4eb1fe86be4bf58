"""Step 1: RAW → linear 16-bit RGB with rawpy (LibRaw); ordinary PNG/TIFF images are read as they are.

Linear output: ``gamma=(1, 1)``, ``no_auto_bright``, ``output_bps=16``; the RAW's white level maps
to 65535. The RAW's orientation tag is applied, as the calibration does when it reads the views.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from lfstudio.errors import DatasetError
from lfstudio.processing.profile import DebayerStep

RAW_SUFFIXES = frozenset({".dng", ".arw", ".cr2", ".cr3", ".nef", ".nrw", ".raf", ".orf", ".rw2",
                          ".pef", ".srw", ".raw", ".3fr", ".iiq", ".erf", ".mos", ".x3f"})


def is_raw(path: str | Path) -> bool:
    return Path(path).suffix.lower() in RAW_SUFFIXES


def processing_scale(path: str | Path, step: DebayerStep) -> float:
    """Size of the decoded image relative to the full-resolution capture (0.5 with half_size RAW)."""
    return 0.5 if step.enabled and step.half_size and is_raw(path) else 1.0


def _params(step: DebayerStep):
    import rawpy

    # adjust_maximum_thr=0: scale by the RAW's white level, never by the image's own maximum (LibRaw's
    # default rescales images with clipped pixels: a brightness jump between views of one scene)
    kw = dict(gamma=(1, 1), no_auto_bright=True, output_bps=16, adjust_maximum_thr=0.0,
              half_size=step.half_size,
              output_color=rawpy.ColorSpace.raw if step.color_space == "raw" else rawpy.ColorSpace.sRGB,
              demosaic_algorithm=getattr(rawpy.DemosaicAlgorithm, step.demosaic))
    if step.white_balance == "camera":
        kw["use_camera_wb"] = True
    elif step.white_balance == "fixed":
        kw["user_wb"] = [float(v) for v in step.wb_multipliers]
    return rawpy.Params(**kw)


def full_size_px(path: str | Path) -> tuple[int, int]:
    """(width, height) of the full-resolution image the file decodes to (without half_size)."""
    path = Path(path)
    if is_raw(path):
        import rawpy

        try:
            with rawpy.imread(str(path)) as raw:
                w, h = int(raw.sizes.width), int(raw.sizes.height)
                return (h, w) if raw.sizes.flip in (5, 6) else (w, h)  # portrait orientation tag
        except Exception as exc:
            raise DatasetError(f"{path}: cannot be read as a RAW file ({exc}); re-capture or remove the view") from None
    img = read_image(path)
    return int(img.shape[1]), int(img.shape[0])


def read_image(path: str | Path) -> np.ndarray:
    """A PNG/TIFF/JPEG as (h, w, 3) uint16 RGB (8-bit images scaled by 257)."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DatasetError(f"{path}: cannot be read as an image; check the file or re-capture the view")
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    else:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if img.dtype == np.uint8:
        img = img.astype(np.uint16) * 257
    elif img.dtype != np.uint16:
        img = np.clip(img.astype(np.float64) * (65535.0 if img.dtype.kind == "f" else 1.0), 0, 65535) \
            .astype(np.uint16)
    return img


def decode(path: str | Path, step: DebayerStep) -> np.ndarray:
    """(h, w, 3) uint16 linear RGB of one capture."""
    path = Path(path)
    if not is_raw(path):
        return read_image(path)
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            return raw.postprocess(_params(step))
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot be decoded as a RAW file ({type(exc).__name__}: {exc}); "
                           "re-capture the view or remove it from the dataset") from None
