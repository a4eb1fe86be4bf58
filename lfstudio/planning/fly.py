"""Fly scanning: the row speed, and what it costs in time, decided from the camera, the scene and the axes.

A fly scan crosses each row at one constant speed ``v`` and takes a frame as the carriage passes
each grid position (rows in meander order; run-up and run-down outside the grid so every position
is crossed at speed). The fastest ``v`` is the smallest of these limits (each in mm/s):

- **blur**: the carriage moves ``v · t_exp`` during the exposure; at the nearest scene distance
  ``Z`` one pixel covers ``Z · s_p / f`` of the scene, so blur ≤ ``b`` px needs
  ``v ≤ b · Z · s_p / (f · t_exp)``;
- **camera**: one frame per grid spacing ``Δ``: ``v ≤ fps · Δ``;
- **bandwidth**: the frames must leave the camera as fast: ``v ≤ (bandwidth / bytes per frame) · Δ``;
- **position reports**: the controller reports its position at least once per grid spacing crossed
  (each frame's position is interpolated between two reports): ``v ≤ report rate · Δ``;
- **axis speed**: the horizontal axis' maximum speed;
- **run-up room**: run-up and run-down (``v² / 2a`` each) fit into the travel beside the row:
  ``v ≤ sqrt(a · (travel − row span))``.

A limit that leaves less than :data:`MIN_FLY_SPEED_MM_S` makes fly scanning impossible: the plan
says why with the numbers (:attr:`FlyResult.refusal`), and ``lfstudio scan --fly`` refuses before
anything moves. Pure arithmetic: no device, no Qt.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

from lfstudio import optics

#: the slowest constant row speed lfstudio flies at (a slower one is a step scan in disguise)
MIN_FLY_SPEED_MM_S = 0.5

#: the limits, in the order they are reported; :attr:`FlyResult.binding` names one of them
LIMITS = ("blur", "camera frame rate", "camera bandwidth", "position reports", "axis speed", "run-up room")


@dataclass(frozen=True)
class FlyInputs:
    """What decides a fly scan's speed. Lengths in mm, times in s; ``None``: no such limit."""

    columns: int
    rows: int
    spacing_mm: tuple[float, float]
    exposure_s: float
    near_mm: float
    focal_length_mm: float
    pixel_pitch_um: float
    blur_limit_px: float = 0.5
    frame_rate_fps: float | None = None
    bandwidth_mb_s: float | None = None
    bytes_per_frame: int | None = None
    report_rate_hz: float | None = None
    max_speed_mm_s: tuple[float, float] = (200.0, 100.0)
    acceleration_mm_s2: tuple[float, float] = (500.0, 300.0)
    travel_mm: float | None = None              # horizontal room for the row with its run-up and run-down
    settle_s: float = 0.3                       # after each row change
    transfer_s: float = 0.0                     # the last frame's, after the last row
    speed_mm_s: float | None = None             # asked for; None: the fastest the limits allow
    frames_per_view: int = 1


@dataclass(frozen=True)
class FlyResult:
    """The decided fly scan. ``possible`` False: ``refusal`` says why, with the numbers."""

    possible: bool
    speed_mm_s: float
    binding: str                                # which limit sets the speed
    limits_mm_s: dict[str, float]               # every limit that applies
    refusal: str = ""
    frame_interval_s: float = 0.0               # between two frames of a row
    run_up_mm: float = 0.0                      # on each side of the row
    row_s: float = 0.0                          # one row: run-up, crossing, run-down
    row_change_s: float = 0.0                   # vertical move and settle between rows
    time_s: float = 0.0                         # the whole fly scan
    blur_px: float = 0.0                        # at the near distance, at the decided speed
    mm_per_px_near: float = 0.0
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["limits_mm_s"] = {k: (v if math.isfinite(v) else None) for k, v in self.limits_mm_s.items()}
        return out


def mm_per_px(depth_mm: float, focal_length_mm: float, pixel_pitch_um: float) -> float:
    """How much of the scene at ``depth_mm`` one pixel covers (mm)."""
    return depth_mm * pixel_pitch_um / 1000.0 / focal_length_mm


