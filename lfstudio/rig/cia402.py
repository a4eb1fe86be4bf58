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
- **Units**: ``increments_per_mm`` of each axis in the rig profile (the feed constant: drive
  position units per mm); positive (a wrong sign would run the axis the wrong way: invert the
  drive's polarity ``607Eh`` instead), never 0.
- **Limits**: a target must be inside the profile's soft limits *and* the drive's own software
  position limits ``607Dh`` (read at connect); nothing is sent otherwise.
- **STOP** (:meth:`Cia402Controller.stop`): quick stop (control word 0Bh) to both drives at once,
  from any thread, each on a thread and a path of its own (a second Modbus TCP connection while the
  link's is busy; on CANopen an SDO exchange stalled for 20 ms is interrupted), so that it never
  waits for a running command nor behind an exchange, and a stalled link delays no other drive; the drives brake on their quick-stop ramp (``605Ah`` = 6: stay in quick
  stop active once at rest, position kept). The waiting command ends with where the rig stopped;
  the next command re-enables operation.
- **Reference**: homed in this connection, or found at connect in profile position mode with
  operation enabled: lfstudio only enters profile position after its own homing, and a fault or
  power loss leaves operation enabled, so such a drive was homed by lfstudio and kept its
  position since (a scan resumed after a crash checks the reported position against the dataset).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import Callable, Protocol

from lfstudio.errors import DeviceError, DeviceTimeout
from lfstudio.optics import move_time_s
from lfstudio.rig.motion import RigConfig, RigState, RigStatus, SoftLimitError, check_target, clamp_target

log = logging.getLogger(__name__)

# -- objects: index -> (subindex, bytes, signed) ---------------------------------------------------
ERROR_CODE, CONTROL, STATUS, QUICK_STOP_OPTION = 0x603F, 0x6040, 0x6041, 0x605A
MODE, MODE_DISPLAY, POSITION, FOLLOWING_WINDOW, VELOCITY = 0x6060, 0x6061, 0x6064, 0x6065, 0x606C
TARGET, SOFTWARE_LIMITS, PROFILE_VELOCITY, PROFILE_ACCELERATION = 0x607A, 0x607D, 0x6081, 0x6083
PROFILE_DECELERATION, QUICK_STOP_DECELERATION = 0x6084, 0x6085
HOMING_METHOD, HOMING_SPEEDS, HOMING_ACCELERATION, FOLLOWING_ERROR = 0x6098, 0x6099, 0x609A, 0x60F4
SIZES: dict[int, tuple[int, bool]] = {
    ERROR_CODE: (2, False), CONTROL: (2, False), STATUS: (2, False), QUICK_STOP_OPTION: (2, True),
    MODE: (1, True), MODE_DISPLAY: (1, True), POSITION: (4, True), FOLLOWING_WINDOW: (4, False),
    VELOCITY: (4, True), TARGET: (4, True), SOFTWARE_LIMITS: (4, True), PROFILE_VELOCITY: (4, False),
    PROFILE_ACCELERATION: (4, False), PROFILE_DECELERATION: (4, False), QUICK_STOP_DECELERATION: (4, False),
    HOMING_METHOD: (1, True), HOMING_SPEEDS: (4, False), HOMING_ACCELERATION: (4, False),
    FOLLOWING_ERROR: (4, True),
}
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


class Cia402Controller:
    """A :class:`lfstudio.rig.motion.MotionController` for two CiA 402 drives (horizontal, vertical).

    ``links``: the two drives' :class:`ObjectLink`; ``port``: the device word (messages, locks).
    After :meth:`connect`: :attr:`drive_limits_mm` (``607Dh`` in mm), :attr:`reference`
    ("homed", "origin", "kept" or "")."""

    def __init__(self, links: tuple[ObjectLink, ObjectLink], rig: RigConfig, *, port: str = "",
                 timeout_s: float = 3.0, poll_hz: float = 50.0, tolerance_mm: float = 0.02,
                 max_status_hz: float = 50.0, stall_s: float = 3.0):
        check_feed_constants(rig)
        self.links = tuple(links)
        self.config = rig
        self.port = port or ",".join(link.address for link in links)
        self.timeout_s = timeout_s
        self.poll_period_s = 1.0 / poll_hz
        self.tolerance_mm = tolerance_mm
        self.min_status_interval_s = 1.0 / max_status_hz
        self.stall_s = stall_s
        self.status_period_s = 0.1              # full status for the listeners while a move runs
        self.status_listener: Callable[[RigStatus], None] | None = None
        #: told one line when homing starts and as each drive reaches its reference (the CLI prints them)
        self.progress: Callable[[str], None] | None = None
        self._axes = (rig.horizontal, rig.vertical)
        self._k = (rig.horizontal.increments_per_mm, rig.vertical.increments_per_mm)
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
        self._last: RigStatus | None = None
        self._last_t = 0.0
        self._jog_target: tuple[float, float] | None = None
        self._homing = False
        self._halt_flags = (False, False)
        self.version = "CiA 402"

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
            threading.Thread(target=self._quick_stop_all, name="quick-stop-on-loss", daemon=True).start()
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

    # -- connection ----------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._connected and not self._lost

    def connect(self) -> None:
        """Open both links and read the drives: power state, fault, ``607Dh``; set the quick stop
        option (``605Ah`` = 6). Nothing moves and no drive is enabled here. A drive in FAULT is
        connected (so that it can be reset) and reported by :meth:`status`; motion is refused."""
        with self._io:
            self._lost = ""
            for i, link in enumerate(self.links):
                try:
                    link.open()
                except DriveNotAnswering as exc:
                    self._close_links()
                    raise DriveNotAnswering(f"{self._name(i)} does not answer: {exc}. Check the address, that "
                                            "the drive is powered and on the network, then connect again") from None
            self._opened = True
            states = []
            for i in range(2):
                try:
                    sw = self._statusword(i)
                except DriveNotAnswering:
                    self._close_links()
                    raise
                states.append(power_state(sw))
                lo = self._read(i, SOFTWARE_LIMITS, 1) / self._k[i]
                hi = self._read(i, SOFTWARE_LIMITS, 2) / self._k[i]
                self.drive_limits_mm[i] = (lo, hi) if lo < hi else None
                self._write(i, QUICK_STOP_OPTION, 6)
            modes = [self._read(i, MODE_DISPLAY) for i in range(2)]
            self._connected = True
            self.reference = "kept" if all(s == "OPERATION ENABLED" for s in states) and \
                all(m == PROFILE_POSITION for m in modes) else ""
            self._last_t = 0.0
            self._query()

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
        return {"statusword": sw, "state": power_state(sw), "error_code": self._read(i, ERROR_CODE),
                "position": self._read(i, POSITION), "following_error": self._read(i, FOLLOWING_ERROR),
                "mode": self._read(i, MODE_DISPLAY)}

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
                lines.append(f"{self._name(i)}: {fault_message(s['error_code'])}")
        return "; ".join(lines)

    def _rig_status(self, snaps: list[dict]) -> RigStatus:
        position = (round(snaps[0]["position"] / self._k[0], 4), round(snaps[1]["position"] / self._k[1], 4))
        states = [s["state"] for s in snaps]
        extra = {"power_state": {"x": states[0], "y": states[1]},
                 "fault_code": {"x": f"{snaps[0]['error_code']:04X}h", "y": f"{snaps[1]['error_code']:04X}h"},
                 "following_error_mm": (snaps[0]["following_error"] / self._k[0],
                                        snaps[1]["following_error"] / self._k[1]),
                 "mode": (snaps[0]["mode"], snaps[1]["mode"]), "reference": self.reference,
                 "drive_limits_mm": list(self.drive_limits_mm), "addresses": [link.address for link in self.links],
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
        return all(self._read(i, VELOCITY) == 0 for i in range(2))

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
                raise DriveFault(f"{self._name(i)}: {fault_message(self._read(i, ERROR_CODE))}")
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
            raise DriveFault(f"{self._name(i)}: {fault_message(self._read(i, ERROR_CODE))}")
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
        if self._stop_pending:
            self._finish_stop()
        self._stop_event.clear()
        self._check_no_fault(doing)

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

    def _home(self, methods: tuple[int, int], doing: str, reference: str) -> None:
        with self._io:
            self._prepare(doing)
            self._jog_target = None
            self.reference = ""
            for i in range(2):
                self._enable(i)
                self._set_mode(i, HOMING)
                a = self._axes[i]
                k = self._k[i]
                self._write(i, HOMING_METHOD, methods[i])
                self._write(i, HOMING_SPEEDS, max(1, round(a.max_speed_mm_s / 4 * k)), 1)
                self._write(i, HOMING_SPEEDS, max(1, round(a.max_speed_mm_s / 20 * k)), 2)
                self._write(i, HOMING_ACCELERATION, max(1, round(a.acceleration_mm_s2 * k)))
                self._write(i, CONTROL, ENABLE_OPERATION)
            for i in range(2):                              # both start together (bit 4 rising)
                self._write(i, CONTROL, ENABLE_OPERATION | NEW_SET_POINT)
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

    def _start(self, target: tuple[float, float], speeds_mm_s: tuple[float, float]) -> None:
        """Profile position to ``target`` on both drives: parameters, then the set-point handshake
        on both (bit 4 up, acknowledge, bit 4 down) before either is waited for."""
        steps = [round(target[i] * self._k[i]) for i in range(2)]
        for i in range(2):
            self._enable(i)
            self._set_mode(i, PROFILE_POSITION)
            a, k = self._axes[i], self._k[i]
            self._write(i, PROFILE_VELOCITY, max(1, round(speeds_mm_s[i] * k)))
            self._write(i, PROFILE_ACCELERATION, max(1, round(a.acceleration_mm_s2 * k)))
            self._write(i, PROFILE_DECELERATION, max(1, round(a.acceleration_mm_s2 * k)))
            self._write(i, QUICK_STOP_DECELERATION, max(1, round(4 * a.acceleration_mm_s2 * k)))
            self._write(i, TARGET, steps[i])
        self._lower_set_point()
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
                                     (fault_message(self._read(i, ERROR_CODE)) if sw & 0x08 else power_state(sw).lower()))
            if pending and time.monotonic() > deadline:
                self._quick_stop_all()
                raise DeviceError(f"{self._name(min(pending))} did not acknowledge the new set-point (6041h bit 12) "
                                  f"within {self.timeout_s:g} s; motion stopped")

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
                self._start((x_mm, y_mm), (self._axes[0].max_speed_mm_s, self._axes[1].max_speed_mm_s))
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
                    raise PositionError(f"move to {where}: {self._name(i)} reports a following error (60F4h = "
                                        f"{st.extra['following_error_mm'][i]:.3f} mm); motion stopped. Check the axis "
                                        "for an obstruction, then home again")
            now = time.monotonic()
            pos = _position_of(st)
            if last_pos is None or max(abs(pos[0] - last_pos[0]), abs(pos[1] - last_pos[1])) > 1e-4:
                last_pos, last_progress = pos, now
            if st.state is RigState.HOLD:
                deadline += self.poll_period_s
                last_progress = now
            if all(sw & TARGET_REACHED for sw in sws) and st.state is RigState.IDLE:
                tol = [max(self.tolerance_mm, 1.0 / k) for k in self._k]
                if abs(pos[0] - target[0]) <= tol[0] and abs(pos[1] - target[1]) <= tol[1]:
                    return st
                raise PositionError(f"position error: the drives report target reached at ({pos[0]:.3f}, "
                                    f"{pos[1]:.3f}) mm, not at the target {where} (tolerance {self.tolerance_mm} mm); "
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
            self._start((x, y), (speeds[0], speeds[1]))
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
                if power_state(self._statusword(i)) == "OPERATION ENABLED" and self._read(i, VELOCITY) != 0:
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
                                             f"{fault_message(self._read(i, ERROR_CODE))}")
                        time.sleep(self.poll_period_s / 4)
                    self._write(i, CONTROL, DISABLE_VOLTAGE)
                    self.reference = ""
                elif state == "QUICK STOP ACTIVE":        # the other drive, stopped when this one faulted
                    deadline = time.monotonic() + self.timeout_s + 3 * self._stop_time_s()
                    while self._read(i, VELOCITY) != 0 and time.monotonic() < deadline:
                        time.sleep(self.poll_period_s / 4)
                    self._write(i, CONTROL, ENABLE_OPERATION)
            self._stop_pending = False
            self._stop_event.clear()
            self._halt_flags = (False, False)
            self._query()

    def unlock(self) -> None:
        """``lfstudio rig unlock``: the same as :meth:`reset` for drives."""
        self.reset()


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
