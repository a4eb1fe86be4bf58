"""GRBL 1.1 motion-controller driver over pyserial (synchronous; run it through a DeviceWorker).

One connection, one lock: every line-based exchange (send a line, read until ``ok``/``error:N``;
send ``?``, read until the status report) holds ``_io``; realtime bytes for STOP (``!``, 0x85,
0x18) are written without it, so :meth:`GrblController.stop` works from any thread at any time.

Safety rules enforced here, before anything is sent:
- every target is inside the rig's soft limits (:func:`lfstudio.rig.motion.check_target`);
- no motion before ``$H`` homing or an explicit origin in this session;
- a move is complete only when the controller is Idle *and* reports the target within tolerance;
- every wait has a timeout; a silent or vanished controller leaves the driver "disconnected"
  with a message, and :meth:`connect` recovers.
"""

from __future__ import annotations

import logging
import math
import re
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import serial

from lfstudio.errors import DeviceError
from lfstudio.optics import move_time_s
from lfstudio.rig.motion import RigConfig, RigState, RigStatus, check_target, clamp_target

log = logging.getLogger(__name__)
#: status polls and reports (several a second): shown only with --debug (lfstudio.support.logs)
status_log = logging.getLogger(__name__ + ".status")

AXIS_LETTERS = "XYZABC"

GRBL_ERRORS: dict[int, str] = {
    1: "G-code words consist of a letter and a value; the letter was not found",
    2: "bad number format or missing value",
    3: "'$' system command not recognised or not supported",
    4: "negative value for an expected positive value",
    5: "homing is not enabled in the controller settings ($22)",
    6: "minimum step pulse time must be greater than 3 µs",
    7: "controller EEPROM read failed; settings restored to defaults",
    8: "'$' command only valid when the controller is Idle",
    9: "G-code locked out during alarm or jog state",
    10: "soft limits cannot be enabled without homing",
    11: "line too long (max characters per line exceeded)",
    12: "step rate too high for this setting",
    13: "safety door detected as opened",
    14: "build info or startup line too long",
    15: "jog target exceeds machine travel",
    16: "invalid jog command",
    17: "laser mode requires PWM output",
    20: "unsupported or invalid G-code command",
    21: "more than one G-code command from the same modal group",
    22: "feed rate has not yet been set or is undefined",
    23: "G-code command requires an integer value",
    24: "more than one G-code command that requires axis words",
    25: "repeated G-code word",
    26: "no axis words found in a command that requires them",
    27: "line number value is invalid",
    28: "G-code command is missing a required value word",
    29: "G59.x work coordinate systems are not supported",
    30: "G53 only allowed with G0 and G1 motion modes",
    31: "axis words found in a command that uses none",
    32: "G2/G3 arcs require at least one in-plane axis word",
    33: "motion command target is invalid",
    34: "arc radius value is invalid",
    35: "G2/G3 arcs require at least one in-plane offset word",
    36: "unused value words found",
    37: "G43.1 tool length offset not assigned to the configured axis",
    38: "tool number greater than the maximum supported value",
}

GRBL_ALARMS: dict[int, str] = {
    1: "hard limit: a limit switch was hit; the position is lost. Reset, then home the rig",
    2: "soft limit: a target beyond the machine travel was refused; position kept. Reset, then unlock",
    3: "reset while moving: the position is likely lost. Home the rig again",
    4: "probe fail: probe not in the expected initial state",
    5: "probe fail: probe did not contact within the programmed travel",
    6: "homing failed: the homing cycle was reset. Home again",
    7: "homing failed: the safety door was opened during homing",
    8: "homing failed: pull-off did not clear the limit switch; check the switches and wiring",
    9: "homing failed: limit switch not found within the search distance; check the switches and wiring",
    10: "homing failed: dual-axis switch not found",
}

_STATE_MAP = {"Idle": RigState.IDLE, "Run": RigState.MOVING, "Jog": RigState.JOGGING,
              "Home": RigState.HOMING, "Hold": RigState.HOLD, "Door": RigState.HOLD,
              "Alarm": RigState.ALARM, "Check": RigState.IDLE, "Sleep": RigState.IDLE}
