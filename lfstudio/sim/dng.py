"""A minimal Bayer DNG writer (uncompressed, one IFD) that rawpy/LibRaw reads back bit-exact.

The simulated camera writes its RAW files with it; tests and the processing stage read them with
rawpy like any camera's RAW. The mosaic is RGGB: row 0 holds R G R G ..., row 1 holds G B G B ...

Pixel values: ``black_level`` is the sensor's zero, ``white_level`` its clipping point (14-bit:
16383). :func:`mosaic_from_rgb` maps linear RGB in [0, 1] (1 = clipping for a neutral grey) to
such a mosaic, scaling each channel by the camera's channel sensitivity ``neutral`` (what a real
sensor does: green is most sensitive). The DNG's AsShotNeutral is that same ``neutral``, so a raw
converter's "camera white balance" undoes it and gives back the linear RGB.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from lfstudio.dataset.dng import CFA_COLOURS, DEFAULT_NEUTRAL, SRGB_TO_XYZ, XYZ_TO_SRGB, write_dng

__all__ = ["CFA_COLOURS", "DEFAULT_NEUTRAL", "SRGB_TO_XYZ", "XYZ_TO_SRGB", "mosaic_from_rgb",
           "rgb_from_mosaic_nearest", "write_dng"]


def mosaic_from_rgb(linear_rgb: np.ndarray, black_level: int = 512, white_level: int = 16383,
                    neutral: Sequence[float] = DEFAULT_NEUTRAL, pattern: str = "RGGB") -> np.ndarray:
    """Sample an H x W x 3 linear RGB float image (1.0 = clipping) into an H x W uint16 Bayer mosaic.

    Each photosite keeps the channel its filter passes, scaled by ``neutral`` (channel
    sensitivity), mapped to ``black_level .. white_level``, rounded and clipped. H and W must be
    even.
    """
    rgb = np.asarray(linear_rgb, dtype=np.float32)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"linear_rgb must be H x W x 3, got shape {rgb.shape}")
    h, w = rgb.shape[:2]
    if h % 2 or w % 2:
        raise ValueError(f"a Bayer mosaic needs even width and height, got {w} x {h}")
    colours = [CFA_COLOURS[c] for c in pattern.upper()]
    span = float(white_level - black_level)
    mosaic = np.empty((h, w), dtype=np.float32)
    for i, colour in enumerate(colours):
        dy, dx = divmod(i, 2)
        mosaic[dy::2, dx::2] = rgb[dy::2, dx::2, colour] * (float(neutral[colour]) * span)
    mosaic += black_level
    np.clip(mosaic, 0, white_level, out=mosaic)
    return np.rint(mosaic).astype(np.uint16)


def rgb_from_mosaic_nearest(mosaic: np.ndarray, black_level: int = 512, white_level: int = 16383,
                            neutral: Sequence[float] = DEFAULT_NEUTRAL) -> np.ndarray:
    """A quick half-resolution RGB (H/2 x W/2 x 3 float32, 1.0 = clipping) from an RGGB mosaic."""
    m = mosaic.astype(np.float32) - black_level
    span = float(white_level - black_level)
    r = m[0::2, 0::2] / (neutral[0] * span)
    g = (m[0::2, 1::2] + m[1::2, 0::2]) / (2 * neutral[1] * span)
    b = m[1::2, 1::2] / (neutral[2] * span)
    return np.dstack([r, g, b])
