"""The linear epipole method: the orientation in closed form from the match lines (known K).

The rig only translates, so every horizontal pair (b to the right of a) has its epipole in the
direction ``R · e_x`` and every vertical pair (b below a) in ``R · e_y`` (camera frame, see
:mod:`lfstudio.calibration.model`). With normalised rays ``x = K⁻¹ · p``, the line through the two
rays of a match, ``l = x_a × x_b``, contains the epipole: ``lᵀ · e = 0``. Stacking the lines of
every horizontal match gives ``e_h`` as the right singular vector of the smallest singular value
(the same for vertical matches and ``e_v``); the rotation taking ``(e_x, e_y)`` to ``(e_h, e_v)``
is then the orthogonal Procrustes (Kabsch) solution. The un-normalised cross product weights a
match by its disparity, which is roughly what its information is worth.

No iteration, no start value: the fit (:mod:`lfstudio.calibration.fit`) uses it as an initial guess
and as a cross-check. It is as good as the fit on clean long-baseline matches and much worse on
short baselines (disparities of a few pixels leave the lines' directions to noise).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from lfstudio.calibration.model import intrinsics, nominal_principal_point, rotation_deg_from_matrix


@dataclass
class LinearResult:
    rotation_deg: np.ndarray            # [rx, ry, rz], the model's Euler convention
    epipole_h: np.ndarray | None        # unit vector R·e_x in the camera frame (None: no horizontal pairs)
    epipole_v: np.ndarray | None        # unit vector R·e_y


def _epipole(xy_a: np.ndarray, xy_b: np.ndarray, Kinv: np.ndarray, nominal: np.ndarray) -> np.ndarray | None:
    """Unit epipole direction of a set of matches sharing one translation direction ``nominal``."""
    if len(xy_a) < 2:
        return None
    ra = np.column_stack([xy_a, np.ones(len(xy_a))]) @ Kinv.T
    rb = np.column_stack([xy_b, np.ones(len(xy_b))]) @ Kinv.T
    lines = np.cross(ra, rb)
    _, _, vt = np.linalg.svd(lines, full_matrices=False)
    e = vt[-1]
    return e if e @ nominal >= 0 else -e


def linear_rotation(matches: Sequence, focal_length_px: float, image_size_px: Sequence[int],
                    principal_point_px: Sequence[float] | None = None) -> LinearResult | None:
    """Closed-form orientation from ``matches`` (:class:`lfstudio.calibration.fit.PairMatches`).

    Needs both horizontal and vertical matches (one direction leaves the rotation about it free);
    returns None otherwise.
    """
    pp = nominal_principal_point(image_size_px) if principal_point_px is None else np.asarray(principal_point_px)
    Kinv = np.linalg.inv(intrinsics(focal_length_px, pp))
    out = {}
    for direction, nominal in (("h", np.array([1.0, 0.0, 0.0])), ("v", np.array([0.0, 1.0, 0.0]))):
        sel = [m for m in matches if m.direction == direction and m.count > 0]
        if not sel:
            out[direction] = None
            continue
        out[direction] = _epipole(np.concatenate([m.xy_a for m in sel]), np.concatenate([m.xy_b for m in sel]),
                                  Kinv, nominal)
    e_h, e_v = out["h"], out["v"]
    if e_h is None or e_v is None:
        return None
    # Kabsch: R minimising |R e_x − e_h|² + |R e_y − e_v|²
    M = np.outer(e_h, [1.0, 0.0, 0.0]) + np.outer(e_v, [0.0, 1.0, 0.0])
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)) or 1.0)])
    R = U @ D @ Vt
    return LinearResult(rotation_deg=np.asarray(rotation_deg_from_matrix(R), float), epipole_h=e_h, epipole_v=e_v)
