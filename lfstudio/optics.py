"""Pure optics and timing formulas of SPEC "The optics". Units are in the names; no hidden conversions.

A base module (it imports nothing of lfstudio): planning, the rig driver, the scan plan, export and
the GUI all use it, so none of them imports another stage for a formula.

Symbols (SPEC): f focal length, s_p pixel pitch (the sensor's own pitch, not a "Bayer" pitch),
Z depth from the acquisition plane, Δ spacing between neighbouring camera positions,
B = (n − 1)·Δ the baseline of a row, c circle of confusion, N f-number, ε repositioning error.

Lengths that enter one formula are converted to millimetres at the boundary; every function says in
its name and arguments which unit it takes and returns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Iterable, overload

if TYPE_CHECKING:
    import numpy as np

#: wavelength used for the diffraction estimate (green, the middle of the visible band)
DIFFRACTION_WAVELENGTH_UM = 0.55


@dataclass(frozen=True)
class ReferenceSetup:
    """The paper's setup (SPEC): a Sony A7R II with a 50 mm lens on the reference gantry, scene
    1.77 m … 4.77 m, 101 × 21 views 4 mm × 6 mm apart. Its one home: the planner's defaults (the
    shipped presets say the same; tests/planning checks), the simulated studio's scene, the
    simulated camera's timing and the calibration study's rig all read it here."""

    sensor_px: tuple[int, int]
    sensor_mm: tuple[float, float]
    pixel_pitch_um: float
    focal_length_mm: float
    near_m: float
    far_m: float
    coc_mm: float
    grid: tuple[int, int]                          # columns, rows
    spacing_mm: tuple[float, float]                # horizontal, vertical
    repeatability_um: tuple[float, float]
    travel_mm: tuple[float, float]
    max_speed_mm_s: tuple[float, float]
    acceleration_mm_s2: tuple[float, float]
    settle_s: float                                # after each move
    exposure_s: float
    transfer_s: float                              # trigger + download of one image


REFERENCE = ReferenceSetup(
    sensor_px=(7952, 5304), sensor_mm=(35.9, 24.0), pixel_pitch_um=4.53, focal_length_mm=50.0,
    near_m=1.77, far_m=4.77, coc_mm=0.029, grid=(101, 21), spacing_mm=(4.0, 6.0),
    repeatability_um=(80.0, 50.0), travel_mm=(4000.0, 500.0), max_speed_mm_s=(200.0, 100.0),
    acceleration_mm_s2=(500.0, 300.0), settle_s=0.3, exposure_s=0.5, transfer_s=2.5)

# -- timing (used by the scan engine too) ---------------------------------------------------------


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


def bracket_camera_s(exposures_s: "Iterable[float]", transfer_s: float) -> float:
    """The camera's part of one view of an exposure bracket: every frame's exposure, and the transfer
    of every frame but the last between them (the camera takes the next frame only once the previous
    one is downloaded); the last frame's transfer overlaps the next move (:func:`view_period_s`).
    One frame: its exposure."""
    exposures = [float(e) for e in exposures_s]
    return sum(exposures) + max(0, len(exposures) - 1) * float(transfer_s)


def view_period_s(move_s: float, settle_s: float, exposure_s: float, transfer_s: float) -> float:
    """Critical-path time of one view of a pipelined scan: the transfer of the previous view overlaps
    this view's move and settle; the camera is needed again only for the exposure."""
    return exposure_s + max(transfer_s, move_s + settle_s)


def scan_duration_s(moves: Iterable[tuple[float, int]], settle_s: float, exposure_s: float, transfer_s: float,
                    pipelined: bool = True) -> float:
    """Estimated duration of a scan (the planner's capture time and the scan plan's estimate).

    ``moves``: (move time in s, how many views are reached by such a move) in path order; the first
    view's move comes first (0 s when the rig already stands there). Pipelined (the scan engine):
    the first view's move, settle and exposure, then :func:`view_period_s` per further view, then
    the last view's transfer. Not pipelined: move, settle, exposure and transfer of every view add up.
    """
    total, views = 0.0, 0
    for move_s, count in moves:
        count = int(count)
        if count <= 0:
            continue
        if not pipelined:
            total += count * (move_s + settle_s + exposure_s + transfer_s)
        else:
            if views == 0:      # nothing to overlap before the first view
                total += move_s + settle_s + exposure_s
                count -= 1
                views += 1
            total += count * view_period_s(move_s, settle_s, exposure_s, transfer_s)
        views += count
    return total + transfer_s if pipelined and views else total


