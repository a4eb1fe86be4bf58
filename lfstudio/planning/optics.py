"""Pure optics and timing formulas. Units are in the names; no hidden conversions.

(The scene-planner formulas of SPEC "The optics" are added here by the planner.)
"""

from __future__ import annotations

import math


def move_time_s(distance_mm: float, max_speed_mm_s: float, acceleration_mm_s2: float) -> float:
    """Time of a point-to-point move with a trapezoidal (or triangular) speed profile, from rest to rest."""
    d = abs(distance_mm)
    if d == 0:
        return 0.0
    if max_speed_mm_s <= 0 or acceleration_mm_s2 <= 0:
        raise ValueError("max_speed_mm_s and acceleration_mm_s2 must be positive")
    d_ramp = max_speed_mm_s ** 2 / acceleration_mm_s2   # distance to reach full speed and stop again
    if d <= d_ramp:
        return 2.0 * math.sqrt(d / acceleration_mm_s2)
    return 2.0 * max_speed_mm_s / acceleration_mm_s2 + (d - d_ramp) / max_speed_mm_s


def view_period_s(move_s: float, settle_s: float, exposure_s: float, transfer_s: float) -> float:
    """Critical-path time of one view of a pipelined scan: the transfer of the previous view overlaps
    this view's move and settle; the camera is needed again only for the exposure."""
    return exposure_s + max(transfer_s, move_s + settle_s)
