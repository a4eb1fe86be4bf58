"""A simulated GRBL 1.1 controller on a pseudo-terminal.

The simulator opens a pty (``os.openpty`` + ``tty.setraw``); :meth:`GrblSimulator.start` returns the
slave path (``/dev/pts/N``), which pyserial or a terminal opens like a real serial port. Everything
the real driver does runs against it byte for byte. Where it and the real GRBL 1.1h firmware
(its official simulator, ``tests/grbl_firmware.py``) could disagree, the firmware is right: the
protocol tests (``tests/rig/test_grbl_protocol.py``) run the same checks against both.

Model (the rig frame: x horizontal, y vertical, mm from the end of travel where GRBL's machine
coordinates are lowest):

- The two rig axes are driven by the profile's controller letters (X/Y/Z); the third stays still.
- Physical carriage position ``phys`` (mm from the low end of travel); limit switches trigger 1 mm
  outside the travel at both ends. ``MPos = phys - machine offset``: 0 at power-up; after ``$H``
  GRBL's negative frame: ``$23`` (default here: the rig's axes home towards the low end, the
  rig's origin) puts MPos ``-$13x + $27`` at the low-end switch, or ``-$27`` at the high end. ``WPos = MPos - WCO`` (``G10 L2``,
  ``G10 L20``, ``G92`` set WCO; G54 survives resets and power cycles like GRBL's EEPROM, G92 not).
- Moves: straight lines, trapezoidal speed profile limited per axis by ``$11x``/``$12x``, in real
  time divided by ``time_scale`` (0: every move completes instantly).
- Homing (``$H``, needs ``$22=1``): each axis seeks its switch at ``$25``, pulls off ``$27``.
  With ``$22=1`` the controller powers up in Alarm (``[MSG:'$H'|'$X' to unlock]``). Soft limits
  (``$20=1``, needs ``$22=1``) check every target against ``-$13x … 0`` in machine coordinates,
  homed or not, as GRBL does: a jog answers error:15, a move raises ALARM 2. Hard limits (``$21``)
  raise ALARM 1. ALARM 1 and 2 are critical: nothing is answered, not even ``?``, until a reset.
- Feed hold: ``Hold:1`` while decelerating, ``Hold:0`` once at rest (also ``!`` when idle); a
  reset in ``Hold:0`` keeps the position, a reset while moving raises ALARM 3.
- :meth:`true_position_mm` is where the camera really is: WPos plus a repeatability error drawn
  per completed move (Gaussian, σ = the axis repeatability; seeded).
- Output sent while no client has the port open is lost, as on a real serial port;
  ``reset_on_open=True`` reboots the controller each time a client opens the port (an Arduino's
  DTR reset); :meth:`power_cycle` does it by hand.
- Spindle output and laser mode (``$32``): ``M3``/``M4`` with ``S`` switch the spindle output
  (:attr:`GrblSimulator.spindle_output`, a :class:`~lfstudio.sim.trigger_line.TriggerLine`: high while
  the PWM is on). As in GRBL 1.1h, with ``$32=1`` an ``S`` word on a ``G1`` line changes the output
  inline with the motion, at the point where that block begins, without stopping (``G0`` turns it
  off); with ``$32=0``, and for every ``M3``/``M4``/``M5`` or a line without motion, GRBL
  synchronises first: the line waits until the carriage has stopped. Consecutive collinear ``G1``
  blocks of one feed are planned through without stopping (GRBL's look-ahead over the blocks it
  holds: it slows down only where the blocks it has end).
- Fault injection: :meth:`inject` with "drop", "silent", "garbage", "alarm_mid_move",
  "position_error"; :meth:`clear_faults` ends "silent"/"garbage".
"""

from __future__ import annotations

import errno
import math
import os
import re
import select
import threading
import time
import tty
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from lfstudio.rig.motion import RigConfig
from lfstudio.sim.trigger_line import TriggerLine

BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n"
UNLOCK_MSG = b"[MSG:'$H'|'$X' to unlock]\r\n"
AXES = "XYZ"
PLANNER_BLOCKS = 15
RX_BUFFER = 128
SWITCH_OUTSIDE_MM = 1.0
PULLOFF_MM = 1.0
STEPS_PER_MM = 100.0
_FLOAT_SETTINGS = {11, 12, 24, 25, 27}
FAULTS = ("drop", "silent", "garbage", "alarm_mid_move", "position_error")
_SPINDLE_WORD = re.compile(r"(M0*[345](?![0-9.])|S[-+]?(?:\d+\.?\d*|\.\d+))")
_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")


@dataclass
class _Segment:
    target: np.ndarray          # machine position (3,)
    feed_mm_s: float
    kind: str                   # "G0" | "G1" | "jog" | "home"
    sent_work_mm: tuple[float, float] | None = None
    output: bool = False        # the spindle output while this block runs
    synced: bool = False        # GRBL synchronised before it (the carriage stopped first)


@dataclass
class _Motion:
    segment: _Segment
    speed_mm_s: float = 0.0
    start_dist: float | None = None      # the distance left when an alarm in mid-move was armed


@dataclass
class SimRecord:
    """What the simulator received: one entry per motion command (rig frame, work coordinates)."""

    kind: str
    target_mm: tuple[float, float]
    line: str = field(default="")