# -- projection and disparity ----------------------------------------------------------------------


def image_coordinate_px(lateral_offset_mm: float, depth_mm: float, focal_length_mm: float,
                        pixel_pitch_um: float) -> float:
    """u = f·X / (s_p·Z): image coordinate (px, from the principal point) of a point at lateral
    offset X and depth Z from the camera."""
    return focal_length_mm * lateral_offset_mm / (pixel_pitch_um * 1e-3 * depth_mm)


@overload          # one depth, or an array of them (the planner's curves): the result is of the same kind
def disparity_px(baseline_mm: float, near_mm: float, far_mm: float, focal_length_mm: float,
                 pixel_pitch_um: float) -> float: ...
@overload
def disparity_px(baseline_mm: float, near_mm: np.ndarray, far_mm: float, focal_length_mm: float,
                 pixel_pitch_um: float) -> np.ndarray: ...
def disparity_px(baseline_mm: float, near_mm: Any, far_mm: float, focal_length_mm: float,
                 pixel_pitch_um: float) -> Any:
    """d = f·b/s_p · (1/Z1 − 1/Z2): disparity (px) between two views a baseline b apart, for the
    depths Z1 = ``near_mm`` and Z2 = ``far_mm`` (``far_mm`` may be ``math.inf``: disparity against
    infinity). With b = Δ it is the neighbour disparity; with b = B the row's scene parallax."""
    inv_far = 0.0 if math.isinf(far_mm) else 1.0 / far_mm
    return focal_length_mm * baseline_mm / (pixel_pitch_um * 1e-3) * (1.0 / near_mm - inv_far)


def baseline_mm(count: int, spacing_mm: float) -> float:
    """B = (n − 1)·Δ: distance between the first and the last of ``count`` positions."""
    return max(int(count) - 1, 0) * spacing_mm


def spacing_for_disparity_mm(max_disparity_px: float, near_mm: float, far_mm: float,
                             focal_length_mm: float, pixel_pitch_um: float) -> float:
    """Inverse of :func:`disparity_px` for the baseline: the largest neighbour spacing Δ (mm) whose
    disparity between ``near_mm`` and ``far_mm`` stays at ``max_disparity_px``."""
    per_mm = disparity_px(1.0, near_mm, far_mm, focal_length_mm, pixel_pitch_um)
    return max_disparity_px / per_mm


def positions_for_parallax(parallax_px: float, spacing_mm: float, near_mm: float, far_mm: float,
                           focal_length_mm: float, pixel_pitch_um: float) -> int:
    """Inverse for the grid size: the fewest positions n (columns of a row, or rows of a column) at
    spacing Δ whose baseline (n − 1)·Δ gives at least ``parallax_px`` between near and far."""
    per_step = disparity_px(spacing_mm, near_mm, far_mm, focal_length_mm, pixel_pitch_um)
    if parallax_px <= 0:
        return 1
    # a tiny tolerance keeps exact multiples from rounding up one position
    return int(math.ceil(parallax_px / per_step - 1e-9)) + 1


# -- depth of field --------------------------------------------------------------------------------


def hyperfocal_mm(focal_length_mm: float, f_number: float, coc_mm: float, exact: bool = True) -> float:
    """H = f + f²/(N·c) (``exact``), or the approximation H ≈ f²/(N·c) used by the depth-of-field
    and aperture formulas below (they are exact inverses of each other with the approximation)."""
    h = focal_length_mm ** 2 / (f_number * coc_mm)
    return h + focal_length_mm if exact else h


def dof_near_mm(hyperfocal_mm_: float, focus_mm: float) -> float:
    """D_N = H·s/(H + s): near limit of the sharp range when focused at s."""
    return hyperfocal_mm_ * focus_mm / (hyperfocal_mm_ + focus_mm)


def dof_far_mm(hyperfocal_mm_: float, focus_mm: float) -> float:
    """D_F = H·s/(H − s) for s < H; ``math.inf`` when focused at or beyond the hyperfocal distance."""
    if focus_mm >= hyperfocal_mm_:
        return math.inf
    return hyperfocal_mm_ * focus_mm / (hyperfocal_mm_ - focus_mm)


