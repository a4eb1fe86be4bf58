"""CiA 402 motion driver: a rig of one drive per axis (igus dryve D1, Nanotec, Festo CMMT, Maxon
EPOS, ...), each reached through an :class:`ObjectLink` (read/write one object of its object
dictionary, as an SDO does): Modbus TCP gateway telegrams (:mod:`lfstudio.rig.dryve`) or CANopen
SDO (:mod:`lfstudio.rig.canopen_link`). Synchronous; run it through a DeviceWorker.

What it does with the drives (object numbers of the CiA 402 profile):

- **Power state machine** read from the status word ``6041h`` (:func:`power_state`): Shutdown
  (``6040h`` = 06h) → Switch on (07h) → Enable operation (0Fh) before the first motion; a quick
  stop (0Bh, bit 2 low) is left with Enable operation; a fault with Fault reset (bit 7 rising,
  :meth:`Cia402Controller.reset`).
- **Homing** (``6060h`` = 6): method ``6098h`` from the rig profile, speeds ``6099h:01/02`` and
  acceleration ``609Ah`` from the profile's axis speed/acceleration; both drives start together
  (bit 4), done when both report homing attained (bit 12) and target reached (bit 10); bit 13 is a
  homing error.
- **Profile position** (``6060h`` = 1): ``6081h`` velocity, ``6083h``/``6084h`` acceleration and
  deceleration, ``607Ah`` target; the new-set-point / set-point-acknowledge handshake (control bit
  4 down until status bit 12 is gone, so that a handshake a killed process left half done cannot
  pass for this one; bit 4 up, wait for bit 12, bit 4 down) on both drives before either is waited for, so both
  axes start together; the move is complete when both report target reached (bit 10) *and*
  ``6064h`` is at the target within the tolerance. A fault or a following error (bit 13, ``60F4h``)
  ends it with the drive's error code ``603Fh`` as an operator message (:func:`fault_message`).
- **Objects discovered, not assumed** (:meth:`Cia402Controller.connect`): each drive's objects are
  read once (a refused read: the drive lacks it), or listed by its EDS/DCF when the rig profile
  names one. Mandatory ones (:data:`MANDATORY`; :data:`MANDATORY_HOMING` for homing) are refused by
  name before anything moves; optional ones (:data:`OPTIONAL`) are used where present, with their
  fallback said once (``warnings`` in the status) where absent.
- **Units** checked before any motion: ``increments_per_mm`` of each axis in the rig profile (drive
  position units per mm; positive, never 0: invert an axis with the drive's polarity ``607Eh``)
  against the drive's SI unit ``60A8h`` and its feed constant ``6092h`` (with the profile's
  ``feed_mm_per_rev``); a mismatch refuses every motion naming both and the fix (:meth:`write_units`
  writes the profile's units to stopped drives). Speeds and accelerations are written in the units
  ``60A9h``/``60AAh`` report, where the drive has them.
- **Arrival**: target reached (bit 10) and ``6064h`` within the drive's position window ``6067h``
  (an explicit ``tolerance_mm`` may tighten it, never loosen it).
- **Limits**: a target must be inside the profile's soft limits *and* the drive's own software
  position limits ``607Dh`` (read at connect); nothing is sent otherwise.
- **STOP** (:meth:`Cia402Controller.stop`): quick stop (control word 0Bh) to both drives at once,
  from any thread, each on a thread and a path of its own (a second Modbus TCP connection while the
  link's is busy; on CANopen an SDO exchange stalled for 20 ms is interrupted), so that it never
  waits for a running command nor behind an exchange, and a stalled link delays no other drive; the drives brake on their quick-stop ramp (``605Ah`` = 6: stay in quick
  stop active once at rest, position kept). The waiting command ends with where the rig stopped;
  the next command re-enables operation.
- **Fly scanning** (:class:`lfstudio.rig.motion.FlyingController`, :meth:`Cia402Controller.fly_to`):
  a row is one profile position move at the row speed (``6081h``); during it the moving drive's
  ``6064h`` is read, each read time-stamped with the middle of its question and answer (half the
  round trip: its uncertainty). Where the drives have touch probe 1 (``60B8h``–``60BBh``, CiA 402 /
  IEC 61800-7-201) it latches the position on both edges of the camera's exposure output
  (:class:`lfstudio.rig.motion.LatchesPositions`). The igus dryve D1 has no touch probe and no
  position compare (its manual's objects; its digital outputs ``60FEh`` are set by a bus write, timed
  by this computer like a software trigger): its fly scans interpolate ``6064h`` reads, said once.
- **Reference** established, never inferred: the rig is homed only when lfstudio homed it (or set
  its origin) on this connection, or when the operator accepts the drives' own reference
  (:meth:`Cia402Controller.accept_reference`: ``--keep-drive-reference``, the Rig panel's **Keep
  drive reference**; logged, reported as reference "kept"). A drive found enabled in profile
  position mode is *not* taken as homed: another program may have enabled it without homing.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import Callable, Protocol

from lfstudio.errors import DeviceError, DeviceTimeout
from lfstudio.optics import move_time_s
from lfstudio.rig.motion import (Latch, PositionReport, RigConfig, RigState, RigStatus, SoftLimitError, check_target,
                                 clamp_target)

log = logging.getLogger(__name__)

# -- objects: index -> (bytes, signed) --------------------------------------------------------------
ERROR_CODE, CONTROL, STATUS, QUICK_STOP_OPTION = 0x603F, 0x6040, 0x6041, 0x605A
MODE, MODE_DISPLAY, POSITION, FOLLOWING_WINDOW, VELOCITY = 0x6060, 0x6061, 0x6064, 0x6065, 0x606C
POSITION_WINDOW, POSITION_WINDOW_TIME = 0x6067, 0x6068
TARGET, SOFTWARE_LIMITS, PROFILE_VELOCITY, PROFILE_ACCELERATION = 0x607A, 0x607D, 0x6081, 0x6083
PROFILE_DECELERATION, QUICK_STOP_DECELERATION = 0x6084, 0x6085
HOMING_METHOD, HOMING_SPEEDS, HOMING_ACCELERATION, FOLLOWING_ERROR = 0x6098, 0x6099, 0x609A, 0x60F4
FEED_CONSTANT, SI_POSITION, SI_VELOCITY, SI_ACCELERATION = 0x6092, 0x60A8, 0x60A9, 0x60AA
SUPPORTED_MODES, SUPPORTED_HOMING = 0x6502, 0x60E3
PROBE_FUNCTION, PROBE_STATUS, PROBE_POSITIVE, PROBE_NEGATIVE = 0x60B8, 0x60B9, 0x60BA, 0x60BB
SIZES: dict[int, tuple[int, bool]] = {
    ERROR_CODE: (2, False), CONTROL: (2, False), STATUS: (2, False), QUICK_STOP_OPTION: (2, True),
    MODE: (1, True), MODE_DISPLAY: (1, True), POSITION: (4, True), FOLLOWING_WINDOW: (4, False),
    VELOCITY: (4, True), TARGET: (4, True), SOFTWARE_LIMITS: (4, True), PROFILE_VELOCITY: (4, False),
    PROFILE_ACCELERATION: (4, False), PROFILE_DECELERATION: (4, False), QUICK_STOP_DECELERATION: (4, False),
    HOMING_METHOD: (1, True), HOMING_SPEEDS: (4, False), HOMING_ACCELERATION: (4, False),
    FOLLOWING_ERROR: (4, True), POSITION_WINDOW: (4, False), POSITION_WINDOW_TIME: (2, False),
    FEED_CONSTANT: (4, False), SI_POSITION: (4, False), SI_VELOCITY: (4, False), SI_ACCELERATION: (4, False),
    SUPPORTED_MODES: (4, False), SUPPORTED_HOMING: (1, True),
    PROBE_FUNCTION: (2, False), PROBE_STATUS: (2, False), PROBE_POSITIVE: (4, True), PROBE_NEGATIVE: (4, True),
}
#: what each object is, for messages
OBJECT_NAMES: dict[int, str] = {
    ERROR_CODE: "error code", CONTROL: "control word", STATUS: "status word", QUICK_STOP_OPTION: "quick stop option code",
    MODE: "modes of operation", MODE_DISPLAY: "modes of operation display", POSITION: "position actual value",
    VELOCITY: "velocity actual value", POSITION_WINDOW: "position window", POSITION_WINDOW_TIME: "position window time",
    TARGET: "target position", SOFTWARE_LIMITS: "software position limit", PROFILE_VELOCITY: "profile velocity",
    PROFILE_ACCELERATION: "profile acceleration", PROFILE_DECELERATION: "profile deceleration",
    QUICK_STOP_DECELERATION: "quick stop deceleration", HOMING_METHOD: "homing method", HOMING_SPEEDS: "homing speeds",
    HOMING_ACCELERATION: "homing acceleration", FOLLOWING_ERROR: "following error actual value",
    FEED_CONSTANT: "feed constant", SI_POSITION: "SI unit position", SI_VELOCITY: "SI unit velocity",
    SI_ACCELERATION: "SI unit acceleration", SUPPORTED_MODES: "supported drive modes",
    SUPPORTED_HOMING: "supported homing methods", FOLLOWING_WINDOW: "following error window",
    PROBE_FUNCTION: "touch probe function", PROBE_STATUS: "touch probe status",
    PROBE_POSITIVE: "touch probe 1 positive edge", PROBE_NEGATIVE: "touch probe 1 negative edge",
}
#: (index, subindex) every motion needs (CiA 402 device control and profile position): refused by name when absent
MANDATORY: tuple[tuple[int, int], ...] = ((CONTROL, 0), (STATUS, 0), (MODE, 0), (MODE_DISPLAY, 0), (POSITION, 0),
                                          (TARGET, 0), (PROFILE_VELOCITY, 0), (PROFILE_ACCELERATION, 0))
#: what homing (and setting the origin, homing method 37) needs besides
MANDATORY_HOMING: tuple[tuple[int, int], ...] = ((HOMING_METHOD, 0), (HOMING_SPEEDS, 1), (HOMING_SPEEDS, 2))
#: (index, subindex) used when the drive has them, each with its fallback (said once when absent)
OPTIONAL: dict[tuple[int, int], str] = {
    (ERROR_CODE, 0): "faults are reported without their error code",
    (QUICK_STOP_OPTION, 0): "STOP uses the drive's own quick stop option",
    (VELOCITY, 0): "standstill is taken from an unchanged position (6064h)",
    (SOFTWARE_LIMITS, 1): "only the rig profile's soft limits are checked",
    (SOFTWARE_LIMITS, 2): "only the rig profile's soft limits are checked",
    (PROFILE_DECELERATION, 0): "the drive decelerates at its profile acceleration",
    (QUICK_STOP_DECELERATION, 0): "STOP brakes on the profile deceleration ramp (605Ah = 5)",
    (HOMING_ACCELERATION, 0): "homing accelerates at the drive's own setting",
    (FOLLOWING_ERROR, 0): "the status has no following error figure",
    (POSITION_WINDOW, 0): "arrival is checked with the driver's tolerance",
    (POSITION_WINDOW_TIME, 0): "",
    (FEED_CONSTANT, 1): "", (FEED_CONSTANT, 2): "",
    (SI_POSITION, 0): "", (SI_VELOCITY, 0): "", (SI_ACCELERATION, 0): "",
    (SUPPORTED_MODES, 0): "", (SUPPORTED_HOMING, 0): "",
    # touch probe 1 (fly scans; said once at the first fly move where absent: the dryve D1 has none)
    (PROBE_FUNCTION, 0): "", (PROBE_STATUS, 0): "", (PROBE_POSITIVE, 0): "", (PROBE_NEGATIVE, 0): "",
}
#: 60B8h bits (CiA 402 / IEC 61800-7-201 touch probe function): enable probe 1, latch on its positive /
#: negative edge (bit 1 low: the first event only, re-armed by bit 0 low then high); 60B9h: stored bits
PROBE_ENABLE, PROBE_ON_RISING, PROBE_ON_FALLING = 0x01, 0x10, 0x20
PROBE_RISING_STORED, PROBE_FALLING_STORED = 0x02, 0x04
PROFILE_POSITION, HOMING = 1, 6
#: how long :meth:`Cia402Controller.stop` waits for the quick stops before it returns (a stalled
#: link's goes on to its deadline on its own thread; the drives that answer have theirs in ms)
STOP_WAIT_S = 0.25
HOMING_METHODS = {17: "negative limit switch", 18: "positive limit switch", 35: "current position",
                  37: "current position"}

# control words
SHUTDOWN, SWITCH_ON, ENABLE_OPERATION, QUICK_STOP, DISABLE_VOLTAGE = 0x06, 0x07, 0x0F, 0x0B, 0x00
FAULT_RESET = 0x80
NEW_SET_POINT, CHANGE_IMMEDIATELY, HALT = 0x10, 0x20, 0x100
# status word bits
TARGET_REACHED, INTERNAL_LIMIT, SET_POINT_ACK, FOLLOWING_ERROR_BIT = 0x0400, 0x0800, 0x1000, 0x2000
HOMING_ATTAINED, HOMING_ERROR = 0x1000, 0x2000

#: (mask, value, name) of the power states (CiA 402 status word table)
POWER_STATES = (
    (0x4F, 0x00, "NOT READY TO SWITCH ON"), (0x4F, 0x40, "SWITCH ON DISABLED"),
    (0x6F, 0x21, "READY TO SWITCH ON"), (0x6F, 0x23, "SWITCHED ON"), (0x6F, 0x27, "OPERATION ENABLED"),
    (0x6F, 0x07, "QUICK STOP ACTIVE"), (0x4F, 0x0F, "FAULT REACTION ACTIVE"), (0x4F, 0x08, "FAULT"),
)

#: 603Fh error codes (CiA 301/402) -> (what happened, what the operator does)
ERROR_CODES: dict[int, tuple[str, str]] = {
    0x2310: ("continuous over-current in the motor", "check the motor and its cable; lower the acceleration"),
    0x2320: ("short circuit at the motor output", "check the motor cable"),
    0x3210: ("DC link over-voltage", "check the supply; lower the deceleration or add a brake resistor"),
    0x3220: ("DC link under-voltage: the power stage has no supply (load supply off or emergency stop)",
             "switch the drive's load supply on or release the emergency stop"),
    0x4210: ("drive temperature too high", "let the drive cool down and check its ventilation"),
    0x5441: ("enable input off: the drive was disabled from outside", "switch the enable input on"),
    0x7305: ("position encoder fault", "check the encoder cable"),
    0x8130: ("heartbeat or life guard error: the drive lost its controller", "check the bus cable"),
    0x8611: ("following error too large: the axis could not follow its demand (obstruction, too much "
             "speed or acceleration)", "check the axis for an obstruction"),
    0x8612: ("reference limit: a limit switch was hit", "check the soft limits of the rig profile"),
}
_ERROR_CLASSES = {0x2: "current", 0x3: "voltage", 0x4: "temperature", 0x5: "drive hardware",
                  0x6: "drive software", 0x7: "additional module", 0x8: "monitoring", 0x9: "external",
                  0xF: "manufacturer-specific"}


def power_state(statusword: int) -> str:
    """The CiA 402 power state the status word ``6041h`` reports."""
    for mask, value, name in POWER_STATES:
        if statusword & mask == value:
            return name
    return "UNKNOWN"


def fault_message(code: int) -> str:
    """An operator line for the error code ``603Fh`` (what happened and the fix)."""
    if code in ERROR_CODES:
        what, fix = ERROR_CODES[code]
    else:
        what = f"{_ERROR_CLASSES.get(code >> 12, 'device')} error (see the drive's manual)"
        fix = "look the code up in the drive's manual"
    return f"fault {code:04X}h, {what}. Fix: {fix}, then Reset fault and home the rig"


def _position_of(status: RigStatus) -> tuple[float, float]:
    """The position of a status the drives answered (:meth:`Cia402Controller._query` always reads it)."""
    assert status.position_mm is not None, "a status read from the drives has their position"
    return status.position_mm


class ObjectLink(Protocol):
    """One drive's object dictionary, reached through a transport. Raises :class:`DriveNotAnswering`
    when the drive does not answer, :class:`ObjectAccessRefused` when it refuses the access."""

    address: str

    def open(self) -> None: ...
    def close(self) -> None: ...
    def read(self, index: int, sub: int, size: int, signed: bool) -> int: ...
    def write(self, index: int, sub: int, value: int, size: int, signed: bool) -> None: ...
    def write_now(self, index: int, sub: int, value: int, size: int, signed: bool) -> None:
        """:meth:`write` that never waits behind another exchange of the link (STOP)."""
        ...


class DriveNotAnswering(DeviceTimeout):
    """The drive at an address does not answer (no connection, no reply in time)."""

    kind = "drive-not-answering"


class ExchangeInterrupted(DriveNotAnswering):
    """An exchange cut short by STOP, whose quick stop took the link's one channel (CANopen: a drive
    slower than STALLED_AFTER_S): the drive is slow, not lost."""

    kind = "exchange-interrupted"


class ObjectAccessRefused(DeviceError):
    """The drive refused a read or write (Modbus exception, SDO abort)."""

    kind = "object-access-refused"


class DriveFault(DeviceError):
    """A drive is in FAULT (its error code in the message)."""

    kind = "drive-fault"


class MotionStopped(DeviceError):
    """A motion command was ended by STOP."""

    kind = "motion-stopped"


class PositionError(DeviceError):
    """The drives report standstill away from the target."""

    kind = "position"


class MissingObject(DeviceError):
    """A drive lacks an object CiA 402 makes mandatory for what was asked (nothing was moved)."""

    kind = "missing-object"


class UnitsMismatch(DeviceError):
    """A drive's position units disagree with the rig profile's feed constant (nothing moves)."""

    kind = "units"


def si_units_per_mm(value: int) -> float | None:
    """Position units per mm of an SI unit object (``60A8h``: byte 3 the power of ten, byte 2 the
    unit, 01h metre; CiA 402 "factor group"); None when the unit is not a length (41h degree: a rotary
    axis). The dryve D1 answers FB010000h for 0.01 mm (its default; OptovisTech/DryveD1API
    Modules/SIUnitPosition.cs: byte 21 movement type 01h linear / 41h rotary, byte 22 the factor FAh … 02h)."""
    if (value >> 16) & 0xFF != 0x01:
        return None
    prefix = (value >> 24) & 0xFF
    prefix = prefix - 256 if prefix > 127 else prefix
    return 10.0 ** (-3 - prefix)


def si_time_factor(value: int, acceleration: bool) -> float | None:
    """Seconds per the time unit of ``60A9h``/``60AAh`` (byte 1: 03h s, 47h min; 57h s²), None if unknown."""
    denominator = (value >> 8) & 0xFF
    if acceleration:
        return {0x57: 1.0, 0x03: 1.0}.get(denominator)
    return {0x03: 1.0, 0x47: 60.0}.get(denominator)


def _si_text(value: int) -> str:
    upm = si_units_per_mm(value)
    if upm is None:
        return f"{value:08X}h (not a length unit: a rotary axis?)"
    return f"{value:08X}h: {1.0 / upm:g} mm"


class Cia402Controller:
    """A :class:`lfstudio.rig.motion.MotionController` for two CiA 402 drives (horizontal, vertical).

    ``links``: the two drives' :class:`ObjectLink`; ``port``: the device word (messages, locks).
    After :meth:`connect`: :attr:`objects` (what each drive has), :attr:`drive_limits_mm` (``607Dh``
    in mm), :attr:`window_mm` (``6067h``), :attr:`units_problem`, :attr:`warnings` and
    :attr:`reference` ("homed", "origin", "kept" or ""). ``known_objects``: each drive's (index, sub)
    from its EDS/DCF (None: read them). ``accept_reference``: :meth:`accept_reference` at the first connect
    (not at a reconnect)."""

    def __init__(self, links: tuple[ObjectLink, ObjectLink], rig: RigConfig, *, port: str = "",
                 timeout_s: float = 3.0, poll_hz: float = 50.0, tolerance_mm: float | None = None,
                 max_status_hz: float = 50.0, stall_s: float = 3.0, accept_reference: bool = False,
                 known_objects: tuple[set | None, set | None] = (None, None)):
        check_feed_constants(rig)
        self.links = tuple(links)
        self.config = rig
        self.port = port or ",".join(link.address for link in links)
        self.timeout_s = timeout_s
        self.poll_period_s = 1.0 / poll_hz
        self.tolerance_mm = tolerance_mm        # None: the drive's own position window 6067h (else 0.02 mm)
        self.accept_reference_at_connect = accept_reference
        self.known_objects = known_objects      # from an EDS/DCF: the (index, sub) each drive has, or None: read them
        self.min_status_interval_s = 1.0 / max_status_hz
        self.stall_s = stall_s
        self.status_period_s = 0.1              # full status for the listeners while a move runs
        self.status_listener: Callable[[RigStatus], None] | None = None
        #: told one line when homing starts and as each drive reaches its reference (the CLI prints them)
        self.progress: Callable[[str], None] | None = None
        self._axes = (rig.horizontal, rig.vertical)
        self._k = (rig.horizontal.increments_per_mm, rig.vertical.increments_per_mm)
        self._kv = list(self._k)                # velocity units per mm/s (60A9h where the drive has it)
        self._ka = list(self._k)                # acceleration units per mm/s² (60AAh)
        self.objects: list[dict[tuple[int, int], int]] = [{}, {}]   # what each drive has (value read at connect)
        self.warnings: list[str] = []           # fallbacks and notes, said once per connection
        self.units_problem: list[str] = ["", ""]
        self.window_mm: list[float | None] = [None, None]
        self._rest_probe: list[int | None] = [None, None]
        self._io = threading.RLock()
        self._stop_event = threading.Event()
        self._stop_pending = False
        self._connected = False
        self._opened = False                    # links opened by connect (STOP goes out even after a loss)
        self._stop_threads: list[threading.Thread] = []
        self._moving = False                    # a move_to under way
        self._lost = ""
        self.reference = ""
        self.drive_limits_mm: list[tuple[float, float] | None] = [None, None]
        self.supported_homing: list[tuple[int, ...] | None] = [None, None]
        self._last: RigStatus | None = None
        self._last_t = 0.0
        self._jog_target: tuple[float, float] | None = None
        self._homing = False
        self._halt_flags = (False, False)
        self.version = "CiA 402"
        #: the fly move under way (fly_to … wait_arrival): axes moving, standing axes' positions, touch probes
        self._fly: dict | None = None
        #: how often report() looks at the touch probe status 60B9h during a fly move (real time)
        self.probe_poll_s = 0.004

    # -- naming ------------------------------------------------------------------------------------
    def _name(self, i: int) -> str:
        return f"drive {'xy'[i]} ({self._axes[i].name}) at {self.links[i].address}"

    # -- object access -------------------------------------------------------------------------------
    def _read(self, i: int, index: int, sub: int = 0) -> int:
        size, signed = SIZES[index]
        try:
            return self.links[i].read(index, sub, size, signed)
        except DriveNotAnswering as exc:
            raise self._mark_lost(i, exc) from None

    def _write(self, i: int, index: int, value: int, sub: int = 0) -> None:
        size, signed = SIZES[index]
        try:
            self.links[i].write(index, sub, int(value), size, signed)
        except ExchangeInterrupted as exc:
            if self._stop_pending:           # STOP took the channel: the command is stopped, the drive not lost
                raise MotionStopped(f"stopped by STOP (the write to {self._name(i)} was cut short for its quick "
                                    "stop)") from None
            raise self._mark_lost(i, exc) from None
        except DriveNotAnswering as exc:
            raise self._mark_lost(i, exc) from None

    def _mark_lost(self, i: int, exc: Exception) -> DriveNotAnswering:
        in_motion = self._connected and (self._moving or self._homing or self._jog_target is not None)
        last = self._last
        if last is None or last.position_mm is None:
            where = "the rig's position is unknown"
        else:
            where = (f"the rig's position is unknown until it answers (last read at ({last.position_mm[0]:.3f}, "
                     f"{last.position_mm[1]:.3f}) mm, {max(time.monotonic() - self._last_t, 0.0):.1f} s before)")
        if in_motion:                    # the other drive must not go on alone: STOP on every path
            # its threads started here and now, known to disconnect() (which waits for them before the links
            # close and the process may end); not waited for here: this drive's may take its deadline
            self._quick_stop_all(wait_s=0.0)
            where += "; quick stop sent to both drives"
        self._lost = (f"{self._name(i)} does not answer ({exc}); {where}. Check its network or bus cable and its "
                      "power, then connect again")
        self._connected = False
        return DriveNotAnswering(self._lost)

    def _tell(self, line: str) -> None:
        log.info("%s", line)
        if self.progress is not None:
            try:
                self.progress(line)
            except Exception as exc:  # noqa: BLE001 - a listener never stops the drives' work
                log.debug("progress listener: %s", exc)

    def _statusword(self, i: int) -> int:
        return self._read(i, STATUS)

    def has(self, i: int, index: int, sub: int = 0) -> bool:
        """Drive ``i`` has the object (learnt at connect)."""
        return (index, sub) in self.objects[i]

    def _say(self, text: str) -> None:
        if text not in self.warnings:
            self.warnings.append(text)
            log.warning("%s", text)

    # -- connection ----------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._connected and not self._lost

    def connect(self) -> None:
        """Open both links and learn each drive: which objects it has (read, or its EDS/DCF), its
        units (``6092h``, ``60A8h``–``60AAh``), limits (``607Dh``), position window (``6067h``),
        power state; set the quick stop option (``605Ah``) where it can be written. Nothing moves and
        no drive is enabled here. A drive lacking a mandatory object is refused by name
        (:class:`MissingObject`); a unit mismatch connects (so that ``units`` can fix it) and refuses
        every motion. A drive in FAULT is connected (so that it can be reset) and reported by
        :meth:`status`; motion is refused. No drive is taken as homed: see :meth:`accept_reference`."""
        with self._io:
            self._lost = ""
            self.warnings = []
            for i, link in enumerate(self.links):
                try:
                    link.open()
                except DriveNotAnswering as exc:
                    self._close_links()
                    raise DriveNotAnswering(f"{self._name(i)} does not answer: {exc}. Check the address, that "
                                            "the drive is powered and on the network, then connect again") from None
            self._opened = True
            try:
                for i in range(2):
                    self._statusword(i)                  # answers at all (else: not answering, named)
                    self._discover(i)
                    missing = [key for key in MANDATORY if key not in self.objects[i]]
                    if missing:
                        raise MissingObject(self._missing_line(i, missing, "any motion"))
                    self._check_units(i)
                    self._learn_limits(i)
                    self._set_quick_stop_option(i)
            except BaseException:
                self._close_links()
                raise
            self._connected = True
            self.reference = ""
            self._rest_probe = [None, None]
            self._last_t = 0.0
            if self.accept_reference_at_connect:
                self.accept_reference()
                # the first connection's only: a reconnect (a scan's recovery, the Rig panel's Recover after
                # a lost link, perhaps a power cut that restarted the counters) never keeps a reference unasked
                self.accept_reference_at_connect = False
            self._query()

    def _missing_line(self, i: int, missing: list[tuple[int, int]], doing: str) -> str:
        names = ", ".join(f"{index:04X}h" + (f":{sub:02X}" if sub else "") + f" ({OBJECT_NAMES.get(index, '?')})"
                          for index, sub in missing)
        source = "its EDS/DCF lists" if self.known_objects[i] is not None else "it answers"
        return (f"{self._name(i)} lacks {names}, which CiA 402 makes mandatory for {doing} ({source} no such "
                "object); nothing was moved. Fix: use a CiA 402 drive with profile position and homing mode, or "
                "check the drive's configuration (and the EDS/DCF named in the rig profile)")

    def _discover(self, i: int) -> None:
        """Which objects drive ``i`` has, with their values: each read (a refused read: absent), or
        the EDS/DCF's list when the profile names one (then only what it lists is read)."""
        found: dict[tuple[int, int], int] = {}
        listed = self.known_objects[i]
        for index, sub in (*MANDATORY, *MANDATORY_HOMING, *OPTIONAL):
            if listed is not None and (index, sub) not in listed:
                continue
            size, signed = SIZES[index]
            try:
                found[(index, sub)] = self.links[i].read(index, sub, size, signed)
            except ObjectAccessRefused as exc:
                if listed is not None:
                    self._say(f"{self._name(i)}: its EDS/DCF lists {index:04X}h:{sub:02X} but the drive refuses it "
                              f"({exc})")
            except DriveNotAnswering as exc:
                raise self._mark_lost(i, exc) from None
        if (SUPPORTED_HOMING, 0) in found:
            methods = []
            for sub in range(1, max(0, min(found[(SUPPORTED_HOMING, 0)], 64)) + 1):
                try:
                    methods.append(self.links[i].read(SUPPORTED_HOMING, sub, 1, True))
                except ObjectAccessRefused:
                    break
            self.supported_homing[i] = tuple(methods)
        else:
            self.supported_homing[i] = None
        self.objects[i] = found
        for key, fallback in OPTIONAL.items():
            if key not in found and fallback and not (key == (SOFTWARE_LIMITS, 2) and (SOFTWARE_LIMITS, 1) not in found):
                self._say(f"{self._name(i)} has no {key[0]:04X}h ({OBJECT_NAMES[key[0]]}): {fallback}")

    def _check_units(self, i: int) -> None:
        """The drive's position units per mm (``60A8h``, and ``6092h`` with the profile's
        ``feed_mm_per_rev``) against the profile's ``increments_per_mm``; velocity and acceleration
        units from ``60A9h``/``60AAh`` where the drive reports them."""
        axis, k, o = self._axes[i], self._k[i], self.objects[i]
        where = f"rig {self.config.name!r} {axis.name}.increments_per_mm = {k:g}"
        fix_cmd = f"lfstudio rig --port {self.port} --rig-profile '{self.config.name}' units"
        problems = []
        si = o.get((SI_POSITION, 0))
        if si is not None:
            upm = si_units_per_mm(si)
            if upm is None or not math.isclose(upm, k, rel_tol=1e-6):
                problems.append(f"its position unit 60A8h = {_si_text(si)} makes "
                                f"{'no length' if upm is None else f'{upm:g} position units per mm'}")
        feed, revs = o.get((FEED_CONSTANT, 1)), o.get((FEED_CONSTANT, 2))
        per_rev = axis.feed_mm_per_rev
        if feed is not None and per_rev > 0:
            revs = revs or 1
            upm = feed / revs / per_rev
            if not math.isclose(upm, k, rel_tol=1e-6):
                problems.append(f"its feed constant 6092h = {feed}/{revs} per revolution at {per_rev:g} mm per "
                                f"revolution makes {upm:g} position units per mm")
        elif si is None:
            self._say(f"{self._name(i)}: its position units cannot be checked (no 60A8h"
                      + ("" if feed is None else f"; 6092h:01 = {feed} per revolution but the profile has no "
                         f"{axis.name}.feed_mm_per_rev") + "): lfstudio trusts the rig profile's "
                      f"increments_per_mm = {k:g}")
        self.units_problem[i] = ""
        if problems:
            self.units_problem[i] = (
                f"{self._name(i)}: {'; '.join(problems)}, but the {where}; nothing moves. Fix: correct the rig "
                f"profile, or write the profile's units to the stopped drive ({fix_cmd})")
        for index, store, acceleration in ((SI_VELOCITY, self._kv, False), (SI_ACCELERATION, self._ka, True)):
            value = o.get((index, 0))
            store[i] = k
            if value is None:
                continue
            upm, per_s = si_units_per_mm(value), si_time_factor(value, acceleration)
            if upm is None or per_s is None:
                self._say(f"{self._name(i)}: {index:04X}h ({OBJECT_NAMES[index]}) = {value:08X}h is a unit lfstudio "
                          f"does not know; it writes {'accelerations' if acceleration else 'speeds'} in position "
                          "units per second")
                continue
            store[i] = upm * (per_s * per_s if acceleration else per_s)

    def _learn_limits(self, i: int) -> None:
        o, k = self.objects[i], self._k[i]
        lo, hi = o.get((SOFTWARE_LIMITS, 1)), o.get((SOFTWARE_LIMITS, 2))
        self.drive_limits_mm[i] = (lo / k, hi / k) if lo is not None and hi is not None and lo < hi else None
        window = o.get((POSITION_WINDOW, 0))
        window_mm = self.window_mm[i] = window / k if window is not None and window not in (0, 0xFFFFFFFF) else None
        if window_mm is not None and self.tolerance_mm is not None and self.tolerance_mm > window_mm:
            self._say(f"{self._name(i)}: the tolerance {self.tolerance_mm:g} mm is looser than the drive's position "
                      f"window 6067h = {window_mm:g} mm; the window is used")

    def _set_quick_stop_option(self, i: int) -> None:
        """605Ah = 6 (quick stop ramp 6085h, stay in quick stop active), 5 (profile deceleration) on
        a drive without 6085h; a drive that refuses the write keeps its own (said once)."""
        if not self.has(i, QUICK_STOP_OPTION):
            return
        wanted = 6 if self.has(i, QUICK_STOP_DECELERATION) else 5
        try:
            self._write(i, QUICK_STOP_OPTION, wanted)
        except ObjectAccessRefused as exc:
            self._say(f"{self._name(i)}: its quick stop option 605Ah stays "
                      f"{self.objects[i][(QUICK_STOP_OPTION, 0)]} (the write was refused: {exc})")

    def tolerance(self, i: int) -> float:
        """Arrival tolerance of axis ``i`` in mm: the drive's position window (6067h), tightened by an
        explicit ``tolerance_mm``, never loosened; 0.02 mm without a window; at least one position unit."""
        window = self.window_mm[i]
        if window is None:
            tol = 0.02 if self.tolerance_mm is None else self.tolerance_mm
        else:
            tol = window if self.tolerance_mm is None else min(window, self.tolerance_mm)
        return max(tol, 1.0 / self._k[i])

    def accept_reference(self) -> None:
        """The operator accepts the drives' own reference (their reported position) without homing:
        logged, shown as "reference kept from the drive". Refused while a drive is in fault."""
        with self._io:
            if not self._connected or self._lost:
                raise DriveNotAnswering(self._lost or f"the rig {self.port} is not connected: connect first")
            st = self._query()
            if st.state is RigState.ALARM:
                raise DriveFault(f"keeping the drives' reference refused: {st.message}")
            self.reference = "kept"
            pos = _position_of(st)
            log.warning("the operator kept the drives' reference on %s: they report (%.3f, %.3f) mm, not homed by "
                        "lfstudio on this connection", self.port, pos[0], pos[1])
            self._query()

    def write_units(self) -> list[str]:
        """Write the rig profile's units to both drives (at rest): ``60A8h`` where the feed constant
        is a power of ten of a mm, ``6092h`` (feed per revolution, 1 revolution) where the profile
        names ``feed_mm_per_rev``. The reference is dropped (home again). Returns what was written."""
        with self._io:
            if not self._connected or self._lost:
                raise DriveNotAnswering(self._lost or f"the rig {self.port} is not connected: connect first")
            for i in range(2):
                if not self._drive_at_rest(i) and not self._drive_at_rest(i):
                    raise DeviceError(f"writing units refused: {self._name(i)} is moving; stop it first")
            for i in range(2):                  # both checked before either drive is written to
                exponent = math.log10(self._k[i])
                if self.has(i, SI_POSITION) and abs(exponent - round(exponent)) >= 1e-9:
                    raise UnitsMismatch(f"{self._name(i)}: increments_per_mm = {self._k[i]:g} is not a power of ten, "
                                        "so no SI unit (60A8h) expresses it; nothing was written to either drive. "
                                        "Fix: set the drive's unit on its own interface")
            done = []
            for i in range(2):
                k, axis = self._k[i], self._axes[i]
                exponent = math.log10(k)
                if self.has(i, SI_POSITION):
                    value = (((-3 - round(exponent)) & 0xFF) << 24) | (0x01 << 16)
                    self._write(i, SI_POSITION, value)
                    done.append(f"{self._name(i)}: 60A8h = {value:08X}h ({1 / k:g} mm)")
                if self.has(i, FEED_CONSTANT, 1) and axis.feed_mm_per_rev > 0:
                    feed = round(k * axis.feed_mm_per_rev)
                    self._write(i, FEED_CONSTANT, feed, 1)
                    if self.has(i, FEED_CONSTANT, 2):
                        self._write(i, FEED_CONSTANT, 1, 2)
                    done.append(f"{self._name(i)}: 6092h = {feed} per revolution ({axis.feed_mm_per_rev:g} mm)")
            self.reference = ""
            for i in range(2):
                self._discover(i)
                self._check_units(i)
                self._learn_limits(i)
                lim = self.drive_limits_mm[i]
                if lim is not None:
                    done.append(f"{self._name(i)}: its software position limits 607Dh now read {lim[0]:g} … "
                                f"{lim[1]:g} mm (their numbers are in the new units: check them)")
            self._query()
            return done

    def _close_links(self) -> None:
        self._opened = False
        for link in self.links:
            try:
                link.close()
            except Exception as exc:  # noqa: BLE001
                log.debug("closing %s: %s", link.address, exc)

    def disconnect(self) -> None:
        """Close the links; the drives stay as they are (enabled drives hold their position). A quick
        stop still under way (a stalled link) is waited for first (its link's deadline)."""
        for t in list(self._stop_threads):
            t.join()
        with self._io:
            self._connected = False
            self._close_links()

    # -- status --------------------------------------------------------------------------------------
    def _axis_snapshot(self, i: int) -> dict:
        sw = self._statusword(i)
        return {"statusword": sw, "state": power_state(sw), "error_code": self._error_code(i),
                "position": self._read(i, POSITION),
                "following_error": self._read(i, FOLLOWING_ERROR) if self.has(i, FOLLOWING_ERROR) else None,
                "mode": self._read(i, MODE_DISPLAY)}

    def _error_code(self, i: int) -> int | None:
        return self._read(i, ERROR_CODE) if self.has(i, ERROR_CODE) else None

    def _fault_of(self, i: int) -> str:
        code = self._error_code(i)
        return fault_message(code) if code is not None else (
            "fault (the drive has no error code object 603Fh: read the code on its display or interface). "
            "Fix: remove the cause, then Reset fault and home the rig")

    def _query(self) -> RigStatus:
        snaps = [self._axis_snapshot(i) for i in range(2)]
        status = self._rig_status(snaps)
        self._last, self._last_t = status, time.monotonic()
        if self.status_listener is not None:
            try:
                self.status_listener(status)
            except Exception as exc:  # noqa: BLE001
                log.debug("status listener: %s", exc)
        return status

    def _fault_line(self, snaps: list[dict]) -> str:
        lines = []
        for i, s in enumerate(snaps):
            if s["state"] in ("FAULT", "FAULT REACTION ACTIVE"):
                lines.append(f"{self._name(i)}: " + (fault_message(s["error_code"]) if s["error_code"] is not None else
                                                    "fault (no error code object 603Fh: read the code on the "
                                                    "drive's display). Fix: remove the cause, then Reset fault and "
                                                    "home the rig"))
        return "; ".join(lines)

    def _rig_status(self, snaps: list[dict]) -> RigStatus:
        position = (round(snaps[0]["position"] / self._k[0], 4), round(snaps[1]["position"] / self._k[1], 4))
        states = [s["state"] for s in snaps]
        codes = ["?" if s["error_code"] is None else f"{s['error_code']:04X}h" for s in snaps]
        following = tuple(None if s["following_error"] is None else s["following_error"] / self._k[i]
                          for i, s in enumerate(snaps))
        extra = {"power_state": {"x": states[0], "y": states[1]},
                 "fault_code": {"x": codes[0], "y": codes[1]},
                 "following_error_mm": following,
                 "mode": (snaps[0]["mode"], snaps[1]["mode"]), "reference": self.reference,
                 "drive_limits_mm": list(self.drive_limits_mm), "addresses": [link.address for link in self.links],
                 "position_window_mm": list(self.window_mm),
                 "warnings": [p for p in self.units_problem if p] + list(self.warnings),
                 "locked": False}
        if self._homing:                      # each drive's homing: at its reference yet (6041h bit 12)?
            extra["homing"] = {"xy"[i]: "at reference" if s["statusword"] & HOMING_ATTAINED else "homing"
                               for i, s in enumerate(snaps)}
        homed = bool(self.reference)
        if any(s in ("FAULT", "FAULT REACTION ACTIVE") for s in states):
            extra["locked"] = True
            return RigStatus(RigState.ALARM, position, False, self._fault_line(snaps), extra)
        if any(s == "QUICK STOP ACTIVE" for s in states):
            return RigStatus(RigState.HOLD, position, homed, "Quick stop: the drives stopped; the next command "
                             "enables them again", extra)
        enabled = all(s == "OPERATION ENABLED" for s in states)
        moving = enabled and any(not s["statusword"] & TARGET_REACHED for s in snaps)
        halted = enabled and any(self._halt_flags)
        if moving and self._homing:
            state = RigState.HOMING
        elif halted:
            state = RigState.HOLD
        elif moving:
            state = RigState.JOGGING if self._jog_target is not None else RigState.MOVING
        else:
            state = RigState.IDLE
        message = ""
        if state is RigState.HOLD:
            message = "Motion held: resume, or STOP to cancel the move"
        elif any(self.units_problem):
            message = next(p for p in self.units_problem if p)
        elif not homed:
            message = ("Not homed: home the rig before moving" if self.config.homing
                       else "No origin: with the carriage at the left/bottom end of its travel, set the origin")
        elif not enabled:
            off = [f"drive {'xy'[i]} {states[i].lower()}" for i in range(2) if states[i] != "OPERATION ENABLED"]
            message = "; ".join(off) + ": the next motion command enables it"
        return RigStatus(state, position, homed, message, extra)

    def status(self) -> RigStatus:
        """A fresh status (at most ``max_status_hz`` reads a second; cached in between); completes
        a pending STOP once the drives are at rest."""
        if not self._connected or self._lost:
            return RigStatus(RigState.DISCONNECTED, None, False, self._lost or f"not connected ({self.port})")
        with self._io:
            if self._last is None or time.monotonic() - self._last_t >= self.min_status_interval_s:
                try:
                    self._query()
                except DriveNotAnswering:
                    return RigStatus(RigState.DISCONNECTED, None, False, self._lost)
            if self._stop_pending and self._at_rest():
                self._finish_stop()
            last = self._last
            assert last is not None, "_query keeps the status it read"
            return last

    def _at_rest(self) -> bool:
        return all([self._drive_at_rest(i) for i in range(2)])

    def _drive_at_rest(self, i: int) -> bool:
        """Velocity 606Ch is 0; without 606Ch: the position 6064h did not change since the last call."""
        if self.has(i, VELOCITY):
            return self._read(i, VELOCITY) == 0
        position = self._read(i, POSITION)
        still = self._rest_probe[i] == position
        self._rest_probe[i] = position
        return still

    # -- power ----------------------------------------------------------------------------------------
    def _check_no_fault(self, doing: str) -> None:
        snaps = [self._axis_snapshot(i) for i in range(2)]
        line = self._fault_line(snaps)
        if line:
            raise DriveFault(f"{doing} refused: {line}")

    def _wait_state(self, i: int, wanted: str, what: str) -> int:
        deadline = time.monotonic() + self.timeout_s
        while True:
            sw = self._statusword(i)
            state = power_state(sw)
            if state == wanted:
                return sw
            if state in ("FAULT", "FAULT REACTION ACTIVE"):
                raise DriveFault(f"{self._name(i)}: {self._fault_of(i)}")
            if time.monotonic() > deadline:
                raise DeviceError(f"{self._name(i)} did not reach {wanted.lower()} after {what} (it is "
                                  f"{state.lower()}); check its enable input and load supply")
            time.sleep(self.poll_period_s / 4)

    def _enable(self, i: int) -> None:
        """Bring drive ``i`` to OPERATION ENABLED (Shutdown → Switch on → Enable operation)."""
        state = power_state(self._statusword(i))
        if state == "OPERATION ENABLED":
            return
        if state in ("FAULT", "FAULT REACTION ACTIVE"):
            raise DriveFault(f"{self._name(i)}: {self._fault_of(i)}")
        if state == "QUICK STOP ACTIVE":
            self._write(i, CONTROL, ENABLE_OPERATION)
            self._wait_state(i, "OPERATION ENABLED", "enable operation")
            return
        if state in ("SWITCH ON DISABLED", "NOT READY TO SWITCH ON"):
            self._write(i, CONTROL, SHUTDOWN)
            self._wait_state(i, "READY TO SWITCH ON", "shutdown (06h)")
            state = "READY TO SWITCH ON"
        if state == "READY TO SWITCH ON":
            self._write(i, CONTROL, SWITCH_ON)
            self._wait_state(i, "SWITCHED ON", "switch on (07h)")
        self._write(i, CONTROL, ENABLE_OPERATION)
        self._wait_state(i, "OPERATION ENABLED", "enable operation (0Fh)")

    def _set_mode(self, i: int, mode: int) -> None:
        if self._read(i, MODE_DISPLAY) == mode:
            return
        self._write(i, MODE, mode)
        deadline = time.monotonic() + self.timeout_s
        while self._read(i, MODE_DISPLAY) != mode:
            if time.monotonic() > deadline:
                raise DeviceError(f"{self._name(i)} did not change to mode {mode} (6061h)")
            time.sleep(self.poll_period_s / 4)

    def _prepare(self, doing: str) -> None:
        if not self._connected or self._lost:
            raise DriveNotAnswering(self._lost or f"the rig {self.port} is not connected: connect first")
        self._fly = None                         # a new command: the last fly move's latches are gone
        if self._stop_pending:
            self._finish_stop()
        self._stop_event.clear()
        self._check_no_fault(doing)
        for problem in self.units_problem:
            if problem:
                raise UnitsMismatch(f"{doing} refused: {problem}")
        for i in range(2):
            modes = self.objects[i].get((SUPPORTED_MODES, 0))
            if modes is not None and not modes & 0x01:
                raise MissingObject(f"{doing} refused: {self._name(i)} does not list profile position mode in its "
                                    f"supported drive modes (6502h = {modes:08X}h, bit 0); nothing was moved. Fix: "
                                    "enable profile position mode on the drive")

    # -- homing ----------------------------------------------------------------------------------------
    def home(self) -> None:
        """Home both drives together (``6098h`` method from the profile)."""
        if not self.config.homing:
            raise DeviceError(f"rig {self.config.name!r} has no limit switches: park the carriage at the "
                              "left/bottom end of its travel and set the origin instead")
        self._home((self._axes[0].homing_method, self._axes[1].homing_method), "homing", "homed")

    def set_origin(self) -> None:
        """The current position becomes (0, 0) (homing method 37: current position)."""
        self._home((37, 37), "setting the origin", "origin")

    def _check_homing(self, methods: tuple[int, int], doing: str) -> None:
        """Homing mode and the methods: the objects it needs, 6502h bit 5 and 60E3h where the drive has them."""
        for i in range(2):
            missing = [key for key in MANDATORY_HOMING if key not in self.objects[i]]
            if missing:
                raise MissingObject(self._missing_line(i, missing, doing))
            modes = self.objects[i].get((SUPPORTED_MODES, 0))
            if modes is not None and not modes & 0x20:
                raise MissingObject(f"{doing} refused: {self._name(i)} does not list homing mode in its supported "
                                    f"drive modes (6502h = {modes:08X}h, bit 5); nothing was moved. Fix: a drive with "
                                    "homing mode, or a rig profile without limit switches (homing = false) whose "
                                    "origin is set by hand")
            listed = self.supported_homing[i]
            if listed is not None and methods[i] not in listed:
                raise MissingObject(f"{doing} refused: {self._name(i)} does not list homing method {methods[i]} "
                                    f"(60E3h supported homing methods: {', '.join(map(str, listed)) or 'none'}); "
                                    f"nothing was moved. Fix: set {self._axes[i].name}.homing_method in rig profile "
                                    f"{self.config.name!r} to one it lists")

    def _home(self, methods: tuple[int, int], doing: str, reference: str) -> None:
        with self._io:
            self._prepare(doing)
            self._check_homing(methods, doing)
            self._jog_target = None
            self.reference = ""
            for i in range(2):
                self._stopped_meanwhile(doing)
                self._enable(i)
                self._set_mode(i, HOMING)
                a = self._axes[i]
                self._write(i, HOMING_METHOD, methods[i])
                self._write(i, HOMING_SPEEDS, max(1, round(a.max_speed_mm_s / 4 * self._kv[i])), 1)
                self._write(i, HOMING_SPEEDS, max(1, round(a.max_speed_mm_s / 20 * self._kv[i])), 2)
                if self.has(i, HOMING_ACCELERATION):
                    self._write(i, HOMING_ACCELERATION, max(1, round(a.acceleration_mm_s2 * self._ka[i])))
                self._write(i, CONTROL, ENABLE_OPERATION)
            self._stopped_meanwhile(doing)
            for i in range(2):                              # both start together (bit 4 rising)
                self._write(i, CONTROL, ENABLE_OPERATION | NEW_SET_POINT)
            self._stopped_meanwhile(doing)                  # a STOP the start writes overtook: stopped again
            self._homing = True
        started = time.monotonic()
        attained: set[int] = set()
        self._tell(f"{doing} (both drives) …")
        try:
            timeout = max(a.travel_mm / (a.max_speed_mm_s / 20) * 1.5 for a in self._axes) + 10.0
            deadline = time.monotonic() + timeout
            while True:
                if self._stop_event.is_set():
                    with self._io:
                        st = self._finish_stop()
                    raise MotionStopped(f"{doing} stopped by STOP; the rig is not homed, "
                                        f"{self._where(st)}")
                with self._io:
                    sws = [self._statusword(i) for i in range(2)]
                    status = self._query()
                if any(power_state(sw) in ("FAULT", "FAULT REACTION ACTIVE") for sw in sws):
                    self._quick_stop_all()
                    raise DriveFault(f"{doing} failed: {status.message}")
                for i, sw in enumerate(sws):
                    if sw & HOMING_ERROR:
                        raise DeviceError(f"{doing} failed: {self._name(i)} reports a homing error (6041h bit 13); "
                                          "check its limit switch and wiring, then home again")
                for i, sw in enumerate(sws):
                    if i not in attained and sw & HOMING_ATTAINED and sw & TARGET_REACHED:
                        attained.add(i)
                        self._tell(f"{doing}: {self._name(i)} {reference} ({time.monotonic() - started:.0f} s)")
                if len(attained) == 2:
                    break
                if time.monotonic() > deadline:
                    self.stop()
                    with self._io:
                        self._finish_stop()
                    raise DeviceError(f"{doing} did not finish within {timeout:.0f} s; motion stopped. Check the "
                                      "limit switches and the homing method (6098h) in the rig profile")
                self._stop_event.wait(self.poll_period_s)
            with self._io:
                for i in range(2):
                    self._write(i, CONTROL, ENABLE_OPERATION)
                    self._set_mode(i, PROFILE_POSITION)
                self.reference = reference
                self._homing = False              # the last status is the homed rig's, not a homing one
                self._query()
        finally:
            self._homing = False

    # -- limits ---------------------------------------------------------------------------------------
    def check_target(self, x_mm: float, y_mm: float) -> tuple[float, float]:
        """The profile's soft limits, then the drives' own ``607Dh``: raise :class:`SoftLimitError`
        naming the limit; nothing is sent for a refused target."""
        x_mm, y_mm = check_target(self.config, x_mm, y_mm)
        for i, (label, value) in enumerate((("x", x_mm), ("y", y_mm))):
            lim = self.drive_limits_mm[i]
            if lim is None:
                continue
            steps = round(value * self._k[i])
            if not round(lim[0] * self._k[i]) <= steps <= round(lim[1] * self._k[i]):
                raise SoftLimitError(f"target {label} ({self._axes[i].name})",
                                     f"{value:g} mm is outside {self._name(i)}'s software position limits "
                                     "(607Dh); nothing was sent", f"{lim[0]:g} … {lim[1]:g} mm")
        return x_mm, y_mm

    def _clamp(self, x_mm: float, y_mm: float) -> tuple[float, float]:
        out = list(clamp_target(self.config, x_mm, y_mm))
        for i in range(2):
            lim = self.drive_limits_mm[i]
            if lim is not None:
                out[i] = min(max(out[i], lim[0]), lim[1])
        return out[0], out[1]

    # -- motion -----------------------------------------------------------------------------------------
    def _require_reference(self, doing: str) -> None:
        if not self.reference:
            raise DeviceError(f"{doing} refused: the position is unknown; " +
                              ("home the rig first" if self.config.homing else "set the origin first"))

    def _start(self, target: tuple[float, float], speeds_mm_s: tuple[float, float], doing: str) -> None:
        """Profile position to ``target`` on both drives: parameters, then the set-point handshake
        on both (bit 4 up, acknowledge, bit 4 down) before either is waited for. A STOP that comes
        meanwhile ends it (:meth:`_stopped_meanwhile`) before its next control word."""
        steps = [round(target[i] * self._k[i]) for i in range(2)]
        for i in range(2):
            self._stopped_meanwhile(doing)
            self._enable(i)
            self._set_mode(i, PROFILE_POSITION)
            a, kv, ka = self._axes[i], self._kv[i], self._ka[i]
            self._write(i, PROFILE_VELOCITY, max(1, round(speeds_mm_s[i] * kv)))
            self._write(i, PROFILE_ACCELERATION, max(1, round(a.acceleration_mm_s2 * ka)))
            if self.has(i, PROFILE_DECELERATION):
                self._write(i, PROFILE_DECELERATION, max(1, round(a.acceleration_mm_s2 * ka)))
            if self.has(i, QUICK_STOP_DECELERATION):
                self._write(i, QUICK_STOP_DECELERATION, max(1, round(4 * a.acceleration_mm_s2 * ka)))
            self._write(i, TARGET, steps[i])
        self._stopped_meanwhile(doing)
        self._lower_set_point()
        self._stopped_meanwhile(doing)
        for i in range(2):
            self._write(i, CONTROL, ENABLE_OPERATION | NEW_SET_POINT | CHANGE_IMMEDIATELY)
        deadline = time.monotonic() + self.timeout_s
        pending = {0, 1}
        while pending:
            for i in sorted(pending):
                sw = self._statusword(i)
                if sw & SET_POINT_ACK:
                    self._write(i, CONTROL, ENABLE_OPERATION)
                    pending.discard(i)
                elif power_state(sw) != "OPERATION ENABLED":
                    raise DriveFault(f"{self._name(i)} left operation enabled while taking the set-point: " +
                                     (self._fault_of(i) if sw & 0x08 else power_state(sw).lower()))
            if pending and time.monotonic() > deadline:
                self._quick_stop_all()
                raise DeviceError(f"{self._name(min(pending))} did not acknowledge the new set-point (6041h bit 12) "
                                  f"within {self.timeout_s:g} s; motion stopped")
        self._stopped_meanwhile(doing)          # a STOP these writes overtook (0Fh leaves quick stop): stopped again

    def _stopped_meanwhile(self, doing: str) -> None:
        """A STOP came while a command set up its motion (its quick stops are out, or going out): the
        command writes nothing more (its next control word, 0Fh or a set-point, would enable the
        quick-stopped drives again and start the motion); the drives are brought to rest (any a write
        of the command enabled again gets a quick stop again) and :class:`MotionStopped` ends it."""
        if self._stop_pending:
            st = self._finish_stop()
            raise MotionStopped(f"{doing} stopped by STOP before it started; {self._where(st)}")

    def _lower_set_point(self) -> None:
        """Bit 4 down and the acknowledge (bit 12) gone on both drives, so that the next bit 4 is a
        rising edge: a process killed inside the handshake leaves bit 4 up and the drive would ignore
        the new set-point while still acknowledging the old one."""
        for i in range(2):
            self._write(i, CONTROL, ENABLE_OPERATION)
        deadline = time.monotonic() + self.timeout_s
        for i in range(2):
            while self._statusword(i) & SET_POINT_ACK:
                if time.monotonic() > deadline:
                    raise DeviceError(f"{self._name(i)} still acknowledges an old set-point (6041h bit 12) "
                                      f"{self.timeout_s:g} s after control bit 4 went down; check the drive")
                time.sleep(self.poll_period_s / 4)

    def expected_move_s(self, dx_mm: float, dy_mm: float) -> float:
        return max(move_time_s(abs(d), a.max_speed_mm_s, a.acceleration_mm_s2)
                   for d, a in ((dx_mm, self._axes[0]), (dy_mm, self._axes[1])))

    def move_to(self, x_mm: float, y_mm: float, timeout_s: float | None = None) -> RigStatus:
        """Both drives to the target in profile position mode; returns when both report target
        reached there. ``timeout_s`` ends the wait only while the axes make no progress."""
        x_mm, y_mm = check_target(self.config, x_mm, y_mm)
        with self._io:
            self._prepare("move")
            self._require_reference("move")
            x_mm, y_mm = self.check_target(x_mm, y_mm)
            if self._jog_target is not None:
                self._cancel_motion()
            st = self._query()
            x0, y0 = _position_of(st)
            expected = self.expected_move_s(x_mm - x0, y_mm - y0)
            if timeout_s is None:
                timeout_s = 1.5 * expected + 5.0
            self._moving = True
            try:
                self._start((x_mm, y_mm), (self._axes[0].max_speed_mm_s, self._axes[1].max_speed_mm_s),
                            f"move to ({x_mm:g}, {y_mm:g}) mm")
            except BaseException:
                self._moving = False
                raise
        try:
            return self._wait_arrival((x_mm, y_mm), timeout_s)
        finally:
            self._moving = False

    def _wait_arrival(self, target: tuple[float, float], timeout_s: float) -> RigStatus:
        start = time.monotonic()
        deadline = start + timeout_s
        last_pos: tuple[float, float] | None = None
        last_progress = start
        where = f"({target[0]:g}, {target[1]:g}) mm"
        while True:
            if self._stop_event.is_set():
                with self._io:
                    st = self._finish_stop()
                raise MotionStopped(f"move to {where} stopped by STOP; {self._where(st)}")
            with self._io:
                # the status words each poll (2 exchanges); the full status (10) when something
                # happened, at the end and every status_period_s (position, progress, listeners)
                sws = [self._statusword(i) for i in range(2)]
                now = time.monotonic()
                quiet = all(power_state(sw) == "OPERATION ENABLED" and not sw & (TARGET_REACHED | FOLLOWING_ERROR_BIT)
                            for sw in sws)
                if quiet and not any(self._halt_flags) and now - self._last_t < self.status_period_s \
                        and self._last is not None:
                    st = self._last                          # still on its way: the last full status
                else:
                    st = self._query()
            if st.state is RigState.ALARM:
                self._quick_stop_all()                   # the other drive must not go on alone
                raise DriveFault(f"move to {where} failed: {st.message}")
            for i, sw in enumerate(sws):
                if sw & FOLLOWING_ERROR_BIT:
                    self._quick_stop_all()
                    lag = st.extra["following_error_mm"][i]
                    raise PositionError(f"move to {where}: {self._name(i)} reports a following error (6041h bit 13" +
                                        ("" if lag is None else f", 60F4h = {lag:.3f} mm") + "); motion stopped. "
                                        "Check the axis for an obstruction, then home again")
            now = time.monotonic()
            pos = _position_of(st)
            if last_pos is None or max(abs(pos[0] - last_pos[0]), abs(pos[1] - last_pos[1])) > 1e-4:
                last_pos, last_progress = pos, now
            if st.state is RigState.HOLD:
                deadline += self.poll_period_s
                last_progress = now
            if all(sw & TARGET_REACHED for sw in sws) and st.state is RigState.IDLE:
                tol = [self.tolerance(i) for i in range(2)]
                if abs(pos[0] - target[0]) <= tol[0] and abs(pos[1] - target[1]) <= tol[1]:
                    return st
                raise PositionError(f"position error: the drives report target reached at ({pos[0]:.3f}, "
                                    f"{pos[1]:.3f}) mm, not at the target {where} (tolerance {tol[0]:g}, {tol[1]:g} "
                                    "mm: the drives' position windows 6067h, or the driver's own); "
                                    "check the feed constants (increments_per_mm) and the axes, then home again")
            if now > deadline and now - last_progress > self.stall_s:
                self.stop()
                with self._io:
                    st = self._finish_stop()
                raise DeviceError(f"move to {where} did not finish in time (expected within {timeout_s:.3g} s, "
                                  f"no progress for {self.stall_s:g} s); motion stopped, {self._where(st)}")
            self._stop_event.wait(self.poll_period_s)

    def _where(self, st: RigStatus | None) -> str:
        if st is None or st.position_mm is None:
            return "the rig's position is unknown"
        if st.state is RigState.ALARM:
            return f"a drive is in fault ({st.message})"
        return f"the rig stands at ({st.position_mm[0]:.3f}, {st.position_mm[1]:.3f}) mm"

    # -- fly scanning (lfstudio.rig.motion.FlyingController, LatchesPositions) ------------------------
    def fly_to(self, x_mm: float, y_mm: float, speed_mm_s: float) -> None:
        """A profile position move (``6060h`` = 1) to the target at ``speed_mm_s`` along the line: each
        moving axis' profile velocity ``6081h`` is its share of the speed (igus, dryve D1 manual V2.4
        §6.5.5 drives the pendulum motion with these objects), its ramps ``6083h``/``6084h`` the rig
        profile's acceleration. Returns once both drives acknowledged the set-point (status bit 12),
        while the carriage moves: :meth:`wait_arrival` waits for it. The target is checked against the
        soft limits and ``607Dh``, the speed against each axis' speed, before anything is sent. Where the
        moving drives have touch probe 1 (``60B8h``–``60BAh``) it is armed to latch the position on both
        edges of its input (the camera's exposure output); where not, that is said once and the fly
        scan interpolates ``6064h`` reads."""
        x_mm, y_mm = check_target(self.config, x_mm, y_mm)
        if not (isinstance(speed_mm_s, (int, float)) and math.isfinite(speed_mm_s) and speed_mm_s > 0):
            raise DeviceError(f"fly move refused: speed {speed_mm_s!r} mm/s is not a positive number; nothing was sent")
        with self._io:
            self._prepare("fly move")
            self._require_reference("fly move")
            x_mm, y_mm = self.check_target(x_mm, y_mm)
            if self._jog_target is not None:
                self._cancel_motion()
            st = self._query()
            if st.state is not RigState.IDLE:
                raise DeviceError(f"fly move refused: the rig is {st.state.value}, not idle")
            start = _position_of(st)
            deltas = (x_mm - start[0], y_mm - start[1])
            distance = math.hypot(*deltas)
            moving = [i for i in range(2) if abs(deltas[i]) > self.tolerance(i)]
            speeds = []
            for i in range(2):
                axis = self._axes[i]
                v = float(speed_mm_s) * abs(deltas[i]) / distance if i in moving else axis.max_speed_mm_s
                if v > axis.max_speed_mm_s * (1 + 1e-9):
                    raise DeviceError(f"fly move refused: {v:g} mm/s on the {axis.name} axis is faster than its "
                                      f"{axis.max_speed_mm_s:g} mm/s (rig profile {self.config.name!r}); nothing was sent")
                speeds.append(v)
            probes = self._arm_probes(moving)
            self._fly = {"moving": moving, "standing": {i: start[i] for i in range(2) if i not in moving},
                         "probes": probes, "latches": [], "probe_after": time.monotonic(), "probe_poll": 0.0}
            self._moving = True
            try:
                self._start((x_mm, y_mm), (speeds[0], speeds[1]),
                            f"fly move to ({x_mm:g}, {y_mm:g}) mm at {speed_mm_s:g} mm/s")
            except BaseException:
                self._moving = False
                self._fly = None
                raise

    def _arm_probes(self, moving: list[int]) -> list[int]:
        """Touch probe 1 of each moving drive armed (first event, both edges where the drive has
        ``60BBh``): the drives whose probes the fly move reads, or [] (then 6064h reads, said once)."""
        needed = (PROBE_FUNCTION, PROBE_STATUS, PROBE_POSITIVE)
        lacking = [i for i in moving if not all(self.has(i, index) for index in needed)]
        for i in lacking:
            self._say(f"{self._name(i)} has no touch probe (60B8h, 60B9h, 60BAh): fly scan positions are "
                      "interpolated from its position reads (6064h), not latched")
        if lacking or not moving:
            return []
        for i in moving:
            function = PROBE_ENABLE | PROBE_ON_RISING | (PROBE_ON_FALLING if self.has(i, PROBE_NEGATIVE) else 0)
            self._write(i, PROBE_FUNCTION, 0)                 # bit 0 low, then high: armed afresh
            self._write(i, PROBE_FUNCTION, function)
        return list(moving)

    def report(self) -> PositionReport:
        """The position ``6064h`` now, time-stamped: ``t_s`` the middle of the question and the answer
        on ``time.monotonic()``, ``uncertainty_s`` half their time apart (the drive took the value
        somewhere in between). During a fly move only the moving drives are read (a standing one holds
        its position); otherwise both. During a fly move with touch probes it also looks at their status
        (every :attr:`probe_poll_s`) and collects what they latched (:meth:`latches`)."""
        with self._io:
            if not self._connected or self._lost:
                raise DriveNotAnswering(self._lost or f"the rig {self.port} is not connected: connect first")
            fly = self._fly if self._fly is not None and not self._fly.get("done") else None
            read = (fly["moving"] or [0]) if fly is not None else [0, 1]
            values: dict[int, float] = dict(fly["standing"]) if fly is not None else {}
            t0 = time.monotonic()
            for i in read:
                values[i] = self._read(i, POSITION) / self._k[i]
            t1 = time.monotonic()
            if fly is not None and fly["probes"] and t1 - fly["probe_poll"] >= self.probe_poll_s:
                self._poll_probes(fly)
        return PositionReport((t0 + t1) / 2.0, values[0], values[1], (t1 - t0) / 2.0)

    def _poll_probes(self, fly: dict) -> None:
        """Touch probe status ``60B9h``: once every armed edge is stored, read ``60BAh``/``60BBh`` of the
        moving drives, keep the latch, arm again (``60B8h`` bit 0 low, then high)."""
        first = fly["probes"][0]
        t_question = time.monotonic()
        status = self._read(first, PROBE_STATUS)
        fly["probe_poll"] = time.monotonic()
        both = self.has(first, PROBE_NEGATIVE)
        wanted = PROBE_RISING_STORED | (PROBE_FALLING_STORED if both else 0)
        if status & wanted != wanted:
            if not status & (PROBE_RISING_STORED | PROBE_FALLING_STORED):
                fly["probe_after"] = t_question               # no edge before this question
            return
        t_seen = fly["probe_poll"]
        values = dict(fly["standing"])
        spans = []
        for i in fly["probes"]:
            rising = self._read(i, PROBE_POSITIVE)
            falling = self._read(i, PROBE_NEGATIVE) if self.has(i, PROBE_NEGATIVE) else rising
            values[i] = (rising + falling) / 2.0 / self._k[i]
            spans.append((falling - rising) / self._k[i])
        t_rearm = time.monotonic()
        for i in fly["probes"]:
            function = PROBE_ENABLE | PROBE_ON_RISING | (PROBE_ON_FALLING if self.has(i, PROBE_NEGATIVE) else 0)
            self._write(i, PROBE_FUNCTION, 0)
            self._write(i, PROBE_FUNCTION, function)
        unc = max(1.0 / self._k[i] for i in fly["probes"])   # one position unit
        fly["latches"].append(Latch(fly["probe_after"], t_seen, values[0], values[1], unc,
                                    "both" if both else "rising", math.hypot(*spans)))
        fly["probe_after"] = t_rearm                          # edges before the probe was armed again are lost

    def latches(self) -> list[Latch]:
        """The positions the drives' touch probes latched since :meth:`fly_to` (oldest first; after a
        last look at the probes), forgotten here; [] without touch probes."""
        with self._io:
            fly = self._fly
            if fly is None:
                return []
            if fly["probes"] and self._connected and not self._lost:
                self._poll_probes(fly)
            out, fly["latches"] = list(fly["latches"]), []
            if fly.get("done"):
                self._fly = None
            return out

    def wait_arrival(self, x_mm: float, y_mm: float, timeout_s: float) -> RigStatus:
        """Wait until both drives report target reached at the target of :meth:`fly_to` (STOP, a fault
        or a following error end it as they end :meth:`move_to`)."""
        try:
            return self._wait_arrival((float(x_mm), float(y_mm)), timeout_s)
        finally:
            self._moving = False
            fly = self._fly
            if fly is not None:                  # its latches stay for latches(); report() reads both drives again
                fly["done"] = True
                self._fly = fly if fly["probes"] else None

    def jog(self, dx_mm: float, dy_mm: float, speed_mm_s: float | None = None) -> None:
        """Start a jog by (dx, dy) mm, clamped to the soft limits and ``607Dh``; returns at once."""
        for name, value in (("jog dx", dx_mm), ("jog dy", dy_mm)):
            if not math.isfinite(value):
                raise DeviceError(f"{name}: {value} is not a number")
        with self._io:
            self._prepare("jog")
            self._require_reference("jog")
            st = self._query()
            if st.state not in (RigState.IDLE, RigState.JOGGING):
                raise DeviceError(f"jog refused: the rig is {st.state.value}")
            x0, y0 = self._jog_target or _position_of(st)
            x, y = self._clamp(x0 + dx_mm, y0 + dy_mm)
            if abs(x - x0) < 1e-6 and abs(y - y0) < 1e-6:
                return
            speeds = [a.max_speed_mm_s if speed_mm_s is None else min(float(speed_mm_s), a.max_speed_mm_s)
                      for a in self._axes]
            if not min(speeds) > 0:
                raise DeviceError(f"jog speed: {speed_mm_s} must be positive")
            self.check_target(x, y)
            self._start((x, y), (speeds[0], speeds[1]), "jog")
            self._jog_target = (x, y)

    def jog_cancel(self) -> None:
        with self._io:
            self._cancel_motion()

    def _cancel_motion(self) -> None:
        """Halt both drives, wait for standstill, then make where they stopped the target."""
        self._jog_target = None
        for i in range(2):
            self._write(i, CONTROL, ENABLE_OPERATION | HALT)
        deadline = time.monotonic() + self.timeout_s + self._stop_time_s()
        while not self._at_rest():
            if time.monotonic() > deadline:
                raise DeviceError("the drives did not stop after halt; press STOP")
            time.sleep(self.poll_period_s / 2)
        for i in range(2):
            if power_state(self._statusword(i)) != "OPERATION ENABLED":
                continue
            self._write(i, TARGET, self._read(i, POSITION))
            self._write(i, CONTROL, ENABLE_OPERATION | HALT | NEW_SET_POINT | CHANGE_IMMEDIATELY)
            self._write(i, CONTROL, ENABLE_OPERATION)
        self._query()

    def _stop_time_s(self) -> float:
        return max(a.max_speed_mm_s / a.acceleration_mm_s2 for a in self._axes)

    def feed_hold(self) -> None:
        """Halt (control word bit 8): both drives decelerate and hold; :meth:`resume` goes on."""
        self._halt_flags = (True, True)
        for i in range(2):
            try:
                self._write(i, CONTROL, ENABLE_OPERATION | HALT)
            except DeviceError as exc:
                log.warning("halt: %s", exc)

    def resume(self) -> None:
        self._halt_flags = (False, False)
        for i in range(2):
            self._write(i, CONTROL, ENABLE_OPERATION)

    def _quick_stop_all(self, wait_s: float | None = None) -> list[str]:
        """Quick stop (control word 0Bh) to both drives at once: each on a thread of its own and on its
        link's own path (:meth:`ObjectLink.write_now`), so that a drive whose link is stalled delays
        no other. Returns once every drive has it or failed (each within its link's deadline), or
        after ``wait_s`` with the slower ones still under way (:meth:`disconnect` waits for them);
        the failures so far, logged, are returned."""
        failures: list[str] = []

        def one(i: int) -> None:
            try:
                self.links[i].write_now(CONTROL, 0, QUICK_STOP, *SIZES[CONTROL])
            except Exception as exc:  # noqa: BLE001 - the other drive's stop must go on whatever this does
                failures.append(f"{self._name(i)}: {exc}")
                log.warning("quick stop of %s: %s", self._name(i), exc)

        threads = [threading.Thread(target=one, args=(i,), name=f"quick-stop-{'xy'[i]}", daemon=True)
                   for i in range(len(self.links))]
        self._stop_threads = [t for t in self._stop_threads if t.is_alive()] + threads
        for t in threads:
            t.start()
        end = None if wait_s is None else time.monotonic() + wait_s
        for t in threads:
            t.join(None if end is None else max(0.0, end - time.monotonic()))
        return list(failures)

    def stop(self) -> None:
        """STOP now: quick stop (control word 0Bh) to both drives at once, each on its own path
        (:meth:`_quick_stop_all`). Safe from any thread (the window's too); never waits for a running
        command nor behind an exchange in flight; returns once each drive has it, or after
        :data:`STOP_WAIT_S` while a stalled link still holds a drive's (it goes on to its deadline).
        The waiting command (or :meth:`status`) re-enables operation once both are at rest."""
        if not self._opened:                   # even after a link was lost: the other drive must stop
            return
        self._stop_pending = True
        self._jog_target = None
        self._quick_stop_all(STOP_WAIT_S)
        self._last_t = 0.0
        self._stop_event.set()

    def _finish_stop(self) -> RigStatus:
        """After STOP: wait until both drives are at rest, then enable operation again (quick stop
        active → operation enabled keeps the position). Returns the status there."""
        deadline = time.monotonic() + self.timeout_s + 3 * self._stop_time_s()
        while not self._at_rest():
            if time.monotonic() > deadline:
                log.warning("the drives did not come to rest within %.1f s after STOP", self.timeout_s)
                break
            for i in range(2):                   # a quick stop that never arrived (its link was stalled)
                if power_state(self._statusword(i)) == "OPERATION ENABLED" and \
                        (not self.has(i, VELOCITY) or self._read(i, VELOCITY) != 0):
                    self._write(i, CONTROL, QUICK_STOP)
            time.sleep(self.poll_period_s / 2)
        self._halt_flags = (False, False)
        for i in range(2):
            state = power_state(self._statusword(i))
            if state == "QUICK STOP ACTIVE":
                self._write(i, CONTROL, ENABLE_OPERATION)
                self._wait_state(i, "OPERATION ENABLED", "enable operation after the quick stop")
            if state in ("QUICK STOP ACTIVE", "OPERATION ENABLED") and self._read(i, MODE_DISPLAY) == HOMING:
                self.reference = ""                        # an interrupted homing leaves no reference
        self._stop_pending = False
        self._stop_event.clear()
        return self._query()

    def reset(self) -> None:
        """Fault reset (control word bit 7 rising) on every drive in FAULT, quick stop left; the
        reference is dropped (home again). Raises :class:`DriveFault` if a fault stays."""
        with self._io:
            if not self._connected:
                raise DriveNotAnswering(self._lost or f"the rig {self.port} is not connected: connect first")
            for i in range(2):
                state = power_state(self._statusword(i))
                if state in ("FAULT", "FAULT REACTION ACTIVE"):
                    self._write(i, CONTROL, DISABLE_VOLTAGE)
                    self._write(i, CONTROL, FAULT_RESET)
                    deadline = time.monotonic() + self.timeout_s
                    while power_state(self._statusword(i)) in ("FAULT", "FAULT REACTION ACTIVE"):
                        if time.monotonic() > deadline:
                            raise DriveFault(f"{self._name(i)} is still in fault after a fault reset: "
                                             f"{self._fault_of(i)}")
                        time.sleep(self.poll_period_s / 4)
                    self._write(i, CONTROL, DISABLE_VOLTAGE)
                    self.reference = ""
                elif state == "QUICK STOP ACTIVE":        # the other drive, stopped when this one faulted
                    deadline = time.monotonic() + self.timeout_s + 3 * self._stop_time_s()
                    while not self._drive_at_rest(i) and time.monotonic() < deadline:
                        time.sleep(self.poll_period_s / 4)
                    self._write(i, CONTROL, ENABLE_OPERATION)
            self._stop_pending = False
            self._stop_event.clear()
            self._halt_flags = (False, False)
            self._query()

    def unlock(self) -> None:
        """``lfstudio rig unlock``: the same as :meth:`reset` for drives."""
        self.reset()


