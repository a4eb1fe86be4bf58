"""Image checks for live view and test shots (Qt-free): a focus measure, clipping, histograms. A test
shot's file becomes an 8-bit picture through :func:`lfstudio.dataset.images.preview_rgb8`."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

@dataclass(frozen=True)
class FrameStats:
    sharpness: float          # variance of the Laplacian of the grey image (higher = sharper)
    sharpness_centre: float   # the same on the central third (where one usually focuses)
    clipped_high: float       # fraction of pixels with a channel at 255 (blown highlights)
    clipped_low: float        # fraction of pixels with every channel at 0 (crushed shadows)
    mean: float               # mean grey level, 0..255


def _grey(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb


def _peak(rgb: np.ndarray) -> np.ndarray:
    """Per-pixel maximum over the channels (``rgb.max(axis=2)`` is ~10x slower on a uint8 frame:
    these checks run on the GUI thread for every live frame and test shot)."""
    return functools.reduce(np.maximum, [rgb[..., i] for i in range(rgb.shape[2])])


def sharpness(rgb: np.ndarray) -> float:
    """Variance of the Laplacian: a standard focus measure; compare values of the same scene only."""
    return float(cv2.Laplacian(_grey(rgb).astype(np.float32), cv2.CV_32F, ksize=3).var())


def frame_stats(rgb: np.ndarray, high: int = 255, low: int = 0) -> FrameStats:
    """Focus and exposure figures of an 8-bit RGB (or grey) frame."""
    grey = _grey(rgb)
    h, w = grey.shape
    centre = rgb[h // 3: 2 * h // 3 or h, w // 3: 2 * w // 3 or w]
    if rgb.ndim == 3:
        peak = _peak(rgb)
        hi = float(np.mean(peak >= high))
        lo = float(np.mean(peak <= low))
    else:
        hi, lo = float(np.mean(rgb >= high)), float(np.mean(rgb <= low))
    return FrameStats(sharpness(rgb), sharpness(centre), hi, lo, float(grey.mean()))


def histograms(rgb: np.ndarray, bins: int = 64) -> tuple[np.ndarray, list[np.ndarray]]:
    """Bin centres (0..255) and one normalised histogram per channel (R, G, B) or one for grey."""
    edges = np.linspace(0, 256, bins + 1)
    chans = [rgb[..., i] for i in range(rgb.shape[2])] if rgb.ndim == 3 else [rgb]
    if rgb.dtype == np.uint8:   # count the 256 values (cv2.calcHist, ~100x faster than np.histogram), then bin them
        bin_of_value = np.searchsorted(edges, np.arange(256), side="right") - 1
        counts = [cv2.calcHist([rgb], [i], None, [256], [0, 256]).ravel() for i in range(len(chans))]
        hists = [np.bincount(bin_of_value, weights=n, minlength=bins) / max(1, c.size) for n, c in zip(counts, chans)]
    else:
        hists = [np.histogram(c, bins=edges)[0].astype(np.float64) / max(1, c.size) for c in chans]
    return (edges[:-1] + edges[1:]) / 2, hists


def clipping_overlay(rgb: np.ndarray, high: int = 255, low: int = 0) -> np.ndarray:
    """A copy with blown highlights painted red and crushed shadows painted blue."""
    out = rgb.copy()
    peak = _peak(rgb)
    out[peak >= high] = (255, 0, 0)
    out[peak <= low] = (0, 0, 255)
    return out
