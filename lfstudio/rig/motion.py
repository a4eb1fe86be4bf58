"""The motion-controller interface every axis driver implements, and the rig's axis configuration.

Drivers are synchronous and know nothing about threads or Qt; :mod:`lfstudio.rig.worker` runs them
on a thread. Positions are in mm in the rig's frame: x horizontal (0 at the left end of travel),
y vertical (0 at the top end of travel), unless the profile says otherwise.
"""

from __future__ import annotations

import enum
import math
from dataclasses import MISSING, dataclass, field
from typing import Callable, Protocol, runtime_checkable

from lfstudio.errors import InputError
from lfstudio.numbers import Number, described


class RigState(str, enum.Enum):
    DISCONNECTED = "disconnected"
    IDLE = "idle"
    MOVING = "moving"
    JOGGING = "jogging"
    HOMING = "homing"
    HOLD = "hold"
    ALARM = "alarm"


#: controller axis letters a profile may name
AXIS_LETTERS = ("X", "Y", "Z", "A", "B", "C")
#: the axis drivers lfstudio has
DRIVERS = ("grbl", "cia402")
#: CiA 402 homing methods (6098h) lfstudio drives: limit switch at the low / high end, current position
HOMING_METHODS = (17, 18, 35, 37)
#: the profile's groups (the rig panel shows them in this order)
MOTION, DRIVE = "motion", "CiA 402 drive"


@dataclass(frozen=True)
class AxisConfig:
    """One linear axis. ``soft_min_mm``/``soft_max_mm``: no target outside this range is ever sent.
    Every field a profile file sets is described once here (:func:`lfstudio.numbers.described`): the
    profile's loader (:func:`lfstudio.rig.profile.rig_from_dict`) checks it and the window shows it."""

    name: str                      # "horizontal" | "vertical" (the profile's table, not a setting)
    letter: str = described(
        MISSING, choices=AXIS_LETTERS, label="Controller axis", group=MOTION,
        tip="The controller's axis letter driving this axis (GRBL: X, Y or Z; CiA 402 drives: optional)")
    travel_mm: float = described(
        MISSING, number=Number("mm", 0, 100_000, low_open=True), label="Travel", group=MOTION,
        tip="Length the carriage can travel; the rig's frame runs from 0 at one end to this at the other")
    soft_min_mm: float = described(
        MISSING, number=Number("mm", 0, 100_000), label="Soft limit (low)", group=MOTION,
        tip="No target below this is ever sent; inside 0 … travel_mm and below soft_max_mm")
    soft_max_mm: float = described(
        MISSING, number=Number("mm", 0, 100_000), label="Soft limit (high)", group=MOTION,
        tip="No target above this is ever sent; inside 0 … travel_mm and above soft_min_mm")
    max_speed_mm_s: float = described(
        MISSING, number=Number("mm/s", 0.01, 10_000), label="Speed", group=MOTION,
        tip="Highest speed of the axis (moves, homing and jogs); from a crawl to faster than any gantry")
    acceleration_mm_s2: float = described(
        MISSING, number=Number("mm/s²", 0.01, 1_000_000), label="Acceleration", group=MOTION,
        tip="Acceleration of the axis")
    repeatability_um: float = described(
        MISSING, number=Number("µm", 0, 100_000), label="Repeatability", group=MOTION,
        tip="Repositioning error of the axis (the planner turns it into image pixels)")
    settle_s: float = described(
        0.3, number=Number("s", 0, 3600), label="Settle", group=MOTION,
        tip="Wait after each move before exposing, for vibrations to die down")
    increments_per_mm: float = described(
        0.0, number=Number("increments/mm", 0, 1e9), label="Feed constant", group=DRIVE,
        tip="CiA 402 drives: the drive's position units per mm (100: it counts 0.01 mm; 6092h); "
            "required and > 0 for driver = \"cia402\", unused by GRBL")
    feed_mm_per_rev: float = described(
        0.0, number=Number("mm", 0, 100_000), label="Feed per revolution", group=DRIVE,
        tip="CiA 402 drives: how far the carriage travels per revolution of the drive's shaft (70 for a "
            "70 mm/rev toothed belt); with it the drive's feed constant 6092h is checked against the feed "
            "constant above before anything moves. 0: not given (the drive's SI unit 60A8h is still checked)")
    eds_file: str = described(
        "", label="EDS/DCF file", group=DRIVE,
        tip="CiA 402 drives: the drive maker's EDS (or a DCF) file; its objects are the drive's (python-canopen "
            "builds the object dictionary from it, for CANopen and Modbus TCP drives alike). A relative path is "
            "taken from the profile file's folder. Empty: the objects are read from the drive at connect")
    homing_method: int = described(
        0, number=Number("", 0, 99, integer=True), choices=(0, *HOMING_METHODS), label="Homing method",
        group=DRIVE, tip="CiA 402 drives: 6098h: 17 negative / 18 positive limit switch, 35/37 the current "
                         "position (default 17); 0: not a CiA 402 axis")

    def contains(self, position_mm: float, tolerance_mm: float = 1e-9) -> bool:
        return self.soft_min_mm - tolerance_mm <= position_mm <= self.soft_max_mm + tolerance_mm


