"""GRBL 1.1 motion-controller driver over pyserial (synchronous; run it through a DeviceWorker).

One connection, one lock: every line-based exchange (send a line, read until ``ok``/``error:N``;
send ``?``, read until the status report) holds ``_io``; realtime bytes for STOP (``!``, 0x85,
0x18) are written without it, so :meth:`GrblController.stop` works from any thread at any time.

Safety rules enforced here, before anything is sent:
- every target is inside the rig profile's soft limits (:func:`lfstudio.rig.motion.check_target`)
  and, when the controller has its own soft limits on (``$20=1``), inside the controller's
  machine travel (``$130``/``$131``/``$132``), checked in machine coordinates: a target GRBL would
  answer with ALARM 2 is refused here with the limit named, and nothing is sent;
- no motion before a reference: ``$H`` homing or an explicit origin in this connection, or a
  homing controller (``$22=1``) that is not in alarm and still carries the mark lfstudio sets after
  homing (tool number ``T1``, see :data:`HOMED_MARK`; GRBL clears it on every reset and power-up,
  so a board unlocked with ``$X`` or reset by opening its port is not taken as homed);
- a move is complete only when the controller is Idle *and* reports the target within tolerance;
- every wait has a timeout, computed from the controller's own rates and accelerations
  (``$110..``/``$120..``, read with ``$$`` on connect) and extended while the axes make progress or
  the operator holds the motion; a silent or vanished controller leaves the driver "disconnected"
  with a message, and :meth:`connect` recovers.

Frame: our positions are GRBL *work* coordinates (G54), 0 at the left/bottom end of the travel,
positive inwards. GRBL's machine coordinates after homing are negative: 0 at the home switch,
``-$130`` at the far end (``HOMING_FORCE_SET_ORIGIN`` builds, OPT flag ``Z``: 0 at the switch on
the side ``$23`` selects). :meth:`GrblController.home` therefore stores the G54 offset so that
``work = machine - (most negative machine position)``, i.e. ``x = MPos + $130`` by default; the
frame then covers ``0 … $130`` and GRBL's soft limits and ours agree. Without limit switches,
:meth:`GrblController.set_origin` makes the current position ``(0, 0)`` (``G10 L20 P1``); keep
``$20=0`` there (GRBL allows soft limits only with homing) and the profile's limits apply.

STOP (:meth:`GrblController.stop`): feed hold and jog cancel at once; then, on the driver's thread,
wait until the hold is complete (``Hold:0``; ``Hold:1`` means still decelerating) and only then
soft-reset to drop the rest of the move. A reset after the hold is complete keeps GRBL's position
(no ALARM 3); the result reports where the rig really stopped.

A board that restarts (banner ``Grbl 1.1h ['$' for help]``, e.g. DTR on opening the port) is
reported: :attr:`GrblController.board_resets`, ``locked`` while it waits in ALARM
(``[MSG:'$H'|'$X' to unlock]`` when homing is enabled), and the reference (homed/origin) is
dropped. Every line from the controller goes through :func:`parse_line`, which never raises:
malformed lines are logged and ignored.

The protocol itself (the error and alarm tables, the exceptions, the line and status parsers, the
firmware's limits from ``$$``) is :mod:`lfstudio.rig.grbl_protocol`, which imports no pyserial; this
module is the driver: the port, its lock, the exchanges and the safety rules above.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque
from typing import Callable

import serial

from lfstudio.errors import DeviceError
from lfstudio.optics import move_time_s
from lfstudio.rig.grbl_protocol import (AXIS_LETTERS, GRBL_ALARMS, HOLD_COMPLETE, HOMED_MARK, MAX_LINE_CHARS,
                                        STATE_MAP, ConnectionLost, FirmwareLimits, GrblAlarm, GrblError, GrblLine,
                                        GrblStatus, MotionStopped, PositionError, parse_line)
from lfstudio.rig.motion import (PositionReport, RigConfig, RigState, RigStatus, SoftLimitError, check_target,
                                  clamp_target)

log = logging.getLogger(__name__)
#: status polls and reports (several a second): shown only with --debug (lfstudio.support.logs)
status_log = logging.getLogger(__name__ + ".status")

def _os_reason(exc: BaseException) -> str:
    """An OS error in words ("Input/output error"), without Python's "[Errno 5]"."""
    return getattr(exc, "strerror", None) or str(exc)


