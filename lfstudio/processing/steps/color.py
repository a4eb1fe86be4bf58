"""Step 3: colour — black and white point taken on the reference view, applied to every view.

``out = (in·g − black) · white_output·65535 / (white − black)`` per channel, where ``g`` folds in
the shading factor and the de-flicker gain. Picking a neutral white patch white-balances too.
Modes: ``auto`` (global percentiles, no colour shift), ``points`` (patches around picked pixels,
full-resolution coordinates), ``values`` (numbers given directly).
"""

from __future__ import annotations

import cv2
import numpy as np

from lfstudio.errors import InputError
from lfstudio.dataset.profile import ColorStep


def patch_mean(img: np.ndarray, point_px, scale: float, patch_px: int, field: str) -> np.ndarray:
    """Per-channel mean of a square ``patch_px`` (full-res pixels) around ``point_px`` (full-res)."""
    h, w = img.shape[:2]
    x = (point_px[0] + 0.5) * scale - 0.5
    y = (point_px[1] + 0.5) * scale - 0.5
    half = max(0, int(round(patch_px * scale / 2)))
    xi, yi = int(round(x)), int(round(y))
    if not (0 <= xi < w and 0 <= yi < h):
        raise InputError(f"processing.toml: [color] {field}",
                         f"({point_px[0]:g}, {point_px[1]:g}) is outside the reference image",
                         f"0..{w / scale - 1:g}, 0..{h / scale - 1:g}")
    patch = img[max(0, yi - half): yi + half + 1, max(0, xi - half): xi + half + 1]
    return patch.reshape(-1, 3).astype(np.float64).mean(axis=0)


def levels(reference: np.ndarray, step: ColorStep, scale: float = 1.0) -> tuple[list[float], list[float]]:
    """(black_rgb, white_rgb) in the units of ``reference`` (linear uint16 after shading)."""
    if step.mode == "values":
        black, white = np.array(step.black_rgb, float), np.array(step.white_rgb, float)
    elif step.mode == "points":
        black = patch_mean(reference, step.black_point_px, scale, step.patch_px, "black_point_px")
        white = patch_mean(reference, step.white_point_px, scale, step.patch_px, "white_point_px")
    else:
        sample = reference[::4, ::4].reshape(-1)
        lo, hi = np.percentile(sample, [step.black_percentile, step.white_percentile])
        black, white = np.full(3, lo, float), np.full(3, hi, float)
    if np.any(white - black <= 1.0):
        raise InputError("processing.toml: [color]",
                         f"white point {np.round(white).tolist()} is not above black point "
                         f"{np.round(black).tolist()} in every channel; pick a brighter white and a darker black")
    return [float(v) for v in black], [float(v) for v in white]


def apply(img: np.ndarray, *, gain: float = 1.0, factor_map: np.ndarray | None = None,
          black=(0.0, 0.0, 0.0), white=(65535.0, 65535.0, 65535.0), white_output: float = 1.0,
          enabled: bool = True) -> np.ndarray:
    """Shading factor, de-flicker gain and black/white levels in one pass; uint16 out (clipped)."""
    if factor_map is not None:
        return apply_map(img, *level_map(factor_map, black, white, white_output, enabled), gain)
    black, scale = _black_and_scale(black, white, white_output, enabled)
    # cv2.transform: out_c = m_c · in_c + offset_c, saturating to the output depth
    M = np.zeros((3, 4), np.float64)
    M[[0, 1, 2], [0, 1, 2]] = gain * scale
    M[:, 3] = -black * scale
    if np.allclose(M[:, :3], np.eye(3)) and not M[:, 3].any():
        return img
    return cv2.transform(img, M)  # uint16 in, uint16 out, rounded and saturated


def _black_and_scale(black, white, white_output: float, enabled: bool) -> tuple[np.ndarray, np.ndarray]:
    """(black level, scale per channel): ``out = (in − black) · scale``; identity when disabled."""
    black = np.asarray(black, np.float64) if enabled else np.zeros(3)
    white = np.asarray(white, np.float64) if enabled else np.full(3, 65535.0)
    return black, (white_output if enabled else 1.0) * 65535.0 / (white - black)


def level_map(factor_map: np.ndarray, black, white, white_output: float = 1.0, enabled: bool = True):
    """(per-pixel multiplier (h, w, 3) float32, offset) folding a shading factor map into the levels;
    compute once per run, then :func:`apply_map` per view."""
    black, scale = _black_and_scale(black, white, white_output, enabled)
    per_pixel = np.ascontiguousarray(factor_map * scale.astype(np.float32), np.float32)
    if per_pixel.shape[2] != 3:
        per_pixel = np.ascontiguousarray(np.repeat(per_pixel, 3, axis=2))
    return per_pixel, tuple(float(v) for v in black * scale) + (0.0,)


def apply_map(img: np.ndarray, per_pixel: np.ndarray, offset: tuple, gain: float = 1.0,
              dst: np.ndarray | None = None) -> np.ndarray:
    """``img · gain · per_pixel − offset`` saturated to uint16: one u16×f32 pass and one saturating
    pass (OpenCV SIMD, ~3× numpy). ``dst``: a uint16 array of the result's shape to write into."""
    f = cv2.multiply(img, per_pixel, scale=float(gain), dtype=cv2.CV_32F)
    # OpenCV takes a Scalar (a tuple) as src2; its stubs declare only arrays
    return cv2.subtract(f, offset, dst=dst, dtype=cv2.CV_16U)  # pyright: ignore[reportCallIssue, reportArgumentType]


def apply_camera(x: np.ndarray, rgb_cam: np.ndarray, *, gain: float = 1.0, level_map: tuple | None = None,
                 black=(0.0, 0.0, 0.0), white=(65535.0, 65535.0, 65535.0), white_output: float = 1.0,
                 enabled: bool = True, dst: np.ndarray | None = None) -> np.ndarray:
    """Camera RGB (float32, white-balanced, 65535 = white level) to the output: the colour matrix
    ``rgb_cam``, then the shading factor (``level_map`` from :func:`level_map`) or the levels, and
    the gain; uint16 out, rounded and saturated (into ``dst`` when given)."""
    if level_map is not None:
        y = cv2.transform(x, np.asarray(rgb_cam, np.float64))
        return apply_map(y, *level_map, gain=gain, dst=dst)
    black, scale = _black_and_scale(black, white, white_output, enabled)
    y = cv2.transform(x, (gain * scale)[:, None] * np.asarray(rgb_cam, np.float64))
    offset = tuple(float(v) for v in black * scale) + (0.0,)    # a Scalar, which the cv2 stubs do not declare
    return cv2.subtract(y, offset, dst=dst, dtype=cv2.CV_16U)  # pyright: ignore[reportCallIssue, reportArgumentType]
