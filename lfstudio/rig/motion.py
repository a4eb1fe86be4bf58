"""The motion-controller interface every axis driver implements, and the rig's axis configuration.

Drivers are synchronous and know nothing about threads or Qt; :mod:`lfstudio.rig.worker` runs them
on a thread. Positions are in mm in the rig's frame: x horizontal (0 at the left end of travel),
y vertical (0 at the top end of travel), unless the profile says otherwise.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from lfstudio.errors import InputError


class RigState(str, enum.Enum):
    DISCONNECTED = "disconnected"
    IDLE = "idle"
    MOVING = "moving"
    JOGGING = "jogging"
    HOMING = "homing"
    HOLD = "hold"
    ALARM = "alarm"


@dataclass(frozen=True)
class AxisConfig:
    """One linear axis. ``soft_min_mm``/``soft_max_mm``: no target outside this range is ever sent."""

    name: str                      # "horizontal" | "vertical"
    letter: str                    # controller axis letter driving it ("X", "Y", "Z", ...)
    travel_mm: float
    soft_min_mm: float
    soft_max_mm: float
    max_speed_mm_s: float
    acceleration_mm_s2: float
    repeatability_um: float
    settle_s: float = 0.3
    increments_per_mm: float = 0.0   # CiA 402 drives: the feed constant (drive position units per mm)
    homing_method: int = 0           # CiA 402 drives: 6098h (17 negative / 18 positive limit switch, 35/37 here)

    def contains(self, position_mm: float, tolerance_mm: float = 1e-9) -> bool:
        return self.soft_min_mm - tolerance_mm <= position_mm <= self.soft_max_mm + tolerance_mm


@dataclass(frozen=True)
class RigConfig:
    """A rig profile (``resources/presets/rigs.toml``)."""

    name: str
    horizontal: AxisConfig
    vertical: AxisConfig
    label: str = ""
    homing: bool = True            # False: no limit switches, set the origin explicitly instead
    driver: str = "grbl"           # "grbl" (one GRBL board) | "cia402" (one CiA 402 drive per axis)


@dataclass(frozen=True)
class RigStatus:
    """A snapshot of the rig. ``position_mm`` is (x, y) as reported by the controller (None if unknown)."""

    state: RigState
    position_mm: tuple[float, float] | None = None
    homed: bool = False            # homed or origin set: motion is allowed
    message: str = ""              # alarm / error text an operator understands, "" when fine
    extra: dict = field(default_factory=dict)   # driver-specific fields (feed, buffer, pins, ...)


@runtime_checkable
class MotionController(Protocol):
    """What the scan engine and the GUI need from an axis controller. All methods block; every
    wait has a timeout and raises :class:`lfstudio.errors.DeviceError` subclasses on failure."""

    config: RigConfig

    def connect(self) -> None: ...
    def disconnect(self) -> None: ...
    def home(self) -> None: ...
    def set_origin(self) -> None: ...
    def move_to(self, x_mm: float, y_mm: float, timeout_s: float | None = None) -> RigStatus:
        """Move to the absolute target and return once Idle *and* at the target within tolerance."""
        ...
    def jog(self, dx_mm: float, dy_mm: float, speed_mm_s: float | None = None) -> None: ...
    def jog_cancel(self) -> None: ...
    def feed_hold(self) -> None: ...
    def resume(self) -> None: ...
    def stop(self) -> None:
        """Stop all motion now (hold + jog cancel, then reset if needed). Safe from any thread."""
        ...
    def reset(self) -> None: ...
    def status(self) -> RigStatus: ...


class SoftLimitError(InputError):
    """A target outside the rig's soft limits; nothing was sent to the controller."""


def check_target(config: RigConfig, x_mm: float, y_mm: float) -> tuple[float, float]:
    """Return (x, y) as floats if both are finite and inside the soft limits, else raise
    :class:`SoftLimitError` naming the axis and the valid range. Call before sending any target."""
    result = []
    for axis, value, label in ((config.horizontal, x_mm, "x"), (config.vertical, y_mm, "y")):
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise SoftLimitError(f"target {label} ({axis.name})", f"{value!r} is not a number") from None
        if not math.isfinite(v):
            raise SoftLimitError(f"target {label} ({axis.name})", f"{value!r} is not a finite number")
        if not axis.contains(v):
            raise SoftLimitError(f"target {label} ({axis.name})",
                                 f"{v:g} mm is outside the soft limits; nothing was sent",
                                 f"{axis.soft_min_mm:g} … {axis.soft_max_mm:g} mm")
        result.append(min(max(v, axis.soft_min_mm), axis.soft_max_mm))
    return result[0], result[1]


def clamp_target(config: RigConfig, x_mm: float, y_mm: float) -> tuple[float, float]:
    """The nearest point inside the soft limits (for jogging up to a limit)."""
    h, v = config.horizontal, config.vertical
    return (min(max(float(x_mm), h.soft_min_mm), h.soft_max_mm),
            min(max(float(y_mm), v.soft_min_mm), v.soft_max_mm))
