"""Step 5: de-flicker — one gain per view that matches its global brightness to the reference view.

The statistic is robust to parallax and highlights: both images are reduced (area average) to a
small luminance image ``size_px`` wide, pixels that are mid-tones in both (``low``..``high`` of full
scale) are kept, and the gain is the median of the per-pixel ratios reference/view
(``median_ratio``) or the ratio of the two medians (``median``).
"""

from __future__ import annotations

import cv2
import numpy as np

from lfstudio.dataset.profile import DeflickerStep

_LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


def small_luminance(img: np.ndarray, size_px: int, rgb_cam: np.ndarray | None = None) -> np.ndarray:
    """Luminance (0..1) of ``img`` reduced by area averaging to ``size_px`` wide (float32).
    ``rgb_cam``: ``img`` is camera RGB, this matrix makes it output RGB (folded into the weights)."""
    h, w = img.shape[:2]
    step = w // (4 * size_px)
    if step > 1:  # thin out first: area-averaging 40 MP to 256 px is 30 ms per view for nothing
        img = img[::step, ::step]
        h, w = img.shape[:2]
    sw = min(size_px, w)
    sh = max(1, int(round(h * sw / w)))
    small = cv2.resize(img, (sw, sh), interpolation=cv2.INTER_AREA).astype(np.float32)
    if small.ndim == 3:
        small = small @ (_LUMA if rgb_cam is None else (_LUMA @ np.asarray(rgb_cam, np.float32)).astype(np.float32))
    return small / 65535.0


def gain(reference_small: np.ndarray, view_small: np.ndarray, step: DeflickerStep) -> tuple[float, float]:
    """(gain, fraction of pixels used) that makes the view's brightness match the reference."""
    if reference_small.shape != view_small.shape:
        view_small = cv2.resize(view_small, reference_small.shape[::-1], interpolation=cv2.INTER_AREA)
    mask = (reference_small > step.low) & (reference_small < step.high) \
        & (view_small > step.low) & (view_small < step.high)
    used = float(mask.mean())
    if mask.sum() < 16:
        return 1.0, used  # nothing comparable (black or clipped view): leave it alone
    if step.statistic == "median":
        return float(np.median(reference_small[mask]) / np.median(view_small[mask])), used
    return float(np.median(reference_small[mask] / view_small[mask])), used