def row_time_s(span_mm: float, speed_mm_s: float, acceleration_mm_s2: float) -> float:
    """One row from rest at its run-up start to rest at its run-down end: accelerate over
    ``v²/2a``, cross the row at ``v``, brake over ``v²/2a``."""
    return 2.0 * speed_mm_s / acceleration_mm_s2 + span_mm / speed_mm_s


def run_up_mm(speed_mm_s: float, acceleration_mm_s2: float) -> float:
    return speed_mm_s ** 2 / (2.0 * acceleration_mm_s2)


def _limit_text(name: str, f: FlyInputs, mpp: float) -> str:
    dh = f.spacing_mm[0]
    if name == "blur":
        return (f"blur ≤ {f.blur_limit_px:g} px at {f.near_mm / 1000:g} m (one pixel covers {mpp * 1000:.0f} µm there) "
                f"with {f.exposure_s * 1000:g} ms exposure")
    if name == "camera frame rate":
        return f"the camera's {f.frame_rate_fps:g} frames/s at {dh:g} mm spacing"
    if name == "camera bandwidth":
        per = (f.bytes_per_frame or 0) / 1e6
        return f"the camera's {f.bandwidth_mb_s:g} MB/s for {per:.1f} MB frames at {dh:g} mm spacing"
    if name == "position reports":
        return f"the controller's {f.report_rate_hz:g} position reports/s (one per {dh:g} mm crossed)"
    if name == "axis speed":
        return f"the horizontal axis' {f.max_speed_mm_s[0]:g} mm/s"
    return (f"run-up and run-down at {f.acceleration_mm_s2[0]:g} mm/s² within the {f.travel_mm or 0:g} mm travel "
            f"beside the {(f.columns - 1) * dh:g} mm row")


def plan_fly(f: FlyInputs) -> FlyResult:
    """The fastest (or the asked) row speed within every limit, and the fly scan's time."""
    dh = float(f.spacing_mm[0])
    span = (f.columns - 1) * dh
    mpp = mm_per_px(f.near_mm, f.focal_length_mm, f.pixel_pitch_um)
    limits: dict[str, float] = {}
    limits["blur"] = f.blur_limit_px * mpp / f.exposure_s if f.exposure_s > 0 else math.inf
    if f.columns > 1:
        if f.frame_rate_fps is not None:
            limits["camera frame rate"] = f.frame_rate_fps * dh
        if f.bandwidth_mb_s is not None and f.bytes_per_frame:
            limits["camera bandwidth"] = f.bandwidth_mb_s * 1e6 / f.bytes_per_frame * dh
        if f.report_rate_hz is not None:
            limits["position reports"] = f.report_rate_hz * dh
    limits["axis speed"] = float(f.max_speed_mm_s[0])
    a = float(f.acceleration_mm_s2[0])
    if f.travel_mm is not None:
        room = max(0.0, float(f.travel_mm) - span)
        limits["run-up room"] = math.sqrt(a * room)
    binding = min(limits, key=lambda k: limits[k])
    fastest = limits[binding]

    def refused(speed: float, text: str) -> FlyResult:
        return FlyResult(False, speed, binding, limits, text, mm_per_px_near=mpp,
                         blur_px=speed * f.exposure_s / mpp if mpp > 0 else 0.0)

    if f.frames_per_view > 1:
        return refused(0.0, f"an exposure bracket ({f.frames_per_view} frames a view) needs the carriage to stand "
                            "still: use a step scan, or one frame a view")
    if f.speed_mm_s is not None:
        over = [k for k in limits if f.speed_mm_s > limits[k] * (1 + 1e-9)]
        if over:
            k = min(over, key=lambda k: limits[k])
            return refused(f.speed_mm_s, f"{f.speed_mm_s:g} mm/s is faster than {_limit_text(k, f, mpp)} allow "
                                         f"({limits[k]:.3g} mm/s); choose at most {fastest:.3g} mm/s "
                                         f"({binding} binds)")
        speed, binding = float(f.speed_mm_s), "asked for"
    else:
        speed = fastest
    if speed < MIN_FLY_SPEED_MM_S:
        fix = {"blur": "a shorter exposure (more light or a strobe), a larger blur limit or a farther scene",
               "camera frame rate": "a faster camera",
               "camera bandwidth": "smaller frames or a faster link",
               "position reports": "a controller that reports its position more often",
               "axis speed": "a faster axis", "run-up room": "a shorter row or more travel"}.get(binding, "")
        return refused(speed, f"no fly speed keeps within {_limit_text(binding, f, mpp)}: it allows "
                              f"{speed:.3g} mm/s, below the slowest fly speed {MIN_FLY_SPEED_MM_S:g} mm/s; "
                              f"use a step scan{', or ' + fix if fix else ''}")
    row_s = row_time_s(span, speed, a)
    v_rate, v_acc = f.max_speed_mm_s[1], f.acceleration_mm_s2[1]
    change_s = optics.move_time_s(f.spacing_mm[1], v_rate, v_acc) + f.settle_s if f.rows > 1 else 0.0
    total = f.settle_s + f.rows * row_s + (f.rows - 1) * change_s + f.transfer_s
    notes = []
    if f.exposure_s > dh / speed:
        notes.append(f"the exposure ({f.exposure_s:g} s) is longer than the time between frames ({dh / speed:.3g} s)")
    return FlyResult(True, speed, binding, limits, "", frame_interval_s=dh / speed, run_up_mm=run_up_mm(speed, a),
                     row_s=row_s, row_change_s=change_s, time_s=total, blur_px=speed * f.exposure_s / mpp,
                     mm_per_px_near=mpp, notes=notes)