_STATUS_RE = re.compile(r"<([^<>]*)>")
_ERROR_RE = re.compile(r"^error:(\d+)$")
_ALARM_RE = re.compile(r"^ALARM:(\d+)$")
_SETTING_RE = re.compile(r"^\$(\d+)=([-+]?[\d.]+)")


class GrblError(DeviceError):
    """The controller refused a line with ``error:N``."""

    def __init__(self, code: int, line: str):
        self.code = code
        self.line = line
        super().__init__(f"controller refused {line!r}: error {code}, "
                         f"{GRBL_ERRORS.get(code, 'unknown error code; see the GRBL 1.1 error list')}")


class GrblAlarm(DeviceError):
    """The controller went into alarm (``ALARM:N``): motion stopped, commands locked."""

    def __init__(self, code: int, context: str = ""):
        self.code = code
        text = f"ALARM {code}: {GRBL_ALARMS.get(code, 'unknown alarm; see the GRBL 1.1 alarm list')}"
        super().__init__(f"{context}: {text}" if context else text)


class ConnectionLost(DeviceError):
    """The port vanished or the controller stopped answering."""


class MotionStopped(DeviceError):
    """A move or homing was interrupted by STOP."""


class PositionError(DeviceError):
    """The controller is Idle but not where it was sent."""


@dataclass(frozen=True)
class GrblStatus:
    """One parsed ``<State|...>`` report. Positions are tuples over the controller's axes."""

    state: str                                   # Idle, Run, Hold, Jog, Alarm, Door, Check, Home, Sleep
    substate: int | None = None                  # Hold:0/1, Door:0..3
    mpos: tuple[float, ...] | None = None
    wpos: tuple[float, ...] | None = None
    wco: tuple[float, ...] | None = None
    feed_mm_min: float | None = None
    spindle_rpm: float | None = None
    planner_free: int | None = None
    rx_free: int | None = None
    line_number: int | None = None
    pins: str = ""
    overrides: tuple[int, ...] | None = None
    accessories: str = ""
    unknown: tuple[str, ...] = field(default=())

    def work_position(self, wco: tuple[float, ...] | None) -> tuple[float, ...] | None:
        """WPos from the report: given directly, or MPos − WCO (this report's or the last known)."""
        if self.wpos is not None:
            return self.wpos
        if self.mpos is None:
            return None
        offset = self.wco or wco
        if offset is None:
            return self.mpos
        return tuple(m - o for m, o in zip(self.mpos, offset))


STATES = tuple(_STATE_MAP)


def _floats(text: str) -> tuple[float, ...]:
    values = tuple(float(v) for v in text.split(","))
    if not values or any(not math.isfinite(v) for v in values):
        raise ValueError(text)
    return values


def parse_status(text: str) -> GrblStatus | None:
    """Parse the last ``<...>`` report in ``text`` (garbage around it is ignored).

    Every GRBL 1.1 field is understood in any order (MPos, WPos, WCO, Bf, Ln, FS, F, Pn, Ov, A);
    unknown or malformed fields are skipped. Returns None when there is no valid report."""
    matches = _STATUS_RE.findall(text)
    for body in reversed(matches):
        parts = body.split("|")
        state, _, sub = parts[0].partition(":")
        if state not in _STATE_MAP:
            continue
        values: dict = {"state": state}
        if sub:
            try:
                values["substate"] = int(sub)
            except ValueError:
                continue
        unknown = []
        for part in parts[1:]:
            key, sep, val = part.partition(":")
            try:
                if not sep:
                    raise ValueError(part)
                if key == "MPos":
                    values["mpos"] = _floats(val)
                elif key == "WPos":
                    values["wpos"] = _floats(val)
                elif key == "WCO":
                    values["wco"] = _floats(val)
                elif key == "FS":
                    f, s = _floats(val)
                    values["feed_mm_min"], values["spindle_rpm"] = f, s
                elif key == "F":
                    values["feed_mm_min"] = _floats(val)[0]
                elif key == "Bf":
                    b, r = (int(v) for v in val.split(","))
                    values["planner_free"], values["rx_free"] = b, r
                elif key == "Ln":
                    values["line_number"] = int(val)
                elif key == "Pn":
                    if not re.fullmatch(r"[XYZABCPDHRSxyzabc]*", val):
                        raise ValueError(val)
                    values["pins"] = val
                elif key == "Ov":
                    ov = tuple(int(v) for v in val.split(","))
                    if len(ov) != 3:
                        raise ValueError(val)
                    values["overrides"] = ov
                elif key == "A":
                    values["accessories"] = val
                else:
                    raise ValueError(part)
            except ValueError:
                unknown.append(part)
        values["unknown"] = tuple(unknown)
        return GrblStatus(**values)
    return None