class GrblSimulator:
    """GRBL 1.1 on a pty. ``start()`` → port path; ``close()``. Thread-safe accessors."""

    def __init__(self, rig: RigConfig, time_scale: float = 1.0, seed: int = 0,
                 tick_s: float = 0.005, reset_on_open: bool = False):
        if time_scale < 0:
            raise ValueError("time_scale must be >= 0")
        self.rig = rig
        self.time_scale = float(time_scale)
        self.tick_s = tick_s
        self.reset_on_open = reset_on_open
        self._rng = np.random.default_rng(seed)
        self._lock = threading.RLock()
        self._ix = [AXES.index(rig.horizontal.letter), AXES.index(rig.vertical.letter)]
        self._axes = [rig.horizontal, rig.vertical]
        # physical position: anywhere inside the travel at power-up
        self._phys = np.zeros(3)
        for ix, axis in zip(self._ix, self._axes):
            # a rig with switches stands anywhere near its home switches (at the low end: $23 has
            # the rig's axes set); one without is parked at its origin end
            self._phys[ix] = float(self._rng.uniform(0.02, 0.15) * axis.travel_mm) if rig.homing else 0.0
        self._offset = self._phys.copy()            # machine offset: MPos 0 at power-up
        self._g54 = np.zeros(3)
        self._g92 = np.zeros(3)
        self._error_mm = np.zeros(2)                # repeatability error of the last completed move
        self._homed = False
        self._critical = False                      # hard/soft limit alarm: only reset helps
        self._settings = self._default_settings()
        self._alarm = self._settings[22] == 1      # homing enabled: boots locked (HOMING_INIT_LOCK)
        self._state = "Alarm" if self._alarm else "Idle"
        self._hold = False
        self._planner: deque[_Segment] = deque()
        self._motion: _Motion | None = None
        self._homing_phases: deque[tuple[str, int, float]] = deque()
        self._jog_cancel = False
        self._modal_g = "G0"
        self._absolute = True
        self._feed_mm_min = 0.0
        self._tool = 0
        self._wco_counter = 0                       # GRBL's report counters (WCO / Ov refresh)
        self._ovr_counter = 0
        self._answer_on_reset = b""                 # the answer of a line a critical alarm interrupted
        self._report_after_homing = False
        self._in = bytearray()
        self._lines: deque[str] = deque()
        self._out = bytearray()
        self._faults: set[str] = set()
        self._garbage_left = 0
        self.records: list[SimRecord] = []
        self.lines_received: list[str] = []
        self.lines_sent: list[str] = []         # what the controller said (also while nobody listened)
        self.realtime_received: list[bytes] = []   # realtime bytes received, except '?'
        self.boots = 1
        self._client_open = False
        self._client_changed = threading.Condition()
        self._master: int | None = None
        self._port: str | None = None
        self._thread: threading.Thread | None = None
        self._running = threading.Event()
        self._last_tick = time.monotonic()
        self._history: deque[tuple[float, float, float]] = deque(maxlen=10000)   # (t, true x, true y)
        self._carry_mm_s = 0.0                      # the speed the next block starts with (look-ahead)
        self._error_log: deque[tuple[float, float, float]] = deque(maxlen=10000)   # (since t, error x, y)
        self._spindle = 5                           # M3 / M4 / M5
        self._spindle_s = 0.0
        self._clock = time.monotonic()              # the instant the motion has been advanced to
        #: the spindle output (PWM on): with laser mode, a fly scan's hardware trigger line
        self.spindle_output = TriggerLine("GRBL spindle output")
        self.spindle_output.poke = self._poke

    # -- lifecycle ---------------------------------------------------------------------------------
    def start(self) -> str:
        """Open the pty, start serving; returns the port path to open with pyserial."""
        if self._thread is not None:
            return self._port or ""
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master = master
        self._port = os.ttyname(slave)
        os.close(slave)                   # the port is free for a client; nobody listens yet
        self._boot_messages()
        self._running.set()
        self._last_tick = time.monotonic()
        self._thread = threading.Thread(target=self._serve, name="grbl-sim", daemon=True)
        self._thread.start()
        return self._port

    @property
    def port(self) -> str | None:
        return self._port

    @property
    def running(self) -> bool:
        return self._running.is_set()

    def close(self) -> None:
        self._running.clear()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)
        self._close_fds()

    def _close_fds(self) -> None:
        fd, self._master = self._master, None
        if fd is not None:
            try:
                os.close(fd)
            except OSError:
                pass

    def power_cycle(self) -> None:
        """Switch the controller off and on: motion stops, MPos is 0 where the carriage stands,
        G92 and the parser state are cleared; settings and G54 are kept (EEPROM); with homing
        enabled it boots locked."""
        with self._lock:
            self._planner.clear()
            self._homing_phases.clear()
            self._motion = None
            self._hold = self._jog_cancel = False
            self._lines.clear()
            self._in.clear()
            self._out.clear()
            self._offset = self._phys.copy()
            self._g92[:] = 0
            self._modal_g, self._absolute, self._feed_mm_min, self._tool = "G0", True, 0.0, 0
            self._spindle, self._spindle_s = 5, 0.0
            self.spindle_output.set(False, time.monotonic())
            self._homed = self._critical = False
            self._alarm = self._settings[22] == 1
            self._state = "Alarm" if self._alarm else "Idle"
            self._wco_counter = self._ovr_counter = 0
            self.boots += 1
            self._boot_messages()

    def _boot_messages(self) -> None:
        self._emit(BANNER)
        if self._alarm:
            self._emit(UNLOCK_MSG)

    def set_settings(self, settings: dict[int, float]) -> None:
        """Change ``$N`` settings directly (as if written earlier and kept in EEPROM); they apply
        from now on (``$22``/``$20`` locking at the next :meth:`power_cycle`)."""
        with self._lock:
            for key, value in settings.items():
                if key not in self._settings:
                    raise KeyError(f"no GRBL setting ${key}")
                self._settings[key] = int(value) if float(value).is_integer() else float(value)

    def __enter__(self) -> "GrblSimulator":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- public, thread-safe -----------------------------------------------------------------------
    def true_position_mm(self) -> tuple[float, float]:
        """Where the carriage physically is, in the rig frame (work coordinates) in mm:
        the reported position plus the repeatability error of the last completed move (the motion
        advanced to this instant first, so a camera asking during a move gets where it is now)."""
        with self._lock:
            if self._running.is_set():
                self._advance()
            w = self._wpos()
            return (float(w[self._ix[0]] + self._error_mm[0]), float(w[self._ix[1]] + self._error_mm[1]))

    def true_position_at(self, t: float) -> tuple[float, float] | None:
        """Where the carriage truly was at monotonic time ``t`` (interpolated in the history the motion
        keeps of its last ~10 000 steps); None when ``t`` is outside it. A camera timing its exposure
        asks this, so the truth is that of its timestamps, not of when its thread got to run."""
        with self._lock:
            if self._running.is_set():
                self._advance()
            hist = list(self._history)
        if not hist or t < hist[0][0] or t > hist[-1][0]:
            return None
        import bisect

        i = bisect.bisect_left([h[0] for h in hist], t)
        if i == 0:
            return hist[0][1], hist[0][2]
        (t0, x0, y0), (t1, x1, y1) = hist[i - 1], hist[i]
        w = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
        return x0 + w * (x1 - x0), y0 + w * (y1 - y0)

    def repeatability_error_at(self, t: float) -> tuple[float, float]:
        """The repeatability error (mm, rig frame) the carriage had at monotonic time ``t``: part of
        :meth:`true_position_at`, seen by no report (a step scan records it as wrongly as a fly scan)."""
        with self._lock:
            log = list(self._error_log)
            current = (float(self._error_mm[0]), float(self._error_mm[1]))
        for since, ex, ey in reversed(log):
            if since <= t:
                return ex, ey
        return (0.0, 0.0) if log else current

    def _poke(self) -> None:
        """Advance the motion to now (the edges of :attr:`spindle_output` that are due are set)."""
        with self._lock:
            if self._running.is_set():
                self._advance()

    def reported_position_mm(self) -> tuple[float, float]:
        with self._lock:
            w = self._wpos()
            return (float(w[self._ix[0]]), float(w[self._ix[1]]))

    @property
    def state(self) -> str:
        with self._lock:
            return self._state_text()

    def inject(self, fault: str) -> None:
        """Inject a fault: "drop" (port vanishes), "silent" (no answers until clear_faults),
        "garbage" (noise lines among the next answers), "alarm_mid_move" (hard-limit alarm halfway
        through the next move), "position_error" (the next move ends 0.5 mm short)."""
        if fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r}; choose one of {', '.join(FAULTS)}")
        with self._lock:
            if fault == "drop":
                self._running.clear()
                self._close_fds()
                return
            if fault == "garbage":
                self._garbage_left = 40
            self._faults.add(fault)

    def push_line(self, text: str) -> None:
        """Send one unsolicited line to the client now (noise, a message from another firmware)."""
        with self._lock:
            self._emit(text.encode("latin-1", "replace") + b"\r\n")

    def clear_faults(self) -> None:
        with self._lock:
            self._faults.clear()
            self._garbage_left = 0

    # -- serving -----------------------------------------------------------------------------------
    def _serve(self) -> None:
        try:
            while self._running.is_set():
                master = self._master
                if master is None:
                    return
                poller = select.poll()
                poller.register(master, select.POLLIN | (select.POLLOUT if self._out else 0))
                try:
                    events = dict(poller.poll(self.tick_s * 1000)).get(master, 0)
                except (OSError, ValueError):
                    return
                if events & select.POLLHUP:           # no client has the port open right now
                    if self._client_open:
                        self._set_client_open(False)
                    with self._lock:
                        self._out.clear()             # nobody listens: a UART's output is lost
                        self._advance()
                        self._process_lines()
                    time.sleep(self.tick_s)
                    continue
                if not self._client_open:
                    self._set_client_open(True)
                    if self.reset_on_open:            # DTR toggles when the port opens: the board reboots
                        self.power_cycle()
                data = b""
                if events & select.POLLIN:
                    try:
                        data = os.read(master, 4096)
                    except BlockingIOError:
                        pass
                    except OSError as exc:
                        if exc.errno != errno.EIO:
                            return
                with self._lock:
                    if data:
                        self._receive(data)
                    self._advance()
                    self._process_lines()
                    self._flush_out(master)
        finally:
            self._running.clear()

    def _set_client_open(self, value: bool) -> None:
        with self._client_changed:
            self._client_open = value
            self._client_changed.notify_all()

    def wait_port_closed(self, timeout_s: float = 10.0) -> bool:
        """Block until the simulator has seen the client close the port (True) or the timeout."""
        with self._client_changed:
            return self._client_changed.wait_for(lambda: not self._client_open, timeout_s)

    def _flush_out(self, master: int) -> None:
        if not self._out:
            return
        try:
            n = os.write(master, bytes(self._out[:1024]))
            del self._out[:n]
        except BlockingIOError:
            pass
        except OSError:
            self._out.clear()
        if len(self._out) > 65536:          # nobody reads: behave like a full UART, drop the oldest
            del self._out[:-4096]

    def _emit(self, data: bytes) -> None:
        if "silent" in self._faults:
            return
        self.lines_sent += [t for t in data.decode("ascii", "replace").split("\r\n") if t]
        if not self._client_open:
            return                                # nobody listens: a UART's output is lost
        if self._garbage_left > 0 and self._rng.random() < 0.5:
            self._garbage_left -= 1
            self._out += self._garbage() + b"\r\n"
        self._out += data

    def _garbage(self) -> bytes:
        n = int(self._rng.integers(1, 24))
        forbidden = set(b"\r\n")
        return bytes(b for b in self._rng.integers(0, 256, n).tolist() if b not in forbidden)

    # -- input -------------------------------------------------------------------------------------
    def _receive(self, data: bytes) -> None:
        if "silent" in self._faults:
            return
        for byte in data:
            if self._critical and byte != 0x18:
                if byte not in (0x0A, 0x0D) and byte < 0x80 and byte not in b"?!~" and len(self._in) < RX_BUFFER:
                    self._in.append(byte)         # GRBL's serial buffer fills; nothing is executed
                elif byte in (0x0A, 0x0D) and self._in:
                    self._lines.append(self._in.decode("ascii", "replace"))
                    self._in.clear()
                continue                          # critical alarm: not even '?' is answered until reset
            if byte in b"!~\x18" or byte >= 0x80:
                self.realtime_received.append(bytes([byte]))
            if byte == 0x3F:                      # '?'
                if self._state == "Home":
                    self._report_after_homing = True   # GRBL reports only once homing ends
                else:
                    self._advance()               # the position of this instant (GRBL's is ~ms fresh)
                    self._emit(self._status_report())
            elif byte == 0x21:                    # '!'
                self._feed_hold()
            elif byte == 0x7E:                    # '~'
                self._cycle_start()
            elif byte == 0x18:                    # Ctrl-X
                self._soft_reset()
            elif byte == 0x85:
                self._cancel_jog()
            elif byte >= 0x80:
                pass                              # other realtime overrides: accepted, no effect
            elif byte in (0x0A, 0x0D):
                if self._in:
                    line = self._in.decode("ascii", "replace")
                    self._in.clear()
                    self._lines.append(line)
            else:
                if len(self._in) < RX_BUFFER:
                    self._in.append(byte)

    def _process_lines(self) -> None:
        while self._lines:
            if self._state in ("Home",) or self._critical:
                return                            # $H blocks the parser until it is done
            line = self._lines[0]
            if self._is_motion_line(line) and len(self._planner) >= PLANNER_BLOCKS:
                return                            # planner full: the ok comes later
            if (self._planner or self._motion is not None) and self._spindle_syncs(line):
                return                            # GRBL's spindle_sync: the ok once the carriage stopped
            self._lines.popleft()
            self.lines_received.append(line)
            reply = self._execute(line)
            if reply is not None:
                self._emit(reply)

    def _spindle_syncs(self, line: str) -> bool:
        """Whether GRBL 1.1h waits for the motion to end before this line (gcode.c: every M3/M4/M5,
        an S change on a line without motion, and without laser mode any S change)."""
        s = "".join(line.split()).upper()
        if s.startswith("$"):
            return False
        words = _SPINDLE_WORD.findall(s)
        if any(w.startswith("M") for w in words):
            return True
        new_s = [float(w[1:]) for w in words if w.startswith("S")]
        if not new_s or new_s[-1] == self._spindle_s:
            return False
        return not (self._settings[32] == 1 and self._is_motion_line(line))

    def _output_level(self, kind: str | None) -> bool:
        """The spindle output for a block of ``kind`` (None: standing still), as GRBL sets its PWM."""
        on = self._spindle in (3, 4) and self._spindle_s > 0
        if self._settings[32] == 1:           # laser mode: only G1/G2/G3 motion carries the power
            return on and (kind if kind is not None else self._modal_g) == "G1"
        return on

    @staticmethod
    def _is_motion_line(line: str) -> bool:
        s = line.strip().upper()
        return s.startswith("$J=") or (not s.startswith("$") and any(c in s for c in "XYZ"))

    def _execute(self, raw: str) -> bytes | None:
        line = "".join(raw.split()).upper()
        if not line:
            return b"ok\r\n"
        if line.startswith("$"):
            return self._system(line)
        if self._alarm:
            return b"error:9\r\n"
        if self._state in ("Jog",):
            return b"error:9\r\n"
        return self._gcode(line, jog=False)

    # -- $ commands --------------------------------------------------------------------------------
    def _system(self, line: str) -> bytes | None:
        # the state checks of GRBL 1.1h's system_execute_line
        if line.startswith("$J"):
            if self._state not in ("Idle", "Jog"):
                return b"error:8\r\n"
            if not line.startswith("$J="):
                return b"error:3\r\n"
            return self._gcode(line[3:], jog=True)
        if line in ("$$", "$G", "$X"):
            if line == "$$":
                if self._state == "Run" or self._state.startswith("Hold"):
                    return b"error:8\r\n"
                body = "".join(f"${k}={v:.3f}\r\n" if k in _FLOAT_SETTINGS or k >= 100 else f"${k}={int(v)}\r\n"
                               for k, v in self._settings.items())
                return body.encode() + b"ok\r\n"
            if line == "$G":
                return (f"[GC:{self._modal_g} G54 G17 G21 {'G90' if self._absolute else 'G91'} G94 M5 M9 "
                        f"T{self._tool} F{self._feed_mm_min:g} S0]\r\nok\r\n").encode()
            if self._state == "Alarm":
                self._alarm = False
                self._state = "Idle"
                return b"[MSG:Caution: Unlocked]\r\nok\r\n"
            return b"ok\r\n"
        if self._state not in ("Idle", "Alarm"):
            return b"error:8\r\n"
        if line == "$I":
            return b"[VER:1.1h.20190830:]\r\n[OPT:V,15,128]\r\nok\r\n"
        if line == "$#":
            def coords(v) -> str:
                return ",".join(f"{x:.3f}" for x in v)
            zero = np.zeros(3)
            params = [f"[G54:{coords(self._g54)}]"] + [f"[G{n}:{coords(zero)}]" for n in range(55, 60)]
            params += [f"[G28:{coords(zero)}]", f"[G30:{coords(zero)}]", f"[G92:{coords(self._g92)}]",
                       "[TLO:0.000]", f"[PRB:{coords(zero)}:0]"]
            return ("\r\n".join(params) + "\r\nok\r\n").encode()
        if line == "$H":
            if self._settings[22] != 1:
                return b"error:5\r\n"
            self._start_homing()
            return None                            # "ok" when homing completes
        m = re.fullmatch(r"\$(\d+)=([-+]?[\d.]+)", line)
        if m:
            key = int(m.group(1))
            if key not in self._settings:
                return b"error:3\r\n"
            value = float(m.group(2))
            if key == 20 and value and self._settings[22] != 1:
                return b"error:10\r\n"              # soft limits need homing
            self._settings[key] = int(value) if value.is_integer() else value
            if key == 22 and not value:
                self._settings[20] = 0                # GRBL turns soft limits off with homing
            return b"ok\r\n"
        return b"error:3\r\n"

    def _default_settings(self) -> dict[int, float | int]:
        s: dict[int, float | int] = {0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010,
                                     12: 0.002, 13: 0, 20: 1 if self.rig.homing else 0,
                                     21: 0, 22: 1 if self.rig.homing else 0,
                                     23: sum(1 << ix for ix in self._ix), 24: 25.0,
                                     25: round(30.0 * min(self.rig.horizontal.max_speed_mm_s, self.rig.vertical.max_speed_mm_s), 3),
                                     26: 250, 27: PULLOFF_MM, 30: 1000, 31: 0, 32: 0}
        rates = [500.0, 500.0, 500.0]
        accels = [10.0, 10.0, 10.0]
        travel = [200.0, 200.0, 200.0]
        for ix, axis in zip(self._ix, self._axes):
            rates[ix] = axis.max_speed_mm_s * 60.0
            accels[ix] = axis.acceleration_mm_s2
            travel[ix] = axis.travel_mm
        for i in range(3):
            s[100 + i] = STEPS_PER_MM
            s[110 + i] = rates[i]
            s[120 + i] = accels[i]
            s[130 + i] = travel[i]
        return s

    # -- G-code ------------------------------------------------------------------------------------
    def _gcode(self, line: str, jog: bool) -> bytes | None:
        words: list[tuple[str, float]] = []
        pos = 0
        for m in _WORD.finditer(line):
            if m.start() != pos:
                return b"error:2\r\n" if line[pos].isalpha() else b"error:1\r\n"
            words.append((m.group(1), float(m.group(2))))
            pos = m.end()
        if pos != len(line):
            return b"error:2\r\n" if line[pos].isalpha() else b"error:1\r\n"
        absolute = self._absolute
        motion = None
        g10 = g92 = g53 = False
        l_word = p_word = None
        feed = None
        m_spindle: int | None = None
        s_word: float | None = None
        axes: dict[int, float] = {}
        seen: set[str] = set()
        for letter, value in words:
            if letter in "XYZFLPN" and letter in seen:
                return b"error:25\r\n"
            seen.add(letter)
            if letter == "G":
                code = round(value, 1)
                if code in (0, 1):
                    if jog:
                        return b"error:16\r\n"
                    motion = f"G{int(code)}"
                elif code == 90:
                    absolute = True
                elif code == 91:
                    absolute = False
                elif code == 10:
                    g10 = True
                elif code == 92:
                    g92 = True
                elif code == 92.1:
                    self._g92[:] = 0
                    self._wco_counter = 0
                elif code == 53:
                    g53 = True
                elif code in (4, 17, 21, 54, 94):
                    pass
                else:
                    return b"error:20\r\n"
            elif letter == "M":
                if int(value) not in (0, 1, 2, 3, 4, 5, 7, 8, 9, 30):
                    return b"error:20\r\n"
                if int(value) in (3, 4, 5):
                    m_spindle = int(value)
            elif letter in AXES:
                axes[AXES.index(letter)] = value
            elif letter == "F":
                if value < 0:
                    return b"error:4\r\n"
                feed = value
            elif letter == "L":
                l_word = value
            elif letter == "P":
                p_word = value
            elif letter == "T":
                if not jog:
                    self._tool = int(value)       # modal; cleared by a reset, as in GRBL
            elif letter == "S":
                if value < 0:
                    return b"error:4\r\n"
                s_word = value
            elif letter == "N":
                pass
            else:
                return b"error:20\r\n"
        jog_feed_mm_min = 0.0
        if jog:
            if feed is None:
                return b"error:22\r\n"
            if not axes:
                return b"error:26\r\n"
            jog_feed_mm_min = feed
        if g10:
            if l_word not in (2, 20) or p_word not in (None, 0, 1):
                return b"error:20\r\n"
            for i, v in axes.items():
                if l_word == 20:
                    self._g54[i] = self._mpos()[i] - self._g92[i] - v
                else:
                    self._g54[i] = v
            self._wco_counter = 0
            return b"ok\r\n"
        if g92:
            for i, v in axes.items():
                self._g92[i] = self._mpos()[i] - self._g54[i] - v
            self._wco_counter = 0
            return b"ok\r\n"
        synced = False
        if not jog:
            self._absolute = absolute
            if feed is not None:
                self._feed_mm_min = feed
            if motion is not None:
                self._modal_g = motion
            before = (self._spindle, self._spindle_s)
            if s_word is not None:
                self._spindle_s = s_word
            if m_spindle is not None:
                self._spindle = m_spindle
            synced = (self._spindle, self._spindle_s) != before and not (
                self._settings[32] == 1 and m_spindle is None and axes)
        if not axes:
            if not jog:                       # standing still (GRBL synchronised first): at once
                self.spindle_output.set(self._output_level(None), time.monotonic())
            return b"ok\r\n"
        # target in machine coordinates
        base = self._planned_end()
        target = base.copy()
        wco = self._g54 + self._g92
        for i, v in axes.items():
            if g53:
                target[i] = v
            elif absolute:
                target[i] = v + wco[i]
            else:
                target[i] = base[i] + v
        work = target - wco
        kind = "jog" if jog else self._modal_g
        self.records.append(SimRecord(kind, (float(work[self._ix[0]]), float(work[self._ix[1]])), line))
        if kind == "G1" and self._feed_mm_min <= 0:
            return b"error:22\r\n"
        if self._settings[20] == 1 and not self._within_travel(target):   # homed or not, as GRBL
            if jog:
                return b"error:15\r\n"
            self._raise_alarm(2, critical=True)
            self._answer_on_reset = b"ok\r\n"        # GRBL answers the line after the reset
            return None
        feed_mm_s = (jog_feed_mm_min if jog else (self._feed_mm_min if kind == "G1" else 1e9)) / 60.0
        target = np.round(target * STEPS_PER_MM) / STEPS_PER_MM
        self._planner.append(_Segment(target, feed_mm_s, kind, output=(self.spindle_output.level if jog else self._output_level(kind)),
                                      synced=synced))
        if self._state == "Idle":
            self._state = "Jog" if jog else "Run"
        if self.time_scale == 0:
            self._advance(instant=True)
        return b"ok\r\n"

    def _within_travel(self, mpos: np.ndarray) -> bool:
        """GRBL's soft-limit envelope: every axis inside -$13x … 0 (machine coordinates)."""
        return all(-self._settings[130 + i] - 1e-6 <= mpos[i] <= 1e-6 for i in range(3))

    # -- motion ------------------------------------------------------------------------------------
    def _mpos(self) -> np.ndarray:
        """Machine position: a whole number of steps, as GRBL counts it."""
        return np.round((self._phys - self._offset) * STEPS_PER_MM) / STEPS_PER_MM

    def _wpos(self) -> np.ndarray:
        return self._mpos() - self._g54 - self._g92

    def _planned_end(self) -> np.ndarray:
        if self._planner:
            return self._planner[-1].target.copy()
        return self._mpos().copy()

    def _limits_for(self, unit: np.ndarray, feed_mm_s: float) -> tuple[float, float]:
        speed, accel = feed_mm_s, math.inf
        for i in range(3):
            c = abs(unit[i])
            if c < 1e-12:
                continue
            speed = min(speed, self._settings[110 + i] / 60.0 / c)
            accel = min(accel, self._settings[120 + i] / c)
        return speed, accel

    def _next_motion(self) -> _Motion | None:
        if self._homing_phases:
            kind, ix, speed = self._homing_phases.popleft()
            target = self._mpos().copy()
            towards_low = bool(int(self._settings[23]) & (1 << ix))
            if kind == "seek":                     # to the switch's trigger point
                trigger = -SWITCH_OUTSIDE_MM if towards_low else self._switch_high(ix)
                target[ix] = trigger - self._offset[ix]
            else:                                  # pull off by $27, away from the switch
                target[ix] += float(self._settings[27]) * (1 if towards_low else -1)
            return _Motion(_Segment(target, speed, "home"))
        if self._planner:
            seg = self._planner[0]
            carry, self._carry_mm_s = self._carry_mm_s, 0.0
            if seg.kind != "home":              # the block's spindle output, where it begins
                self.spindle_output.set(seg.output, self._clock)
            return _Motion(seg, speed_mm_s=carry)
        return None

    def _chain(self, seg: _Segment) -> list[_Segment]:
        """The blocks after ``seg`` (the running one) that GRBL plans through without stopping: the
        same straight line, direction and feed, no synchronisation between."""
        out: list[_Segment] = []
        if seg.kind != "G1":
            return out
        prev_end = seg.target
        unit = None
        for nxt in list(self._planner)[1:] if self._planner and self._planner[0] is seg else []:
            if nxt.kind != "G1" or nxt.synced or abs(nxt.feed_mm_s - seg.feed_mm_s) > 1e-9:
                break
            d = nxt.target - prev_end
            n = float(np.linalg.norm(d))
            if n < 1e-9:
                break
            u = d / n
            if unit is None:
                start = seg.target - (self._phys - self._offset)
                ns = float(np.linalg.norm(start))
                unit = start / ns if ns > 1e-9 else u
            if float(np.dot(u, unit)) < 1 - 1e-9:
                break
            out.append(nxt)
            prev_end = nxt.target
        return out

    def _exit_speed(self, seg: _Segment, unit: np.ndarray) -> float:
        """The speed the running block may end with: what the blocks GRBL holds after it allow,
        braking to a stop at the end of the last one (its look-ahead)."""
        chain = self._chain(seg)
        if not chain:
            return 0.0
        vmax, accel = self._limits_for(unit, seg.feed_mm_s)
        v_end = 0.0
        prev = seg.target
        lengths = []
        for nxt in chain:
            lengths.append(float(np.linalg.norm(nxt.target - prev)))
            prev = nxt.target
        for length in reversed(lengths):
            v_end = min(vmax, math.sqrt(v_end * v_end + 2.0 * accel * length))
        return v_end

    def _advance(self, instant: bool = False) -> None:
        try:
            self._advance_motion(instant)
        finally:
            w = self._phys - self._offset - self._g54 - self._g92     # the carriage itself, not its step count
            self._history.append((self._last_tick, float(w[self._ix[0]] + self._error_mm[0]),
                                  float(w[self._ix[1]] + self._error_mm[1])))

    def _advance_motion(self, instant: bool = False) -> None:
        now = time.monotonic()
        real_dt = now - self._last_tick
        self._last_tick = now
        if self.time_scale == 0:
            instant = True
        dt = math.inf if instant else real_dt / self.time_scale
        self._clock = now if instant else now - real_dt
        for _ in range(10000):
            if dt <= 0:
                return
            if self._hold and (self._motion is None or self._motion.speed_mm_s <= 0):
                if self._state == "Hold:1":           # decelerated to rest: the hold is complete
                    self._state = "Hold:0"
                    self._draw_repeatability()
                return
            if self._jog_cancel and (self._motion is None or self._motion.speed_mm_s <= 0):
                self._end_jog_cancel()
                return
            if self._motion is None:
                self._motion = self._next_motion()
                if self._motion is None:
                    if self._state in ("Run", "Jog"):
                        self._state = "Idle"
                    return
            left = self._step(self._motion, dt)
            if math.isfinite(dt) and math.isfinite(left):
                self._clock += (dt - left) * self.time_scale
            dt = left

    def _step(self, m: _Motion, dt: float) -> float:
        """Advance the current segment by up to dt seconds (sim time); return the unused time."""
        seg = m.segment
        # from where the carriage is, not from its step count (rounded to a step): the time a block
        # ends (an edge of the spindle output) is then exact
        delta = seg.target - (self._phys - self._offset)
        dist = float(np.linalg.norm(delta))
        if dist < 1e-9:
            m.speed_mm_s = 0.0
            self._phys = self._offset + seg.target
            self._finish_segment()
            return dt
        unit = delta / dist
        vmax, accel = self._limits_for(unit, seg.feed_mm_s)
        if self._hold or self._jog_cancel:          # decelerate to a stop along the path
            if math.isinf(dt):
                m.speed_mm_s = 0.0
                return dt
            t = min(dt, m.speed_mm_s / accel)
            self._phys += unit * min(dist, m.speed_mm_s * t - 0.5 * accel * t * t)
            m.speed_mm_s = max(0.0, m.speed_mm_s - accel * t)
            if m.speed_mm_s <= 1e-9:
                m.speed_mm_s = 0.0
            return dt - t if m.speed_mm_s == 0.0 else 0.0
        mid_alarm = "alarm_mid_move" in self._faults and seg.kind != "home"
        if mid_alarm and m.start_dist is None:
            m.start_dist = dist
        if math.isinf(dt):
            if mid_alarm:
                self._phys += delta * 0.5
                self._hit_alarm_mid_move()
                return 0.0
            self._phys += delta
            if seg.kind != "home" and self._check_hard_limits():
                return 0.0
            self._finish_segment()
            return dt
        t = min(dt, self.tick_s / max(self.time_scale, 1e-9))
        v_exit = self._exit_speed(seg, unit) if seg.kind == "G1" else 0.0
        v_new = min(m.speed_mm_s + accel * t, vmax, math.sqrt(v_exit * v_exit + 2.0 * accel * dist))
        reach = max(0.5 * (m.speed_mm_s + v_new) * t, 1e-6)
        travel = min(dist, reach)
        m.speed_mm_s = v_new
        if mid_alarm and m.start_dist is not None and dist - travel <= 0.5 * m.start_dist:
            self._phys += unit * (dist - 0.5 * m.start_dist)
            self._hit_alarm_mid_move()
            return 0.0
        self._phys += unit * travel
        if seg.kind != "home" and self._check_hard_limits():
            return 0.0
        if travel >= dist - 1e-9:
            t_used = t * min(1.0, dist / reach)        # the block ends within this tick
            self._phys = self._offset + seg.target     # land exactly on the step grid
            carry = min(v_new, v_exit) if v_exit > 0 else 0.0
            m.speed_mm_s = 0.0
            self._finish_segment()
            if carry > 0 and self._planner and self._motion is None:
                self._carry_mm_s = carry               # planned through: the next block starts at speed
                self._note_history(self._clock + t_used * self.time_scale)
                return dt - t_used
            return dt - t
        return dt - t

    def _note_history(self, t: float) -> None:
        w = self._phys - self._offset - self._g54 - self._g92
        self._history.append((t, float(w[self._ix[0]] + self._error_mm[0]), float(w[self._ix[1]] + self._error_mm[1])))

    def _check_hard_limits(self) -> bool:
        if self._settings[21] != 1:
            return False
        for ix, axis in zip(self._ix, self._axes):
            # pressing a switch past its trigger point (reaching it is allowed: GRBL's machine 0)
            if self._phys[ix] < -SWITCH_OUTSIDE_MM - 1e-6 or self._phys[ix] > self._switch_high(ix) + 1e-6:
                self._phys[ix] = min(max(self._phys[ix], -SWITCH_OUTSIDE_MM), self._switch_high(ix))
                self._raise_alarm(1, critical=True)
                return True
        return False

    def _hit_alarm_mid_move(self) -> None:
        self._faults.discard("alarm_mid_move")
        self._raise_alarm(1, critical=True)

    def _finish_segment(self) -> None:
        m = self._motion
        self._motion = None
        if m is None:
            return
        seg = m.segment
        if seg.kind == "home":
            if not self._homing_phases and self._state == "Home":
                self._finish_homing()
            return
        if self._planner and self._planner[0] is seg:
            self._planner.popleft()
        if "position_error" in self._faults:
            self._faults.discard("position_error")
            self._phys[self._ix[0]] -= 0.5
        if not self._planner:
            self._draw_repeatability()
            if self._state in ("Run", "Jog"):
                self._state = "Idle"

    def _draw_repeatability(self) -> None:
        self._error_mm = np.array([self._rng.normal(0.0, a.repeatability_um / 1000.0) for a in self._axes])
        self._error_log.append((self._clock, float(self._error_mm[0]), float(self._error_mm[1])))

    def _end_jog_cancel(self) -> None:
        self._jog_cancel = False
        self._motion = None
        self._planner.clear()
        if self._state == "Jog":
            self._state = "Idle"
        self._draw_repeatability()

    def _feed_hold(self) -> None:
        if self._state == "Jog":          # GRBL: a feed hold during a jog cancels the jog
            self._jog_cancel = True
        elif self._state == "Run":
            self._hold = True
            self._state = "Hold:1"        # decelerating; Hold:0 once at rest
        elif self._state == "Idle":
            self._hold = True
            self._state = "Hold:0"        # nothing moves: the hold is complete at once
            return
        else:
            return
        if self.time_scale == 0:
            self._advance(instant=True)

    def _cycle_start(self) -> None:
        if self._state == "Hold:0":       # GRBL resumes only a complete hold
            self._hold = False
            self._state = "Run" if (self._planner or self._motion is not None) else "Idle"
            if self.time_scale == 0:
                self._advance(instant=True)

    def _cancel_jog(self) -> None:
        if self._state == "Jog":
            self._jog_cancel = True
            if self.time_scale == 0:
                self._advance(instant=True)

    def _soft_reset(self) -> None:
        homing = self._state == "Home"
        # GRBL's mc_reset: an alarm when the steppers may be running (cycle, jog, homing, or a hold
        # still decelerating); the position is then lost
        moving = self._state in ("Run", "Jog", "Home", "Hold:1")
        answer, self._answer_on_reset = self._answer_on_reset, b""
        self._report_after_homing = False
        self._planner.clear()
        self._homing_phases.clear()
        self._motion = None
        self._hold = False
        self._jog_cancel = False
        self._lines.clear()
        self._in.clear()
        self._modal_g, self._absolute, self._feed_mm_min, self._tool = "G0", True, 0.0, 0
        self._spindle, self._spindle_s = 5, 0.0
        self.spindle_output.set(False, time.monotonic())
        self._g92[:] = 0
        self._critical = False
        self._wco_counter = self._ovr_counter = 0
        if moving:
            self._homed = False
            self._alarm = True
            self._emit(b"ALARM:6\r\n" if homing else b"ALARM:3\r\n")
        self._emit(answer)
        self._emit(BANNER)
        if self._alarm:
            self._state = "Alarm"
            self._emit(UNLOCK_MSG)
        else:
            self._state = "Idle"

    def _raise_alarm(self, code: int, critical: bool) -> None:
        self.spindle_output.set(False, time.monotonic())     # GRBL's mc_reset stops the spindle
        self._planner.clear()
        self._homing_phases.clear()
        self._motion = None
        self._hold = False
        self._lines.clear()
        self._alarm = True
        self._critical = critical
        self._homed = False
        self._state = "Alarm"
        self._emit(f"ALARM:{code}\r\n".encode())
        if critical:
            self._emit(b"[MSG:Reset to continue]\r\n")

    # -- homing ------------------------------------------------------------------------------------
    def _switch_high(self, ix: int) -> float:
        """Physical position (mm) where the high-end limit switch of machine axis ``ix`` triggers."""
        axis = self._axes[self._ix.index(ix)] if ix in self._ix else None
        return (axis.travel_mm if axis is not None else 0.0) + SWITCH_OUTSIDE_MM

    def _start_homing(self) -> None:
        self._state = "Home"
        self._alarm = False
        self._answer_on_reset = b"ok\r\n"        # a reset aborts homing: ALARM:6, then the ok
        self._homing_phases.clear()
        seek = float(self._settings[25]) / 60.0
        for ix in reversed(self._ix):              # vertical first, like Z in GRBL
            self._homing_phases.append(("seek", ix, seek))
            self._homing_phases.append(("pulloff", ix, seek))
        if self.time_scale == 0:
            self._advance(instant=True)

    def _finish_homing(self) -> None:
        """GRBL's negative machine frame: MPos -$27 at the switch on the high end, or
        -$13x + $27 at the switch on the low end ($23 bit set)."""
        for ix in self._ix:
            pulloff = float(self._settings[27])
            if int(self._settings[23]) & (1 << ix):
                mpos = -float(self._settings[130 + ix]) + pulloff
            else:
                mpos = -pulloff
            self._offset[ix] = self._phys[ix] - mpos
        self._answer_on_reset = b""
        if self._report_after_homing:
            self._report_after_homing = False
            self._emit(self._status_report())
        self._homed = True
        self._alarm = False
        self._state = "Idle"
        self._wco_counter = 0
        self._draw_repeatability()
        self._emit(b"ok\r\n")

    # -- status ------------------------------------------------------------------------------------
    def _state_text(self) -> str:
        return self._state

    def _status_report(self) -> bytes:
        """GRBL 1.1h's report: MPos or WPos ($10 bit 0), Bf ($10 bit 1), FS, Pn when a pin is
        active, WCO every 10th report when idle (30th when busy) and after an offset change, Ov on
        the report after WCO and every 10th (20th) after that."""
        mpos = self._mpos()
        busy = self._state not in ("Idle", "Alarm")
        fields = [self._state_text()]
        if int(self._settings[10]) & 1:
            fields.append("MPos:" + ",".join(f"{v:.3f}" for v in mpos))
        else:
            fields.append("WPos:" + ",".join(f"{v:.3f}" for v in self._wpos()))
        if int(self._settings[10]) & 2:
            fields.append(f"Bf:{PLANNER_BLOCKS - len(self._planner)},{RX_BUFFER - len(self._in)}")
        speed = self._motion.speed_mm_s * 60.0 if self._motion is not None else 0.0
        fields.append(f"FS:{speed:.0f},0")
        pins = ""
        for ix in self._ix:
            if self._phys[ix] <= -SWITCH_OUTSIDE_MM + 1e-6 or self._phys[ix] >= self._switch_high(ix) - 1e-6:
                pins += AXES[ix]
        if pins:
            fields.append(f"Pn:{pins}")
        if self._wco_counter > 0:
            self._wco_counter -= 1
        else:
            self._wco_counter = 29 if busy else 9
            if self._ovr_counter == 0:
                self._ovr_counter = 1
            fields.append("WCO:" + ",".join(f"{v:.3f}" for v in self._g54 + self._g92))
        if self._ovr_counter > 0:
            self._ovr_counter -= 1
        else:
            self._ovr_counter = 19 if busy else 9
            fields.append("Ov:100,100,100")
        return ("<" + "|".join(fields) + ">\r\n").encode()
