"""Step 4: shading — flat-field correction from a flat image, or a radial vignetting model.

The correction is a per-pixel factor map in the captured frame, 1 at the image centre:
``flat`` mode divides by the flat image normalised to its central region (per channel, so a colour
cast of the light falls off too, and dust spots are removed); ``model`` mode divides by
``V(r) = 1 + k1 r² + k2 r⁴ + k3 r⁶`` with r the distance from the centre over the half diagonal,
with the coefficients given or fitted to the flat image.
"""

from __future__ import annotations

import cv2
import numpy as np

from lfstudio.dataset.profile import ShadingStep
from lfstudio.errors import InputError

MIN_FLAT = 0.05  # of the centre level: darker flat pixels are not trusted (factor capped at 20)


def radius_sq(size_wh: tuple[int, int]) -> np.ndarray:
    """r² (float32, (h, w)) of each pixel centre, r = distance from the image centre / half diagonal."""
    w, h = size_wh
    x = (np.arange(w, dtype=np.float32) - (w - 1) / 2.0)
    y = (np.arange(h, dtype=np.float32) - (h - 1) / 2.0)
    half_diag_sq = ((w / 2.0) ** 2 + (h / 2.0) ** 2)
    return (x[None, :] ** 2 + y[:, None] ** 2) / np.float32(half_diag_sq)


def vignetting(size_wh: tuple[int, int], coefficients) -> np.ndarray:
    """V(r) = 1 + k1 r² + k2 r⁴ + k3 r⁶ on the pixel grid (float32, (h, w))."""
    k = list(coefficients) + [0.0] * (3 - len(coefficients))
    r2 = radius_sq(size_wh)
    return 1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[2]))


def centre_level(img: np.ndarray) -> np.ndarray:
    """Per-channel median of the central 10 % × 10 % of ``img`` (float; robust to a dust spot)."""
    h, w = img.shape[:2]
    y0, x0 = int(h * 0.45), int(w * 0.45)
    patch = img[y0: max(y0 + 1, int(h * 0.55)), x0: max(x0 + 1, int(w * 0.55))]
    return np.median(patch.reshape(-1, patch.shape[-1] if patch.ndim == 3 else 1), axis=0).astype(np.float64)


def fit_vignetting(flat: np.ndarray, max_side_px: int = 256) -> list[float]:
    """Least-squares k1, k2, k3 of the flat image's luminance falloff (normalised at the centre)."""
    h, w = flat.shape[:2]
    s = min(1.0, max_side_px / max(w, h))
    small = cv2.resize(flat, (max(8, int(w * s)), max(8, int(h * s))), interpolation=cv2.INTER_AREA)
    lum = small.astype(np.float64).mean(axis=2) if small.ndim == 3 else small.astype(np.float64)
    lum /= max(float(centre_level(lum[..., None])[0]), 1e-9)
    r2 = radius_sq((lum.shape[1], lum.shape[0])).astype(np.float64)
    A = np.stack([r2, r2 ** 2, r2 ** 3], axis=-1).reshape(-1, 3)
    k, *_ = np.linalg.lstsq(A, (lum - 1.0).reshape(-1), rcond=None)
    return [float(v) for v in k]


def correction_from_flat(flat: np.ndarray, blur_px: float = 0.0) -> np.ndarray:
    """Factor map (float32, (h, w, 3)) that makes ``flat`` uniform at its centre level."""
    f = flat.astype(np.float32)
    if blur_px > 0:
        f = cv2.GaussianBlur(f, (0, 0), blur_px)
    level = centre_level(f).astype(np.float32)
    f = np.maximum(f, level * MIN_FLAT)
    return level / f


def correction_from_model(size_wh: tuple[int, int], coefficients) -> np.ndarray:
    """Factor map (float32, (h, w, 1)) 1/V(r)."""
    v = np.maximum(vignetting(size_wh, coefficients), MIN_FLAT)
    return (1.0 / v)[:, :, None].astype(np.float32)


def correction(step: ShadingStep, size_wh: tuple[int, int], flat: np.ndarray | None) -> tuple[np.ndarray, list[float]]:
    """(factor map for an image of ``size_wh``, model coefficients used or []); ``flat`` (the flat
    image) is needed unless the model's coefficients are given (:meth:`Profile.validate` says so)."""
    if step.mode == "model" and step.coefficients:
        coeffs = list(step.coefficients)
        return correction_from_model(size_wh, coeffs), coeffs
    if flat is None:
        raise InputError("processing.toml: [shading] flat_file", f"shading mode {step.mode!r} needs a flat image "
                         "(a RAW or PNG of a uniformly lit white card)"
                         f"{'' if step.mode == 'flat' else ' or the coefficients'}")
    if step.mode == "model":
        coeffs = fit_vignetting(flat)
        return correction_from_model(size_wh, coeffs), coeffs
    if flat.shape[1] != size_wh[0] or flat.shape[0] != size_wh[1]:
        flat = cv2.resize(flat, tuple(size_wh), interpolation=cv2.INTER_AREA)
    return correction_from_flat(flat, step.blur_px), []