def f_number_for_range(near_mm: float, far_mm: float, focal_length_mm: float, coc_mm: float) -> float:
    """N = f²/c · (D_F − D_N)/(2·D_F·D_N): the f-number that keeps [D_N, D_F] sharp (when focused
    at :func:`focus_for_range_mm`). ``far_mm`` may be ``math.inf``."""
    if math.isinf(far_mm):
        return focal_length_mm ** 2 / coc_mm / (2.0 * near_mm)
    return focal_length_mm ** 2 / coc_mm * (far_mm - near_mm) / (2.0 * far_mm * near_mm)


def focus_for_range_mm(near_mm: float, far_mm: float) -> float:
    """s = 2·D_N·D_F/(D_N + D_F): the focus distance that centres the sharp range on [D_N, D_F]
    (the harmonic mean; 2·D_N when D_F is infinite)."""
    if math.isinf(far_mm):
        return 2.0 * near_mm
    return 2.0 * near_mm * far_mm / (near_mm + far_mm)


@overload          # one depth, or an array of them (the planner's curves): the result is of the same kind
def blur_diameter_mm(depth_mm: float, focus_mm: float, focal_length_mm: float, f_number: float) -> float: ...
@overload
def blur_diameter_mm(depth_mm: np.ndarray, focus_mm: float, focal_length_mm: float, f_number: float) -> np.ndarray: ...
def blur_diameter_mm(depth_mm: Any, focus_mm: float, focal_length_mm: float, f_number: float) -> Any:
    """Blur-circle diameter on the sensor of a point at depth Z when focused at s:
    b = f²/N · |1/s − 1/Z| (the same approximation as the formulas above: b = c exactly at D_N, D_F)."""
    return focal_length_mm ** 2 / f_number * abs(1.0 / focus_mm - 1.0 / depth_mm)


# -- repositioning error ---------------------------------------------------------------------------


def reposition_error_px(error_um: float, depth_mm: float, focal_length_mm: float,
                        pixel_pitch_um: float) -> float:
    """ε̃ = f·ε/(s_p·Z): a position error ε of the camera seen as an image shift (px) at depth Z."""
    return focal_length_mm * error_um / (pixel_pitch_um * depth_mm)


def min_distance_mm(error_um: float, focal_length_mm: float, pixel_pitch_um: float,
                    max_error_px: float = 0.5) -> float:
    """Z_min = f·ε/(ε̃_max·s_p): the closest depth at which the repositioning error stays below
    ``max_error_px`` (SPEC: 0.5 px)."""
    return focal_length_mm * error_um / (max_error_px * pixel_pitch_um)


# -- diffraction -----------------------------------------------------------------------------------


def airy_disk_um(f_number: float, wavelength_um: float = DIFFRACTION_WAVELENGTH_UM) -> float:
    """Diameter of the Airy disk (to the first dark ring), 2.44·λ·N, in µm."""
    return 2.44 * wavelength_um * f_number


def diffraction_limit_f_number(blur_um: float, wavelength_um: float = DIFFRACTION_WAVELENGTH_UM) -> float:
    """The f-number at which the Airy disk reaches ``blur_um`` (a circle of confusion, or 2 pixels)."""
    return blur_um / (2.44 * wavelength_um)


def diffraction_check(f_number: float, coc_mm: float, pixel_pitch_um: float,
                      wavelength_um: float = DIFFRACTION_WAVELENGTH_UM) -> tuple[str, float]:
    """How diffraction limits sharpness at ``f_number``: ``("ok" | "pixels" | "coc", airy_um)``.

    "pixels": the Airy disk is wider than 2 pixels, so the finest detail is softened (the image is
    diffraction-limited, while the depth-of-field criterion still holds); "coc": it is wider than the
    circle of confusion, so nothing is as sharp as the depth-of-field figures assume.
    """
    airy = airy_disk_um(f_number, wavelength_um)
    if airy > coc_mm * 1000.0:
        return "coc", airy
    if airy > 2.0 * pixel_pitch_um:
        return "pixels", airy
    return "ok", airy


# -- storage ---------------------------------------------------------------------------------------


def raw_bytes_per_image(width_px: int, height_px: int, bits: int = 14) -> int:
    """Size of an uncompressed raw frame: one sample per pixel, stored in whole bytes (14-bit data
    in 16-bit words, as uncompressed ARW/DNG do)."""
    return int(width_px) * int(height_px) * int(math.ceil(bits / 8))
