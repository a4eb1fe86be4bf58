"""Step 7: downsampling by area averaging (``cv2.INTER_AREA``); the paper halves the resolution."""

from __future__ import annotations

import cv2
import numpy as np


def output_size(full_size_wh: tuple[int, int], scale: float) -> tuple[int, int]:
    """(width, height) of the output for a full-resolution capture of ``full_size_wh``."""
    w, h = full_size_wh
    return max(1, int(round(w * scale))), max(1, int(round(h * scale)))


def apply(img: np.ndarray, size_wh: tuple[int, int], dst: np.ndarray | None = None) -> np.ndarray:
    """``img`` resized to ``size_wh`` by area averaging (unchanged if it already has that size);
    ``dst``: an array of the result's shape and type to write into."""
    if (img.shape[1], img.shape[0]) == tuple(size_wh):
        return img
    return cv2.resize(img, tuple(size_wh), dst=dst, interpolation=cv2.INTER_AREA)