def fly_inputs_of(plan: Any, **changes: Any) -> FlyInputs:
    """The :class:`FlyInputs` of a scene plan (:class:`lfstudio.planning.scene_plan.ScenePlan`)."""
    from dataclasses import replace

    per_image = plan.bytes_per_image if plan.bytes_per_image is not None else \
        optics.raw_bytes_per_image(int(plan.sensor_px[0]), int(plan.sensor_px[1]), int(plan.raw_bits))
    fps = plan.frame_rate_fps
    if fps is None:                           # a tethered camera: each frame downloaded before the next
        fps = 1.0 / plan.transfer_s if plan.transfer_s > 0 else None
    inputs = FlyInputs(
        columns=int(plan.grid_columns), rows=int(plan.grid_rows),
        spacing_mm=(float(plan.spacing_mm[0]), float(plan.spacing_mm[1])),
        exposure_s=max(plan.frame_exposures_s()), near_mm=plan.near_m * 1000.0,
        focal_length_mm=float(plan.focal_length_mm), pixel_pitch_um=plan.pixel_pitch_used_um,
        blur_limit_px=float(plan.blur_limit_px), frame_rate_fps=fps, bandwidth_mb_s=plan.bandwidth_mb_s,
        bytes_per_frame=int(per_image), report_rate_hz=plan.report_rate_hz,
        max_speed_mm_s=(float(plan.max_speed_mm_s[0]), float(plan.max_speed_mm_s[1])),
        acceleration_mm_s2=(float(plan.acceleration_mm_s2[0]), float(plan.acceleration_mm_s2[1])),
        travel_mm=float(plan.travel_mm[0]), settle_s=float(plan.settle_s),
        transfer_s=float(plan.transfer_s) if plan.frame_rate_fps is None else 0.0,
        speed_mm_s=plan.fly_speed_mm_s, frames_per_view=plan.frames_per_view)
    return replace(inputs, **changes) if changes else inputs


def format_fly(r: FlyResult) -> str:
    """One line for the plan's table."""
    if not r.possible:
        return f"not possible: {r.refusal}"
    return (f"{r.speed_mm_s:.3g} mm/s ({r.binding} binds), a frame every {r.frame_interval_s * 1000:.0f} ms, "
            f"blur {r.blur_px:.2f} px at the near distance, run-up {r.run_up_mm:.2g} mm")