def load_object_dictionary(path: str, node_id: int, where: str) -> tuple[object, set[tuple[int, int]]]:
    """The drive's object dictionary from its EDS/DCF file (python-canopen's ``import_od``) and the
    (index, subindex) it lists. ``where``: the profile key naming the file, for the one-line refusal
    (:class:`lfstudio.errors.InputError`) of a file that is missing or not an EDS/DCF."""
    from lfstudio.errors import InputError

    fix = "the drive maker's EDS file (or a DCF written from it), or leave eds_file out: the objects are then read from the drive"
    try:
        import configparser

        import canopen

        sections = configparser.RawConfigParser(strict=False)
        with open(path, encoding="utf-8", errors="replace") as f:
            sections.read_file(f)
        if not sections.has_section("DeviceInfo"):
            raise ValueError("no [DeviceInfo] section, which every EDS and DCF has")
        od = canopen.import_od(path, node_id)
    except FileNotFoundError:
        raise InputError(where, f"{path}: no such file; nothing was sent to the drive", fix) from None
    except Exception as exc:  # noqa: BLE001 - configparser and python-canopen raise many kinds
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(where, f"{path} is not an EDS/DCF file ({first}); nothing was sent to the drive",
                         fix) from None
    listed: set[tuple[int, int]] = set()
    for index in od.keys() if hasattr(od, "keys") else ():
        if not isinstance(index, int):
            continue
        obj = od[index]
        subs = getattr(obj, "subindices", None)
        if subs:
            listed.update((index, int(sub)) for sub in subs if isinstance(sub, int))
        else:
            listed.add((index, 0))
    if (STATUS, 0) not in listed or (CONTROL, 0) not in listed:
        raise InputError(where, f"{path} lists no CiA 402 drive (no status word 6041h or control word 6040h); "
                         "nothing was sent to the drive", fix)
    return od, listed


def check_feed_constants(rig: RigConfig) -> None:
    """Every axis of a CiA 402 rig names a positive feed constant (``increments_per_mm``)."""
    from lfstudio.errors import InputError

    for axis in (rig.horizontal, rig.vertical):
        k = axis.increments_per_mm
        where = f"rig {rig.name!r} {axis.name}.increments_per_mm"
        if not isinstance(k, (int, float)) or not math.isfinite(k) or k == 0:
            raise InputError(where, f"{k!r}: the feed constant (drive position units per mm) must be a positive "
                             "number, e.g. 100 for a drive counting 0.01 mm")
        if k < 0:
            raise InputError(where, f"{k:g} is negative: a wrong sign would drive the axis the wrong way; nothing "
                             "was sent", "set the drive's polarity (607Eh) to invert the axis and a positive "
                             "feed constant here")