@dataclass(frozen=True)
class RigConfig:
    """A rig profile (``resources/presets/rigs.toml``): its fields described once, as
    :class:`AxisConfig`'s; ``horizontal``/``vertical`` are the profile's axis tables."""

    name: str
    horizontal: AxisConfig
    vertical: AxisConfig
    label: str = described("", label="Description", tip="What the rig is, as the Rig panel shows it")
    homing: bool = described(True, flag=True, label="Limit switches",
                             tip="true: the rig homes to its limit switches; false: no switches, the operator "
                                 "sets the origin instead")
    driver: str = described("grbl", choices=DRIVERS, label="Driver",
                            tip="grbl: one GRBL board for both axes; cia402: one CiA 402 drive per axis "
                                "(igus dryve D1 over Modbus TCP or CANopen)")


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


@dataclass(frozen=True)
class PositionReport:
    """Where the controller said the carriage was, and when: ``t_s`` on the ``time.monotonic()`` clock
    (the middle of the question and the answer), ``uncertainty_s`` half their time apart."""

    t_s: float
    x_mm: float
    y_mm: float
    uncertainty_s: float = 0.0


@runtime_checkable
class FlyingController(Protocol):
    """A controller that moves at a chosen constant speed and reports time-stamped positions (fly
    scanning). ``fly_to`` starts a straight move at ``speed_mm_s`` and returns once the controller
    has it (not when it arrives); ``report`` asks the position now; ``wait_arrival`` waits until Idle
    at the target (STOP ends it as it ends ``move_to``)."""

    def fly_to(self, x_mm: float, y_mm: float, speed_mm_s: float) -> None: ...
    def report(self) -> PositionReport: ...
    def wait_arrival(self, x_mm: float, y_mm: float, timeout_s: float) -> RigStatus: ...


@dataclass(frozen=True)
class Latch:
    """A position the controller latched in hardware on an input edge (CiA 402 touch probe: the
    camera's exposure output wired to the drive's probe input). The edges came after ``t_after_s`` and
    before ``t_seen_s`` (``time.monotonic()``: when the driver looked and did not see them yet, and when
    it saw them); ``x_mm``/``y_mm`` where the carriage was (the exposure's centre when ``edges`` is
    "both": the mean of the rising and falling edge; its start when "rising"). ``span_mm``: how far
    apart the two edges were latched (the travel during the exposure, when both belong to one frame)."""

    t_after_s: float
    t_seen_s: float
    x_mm: float
    y_mm: float
    uncertainty_mm: float
    edges: str = "both"
    span_mm: float = 0.0


@runtime_checkable
class LatchesPositions(Protocol):
    """A :class:`FlyingController` whose drives latch positions in hardware: ``latches`` returns (and
    forgets) those latched since the last ``fly_to``, oldest first; empty when it latched none."""

    def latches(self) -> list[Latch]: ...


@runtime_checkable
class PulsesAtPositions(Protocol):
    """A controller that drives the camera's trigger line itself as the carriage passes positions
    during a fly (a hardware trigger: GRBL 1.1's spindle output in laser mode). ``pulse_problem``
    says with the numbers why it cannot at that spacing and speed (None: it can); ``fly_pulsing``
    flies to ``end_x_mm`` at the speed, the line rising at each of ``xs_mm``, and returns once the
    controller holds the whole row (``wait_arrival`` then waits); ``pulse_off`` ends the output."""

    def pulse_problem(self, spacing_mm: float, speed_mm_s: float) -> str | None: ...
    def fly_pulsing(self, xs_mm: list[float], end_x_mm: float, y_mm: float, speed_mm_s: float) -> None: ...
    def pulse_off(self) -> None: ...


class SoftLimitError(InputError):
    """A target outside the rig's soft limits; nothing was sent to the controller."""

    kind = "soft-limit"


@runtime_checkable
class ReportsProgress(Protocol):
    """A controller that says what each axis is doing while it homes (the CiA 402 drive pair):
    ``progress`` is called with one line at a time (None: nobody listens)."""

    progress: Callable[[str], None] | None

    def home(self) -> None: ...


@runtime_checkable
class ChecksTargets(Protocol):
    """A controller that checks a target against its limits without moving (raises SoftLimitError)."""

    def check_target(self, x_mm: float, y_mm: float) -> tuple[float, float]: ...


@runtime_checkable
class HasPort(Protocol):
    """A controller that tells what it opened (a serial port, the drives' word)."""

    port: str


@runtime_checkable
class KnowsTruePosition(Protocol):
    """A simulated controller that knows where its carriage really is (the simulated camera renders
    from it)."""

    def true_position_mm(self) -> tuple[float, float]: ...


@runtime_checkable
class HasFirmware(Protocol):
    """A controller that tells its firmware's version (GRBL's banner: "1.1h")."""

    version: str


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
