"""Step 1: RAW → linear 16-bit RGB; ordinary PNG/TIFF images are read as they are.

Files are read through :mod:`lfstudio.dataset.images` (LibRaw for RAW, decided by LibRaw itself).
Demosaic ``auto`` (the default) lets the worker demosaic at the resolution the output needs: when
the output is at most half the capture's size and the RAW is an RGB Bayer mosaic,
:func:`lfstudio.dataset.images.read_bayer` gives the mosaic with LibRaw's black level, white balance
and scaling applied, the luminance comes from OpenCV's edge-aware demosaic at full resolution
(:func:`demosaic_ea`) and the colour differences (R − G, B − G) from the Bayer sites themselves at
half resolution (see :mod:`lfstudio.processing.worker`). Measured against the virtual studio's
ground truth this is at least as close as LibRaw's AHD and ~4× faster
(``benchmarks/processing_quality.py``). A full-resolution develop
(:func:`lfstudio.dataset.images.develop`) with ``auto`` is LibRaw's AHD.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from lfstudio.dataset import images
from lfstudio.dataset.profile import DebayerStep


def processing_scale(path: str | Path, step: DebayerStep) -> float:
    """Size of the decoded image relative to the full-resolution capture (0.5 with half_size RAW)."""
    return 0.5 if step.enabled and step.half_size and images.is_raw(path) else 1.0


def demosaic_ea(bayer: images.Bayer, dst: np.ndarray | None = None) -> np.ndarray:
    """Full-resolution camera RGB (uint16) of ``bayer`` by OpenCV's edge-aware demosaic."""
    return cv2.cvtColor(bayer.mosaic, bayer.ea_code, dst=dst)


def output_rgb(camera_rgb: np.ndarray, rgb_cam: np.ndarray) -> np.ndarray:
    """Camera RGB (uint16) through the colour matrix, rounded and saturated (what LibRaw outputs)."""
    if np.allclose(rgb_cam, np.eye(3)):
        return camera_rgb
    return cv2.transform(camera_rgb, np.asarray(rgb_cam, np.float64))