class GrblController:
    """A :class:`lfstudio.rig.motion.MotionController` for GRBL 1.1 on a serial port.

    ``port``: a device path (``/dev/ttyUSB0``, ``/dev/pts/3``, ``COM3``) or a pyserial URL.
    ``timeout_s``: how long any single answer may take. ``poll_hz``: ``?`` rate while waiting for
    motion (GRBL recommends ≤ 5–10 Hz on real hardware; the pty simulator takes more).
    ``status_listener``: set by :class:`lfstudio.rig.worker.DeviceWorker`; called with fresh
    :class:`RigStatus` snapshots while a long command waits.

    After :meth:`connect`: :attr:`settings` (``$$``), :attr:`firmware` (what GRBL enforces),
    :attr:`warnings` (where the rig profile and the controller disagree), :attr:`board_resets`
    (banners seen), :attr:`reference` ("homed" after our own ``$H``, "origin" after
    :meth:`set_origin`, "" otherwise), :attr:`locked` (the last report said Alarm).
    """

    def __init__(self, port: str, rig: RigConfig, baudrate: int = 115200, *, timeout_s: float = 3.0,
                 poll_hz: float = 20.0, tolerance_mm: float = 0.02, max_status_hz: float = 50.0,
                 idle_grace_s: float = 0.5, stall_s: float = 3.0):
        self.port = port
        self.config = rig
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self.poll_period_s = 1.0 / poll_hz
        self.tolerance_mm = tolerance_mm
        self.min_status_interval_s = 1.0 / max_status_hz
        self.idle_grace_s = idle_grace_s
        self.stall_s = stall_s
        self.status_listener: Callable[[RigStatus], None] | None = None
        self._letters = (rig.horizontal.letter, rig.vertical.letter)
        self._ix = (AXIS_LETTERS.index(rig.horizontal.letter), AXIS_LETTERS.index(rig.vertical.letter))
        self._serial: serial.Serial | None = None
        self._io = threading.RLock()
        self._wlock = threading.Lock()
        self._rx = bytearray()
        self._stop_event = threading.Event()
        self._homing_reset = threading.Event()   # STOP sent a reset during homing
        self._homing = False                     # $H is running (GRBL sends no reports meanwhile)
        self._stop_pending = False
        self._banner_expected = False            # we reset, or an alarm may make GRBL reset itself
        self._unanswered = 0                     # lines whose ok/error we stopped waiting for
        self._banners = 0
        self.reference = ""                      # "homed" | "origin" | "": set by us in this connection
        self._critical = False                   # "Reset to continue": only a soft reset helps
        self._alarm_code: int | None = None
        self._lost = ""                          # why the connection is unusable ("" when fine)
        self._last: GrblStatus | None = None
        self._last_t = 0.0
        #: when each '?' not yet matched to a report was sent, oldest first. GRBL answers a '?' once
        #: its main loop sees the realtime flag, and several '?' before that share one report
        #: (protocol.c EXEC_STATUS_REPORT), so the n-th report answers the n-th '?' or a later one:
        #: the oldest unmatched '?' is the earliest the report can have been made.
        self._asked: deque[float] = deque()
        self._asks = 0                           # '?' sent in this connection
        #: '?' no longer counted whose reports may still come (see _query_status): the oldest one's
        #: time and how many; that many next reports (within timeout_s) are dated from it at the latest
        self._floor: tuple[float, int] | None = None
        self._last_asked_t = 0.0                 # that earliest time, for the last report read
        self._last_read_t = 0.0                  # when the last report was read (the latest it was made)
        self._reports = 0                        # reports read in this connection
        self._wco: tuple[float, ...] | None = None
        self._jog_target: tuple[float, float] | None = None
        self.settings: dict[int, float] = {}
        self.firmware = FirmwareLimits.from_settings({})
        self.options = ""
        self.planner_blocks = 15                 # blocks GRBL plans ahead ($I's [OPT:...,15,128])
        self.rx_buffer = 128                     # bytes of its serial receive buffer (the same)
        #: (code, line number in the stream, the line as sent) of each error:N answered to a streamed line
        #: (fly_pulsing; number 0, line "": the late answer to a line sent before the stream)
        self._stream_errors: list[tuple[int, int, str]] = []
        self._stream_lines: list[str] = []       # the lines of the last stream, in order
        self._stream_answers = 0                 # answers to them read so far
        self._stream_owed = 0                    # answers owed from before the stream, still to come
        self.warnings: list[str] = []
        self.version = ""
        self.messages: list[str] = []            # [MSG:...] push messages, newest last
        self.garbage_lines = 0
        self.board_resets = 0                    # banners we did not cause (board restarted)
        self.alarms: list[int] = []              # every ALARM:N of this connection, oldest first

    # -- connection --------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._serial is not None and not self._lost

    @property
    def _homed(self) -> bool:
        return bool(self.reference)

    @property
    def locked(self) -> bool:
        """The controller reports Alarm: it accepts only ``$H``, ``$X``, settings and reset."""
        return self._last is not None and self._last.state == "Alarm"

    def connect(self) -> None:
        """Open the port and shake hands: wait for the controller (a board may reboot when its port
        opens, see ``board_resets``), then ``$I`` (must be GRBL 1.1), ``$$`` and ``$#``."""
        with self._io:
            self._close_port()
            try:
                self._serial = serial.serial_for_url(self.port, baudrate=self.baudrate, timeout=0.02,
                                                     write_timeout=self.timeout_s)
            except (serial.SerialException, OSError, ValueError) as exc:
                self._serial = None
                number = getattr(exc, "errno", None)     # pyserial repeats it: "[Errno 2] could not open …: [Errno 2] …"
                reason = f"{os.strerror(number)} (errno {number})" if isinstance(number, int) else str(exc)
                error = DeviceError(f"cannot open the rig port {self.port!r}: {reason}. Check the cable and "
                                    "the port name (lfstudio rig --port ...), or use 'sim'")
                error.window_text = (f"cannot open the rig port {self.port!r}: {reason}. Check the cable and "
                                     "choose the controller's port in the Rig panel's Port list (↻ looks for "
                                     "ports again), or 'Simulated GRBL'")
                raise error from exc
            self._lost = ""
            self._rx.clear()
            self.reference = ""
            self._critical = False
            self._alarm_code = None
            self._last = None
            self._stop_event.clear()
            self._stop_pending = False
            self._banner_expected = False
            self._unanswered = 0
            self._stream_owed = 0
            self.board_resets = 0
            self.alarms = []
            self.messages = []
            try:
                self._handshake()
            except DeviceError:
                self._close_port()
                raise

    def _handshake(self) -> None:
        # an Arduino resets when the port opens and talks ~1-2 s later (bytes sent while it boots
        # are lost): ask until a report comes. Lines before it (banner, [MSG:...], error:7 and the
        # settings of a fresh EEPROM) are dispatched in order.
        start = time.monotonic()
        deadline = start + max(self.timeout_s, 2.5) + 1.0
        status = None
        reset_sent = False
        while status is None:
            now = time.monotonic()
            if now > deadline:
                raise ConnectionLost(f"no GRBL controller answers on {self.port}: check that the controller "
                                     f"is powered, the port and the baud rate ({self.baudrate})")
            if not reset_sent and now - start > max(self.timeout_s, 2.5) - 0.5:
                # after a hard/soft-limit alarm GRBL answers nothing, not even '?', until a reset
                log.warning("the controller on %s does not answer: sending a reset", self.port)
                self._banner_expected = True
                self._write(b"\x18")
                reset_sent = True
            self._ask_status()
            end = time.monotonic() + 0.25
            while status is None and time.monotonic() < end:
                line = self._readline(end)
                if line is not None and self._dispatch(line).kind == "status":
                    status = self._last
        info = self._command("$I")
        ver = next((i for i in info if i.startswith("[VER:")), "")
        self.version = ver[5:-1] if ver else ""
        opt = next((i for i in info if i.startswith("[OPT:")), "")
        self.options = opt[5:-1].split(",")[0] if opt else ""
        fields = opt[5:-1].split(",") if opt else []
        self.planner_blocks = int(fields[1]) if len(fields) > 1 and fields[1].strip().isdigit() else 15
        self.rx_buffer = int(fields[2]) if len(fields) > 2 and fields[2].strip().isdigit() else 128
        if not self.version.startswith("1.1"):
            raise DeviceError(f"the controller on {self.port} is not GRBL 1.1 (it reports "
                              f"{self.version or 'no version'}); lfstudio speaks GRBL 1.1")
        self.settings = {}
        for line in self._command("$$"):
            parsed = parse_line(line)
            if parsed.kind == "setting" and parsed.value is not None and parsed.key is not None:
                self.settings[parsed.key] = parsed.value
        self.firmware = FirmwareLimits.from_settings(self.settings, self.options)
        self._read_offsets()
        self._critical = False               # it answered: not stuck in a critical alarm
        modes = next((i for i in self._command("$G") if i.startswith("[GC:")), "")
        if (self.config.homing and self.firmware.homing and status.state != "Alarm"
                and HOMED_MARK in modes[4:-1].split()):
            self.reference = "homed"         # homed by an earlier connection, not reset since
        self.warnings = self._compare_profile()
        for text in self.warnings:
            log.warning("rig %s on %s: %s", self.config.name, self.port, text)

    def _compare_profile(self) -> list[str]:
        """Where the rig profile and the controller's own settings disagree (operator-readable)."""
        out = []
        fw = self.firmware
        for axis in (self.config.horizontal, self.config.vertical):
            i = AXIS_LETTERS.index(axis.letter)
            name = f"{axis.name} axis ({axis.letter})"
            rate = fw.max_rate_mm_min.get(axis.letter)
            if rate is not None and abs(rate / 60.0 - axis.max_speed_mm_s) > 0.01 * axis.max_speed_mm_s:
                out.append(f"{name}: the rig profile says {axis.max_speed_mm_s:g} mm/s, the controller's "
                           f"${110 + i} = {rate:g} mm/min ({rate / 60.0:.4g} mm/s); moves run at the "
                           "controller's rate and their timeouts follow it")
            acc = fw.acceleration_mm_s2.get(axis.letter)
            if acc is not None and abs(acc - axis.acceleration_mm_s2) > 0.01 * axis.acceleration_mm_s2:
                out.append(f"{name}: the rig profile says {axis.acceleration_mm_s2:g} mm/s², the controller's "
                           f"${120 + i} = {acc:g} mm/s²")
            travel = fw.max_travel_mm.get(axis.letter)
            if fw.soft_limits and travel is not None and axis.soft_max_mm - min(axis.soft_min_mm, 0) > travel:
                out.append(f"{name}: the rig profile's soft limits reach {axis.soft_max_mm:g} mm but the "
                           f"controller's travel is ${130 + i} = {travel:g} mm ($20 = 1): targets beyond the "
                           "controller's travel are refused")
        if self.config.homing and not fw.homing and self.settings:
            out.append("the rig profile expects limit switches (homing) but homing is off in the controller "
                       "($22 = 0): enable it ($22=1) or use 'set origin'")
        if not self.config.homing and fw.homing:
            out.append("homing is on in the controller ($22 = 1) but the rig profile has no limit switches: "
                       "the controller starts locked; unlock it, then set the origin")
        return out

    def _read_offsets(self) -> None:
        offsets: dict[str, tuple[float, ...]] = {}
        for line in self._command("$#"):
            parsed = parse_line(line)
            if parsed.kind == "param" and parsed.name in ("G54", "G92"):
                offsets[parsed.name] = parsed.values
        if "G54" in offsets:
            g92 = offsets.get("G92", tuple(0.0 for _ in offsets["G54"]))
            self._wco = tuple(a + b for a, b in zip(offsets["G54"], g92))

    def disconnect(self) -> None:
        with self._io:
            self._close_port()
            self._lost = ""
            self.reference = ""

    def _close_port(self) -> None:
        ser, self._serial = self._serial, None
        if ser is not None:
            try:
                ser.close()
            except Exception:  # noqa: BLE001 - closing a dead port
                pass

    def _mark_lost(self, reason: str) -> ConnectionLost:
        self._lost = reason
        self.reference = ""
        log.warning("rig connection lost: %s", reason)
        return ConnectionLost(reason)

    # -- bytes -------------------------------------------------------------------------------------
    def _ask_status(self) -> None:
        """Send ``?``, noting when (before the bytes leave: GRBL cannot answer earlier)."""
        self._asked.append(time.monotonic())
        self._asks += 1
        self._write(b"?")

    def _write(self, data: bytes) -> None:
        ser = self._serial
        if ser is None or self._lost:
            raise ConnectionLost(self._lost or f"the rig on {self.port} is not connected: connect first")
        (status_log if data == b"?" else log).debug("%s > %r", self.port, data)
        try:
            with self._wlock:
                ser.write(data)
        except (serial.SerialException, OSError) as exc:
            raise self._mark_lost(f"connection to the rig on {self.port} lost ({_os_reason(exc)}); check the cable, "
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
                    (status_log if line.startswith("<") else log).debug("%s < %s", self.port, line[:200])
                    return line
                continue
            if time.monotonic() >= deadline:
                return None
            if ser is None or self._lost:
                raise ConnectionLost(self._lost or "not connected")
            try:
                chunk = ser.read(max(1, ser.in_waiting or 1))
            except (serial.SerialException, OSError, TypeError) as exc:
                raise self._mark_lost(f"connection to the rig on {self.port} lost ({_os_reason(exc)}); check the cable, "
                                      "then connect again") from exc
            if chunk:
                self._rx += chunk
                if len(self._rx) > 4 * MAX_LINE_CHARS and self._rx.find(b"\n") < 0:   # noise without line ends
                    del self._rx[:-MAX_LINE_CHARS]

    def _dispatch(self, line: str) -> GrblLine:
        """Classify a line and record its side effects."""
        parsed = parse_line(line)
        kind = parsed.kind
        if kind in ("ok", "error") and self._unanswered > 0:
            self._unanswered -= 1                # the late answer to a line we gave up on (or streamed)
            number, text = 0, ""
            if self._stream_owed > 0:            # GRBL answers in order: those from before the stream first
                self._stream_owed -= 1
            else:
                self._stream_answers += 1
                if self._stream_answers <= len(self._stream_lines):
                    number, text = self._stream_answers, self._stream_lines[self._stream_answers - 1]
            if kind == "error":
                self._stream_errors.append((parsed.code or 0, number, text))
            return GrblLine("stale", parsed.text, code=parsed.code)
        if kind == "alarm":
            self._last_t = 0.0
            self._alarm_code = parsed.code
            self.alarms.append(parsed.code or 0)
            self.reference = ""
            self._banner_expected = True         # GRBL resets itself after most alarms
            if parsed.code in (1, 2):
                self._critical = True
        elif kind == "status":
            assert parsed.status is not None
            self._last_read_t = now = time.monotonic()
            horizon = now - self.timeout_s       # a '?' unanswered that long was lost (else the link is)
            while self._asked and self._asked[0] < horizon:
                self._asked.popleft()
            if self._asked:
                asked = self._asked.popleft()
            else:                                # unasked (a restart ate the count): keep the older bound
                asked = max(self._last_asked_t, horizon)
            if self._floor is not None and self._floor[0] >= horizon:
                asked = min(asked, self._floor[0])
                self._floor = (self._floor[0], self._floor[1] - 1) if self._floor[1] > 1 else None
            else:
                self._floor = None
            self._last_asked_t = asked
            self._reports += 1
            self._store_status(parsed.status)
        elif kind == "banner":
            self._last_t = 0.0
            self._critical = False
            self._stop_pending = False
            self._unanswered = 0                 # a restarted GRBL owes no answers
            self._asked.clear()                  # nor reports: its reset dropped the '?' flag
            self._floor = None
            self._stream_owed = 0
            self._banners += 1
            if self._banner_expected:
                self._banner_expected = False
            else:                                # the board restarted: position and reference are gone
                self.board_resets += 1
                if self.reference:
                    log.warning("the controller on %s restarted (%s): home the rig or set the origin again",
                                self.port, parsed.text)
                self.reference = ""
                self._jog_target = None
        elif kind == "msg":
            self.messages = (self.messages + [parsed.name])[-20:]
            if "Reset to continue" in parsed.name:
                self._critical = True
        elif kind == "garbage":
            self.garbage_lines += 1
            log.debug("ignored line from the controller: %r", line[:200])
        return parsed

    def _announce(self, state: RigState, message: str) -> None:
        """Tell the status listener about a state the controller does not report itself."""
        if self.status_listener is not None:
            last = self._rig_status(self._last)
            try:
                self.status_listener(RigStatus(state, last.position_mm, False, message, dict(last.extra)))
            except Exception:  # noqa: BLE001
                log.exception("status listener failed")

    def _store_status(self, st: GrblStatus) -> None:
        self._last = st
        self._last_t = time.monotonic()
        if st.wco is not None:
            self._wco = st.wco
        if st.state == "Alarm":
            self.reference = ""
        if self.status_listener is not None:
            try:
                self.status_listener(self._rig_status(st))
            except Exception:  # noqa: BLE001
                log.exception("status listener failed")

    # -- exchanges ---------------------------------------------------------------------------------
    def _command(self, line: str, timeout_s: float | None = None, poll: bool = False) -> list[str]:
        """Send one line and wait for ``ok``; returns the lines that came before it.

        ``poll``: a long command (``$H``): watch for STOP meanwhile and ask ``?`` (GRBL answers
        no report until homing ends, so silence is not a lost connection then; ``timeout_s`` is).
        Raises GrblError on ``error:N``, GrblAlarm on ``ALARM:N``, ConnectionLost on silence."""
        timeout_s = self.timeout_s if timeout_s is None else timeout_s
        with self._io:
            if self._unanswered:
                self._drain()
            banners = self._banners
            self._write(line.encode("ascii") + b"\n")
            try:
                return self._exchange(line, timeout_s, poll)
            except GrblError:
                raise                            # the answer itself
            except BaseException:
                if self._banners == banners:     # GRBL still owes the answer: _dispatch skips it
                    self._unanswered += 1
                raise

    def _exchange(self, line: str, timeout_s: float, poll: bool) -> list[str]:
        """Read the answer to ``line`` (just sent); see :meth:`_command`."""
        with self._io:
            infos: list[str] = []
            deadline = time.monotonic() + timeout_s
            next_poll = time.monotonic() + self.poll_period_s if poll else math.inf
            while True:
                now = time.monotonic()
                if poll and now >= next_poll:
                    if self._stop_event.is_set():
                        raise MotionStopped(f"{line!r} interrupted by STOP")
                    if not self._asked:     # GRBL reports once homing ends, for all '?' at once
                        self._ask_status()
                    next_poll = now + self.poll_period_s
                got = self._readline(min(deadline, next_poll))
                if got is None:
                    now = time.monotonic()
                    if now >= deadline:
                        raise self._mark_lost(f"the controller did not answer {line!r} within {timeout_s:g} s; "
                                              "check its power and cable, then connect again")
                    continue
                parsed = self._dispatch(got)
                kind = parsed.kind
                if kind == "ok":
                    self._last_t = 0.0      # the state may have changed: the next status() asks
                    return infos
                if kind == "error":
                    raise GrblError(parsed.code or 0, line)
                if kind == "alarm":
                    if parsed.code not in (1, 2):
                        self._await_restart()   # GRBL resets itself; bytes sent meanwhile are lost
                    if self._stop_event.is_set() or self._homing_reset.is_set():  # STOP's own alarm (recorded)
                        raise MotionStopped(f"{line!r} interrupted by STOP")
                    raise GrblAlarm(self._alarm_code or 0, f"during {line!r}")
                if kind == "banner" and self._stop_event.is_set():
                    raise MotionStopped(f"{line!r} interrupted by STOP")
                if kind == "banner":
                    raise DeviceError(f"the controller restarted while running {line!r}; "
                                      "home the rig or set the origin again")
                if kind in ("info", "msg", "setting", "param"):
                    infos.append(got)

    def _await_restart(self) -> None:
        """After an alarm that makes GRBL reset itself (homing and probe failures, a reset while
        moving): dispatch lines until its banner, so nothing is sent while it re-initialises."""
        deadline = time.monotonic() + self.timeout_s
        while self._banner_expected:
            got = self._readline(deadline)
            if got is None:
                return
            self._dispatch(got)

    def _drain(self) -> None:
        """Handle lines that already arrived (push messages, a report to an abandoned query) so
        the next answer read is the answer to the next question."""
        ser = self._serial
        try:
            waiting = ser.in_waiting if ser is not None else 0
        except (serial.SerialException, OSError) as exc:
            raise self._mark_lost(f"connection to the rig on {self.port} lost ({_os_reason(exc)}); check the cable, "
                                  "then connect again") from exc
        if waiting and ser is not None:
            self._rx += ser.read(waiting)
        while b"\n" in self._rx:
            line = self._readline(0.0)
            if line is None:
                break
            self._dispatch(line)

    def _query_status(self) -> GrblStatus:
        """Ask ``?`` and wait for the report to it. After a critical alarm (ALARM 1/2, "Reset to
        continue") GRBL answers nothing, not even ``?``, until a reset: the last known state is
        returned as Alarm without asking.

        Reports come in the order of the questions, each ``?`` counted (:attr:`_asked`): a report
        to an earlier ``?`` (asked again after 0.5 s without an answer, then answered late) is read
        and dated by that question, and the wait goes on for the report to ours. GRBL answers all
        the ``?`` it holds with one report, so after a report and 0.5 s of silence ours shared an
        earlier one: the questions still counted are dropped, and as many next reports (those that
        may still come late, within ``timeout_s``) are dated from their oldest at the latest."""
        with self._io:
            self._drain()
            if self._critical:
                return self._critical_status()
            self._ask_status()
            ours = self._asks                            # ours is answered once this many are
            reports = self._reports
            deadline = time.monotonic() + self.timeout_s
            ask_again = time.monotonic() + 0.5
            while True:
                got = self._readline(min(deadline, ask_again))
                if got is None:
                    if time.monotonic() < deadline and self._reports > reports and self._last is not None:
                        if self._asked:          # those '?' were answered with an earlier report, or lost
                            floor, count = self._floor or (math.inf, 0)
                            self._floor = (min(floor, self._asked[0]), count + len(self._asked))
                            self._asked.clear()
                        return self._last
                    if time.monotonic() < deadline:  # a '?' sent while GRBL resets is lost: ask again
                        self._ask_status()           # (if not, its late report is dated from the first)
                        ask_again = time.monotonic() + 0.5
                        continue
                    raise self._mark_lost(f"the controller did not send a status report within "
                                          f"{self.timeout_s:g} s; check its power and cable, then connect again")
                if self._dispatch(got).kind == "status" and self._asks - len(self._asked) >= ours:
                    assert self._last is not None
                    return self._last
                if self._critical:
                    return self._critical_status()

    def _critical_status(self) -> GrblStatus:
        last = self._last
        st = GrblStatus("Alarm", mpos=last.mpos if last else None, wpos=last.wpos if last else None,
                        wco=last.wco if last else None)
        if last is None or last.state != "Alarm":
            self._store_status(st)
        return self._last or st

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
        state = STATE_MAP.get(st.state, RigState.IDLE)
        message = ""
        if st.state == "Alarm":
            if self._alarm_code is not None:
                message = f"ALARM {self._alarm_code}: {GRBL_ALARMS.get(self._alarm_code, 'unknown alarm')}"
            else:
                started = "restarted and is" if self.board_resets else "is"
                message = (f"The controller {started} locked (alarm): home the rig" if self.config.homing
                           else f"The controller {started} locked (alarm): unlock it, then set the origin")
            if self._critical:
                message += " (reset first)"
        elif st.state in ("Hold", "Door"):
            message = "Motion held: resume, or STOP to cancel the move"
        elif not self.reference:
            message = ("Not homed: home the rig before moving" if self.config.homing
                       else "No origin: with the carriage at the left/bottom end of its travel, set the origin")
        extra = {"grbl_state": st.state if st.substate is None else f"{st.state}:{st.substate}",
                 "feed_mm_min": st.feed_mm_min, "planner_free": st.planner_free, "pins": st.pins,
                 "overrides": st.overrides, "mpos": st.machine_position(self._wco),
                 "reference": self.reference, "locked": st.state == "Alarm", "alarm_code": self._alarm_code,
                 "board_resets": self.board_resets, "warnings": list(self.warnings)}
        return RigStatus(state, position, bool(self.reference), message, extra)

    # -- MotionController --------------------------------------------------------------------------
    def status(self) -> RigStatus:
        """A fresh status (at most ``max_status_hz`` queries per second; cached in between).
        Also completes a pending STOP (reset once the hold is complete)."""
        if self._serial is None or self._lost:
            return self._rig_status(None)
        with self._io:
            if self._last is None or time.monotonic() - self._last_t >= self.min_status_interval_s:
                self._query_status()
            last = self._last
            if self._stop_pending and last is not None and (
                    last.state in ("Idle", "Alarm") or (last.state == "Hold" and last.substate == HOLD_COMPLETE)):
                self._finish_stop()
            return self._rig_status(self._last)

    def _axis_rate_mm_s(self, axis) -> float:
        rate = self.firmware.max_rate_mm_min.get(axis.letter)
        return rate / 60.0 if rate and rate > 0 else axis.max_speed_mm_s

    def _axis_accel_mm_s2(self, axis) -> float:
        acc = self.firmware.acceleration_mm_s2.get(axis.letter)
        return acc if acc and acc > 0 else axis.acceleration_mm_s2

    def expected_move_s(self, dx_mm: float, dy_mm: float) -> float:
        """How long GRBL takes for a straight rapid move by (dx, dy): its planner limits the speed and
        acceleration along the line so that no axis exceeds its own ``$11x``/``$12x``."""
        d = math.hypot(dx_mm, dy_mm)
        if d < 1e-9:
            return 0.0
        speed = accel = math.inf
        for axis, delta in ((self.config.horizontal, dx_mm), (self.config.vertical, dy_mm)):
            share = abs(delta) / d
            if share > 1e-12:
                speed = min(speed, self._axis_rate_mm_s(axis) / share)
                accel = min(accel, self._axis_accel_mm_s2(axis) / share)
        return move_time_s(d, speed, accel)

    def _homing_time_s(self) -> float:
        """Upper bound of GRBL's homing cycle from its settings: search 1.5 x travel at $25 per
        axis, locate 5 x pull-off at $24 twice, pull-offs and debounce delays."""
        seek = self.settings.get(25, 0.0) / 60.0
        feed = self.settings.get(24, 0.0) / 60.0
        pulloff = self.settings.get(27, 1.0)
        travel = self.firmware.max_travel_mm
        if seek <= 0 or feed <= 0 or not travel:
            h, v = self.config.horizontal, self.config.vertical
            return 1.5 * (h.travel_mm / (h.max_speed_mm_s / 2) + v.travel_mm / (v.max_speed_mm_s / 2)) + 10.0
        search = sum(1.5 * t / seek for t in travel.values())
        locate = 3 * (5 * pulloff / feed + 2 * pulloff / seek)
        return search + locate + 6 * self.settings.get(26, 250.0) / 1000.0 + 10.0

    def home(self) -> None:
        """``$H``, then store the G54 offset that makes GRBL's machine envelope our ``0 … $13x``
        frame (see the module docstring). Reference "homed"."""
        if not self.config.homing:
            raise DeviceError(f"rig {self.config.name!r} has no limit switches: park the carriage at the "
                              "left/bottom end of its travel and use 'set origin' instead of homing")
        with self._io:
            self._prepare_for_command()
            if self._critical:
                self.reset()
            self._stop_event.clear()
            self._homing_reset.clear()
            self._homing = True
            self._announce(RigState.HOMING, "Homing")   # GRBL sends no status report until it is done
            try:
                self._command("$H", timeout_s=self._homing_time_s(), poll=True)
            finally:
                self._homing = False
            self._alarm_code = None
            self._critical = False
            self._jog_target = None
            words = []
            for letter in self._letters:
                span = self.firmware.machine_range(letter)
                if span is not None:
                    words.append(f"{letter}{span[0]:.3f}")
            if words:
                self._command("G10 L2 P1 " + " ".join(words))
                self._read_offsets()
            self._command(HOMED_MARK)
            self.reference = "homed"
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
            self._command(f"G10 L20 P1 {self._letters[0]}0 {self._letters[1]}0")
            self._read_offsets()
            self.reference = "origin"
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
        if not self.reference:
            raise DeviceError("motion refused: the position is unknown; " +
                              ("home the rig first" if self.config.homing else "set the origin first"))
        return st

    def _position(self, st: GrblStatus) -> tuple[float, float]:
        pos = st.work_position(self._wco)
        if pos is None:
            raise DeviceError("the controller's status report has no position")
        return pos[self._ix[0]], pos[self._ix[1]]

    def firmware_range_mm(self, safe: bool = True) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """The controller's own soft-limit travel in our frame ((x_lo, x_hi), (y_lo, y_hi)), or None
        when GRBL's soft limits are off (``$20=0``) or its travel is unknown. ``safe``: without the
        pull-off at the home switch when hard limits are on (see ``FirmwareLimits.safe_machine_range``)."""
        if not self.firmware.soft_limits:
            return None
        out = []
        for letter, ix in zip(self._letters, self._ix):
            span = (self.firmware.safe_machine_range if safe else self.firmware.machine_range)(letter)
            if span is None:
                return None
            w = self._wco[ix] if self._wco is not None and len(self._wco) > ix else 0.0
            out.append((span[0] - w, span[1] - w))
        return out[0], out[1]

    def check_target(self, x_mm: float, y_mm: float) -> tuple[float, float]:
        """The profile's soft limits, then (``$20=1``) the controller's own travel: raise
        :class:`SoftLimitError` naming the limit; nothing is sent for a refused target."""
        x_mm, y_mm = check_target(self.config, x_mm, y_mm)
        span, envelope = self.firmware_range_mm(), self.firmware_range_mm(safe=False)
        if span is None or envelope is None:
            return x_mm, y_mm
        for k, (label, axis, value) in enumerate((("x", self.config.horizontal, x_mm),
                                                  ("y", self.config.vertical, y_mm))):
            rounded = round(value, 3)                # what goes on the wire
            (lo, hi), (env_lo, env_hi) = span[k], envelope[k]
            if lo - 1e-6 <= rounded <= hi + 1e-6:
                continue
            i = self._ix[k]
            if env_lo - 1e-6 <= rounded <= env_hi + 1e-6:
                problem = (f"{value:g} mm is on the home switch, within the pull-off ($27 = "
                           f"{self.firmware.pulloff_mm:g} mm) of where it triggers; with hard limits on "
                           "($21 = 1) touching it raises ALARM 1. Nothing was sent")
            else:
                problem = (f"{value:g} mm is beyond the controller's soft limit (${130 + i} = "
                           f"{self.firmware.max_travel_mm[axis.letter]:g} mm of travel, $20 = 1); nothing was sent")
            raise SoftLimitError(f"target {label} ({axis.name})", problem, f"{lo:g} … {hi:g} mm")
        return x_mm, y_mm

    def _clamp(self, x_mm: float, y_mm: float) -> tuple[float, float]:
        x, y = clamp_target(self.config, x_mm, y_mm)
        span = self.firmware_range_mm()
        if span is not None:
            x = min(max(x, span[0][0]), span[0][1])
            y = min(max(y, span[1][0]), span[1][1])
        return x, y

    def move_to(self, x_mm: float, y_mm: float, timeout_s: float | None = None) -> RigStatus:
        """Rapid (``G0``) to the target in our frame; returns when Idle there.

        ``timeout_s`` (default: from the controller's rates, see :meth:`expected_move_s`) ends the
        wait only while the axes make no progress; time spent in a feed hold does not count."""
        x_mm, y_mm = check_target(self.config, x_mm, y_mm)
        with self._io:
            st = self._require_motion_allowed()
            x_mm, y_mm = self.check_target(x_mm, y_mm)
            if st.state == "Jog":
                self._cancel_jog_locked()
                st = self._last or st
            if st.state not in ("Idle",):
                raise DeviceError(f"move refused: the rig is {st.state.lower()}, not idle")
            x0, y0 = self._position(st)
            expected = self.expected_move_s(x_mm - x0, y_mm - y0)
            if timeout_s is None:
                timeout_s = 1.5 * expected + 5.0
            h, v = self.config.horizontal, self.config.vertical
            line = f"G90 G54 G0 {h.letter}{x_mm:.3f} {v.letter}{y_mm:.3f}"
            self._command(line)
        return self._wait_arrival((x_mm, y_mm), timeout_s, line)

    # -- fly scanning (lfstudio.rig.motion.FlyingController) ---------------------------------------
    def fly_to(self, x_mm: float, y_mm: float, speed_mm_s: float) -> None:
        """A straight feed move (``G1 … F``) at ``speed_mm_s`` to the target; returns once GRBL has
        queued it (its ``ok``), while the carriage still moves: :meth:`wait_arrival` waits for it."""
        x_mm, y_mm = check_target(self.config, x_mm, y_mm)
        if not (math.isfinite(speed_mm_s) and speed_mm_s > 0):
            raise DeviceError(f"fly move refused: speed {speed_mm_s!r} mm/s is not a positive number")
        with self._io:
            st = self._require_motion_allowed()
            x_mm, y_mm = self.check_target(x_mm, y_mm)
            if st.state not in ("Idle",):
                raise DeviceError(f"fly move refused: the rig is {st.state.lower()}, not idle")
            h, v = self.config.horizontal, self.config.vertical
            self._command(f"G90 G54 G1 {h.letter}{x_mm:.3f} {v.letter}{y_mm:.3f} F{speed_mm_s * 60.0:.3f}")

    # -- the camera's trigger line on the spindle output (lfstudio.rig.motion.PulsesAtPositions) ----
    #: how far along the row the output stays high after each view (mm; at most half the spacing)
    pulse_mm = 1.0

    def pulse_problem(self, spacing_mm: float, speed_mm_s: float) -> str | None:
        """Why GRBL cannot switch its spindle output (the camera's trigger line) at each view of a row
        flown at ``speed_mm_s``, views ``spacing_mm`` apart, without slowing down; None when it can.

        GRBL 1.1 changes the spindle PWM inline with G1 motion only in laser mode (``$32=1``; else it
        stops the carriage at every change), with a variable spindle (``V`` in ``$I``'s options), and
        it plans only the blocks it holds (``planner_blocks``, two a view): those must cover the
        distance it needs to stop, or it slows down between views."""
        if not self.settings:
            return "the controller's settings are not known (connect first)"
        if "V" not in self.options.upper():
            return ("this GRBL build has no variable spindle (no V in the options $I reports), so it has no "
                    "laser mode to switch its spindle output during a move")
        if int(self.settings.get(32, 0)) != 1:
            return ("GRBL's laser mode is off ($32 = 0): it would stop the carriage at every change of its spindle "
                    "output (the camera's trigger line); send $32=1 to the controller once (it keeps it)")
        if float(self.settings.get(30, 0) or 0) <= 0:
            return "GRBL's maximum spindle speed is 0 ($30 = 0): its spindle output cannot be switched on"
        letter = self.config.horizontal.letter
        accel = self.firmware.acceleration_mm_s2.get(letter) or self.config.horizontal.acceleration_mm_s2
        ahead_mm = (self.planner_blocks - 1) // 2 * spacing_mm
        stop_mm = speed_mm_s * speed_mm_s / (2.0 * accel)
        if ahead_mm < stop_mm:
            top = math.sqrt(2.0 * accel * ahead_mm)
            return (f"GRBL plans {self.planner_blocks} moves ahead, {(self.planner_blocks - 1) // 2} views "
                    f"({ahead_mm:.3g} mm), less than the {stop_mm:.3g} mm it needs to stop from {speed_mm_s:.3g} mm/s "
                    f"at {accel:g} mm/s² (${120 + AXIS_LETTERS.index(letter)}): it would slow down between the "
                    f"views; at most {top:.3g} mm/s with these views")
        lines_s = 2.0 * speed_mm_s / spacing_mm
        chars_s = lines_s * 26 * 10                  # ~26 characters a line, 10 bits a character
        if chars_s > 0.5 * self.baudrate:
            return (f"{lines_s:.0f} lines/s of G-code ({chars_s:.0f} bit/s) are more than half the serial link's "
                    f"{self.baudrate} baud; at most {0.5 * self.baudrate / 260 * spacing_mm / 2:.3g} mm/s")
        return None

    def fly_pulsing(self, xs_mm: list[float], end_x_mm: float, y_mm: float, speed_mm_s: float) -> None:
        """Fly from where the carriage stands to ``end_x_mm`` at ``speed_mm_s``, the spindle output
        (the camera's trigger line) rising exactly as the carriage passes each of ``xs_mm`` and falling
        :attr:`pulse_mm` later (laser mode: GRBL switches it as that block's first step segment loads,
        without stopping). Streams the G-code and returns once GRBL holds its last line, while the
        carriage still moves: :meth:`wait_arrival` waits for it. STOP ends it like any move."""
        if not xs_mm:
            raise DeviceError("fly move refused: no positions to trigger at")
        if not (math.isfinite(speed_mm_s) and speed_mm_s > 0):
            raise DeviceError(f"fly move refused: speed {speed_mm_s!r} mm/s is not a positive number")
        spacing = min((abs(b - a) for a, b in zip(xs_mm, xs_mm[1:])), default=2.0 * self.pulse_mm)
        problem = self.pulse_problem(spacing if spacing > 0 else 2.0 * self.pulse_mm, speed_mm_s)
        if problem is not None:
            raise DeviceError(f"hardware trigger refused: {problem}")
        end_x_mm, y_mm = check_target(self.config, end_x_mm, y_mm)
        for x in xs_mm:
            check_target(self.config, x, y_mm)
        direction = 1.0 if end_x_mm >= xs_mm[0] else -1.0
        pulse = min(self.pulse_mm, 0.5 * spacing) if spacing > 0 else self.pulse_mm
        h = self.config.horizontal
        s_on = f"S{float(self.settings.get(30, 1000)):g}"
        lines = []
        for x in xs_mm:
            # the output falls pulse_mm on, never past the row's end (checked against the soft limits
            # above): a view near the end of travel, whose run-down the soft limit cut short, gets a
            # shorter pulse instead of a target beyond the limit
            off = min(x + pulse, end_x_mm) if direction > 0 else max(x - pulse, end_x_mm)
            lines.append(f"G1 {h.letter}{x:.3f} S0")
            lines.append(f"G1 {h.letter}{off:.3f} {s_on}")
        lines.append(f"G1 {h.letter}{end_x_mm:.3f} S0")
        with self._io:
            st = self._require_motion_allowed()
            self.check_target(end_x_mm, y_mm)
            if st.state not in ("Idle",):
                raise DeviceError(f"fly move refused: the rig is {st.state.lower()}, not idle")
            # M3 synchronises (GRBL waits for the motion to end): sent standing still, output low
            self._command(f"G90 G54 G1 F{speed_mm_s * 60.0:.3f} M3 S0")
        self._stream(lines)

    def _stream(self, lines: list[str]) -> None:
        """Send ``lines`` with GRBL's character-counting protocol: as many as its serial buffer holds
        (``rx_buffer`` bytes) are in flight, so no round trip lies between two blocks and the planner
        stays ahead of the carriage even when this computer is slow to answer. Their ``ok``s are
        counted as answers owed (``_unanswered``: whoever reads next consumes them, in order); an
        ``error`` among them is raised here, or by :meth:`pulse_off` once the stream has left."""
        in_flight: list[int] = []
        with self._io:
            if self._unanswered:
                self._drain()
            self._stream_errors = []
            self._stream_lines, self._stream_answers, self._stream_owed = list(lines), 0, self._unanswered
        sent = 0
        last_progress = time.monotonic()
        for line in lines:
            data = line.encode("ascii") + b"\n"
            while True:
                if self._stop_event.is_set():
                    raise MotionStopped("the fly move was stopped by STOP")
                with self._io:
                    # GRBL answers in order: the answers owed from before come first, then ours
                    waiting = min(sent, self._unanswered)
                    if waiting < len(in_flight):
                        del in_flight[:len(in_flight) - waiting]
                        last_progress = time.monotonic()
                    if self._stream_errors:
                        raise self._halt_refused_row()
                    if sum(in_flight) + len(data) <= self.rx_buffer - 1:
                        self._write(data)
                        self._unanswered += 1
                        in_flight.append(len(data))
                        sent += 1
                        break
                    got = self._readline(time.monotonic() + 0.005)
                    if got is not None:
                        self._dispatch(got)
                if time.monotonic() - last_progress > max(self.timeout_s, 10.0):
                    raise self._mark_lost("the controller stopped taking the fly move's lines; check its power "
                                          "and cable, then connect again")

    def _halt_refused_row(self) -> GrblError:
        """GRBL refused a streamed line of the fly row (``error:N``): stop the carriage and drop the rest
        of the row; the error to raise, saying where the rig stands (call with ``_io`` held).

        GRBL 1.1h drops a line it refuses and goes on with the next ones (protocol.c reports the
        error and reads the next line; the blocks already planned run on): the carriage would fly on
        along the row, past a view whose switch of the trigger line is missing, while the scan pauses.
        So: feed hold (``!``), wait until the hold is complete (``Hold:0``), then soft reset (0x18),
        which empties the planner and the lines waiting in GRBL's serial buffer. After a complete hold
        the reset keeps the position (mc_reset alarms only while the steppers may run: a cycle, a jog,
        homing or a hold still decelerating). A hold that does not complete in time is reset anyway:
        GRBL then raises ALARM 3 and its position is lost; the message says so (home the rig)."""
        codes, self._stream_errors = self._stream_errors, []
        self._write(b"!")
        self._stop_pending = True            # a reset is owed until it is done (status() would finish it)
        deadline = time.monotonic() + self.timeout_s + 3 * self._stop_time_s()
        while True:
            st = self._query_status()
            if st.state == "Alarm" or (st.state == "Hold" and st.substate == HOLD_COMPLETE):
                break
            if st.state == "Idle":           # between blocks, or the row's end: lines may still wait
                self._write(b"!")            # GRBL holds from Idle at once (Hold:0)
            if time.monotonic() > deadline:
                log.warning("the rig did not hold within %.1f s after a refused fly line (state %s); resetting",
                            self.timeout_s + 3 * self._stop_time_s(), st.state)
                break
            time.sleep(self.poll_period_s / 4)
        if st.state != "Alarm" or not self._critical:
            self._soft_reset_locked()
        self._stop_pending = False
        self._stop_event.clear()
        st = self._query_status()
        if st.state == "Alarm":
            where = (f"the hold did not complete in time, so the reset put GRBL in ALARM {self._alarm_code or 3} "
                     "(reset while moving): its position is lost; home the rig again")
        else:
            try:
                x, y = self._position(st)
                where = f"the carriage stopped at x = {x:.3f} mm, y = {y:.3f} mm, position kept"
            except DeviceError:
                where = self._where(st)
        # where the carriage stands first: a panel's few lines show that before the why
        after = (f"{where} (GRBL goes on with the lines after a refused one, so the carriage was held and the rest "
                 "of the row dropped: feed hold, then reset)")
        return self._refused_line(codes[0], after)

    def _refused_line(self, error: tuple[int, int, str], after: str) -> GrblError:
        """The :class:`GrblError` of a streamed line GRBL refused, naming the line: which of the row's
        lines, as sent, and GRBL's own error number and meaning."""
        code, number, line = error
        if not number:                   # the late answer to a line sent before the stream
            return GrblError(code, "a line sent before the fly row", after=after)
        return GrblError(code, line, after=after,
                         what=f'line {number} of {len(self._stream_lines)} of the fly row, "{line}",')

    def pulse_off(self) -> None:
        """Spindle output off (``M5``; GRBL waits until the carriage stands). Raises an ``error:N``
        GRBL answered to a line streamed by :meth:`fly_pulsing`."""
        with self._io:
            self._command("M5", timeout_s=max(self.timeout_s, 30.0))
            errors, self._stream_errors = self._stream_errors, []
        if errors:
            raise self._refused_line(errors[0], "its answer came once the row was flown (the carriage stands at "
                                                "its end)")

    def report(self) -> PositionReport:
        """The position GRBL reports now, time-stamped at the middle of the question and the answer
        (``uncertainty_s``: half their time apart)."""
        with self._io:
            t0 = time.monotonic()
            reports = self._reports
            st = self._query_status()
            t1 = time.monotonic()
            x, y = self._position(st)
            if self._reports != reports:
                # dated by the question it answers, not by ours: a report to an earlier '?' (asked
                # again after 0.5 s without an answer, and answered late) can come after our '?'
                t0, t1 = min(self._last_asked_t, t0), self._last_read_t
        return PositionReport((t0 + t1) / 2.0, x, y, (t1 - t0) / 2.0)

    def wait_arrival(self, x_mm: float, y_mm: float, timeout_s: float) -> RigStatus:
        """Wait until Idle at the target of :meth:`fly_to` (STOP ends it as it ends :meth:`move_to`)."""
        return self._wait_arrival((float(x_mm), float(y_mm)), timeout_s, "G1 (fly)", fly=True)

    def _wait_arrival(self, target: tuple[float, float], timeout_s: float, line: str, fly: bool = False) -> RigStatus:
        start = time.monotonic()
        deadline = start + timeout_s
        idle_off_since: float | None = None
        idle_polls = 0
        last_pos: tuple[float, float] | None = None
        last_progress = start
        held_since: float | None = None
        while True:
            if self._stop_event.is_set():
                with self._io:
                    st = self._finish_stop()
                raise MotionStopped(f"move to ({target[0]:g}, {target[1]:g}) mm stopped by STOP; "
                                    + self._where(st))
            with self._io:
                st = self._query_status()
                if fly and self._stream_errors:     # a streamed line refused: GRBL runs the rest (see there)
                    raise self._halt_refused_row()
            if st.state == "Alarm":
                raise GrblAlarm(self._alarm_code or 0, f"move to ({target[0]:g}, {target[1]:g}) mm")
            now = time.monotonic()
            pos = self._position(st)
            if last_pos is None or max(abs(pos[0] - last_pos[0]), abs(pos[1] - last_pos[1])) > 1e-4:
                last_pos, last_progress = pos, now
            if st.state in ("Hold", "Door"):            # held by the operator: the clock stops
                held_since = held_since or now
            elif held_since is not None:
                deadline += now - held_since
                last_progress = now
                held_since = None
            if st.state == "Idle":
                x, y = pos
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
            if held_since is None and now > deadline and now - last_progress > self.stall_s:
                self.stop()
                with self._io:
                    st = self._finish_stop()
                raise DeviceError(f"move to ({target[0]:g}, {target[1]:g}) mm did not finish in time "
                                  f"(expected within {timeout_s:.3g} s, no progress for {self.stall_s:g} s); "
                                  f"motion stopped, {self._where(st)}. Check the axes and try again")
            self._stop_event.wait(self.poll_period_s)

    def _where(self, st: GrblStatus | None) -> str:
        """Where STOP left the rig, truthfully."""
        if st is None:
            return "the rig's position is unknown"
        if st.state == "Alarm":
            return (f"but the controller is in ALARM {self._alarm_code or ''}".rstrip() +
                    ": its position is lost; home the rig again")
        try:
            x, y = self._position(st)
        except DeviceError:
            return f"the rig is {st.state.lower()}"
        return f"the rig is {st.state.lower()} at ({x:.3f}, {y:.3f}) mm"

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
            x, y = self._clamp(x0 + dx_mm, y0 + dy_mm)
            if abs(x - x0) < 1e-6 and abs(y - y0) < 1e-6:
                return                      # already at the soft limit in that direction
            h, v = self.config.horizontal, self.config.vertical
            limits = [min(a.max_speed_mm_s, self._axis_rate_mm_s(a))
                      for a, d in ((h, x - x0), (v, y - y0)) if abs(d) > 1e-9]
            speed = min(limits) if speed_mm_s is None else min(float(speed_mm_s), min(limits))
            if not speed > 0:
                raise DeviceError(f"jog speed: {speed_mm_s} must be positive")
            self.check_target(x, y)
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
        the flush of the held move (soft reset once the hold is complete) follows on the driver's
        thread (:meth:`status` or the waiting command)."""
        ser = self._serial
        if ser is None or self._lost:
            return
        homing = self._homing or (self._last is not None and self._last.state == "Home")
        data = b"\x18" if homing else b"!\x85"   # GRBL ignores a feed hold while homing
        log.debug("%s > %r (STOP)", self.port, data)
        if homing:                          # the ALARM:6 reply may be read before _stop_event is set below
            self._homing_reset.set()
            self._banner_expected = True
        try:
            with self._wlock:
                ser.write(data)
        except (serial.SerialException, OSError) as exc:
            log.warning("STOP could not be written: %s", exc)
        self._stop_pending = not homing
        self._jog_target = None
        self._last_t = 0.0                  # the next status() asks the controller
        self._stop_event.set()

    def complete_stop(self) -> None:
        """Block until a STOP is complete: the hold has ended the motion and a soft reset dropped the
        rest of the move (what the waiting command or :meth:`status` would do; for a caller that is
        about to disconnect, e.g. ``lfstudio rig``'s Ctrl+C). A controller that already reports Idle is
        reset too: a move it had received but not started when the hold came may still be queued."""
        with self._io:
            if self._serial is not None and not self._lost and self._stop_pending:
                if self._query_status().state == "Idle":
                    self._soft_reset_locked()
                    self._stop_pending = False
                    self._stop_event.clear()
                    self._query_status()
                else:
                    self._finish_stop()

    def _stop_time_s(self) -> float:
        """The longest deceleration from full speed on either axis, from the controller's settings."""
        return max(self._axis_rate_mm_s(a) / self._axis_accel_mm_s2(a)
                   for a in (self.config.horizontal, self.config.vertical))

    def _finish_stop(self) -> GrblStatus:
        """After STOP: wait until the hold is complete (``Hold:0``), then soft-reset to drop the rest
        of the move; a jog cancel ends Idle by itself. Returns the final status."""
        start = time.monotonic()
        deadline = start + self.timeout_s + 3 * self._stop_time_s()
        hold_resent = False
        while True:
            st = self._query_status()
            if st.state in ("Idle", "Alarm"):
                break
            if st.state == "Hold" and st.substate == HOLD_COMPLETE:
                self._soft_reset_locked()
                break
            now = time.monotonic()
            if st.state == "Run" and not hold_resent and now - start > 0.5:
                self._write(b"!")           # the hold did not arrive (noise on the line): again
                hold_resent = True
            if now > deadline:
                log.warning("the rig did not come to rest within %.1f s after STOP (state %s); resetting",
                            now - start, st.state)
                self._soft_reset_locked()
                break
            time.sleep(self.poll_period_s / 2)
        self._stop_pending = False
        self._stop_event.clear()
        return self._query_status()

    def reset(self) -> None:
        """Soft reset (Ctrl-X): clears the planner and a critical alarm; waits for the banner."""
        with self._io:
            self._soft_reset_locked()
            self._query_status()

    def _soft_reset_locked(self) -> None:
        self._banner_expected = True
        self._write(b"\x18")
        self._jog_target = None
        deadline = time.monotonic() + self.timeout_s
        while True:
            got = self._readline(deadline)
            if got is None:
                raise self._mark_lost("the controller did not restart after a reset; check its power, "
                                      "then connect again")
            if self._dispatch(got).kind == "banner":
                break
        # drain the push messages that follow the banner ([MSG:...])
        end = time.monotonic() + 0.05
        while (got := self._readline(end)) is not None:
            self._dispatch(got)
        self._critical = False
        self._read_offsets()                 # a reset clears G92 (G54 is kept in EEPROM)
        if self.reference == "homed" and self._query_status().state == "Idle":
            self._command(HOMED_MARK)        # the reset cleared the mark, not the position