class GrblController:
    """A :class:`lfstudio.rig.motion.MotionController` for GRBL 1.1 on a serial port.

    ``port``: a device path (``/dev/ttyUSB0``, ``/dev/pts/3``, ``COM3``) or a pyserial URL.
    ``timeout_s``: how long any single answer may take. ``poll_hz``: ``?`` rate while waiting for
    motion (GRBL recommends ≤ 5–10 Hz on real hardware; the pty simulator takes more).
    ``status_listener``: set by :class:`lfstudio.rig.worker.DeviceWorker`; called with fresh
    :class:`RigStatus` snapshots while a long command waits.
    """

    def __init__(self, port: str, rig: RigConfig, baudrate: int = 115200, *, timeout_s: float = 3.0,
                 poll_hz: float = 20.0, tolerance_mm: float = 0.02, max_status_hz: float = 50.0,
                 idle_grace_s: float = 0.5):
        self.port = port
        self.config = rig
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self.poll_period_s = 1.0 / poll_hz
        self.tolerance_mm = tolerance_mm
        self.min_status_interval_s = 1.0 / max_status_hz
        self.idle_grace_s = idle_grace_s
        self.status_listener: Callable[[RigStatus], None] | None = None
        self._ix = (AXIS_LETTERS.index(rig.horizontal.letter), AXIS_LETTERS.index(rig.vertical.letter))
        self._serial: serial.Serial | None = None
        self._io = threading.RLock()
        self._wlock = threading.Lock()
        self._rx = bytearray()
        self._stop_event = threading.Event()
        self._homing_reset = threading.Event()   # STOP sent a reset during homing
        self._stop_pending = False
        self._homed = False
        self._critical = False          # "Reset to continue": only a soft reset helps
        self._alarm_code: int | None = None
        self._lost = ""                 # why the connection is unusable ("" when fine)
        self._last: GrblStatus | None = None
        self._last_t = 0.0
        self._wco: tuple[float, ...] | None = None
        self._jog_target: tuple[float, float] | None = None
        self.settings: dict[int, float] = {}
        self.version = ""
        self.messages: list[str] = []   # [MSG:...] push messages, newest last
        self.garbage_lines = 0

    # -- connection --------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._serial is not None and not self._lost

    def connect(self) -> None:
        """Open the port and shake hands: a status report, ``$I`` (must be GRBL 1.1), ``$$``, ``$#``."""
        with self._io:
            self._close_port()
            try:
                self._serial = serial.serial_for_url(self.port, baudrate=self.baudrate, timeout=0.02,
                                                     write_timeout=self.timeout_s)
            except (serial.SerialException, OSError, ValueError) as exc:
                self._serial = None
                raise DeviceError(f"cannot open the rig port {self.port!r}: {exc}. Check the cable and "
                                  "the port name (lfstudio rig --port ...), or use 'sim'") from exc
            self._lost = ""
            self._rx.clear()
            self._homed = False
            self._critical = False
            self._alarm_code = None
            self._stop_event.clear()
            self._stop_pending = False
            try:
                self._serial.reset_input_buffer()
                self._handshake()
            except DeviceError:
                self._close_port()
                raise

    def _handshake(self) -> None:
        # an Arduino resets when the port opens and talks ~1-2 s later: ask until a report comes
        deadline = time.monotonic() + max(self.timeout_s, 2.5)
        status = None
        while status is None:
            if time.monotonic() > deadline:
                raise ConnectionLost(f"no GRBL controller answers on {self.port}: check that the controller "
                                     "is powered, the port and the baud rate ({self.baudrate})".replace(
                                         "{self.baudrate}", str(self.baudrate)))
            self._write(b"?")
            end = time.monotonic() + 0.25
            while status is None and time.monotonic() < end:
                line = self._readline(end)
                if line is not None:
                    kind = self._dispatch(line)
                    if kind == "status":
                        status = self._last
        info = self._command("$I")
        ver = next((i for i in info if i.startswith("[VER:")), "")
        self.version = ver[5:-1] if ver else ""
        if not self.version.startswith("1.1"):
            raise DeviceError(f"the controller on {self.port} is not GRBL 1.1 (it reports "
                              f"{self.version or 'no version'}); lfstudio speaks GRBL 1.1")
        for line in self._command("$$"):
            m = _SETTING_RE.match(line)
            if m:
                self.settings[int(m.group(1))] = float(m.group(2))
        self._read_offsets()
        self._critical = any("Reset to continue" in m for m in self.messages[-2:]) and status.state == "Alarm"
        # a homing controller ($22=1) starts locked in ALARM and leaves it only through $H (or an explicit
        # $X): not in alarm now means an earlier connection homed it and it has not been reset since
        self._homed = bool(self.config.homing and self.settings.get(22) == 1 and status.state != "Alarm")

    def _read_offsets(self) -> None:
        offsets: dict[str, tuple[float, ...]] = {}
        for line in self._command("$#"):
            m = re.match(r"^\[(G54|G92):([-\d.,]+)", line)
            if m:
                offsets[m.group(1)] = _floats(m.group(2))
        if "G54" in offsets:
            g92 = offsets.get("G92", tuple(0.0 for _ in offsets["G54"]))
            self._wco = tuple(a + b for a, b in zip(offsets["G54"], g92))

    def disconnect(self) -> None:
        with self._io:
            self._close_port()
            self._lost = ""
            self._homed = False

    def _close_port(self) -> None:
        ser, self._serial = self._serial, None
        if ser is not None:
            try:
                ser.close()
            except Exception:  # noqa: BLE001 - closing a dead port
                pass

    def _mark_lost(self, reason: str) -> ConnectionLost:
        self._lost = reason
        self._homed = False
        log.warning("rig connection lost: %s", reason)
        return ConnectionLost(reason)

    # -- bytes -------------------------------------------------------------------------------------
    def _write(self, data: bytes) -> None:
        ser = self._serial
        if ser is None or self._lost:
            raise ConnectionLost(self._lost or f"the rig on {self.port} is not connected: connect first")
        (status_log if data == b"?" else log).debug("%s > %r", self.port, data)
        try:
            with self._wlock:
                ser.write(data)
        except (serial.SerialException, OSError) as exc:
            raise self._mark_lost(f"connection to the rig on {self.port} lost ({exc}); check the cable, "
                                  "then connect again") from exc

    def _readline(self, deadline: float) -> str | None:
        """One line (stripped) or None when ``deadline`` passes first."""
        ser = self._serial
        while True:
            nl = self._rx.find(b"\n")
            if nl >= 0:
                raw = bytes(self._rx[:nl])
                del self._rx[:nl + 1]
                line = raw.decode("ascii", "replace").strip()
                if line:
                    (status_log if line.startswith("<") else log).debug("%s < %s", self.port, line)
                    return line
                continue
            if time.monotonic() >= deadline:
                return None
            if ser is None or self._lost:
                raise ConnectionLost(self._lost or "not connected")
            try:
                chunk = ser.read(max(1, ser.in_waiting or 1))
            except (serial.SerialException, OSError, TypeError) as exc:
                raise self._mark_lost(f"connection to the rig on {self.port} lost ({exc}); check the cable, "
                                      "then connect again") from exc
            if chunk:
                self._rx += chunk
                if len(self._rx) > 1 << 16:      # a flood of noise without line ends
                    del self._rx[:-1024]

    def _dispatch(self, line: str) -> str:
        """Classify a line and record its side effects; returns its kind."""
        if line == "ok":
            return "ok"
        if _ERROR_RE.match(line):
            return "error"
        m = _ALARM_RE.match(line)
        if m:
            self._last_t = 0.0
            self._alarm_code = int(m.group(1))
            self._homed = False
            if self._alarm_code in (1, 2):
                self._critical = True
            return "alarm"
        if "<" in line and ">" in line:
            st = parse_status(line)
            if st is not None:
                self._store_status(st)
                return "status"
        if line.startswith("Grbl ") or "Grbl 1." in line:
            self._last_t = 0.0
            self._critical = False
            self._stop_pending = False
            return "banner"
        if line.startswith("[MSG:"):
            self.messages = (self.messages + [line[5:-1]])[-20:]
            if "Reset to continue" in line:
                self._critical = True
            return "msg"
        if line.startswith("[") and line.endswith("]"):
            return "info"
        if _SETTING_RE.match(line):
            return "info"
        self.garbage_lines += 1
        log.debug("ignored line from the controller: %r", line)
        return "garbage"

    def _store_status(self, st: GrblStatus) -> None:
        self._last = st
        self._last_t = time.monotonic()
        if st.wco is not None:
            self._wco = st.wco
        if st.state == "Alarm":
            self._homed = False
        if self.status_listener is not None:
            try:
                self.status_listener(self._rig_status(st))
            except Exception:  # noqa: BLE001
                log.exception("status listener failed")

    # -- exchanges ---------------------------------------------------------------------------------
    def _command(self, line: str, timeout_s: float | None = None, poll: bool = False) -> list[str]:
        """Send one line and wait for ``ok``; returns the lines that came before it.

        Raises GrblError on ``error:N``, GrblAlarm on ``ALARM:N``, ConnectionLost on silence."""
        timeout_s = self.timeout_s if timeout_s is None else timeout_s
        with self._io:
            self._write(line.encode("ascii") + b"\n")
            infos: list[str] = []
            deadline = time.monotonic() + timeout_s
            next_poll = time.monotonic() + self.poll_period_s if poll else math.inf
            last_answer = time.monotonic()
            while True:
                now = time.monotonic()
                if poll and now >= next_poll:
                    if self._stop_event.is_set():
                        raise MotionStopped(f"{line!r} interrupted by STOP")
                    self._write(b"?")
                    next_poll = now + self.poll_period_s
                got = self._readline(min(deadline, next_poll))
                if got is None:
                    now = time.monotonic()
                    if now >= deadline:
                        raise self._mark_lost(f"the controller did not answer {line!r} within {timeout_s:g} s; "
                                              "check its power and cable, then connect again")
                    if poll and now - last_answer > self.timeout_s:
                        raise self._mark_lost(f"the controller stopped answering during {line!r}; "
                                              "check its power and cable, then connect again")
                    continue
                last_answer = time.monotonic()
                kind = self._dispatch(got)
                if kind == "ok":
                    self._last_t = 0.0      # the state may have changed: the next status() asks
                    return infos
                if kind == "error":
                    raise GrblError(int(got.split(":")[1]), line)
                if kind == "alarm":
                    if self._stop_event.is_set() or self._homing_reset.is_set():  # STOP's own alarm (recorded)
                        raise MotionStopped(f"{line!r} interrupted by STOP")
                    raise GrblAlarm(self._alarm_code or 0, f"during {line!r}")
                if kind == "banner" and self._stop_event.is_set():
                    raise MotionStopped(f"{line!r} interrupted by STOP")
                if kind in ("info", "msg"):
                    infos.append(got)

    def _drain(self) -> None:
        """Handle lines that already arrived (push messages, a report to an abandoned query) so
        the next answer read is the answer to the next question."""
        ser = self._serial
        try:
            waiting = ser.in_waiting if ser is not None else 0
        except (serial.SerialException, OSError) as exc:
            raise self._mark_lost(f"connection to the rig on {self.port} lost ({exc}); check the cable, "
                                  "then connect again") from exc
        if waiting:
            self._rx += ser.read(waiting)
        while b"\n" in self._rx:
            line = self._readline(0.0)
            if line is None:
                break
            self._dispatch(line)

    def _query_status(self) -> GrblStatus:
        with self._io:
            self._drain()
            self._write(b"?")
            deadline = time.monotonic() + self.timeout_s
            while True:
                got = self._readline(deadline)
                if got is None:
                    raise self._mark_lost(f"the controller did not send a status report within "
                                          f"{self.timeout_s:g} s; check its power and cable, then connect again")
                if self._dispatch(got) == "status":
                    assert self._last is not None
                    return self._last

    def _rig_status(self, st: GrblStatus | None) -> RigStatus:
        if self._serial is None or self._lost:
            return RigStatus(RigState.DISCONNECTED, None, False,
                             self._lost or f"not connected ({self.port})")
        if st is None:
            return RigStatus(RigState.DISCONNECTED, None, False, "no status yet")
        pos = st.work_position(self._wco)
        position = None
        if pos is not None and len(pos) > max(self._ix):
            position = (round(pos[self._ix[0]], 4), round(pos[self._ix[1]], 4))
        state = _STATE_MAP.get(st.state, RigState.IDLE)
        message = ""
        if st.state == "Alarm":
            if self._alarm_code is not None:
                message = f"ALARM {self._alarm_code}: {GRBL_ALARMS.get(self._alarm_code, 'unknown alarm')}"
            else:
                message = ("The controller is locked (alarm): home the rig"
                           if self.config.homing else "The controller is locked (alarm): unlock it")
            if self._critical:
                message += " (reset first)"
        elif st.state in ("Hold", "Door"):
            message = "Motion held: resume, or STOP to cancel the move"
        elif not self._homed:
            message = ("Not homed: home the rig before moving" if self.config.homing
                       else "No origin: with the carriage at the left/top end of its travel, set the origin")
        extra = {"grbl_state": st.state if st.substate is None else f"{st.state}:{st.substate}",
                 "feed_mm_min": st.feed_mm_min, "planner_free": st.planner_free, "pins": st.pins,
                 "overrides": st.overrides, "mpos": st.mpos}
        return RigStatus(state, position, self._homed, message, extra)

    # -- MotionController --------------------------------------------------------------------------
    def status(self) -> RigStatus:
        """A fresh status (at most ``max_status_hz`` queries per second; cached in between).
        Also completes a pending STOP (reset once the hold has come to rest)."""
        if self._serial is None or self._lost:
            return self._rig_status(None)
        with self._io:
            if self._last is None or time.monotonic() - self._last_t >= self.min_status_interval_s:
                self._query_status()
            last = self._last
            if self._stop_pending and last is not None and (
                    last.state in ("Idle", "Alarm") or (last.state == "Hold" and last.substate == 1)):
                self._finish_stop()
            return self._rig_status(self._last)

    def home(self) -> None:
        if not self.config.homing:
            raise DeviceError(f"rig {self.config.name!r} has no limit switches: park the carriage at the "
                              "left/top end of its travel and use 'set origin' instead of homing")
        with self._io:
            self._prepare_for_command()
            if self._critical:
                self.reset()
            h, v = self.config.horizontal, self.config.vertical
            timeout = 1.5 * (h.travel_mm / (h.max_speed_mm_s / 2) + v.travel_mm / (v.max_speed_mm_s / 2)) + 10.0
            self._stop_event.clear()
            self._homing_reset.clear()
            self._command("$H", timeout_s=timeout, poll=True)
            self._homed = True
            self._alarm_code = None
            self._critical = False
            self._jog_target = None
            self._query_status()

    def unlock(self) -> None:
        """Leave an alarm (``$X``; a soft reset first after a hard/soft-limit alarm).
        The position is then unknown: home or set the origin before moving."""
        with self._io:
            self._prepare_for_command()
            if self._critical:
                self.reset()
            self._command("$X")
            self._alarm_code = None
            self._query_status()

    def set_origin(self) -> None:
        """Make the current position the rig origin (0, 0) with ``G10 L20 P1``; allows motion."""
        with self._io:
            self._prepare_for_command()
            st = self._query_status()
            if st.state == "Alarm":
                raise DeviceError("the controller is in alarm: unlock it first, then set the origin")
            if st.state != "Idle":
                raise DeviceError(f"set the origin only when the rig is idle (it is {st.state.lower()})")
            self._command(f"G10 L20 P1 {self.config.horizontal.letter}0 {self.config.vertical.letter}0")
            self._read_offsets()
            self._homed = True
            self._query_status()

    def _prepare_for_command(self) -> None:
        """Finish a pending STOP before a new command (never leave a held move queued)."""
        if self._serial is None or self._lost:
            raise ConnectionLost(self._lost or f"the rig on {self.port} is not connected: connect first")
        if self._stop_pending:
            self._finish_stop()
        self._stop_event.clear()

    def _require_motion_allowed(self) -> GrblStatus:
        self._prepare_for_command()
        st = self._query_status()
        if st.state == "Alarm":
            raise GrblAlarm(self._alarm_code or 0, "motion refused") if self._alarm_code else DeviceError(
                "motion refused: the controller is locked (alarm); " +
                ("home the rig" if self.config.homing else "unlock it and set the origin"))
        if not self._homed:
            raise DeviceError("motion refused: the position is unknown; " +
                              ("home the rig first" if self.config.homing else "set the origin first"))
        return st

    def _position(self, st: GrblStatus) -> tuple[float, float]:
        pos = st.work_position(self._wco)
        if pos is None:
            raise DeviceError("the controller's status report has no position")
        return pos[self._ix[0]], pos[self._ix[1]]

    def move_to(self, x_mm: float, y_mm: float, timeout_s: float | None = None) -> RigStatus:
        x_mm, y_mm = check_target(self.config, x_mm, y_mm)
        with self._io:
            st = self._require_motion_allowed()
            if st.state == "Jog":
                self._cancel_jog_locked()
                st = self._last or st
            if st.state not in ("Idle",):
                raise DeviceError(f"move refused: the rig is {st.state.lower()}, not idle")
            x0, y0 = self._position(st)
            h, v = self.config.horizontal, self.config.vertical
            if timeout_s is None:
                timeout_s = 2.0 * max(move_time_s(x_mm - x0, h.max_speed_mm_s, h.acceleration_mm_s2),
                                      move_time_s(y_mm - y0, v.max_speed_mm_s, v.acceleration_mm_s2)) + 5.0
            line = f"G90 G0 {h.letter}{x_mm:.3f} {v.letter}{y_mm:.3f}"
            self._command(line)
        return self._wait_arrival((x_mm, y_mm), time.monotonic() + timeout_s, line)

    def _wait_arrival(self, target: tuple[float, float], deadline: float, line: str) -> RigStatus:
        idle_off_since: float | None = None
        idle_polls = 0
        while True:
            if self._stop_event.is_set():
                with self._io:
                    self._finish_stop()
                raise MotionStopped(f"move to ({target[0]:g}, {target[1]:g}) mm stopped by STOP; "
                                    "the rig is idle at its current position")
            with self._io:
                st = self._query_status()
            if st.state == "Alarm":
                raise GrblAlarm(self._alarm_code or 0, f"move to ({target[0]:g}, {target[1]:g}) mm")
            now = time.monotonic()
            if st.state == "Idle":
                x, y = self._position(st)
                if abs(x - target[0]) <= self.tolerance_mm and abs(y - target[1]) <= self.tolerance_mm:
                    return self._rig_status(st)
                idle_polls += 1
                idle_off_since = idle_off_since or now
                if idle_polls >= 3 and now - idle_off_since >= self.idle_grace_s:
                    raise PositionError(
                        f"position error: the controller stopped at ({x:.3f}, {y:.3f}) mm, not at the target "
                        f"({target[0]:.3f}, {target[1]:.3f}) mm (tolerance {self.tolerance_mm} mm); "
                        "check the axes for lost steps or obstruction, then home again")
            else:
                idle_off_since, idle_polls = None, 0
            if now > deadline:
                self.stop()
                with self._io:
                    self._finish_stop()
                raise DeviceError(f"move to ({target[0]:g}, {target[1]:g}) mm did not finish in time "
                                  f"(state {st.state}); motion stopped. Check the axes and try again")
            self._stop_event.wait(self.poll_period_s)

    def jog(self, dx_mm: float, dy_mm: float, speed_mm_s: float | None = None) -> None:
        """Jog by (dx, dy) mm, clamped to the soft limits (``$J=`` with an absolute target)."""
        for name, value in (("jog dx", dx_mm), ("jog dy", dy_mm)):
            if not math.isfinite(value):
                raise DeviceError(f"{name}: {value} is not a number")
        with self._io:
            st = self._require_motion_allowed()
            if st.state not in ("Idle", "Jog"):
                raise DeviceError(f"jog refused: the rig is {st.state.lower()}")
            if st.state == "Jog" and self._jog_target is not None:
                x0, y0 = self._jog_target
            else:
                x0, y0 = self._position(st)
            x, y = clamp_target(self.config, x0 + dx_mm, y0 + dy_mm)
            if abs(x - x0) < 1e-6 and abs(y - y0) < 1e-6:
                return                      # already at the soft limit in that direction
            h, v = self.config.horizontal, self.config.vertical
            limits = [a.max_speed_mm_s for a, d in ((h, x - x0), (v, y - y0)) if abs(d) > 1e-9]
            speed = min(limits) if speed_mm_s is None else min(float(speed_mm_s), min(limits))
            if not speed > 0:
                raise DeviceError(f"jog speed: {speed_mm_s} must be positive")
            check_target(self.config, x, y)
            self._command(f"$J=G90 G21 {h.letter}{x:.3f} {v.letter}{y:.3f} F{speed * 60:.0f}")
            self._jog_target = (x, y)

    def jog_cancel(self) -> None:
        with self._io:
            self._cancel_jog_locked()

    def _cancel_jog_locked(self) -> None:
        self._write(b"\x85")
        self._jog_target = None
        deadline = time.monotonic() + self.timeout_s + self._stop_time_s()
        while True:
            st = self._query_status()
            if st.state != "Jog":
                return
            if time.monotonic() > deadline:
                raise DeviceError("the jog did not stop after jog cancel; press STOP")
            time.sleep(self.poll_period_s / 2)

    def feed_hold(self) -> None:
        self._write(b"!")

    def resume(self) -> None:
        self._write(b"~")

    def stop(self) -> None:
        """STOP now: feed hold + jog cancel (a reset during homing). Never waits for the lock;
        the flush of the held move (soft reset) follows on the driver's thread."""
        ser = self._serial
        if ser is None or self._lost:
            return
        last = self._last.state if self._last is not None else ""
        data = b"\x18" if last == "Home" else b"!\x85"
        log.debug("%s > %r (STOP)", self.port, data)
        if last == "Home":                  # the ALARM:6 reply may be read before _stop_event is set below
            self._homing_reset.set()
        try:
            with self._wlock:
                ser.write(data)
        except (serial.SerialException, OSError) as exc:
            log.warning("STOP could not be written: %s", exc)
        self._stop_pending = last != "Home"
        self._jog_target = None
        self._last_t = 0.0                  # the next status() asks the controller
        self._stop_event.set()

    def _stop_time_s(self) -> float:
        h, v = self.config.horizontal, self.config.vertical
        return max(h.max_speed_mm_s / h.acceleration_mm_s2, v.max_speed_mm_s / v.acceleration_mm_s2)

    def _finish_stop(self) -> None:
        """After STOP: wait for the hold to come to rest, then soft-reset to drop the rest of the move."""
        deadline = time.monotonic() + self.timeout_s + 2 * self._stop_time_s()
        while True:
            st = self._query_status()
            if st.state in ("Idle", "Alarm"):
                break
            if st.state == "Hold" and st.substate == 1:
                self._soft_reset_locked()
                break
            if time.monotonic() > deadline:
                self._soft_reset_locked()
                break
            time.sleep(self.poll_period_s / 2)
        self._stop_pending = False
        self._stop_event.clear()
        self._query_status()

    def reset(self) -> None:
        """Soft reset (Ctrl-X): clears the planner and a critical alarm; waits for the banner."""
        with self._io:
            self._soft_reset_locked()
            self._query_status()

    def _soft_reset_locked(self) -> None:
        self._write(b"\x18")
        self._jog_target = None
        deadline = time.monotonic() + self.timeout_s
        while True:
            got = self._readline(deadline)
            if got is None:
                raise self._mark_lost("the controller did not restart after a reset; check its power, "
                                      "then connect again")
            if self._dispatch(got) == "banner":
                break
        # drain the push messages that follow the banner ([MSG:...], ALARM:3)
        end = time.monotonic() + 0.05
        while (got := self._readline(end)) is not None:
            self._dispatch(got)
        self._critical = False
