"""The camera model shared by calibration, simulation, processing and the virtual studio.

Conventions (see ``docs/conventions.md``):

- rig frame: x to the right, y down, z into the scene; pixel (0, 0) is the centre of the top-left
  pixel, u to the right, v down;
- ``K = [[f, 0, cx], [0, f, cy], [0, 0, 1]]``; the nominal principal point is ``((w-1)/2, (h-1)/2)``;
- orientation error ``rotation_deg = [rx, ry, rz]``,
  ``R = Rotation.from_euler("xyz", rotation_deg, degrees=True).as_matrix()``;
- a world point X seen from camera centre C is captured at ``p ~ K_true · R · (X − C)``;
- the ideal (rectified) camera ``K0`` has the same f and the nominal centre: ``p_rect ~ K0 · (X − C)``;
- so the rectifying homography (captured full-resolution pixel → rectified pixel) is
  ``H = K0 · Rᵀ · K_true⁻¹``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

ROTATION_CONVENTION = (
    "R = scipy.spatial.transform.Rotation.from_euler('xyz', rotation_deg, degrees=True).as_matrix(); "
    "rig frame x right, y down, z into the scene; a point X seen from camera centre C is captured at "
    "p ~ K_true R (X - C); rectified p_rect ~ K0 (X - C); H = K0 R^T K_true^-1 maps a captured "
    "full-resolution pixel to the rectified pixel; pixel centres at integer coordinates")


def rotation_matrix(rotation_deg: Sequence[float]) -> np.ndarray:
    """3 × 3 orientation error R from ``[rx, ry, rz]`` in degrees (extrinsic x-y-z)."""
    return Rotation.from_euler("xyz", np.asarray(rotation_deg, dtype=float), degrees=True).as_matrix()


def rotation_deg_from_matrix(R: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(R).as_euler("xyz", degrees=True)


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle of the rotation taking R_a to R_b (geodesic distance), degrees."""
    return float(np.degrees(Rotation.from_matrix(R_a.T @ R_b).magnitude()))


def nominal_principal_point(image_size_px: Sequence[int]) -> np.ndarray:
    w, h = image_size_px
    return np.array([(w - 1) / 2.0, (h - 1) / 2.0])


def intrinsics(focal_length_px: float, principal_point_px: Sequence[float]) -> np.ndarray:
    cx, cy = principal_point_px
    f = float(focal_length_px)
    return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])


def rectifying_homography(rotation_deg: Sequence[float], focal_length_px: float, image_size_px: Sequence[int],
                          principal_point_px: Sequence[float] | None = None) -> np.ndarray:
    """``H = K0 · Rᵀ · K_true⁻¹`` normalised to ``H[2, 2] = 1`` (captured full-res pixel → rectified pixel)."""
    nominal = nominal_principal_point(image_size_px)
    pp = nominal if principal_point_px is None else np.asarray(principal_point_px, dtype=float)
    K0 = intrinsics(focal_length_px, nominal)
    K = intrinsics(focal_length_px, pp)
    H = K0 @ rotation_matrix(rotation_deg).T @ np.linalg.inv(K)
    return H / H[2, 2]


def apply_homography(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Map points ``xy`` (N × 2) through H; returns N × 2."""
    xy = np.asarray(xy, dtype=float)
    p = xy @ H[:, :2].T + H[:, 2]
    w = p[:, 2:3]
    w = np.where(np.abs(w) < 1e-12, 1e-12, w)
    return p[:, :2] / w


def pixel_scale_matrix(scale: float) -> np.ndarray:
    """Map pixel coordinates of an image to those of the same image scaled by ``scale``.

    Pixel centres sit at integer coordinates, so ``x_scaled = (x + 0.5) · scale − 0.5``.
    """
    s = float(scale)
    o = 0.5 * s - 0.5
    return np.array([[s, 0.0, o], [0.0, s, o], [0.0, 0.0, 1.0]])


def scale_homography(H: np.ndarray, from_size_px: Sequence[int], to_size_px: Sequence[int]) -> np.ndarray:
    """The full-resolution homography H expressed for images of ``to_size_px`` (same aspect).

    ``H_to = S · H · S⁻¹`` with ``S`` = :func:`pixel_scale_matrix` (to_width / from_width).
    """
    S = pixel_scale_matrix(float(to_size_px[0]) / float(from_size_px[0]))
    return S @ np.asarray(H, dtype=float) @ np.linalg.inv(S)


def project(points_m: np.ndarray, centre_m: np.ndarray, R: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of world points (N × 3) seen from ``centre_m``: ``p ~ K R (X − C)``; also the depth."""
    cam = (np.asarray(points_m) - np.asarray(centre_m)) @ R.T
    p = cam @ K.T
    return p[:, :2] / p[:, 2:3], cam[:, 2]
