"""A simulated GRBL 1.1 controller on a pseudo-terminal.

The simulator opens a pty (``os.openpty`` + ``tty.setraw``); :meth:`GrblSimulator.start` returns the
slave path (``/dev/pts/N``), which pyserial or a terminal opens like a real serial port. Everything
the real driver does runs against it byte for byte.

Model (the rig frame: x horizontal, mm from the left end; y vertical, mm from the top end, down):

- The two rig axes are driven by the profile's controller letters (X/Y/Z); the third stays still.
- Physical carriage position ``phys`` (mm from the end of travel); limit switches sit 1 mm outside
  the travel at both ends. ``MPos = phys - machine offset`` (0 at power-up, 0 at the home position
  after ``$H``); ``WPos = MPos - WCO`` (``G10 L20``/``G92`` set WCO).
- Moves: straight lines, trapezoidal speed profile limited per axis by the profile's speed and
  acceleration, in real time divided by ``time_scale`` (0: every move completes instantly).
- Homing (``$H``): each axis seeks its min switch, pulls off 1 mm, and that point becomes MPos 0.
  A homing rig powers up in Alarm (``[MSG:'$H'|'$X' to unlock]``); soft limits (machine travel)
  apply once homed; hard limits always (ALARM:1, critical: reset to continue).
- :meth:`true_position_mm` is where the camera really is: WPos plus a repeatability error drawn
  per completed move (Gaussian, σ = the axis repeatability; seeded).
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
_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")


@dataclass
class _Segment:
    target: np.ndarray          # machine position (3,)
    feed_mm_s: float
    kind: str                   # "G0" | "G1" | "jog" | "home"
    sent_work_mm: tuple[float, float] | None = None


@dataclass
class _Motion:
    segment: _Segment
    speed_mm_s: float = 0.0


@dataclass
class SimRecord:
    """What the simulator received: one entry per motion command (rig frame, work coordinates)."""

    kind: str
    target_mm: tuple[float, float]
    line: str = field(default="")


class GrblSimulator:
    """GRBL 1.1 on a pty. ``start()`` → port path; ``close()``. Thread-safe accessors."""

    def __init__(self, rig: RigConfig, time_scale: float = 1.0, seed: int = 0,
                 tick_s: float = 0.005):
        if time_scale < 0:
            raise ValueError("time_scale must be >= 0")
        self.rig = rig
        self.time_scale = float(time_scale)
        self.tick_s = tick_s
        self._rng = np.random.default_rng(seed)
        self._lock = threading.RLock()
        self._ix = [AXES.index(rig.horizontal.letter), AXES.index(rig.vertical.letter)]
        self._axes = [rig.horizontal, rig.vertical]
        # physical position: anywhere inside the travel at power-up
        self._phys = np.zeros(3)
        for ix, axis in zip(self._ix, self._axes):
            # a rig with switches stands anywhere near home; one without is parked at its origin end
            self._phys[ix] = float(self._rng.uniform(0.02, 0.15) * axis.travel_mm) if rig.homing else 0.0
        self._offset = self._phys.copy()            # machine offset: MPos 0 at power-up
        self._g54 = np.zeros(3)
        self._g92 = np.zeros(3)
        self._error_mm = np.zeros(2)                # repeatability error of the last completed move
        self._homed = False
        self._critical = False                      # hard/soft limit alarm: only reset helps
        self._alarm = rig.homing                    # a homing rig boots locked
        self._state = "Alarm" if self._alarm else "Idle"
        self._hold = False
        self._planner: deque[_Segment] = deque()
        self._motion: _Motion | None = None
        self._homing_phases: deque[tuple[str, int, float]] = deque()
        self._jog_cancel = False
        self._modal_g = "G0"
        self._absolute = True
        self._feed_mm_min = 0.0
        self._settings = self._default_settings()
        self._reports = 0
        self._wco_changed = True
        self._in = bytearray()
        self._lines: deque[str] = deque()
        self._out = bytearray()
        self._faults: set[str] = set()
        self._garbage_left = 0
        self.records: list[SimRecord] = []
        self.lines_received: list[str] = []
        self._master: int | None = None
        self._slave: int | None = None
        self._port: str | None = None
        self._thread: threading.Thread | None = None
        self._running = threading.Event()
        self._last_tick = time.monotonic()

    # -- lifecycle ---------------------------------------------------------------------------------
    def start(self) -> str:
        """Open the pty, start serving; returns the port path to open with pyserial."""
        if self._thread is not None:
            return self._port or ""
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._port = os.ttyname(slave)
        self._emit(BANNER)
        if self._alarm:
            self._emit(UNLOCK_MSG)
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
        for name in ("_master", "_slave"):
            fd = getattr(self, name)
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
                setattr(self, name, None)

    def __enter__(self) -> "GrblSimulator":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- public, thread-safe -----------------------------------------------------------------------
    def true_position_mm(self) -> tuple[float, float]:
        """Where the carriage physically is, in the rig frame (work coordinates) in mm:
        the reported position plus the repeatability error of the last completed move."""
        with self._lock:
            w = self._wpos()
            return (float(w[self._ix[0]] + self._error_mm[0]), float(w[self._ix[1]] + self._error_mm[1]))

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
                want_write = bool(self._out)
                try:
                    r, w, _ = select.select([master], [master] if want_write else [], [], self.tick_s)
                except (OSError, ValueError):
                    return
                if r:
                    try:
                        data = os.read(master, 4096)
                    except BlockingIOError:
                        data = b""
                    except OSError as exc:
                        if exc.errno == errno.EIO:   # no client has the port open right now
                            data = b""
                            time.sleep(self.tick_s)
                        else:
                            return
                    if data:
                        with self._lock:
                            self._receive(data)
                with self._lock:
                    self._advance()
                    self._process_lines()
                    self._flush_out(master)
        finally:
            self._running.clear()

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
            if byte == 0x3F:                      # '?'
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
            if self._state in ("Home",):
                return                            # $H blocks the parser until it is done
            line = self._lines[0]
            if self._is_motion_line(line) and len(self._planner) >= PLANNER_BLOCKS:
                return                            # planner full: the ok comes later
            self._lines.popleft()
            self.lines_received.append(line)
            reply = self._execute(line)
            if reply is not None:
                self._emit(reply)

    @staticmethod
    def _is_motion_line(line: str) -> bool:
        s = line.strip().upper()
        return s.startswith("$J=") or (not s.startswith("$") and any(c in s for c in "XYZ"))

    def _execute(self, raw: str) -> bytes | None:
        line = "".join(raw.split()).upper()
        if not line:
            return b"ok\r\n"
        if self._critical:
            return b"error:9\r\n"
        if line.startswith("$"):
            return self._system(line)
        if self._alarm:
            return b"error:9\r\n"
        if self._state in ("Jog",):
            return b"error:9\r\n"
        return self._gcode(line, jog=False)

    # -- $ commands --------------------------------------------------------------------------------
    def _system(self, line: str) -> bytes | None:
        if line.startswith("$J="):
            if self._alarm:
                return b"error:9\r\n"
            if self._state not in ("Idle", "Jog"):
                return b"error:8\r\n"
            return self._gcode(line[3:], jog=True)
        if self._state not in ("Idle", "Alarm"):
            return b"error:8\r\n"
        if line == "$$":
            body = "".join(f"${k}={v:.3f}\r\n" if k in _FLOAT_SETTINGS or k >= 100 else f"${k}={int(v)}\r\n"
                           for k, v in self._settings.items())
            return body.encode() + b"ok\r\n"
        if line == "$I":
            return b"[VER:1.1h.20190825:]\r\n[OPT:V,15,128]\r\nok\r\n"
        if line == "$G":
            return (f"[GC:{self._modal_g} G54 G17 G21 {'G90' if self._absolute else 'G91'} G94 M5 M9 T0 "
                    f"F{self._feed_mm_min:g} S0]\r\nok\r\n").encode()
        if line == "$#":
            g54 = ",".join(f"{v:.3f}" for v in self._g54)
            g92 = ",".join(f"{v:.3f}" for v in self._g92)
            return f"[G54:{g54}]\r\n[G92:{g92}]\r\nok\r\n".encode()
        if line == "$X":
            if self._alarm:
                self._alarm = False
                self._state = "Idle"
                return b"[MSG:Caution: Unlocked]\r\nok\r\n"
            return b"ok\r\n"
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
            self._settings[key] = int(value) if value.is_integer() else value
            return b"ok\r\n"
        return b"error:3\r\n"

    def _default_settings(self) -> dict[int, float | int]:
        s: dict[int, float | int] = {0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010,
                                     12: 0.002, 13: 0, 20: 1 if self.rig.homing else 0,
                                     21: 1, 22: 1 if self.rig.homing else 0, 23: 0, 24: 25.0,
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
                    self._wco_changed = True
                elif code == 53:
                    g53 = True
                elif code in (4, 17, 21, 54, 94):
                    pass
                else:
                    return b"error:20\r\n"
            elif letter == "M":
                if int(value) not in (0, 1, 2, 3, 4, 5, 7, 8, 9, 30):
                    return b"error:20\r\n"
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
            elif letter in "NST":
                pass
            else:
                return b"error:20\r\n"
        if jog:
            if feed is None:
                return b"error:22\r\n"
            if not axes:
                return b"error:26\r\n"
        if g10:
            if l_word not in (2, 20) or p_word not in (None, 0, 1):
                return b"error:20\r\n"
            for i, v in axes.items():
                if l_word == 20:
                    self._g54[i] = self._mpos()[i] - self._g92[i] - v
                else:
                    self._g54[i] = v
            self._wco_changed = True
            return b"ok\r\n"
        if g92:
            for i, v in axes.items():
                self._g92[i] = self._mpos()[i] - self._g54[i] - v
            self._wco_changed = True
            return b"ok\r\n"
        if not jog:
            self._absolute = absolute
            if feed is not None:
                self._feed_mm_min = feed
            if motion is not None:
                self._modal_g = motion
            motion = self._modal_g
        if not axes:
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
        kind = "jog" if jog else motion
        self.records.append(SimRecord(kind, (float(work[self._ix[0]]), float(work[self._ix[1]])), line))
        if self._homed and self._settings[20] == 1 and not self._within_travel(target):
            if jog:
                return b"error:15\r\n"
            self._raise_alarm(2, critical=True)
            return None
        if kind == "G1" and self._feed_mm_min <= 0:
            return b"error:22\r\n"
        feed_mm_s = (feed if jog else (self._feed_mm_min if kind == "G1" else 1e9)) / 60.0
        target = np.round(target * STEPS_PER_MM) / STEPS_PER_MM
        self._planner.append(_Segment(target, feed_mm_s, kind))
        if self._state == "Idle":
            self._state = "Jog" if jog else "Run"
        if self.time_scale == 0:
            self._advance(instant=True)
        return b"ok\r\n"

    def _within_travel(self, mpos: np.ndarray) -> bool:
        for ix, axis in zip(self._ix, self._axes):
            if not (-1e-6 <= mpos[ix] <= axis.travel_mm + 1e-6):
                return False
        return True

    # -- motion ------------------------------------------------------------------------------------
    def _mpos(self) -> np.ndarray:
        return self._phys - self._offset

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
            target[ix] = (-SWITCH_OUTSIDE_MM - self._offset[ix]) if kind == "seek" else target[ix] + PULLOFF_MM
            return _Motion(_Segment(target, speed, "home"))
        if self._planner:
            return _Motion(self._planner[0])
        return None

    def _advance(self, instant: bool = False) -> None:
        now = time.monotonic()
        real_dt = now - self._last_tick
        self._last_tick = now
        if self.time_scale == 0:
            instant = True
        dt = math.inf if instant else real_dt / self.time_scale
        for _ in range(10000):
            if dt <= 0:
                return
            if self._hold and (self._motion is None or self._motion.speed_mm_s <= 0):
                if self._state == "Hold:0":
                    self._state = "Hold:1"
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
            dt = self._step(self._motion, dt)

    def _step(self, m: _Motion, dt: float) -> float:
        """Advance the current segment by up to dt seconds (sim time); return the unused time."""
        seg = m.segment
        delta = seg.target - self._mpos()
        dist = float(np.linalg.norm(delta))
        if dist < 1e-9:
            m.speed_mm_s = 0.0
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
        if mid_alarm and not hasattr(m, "start_dist"):
            m.start_dist = dist  # type: ignore[attr-defined]
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
        v_new = min(m.speed_mm_s + accel * t, vmax, math.sqrt(2.0 * accel * dist))
        travel = min(dist, max(0.5 * (m.speed_mm_s + v_new) * t, 1e-6))
        m.speed_mm_s = v_new
        if mid_alarm and dist - travel <= 0.5 * m.start_dist:  # type: ignore[attr-defined]
            self._phys += unit * (dist - 0.5 * m.start_dist)  # type: ignore[attr-defined]
            self._hit_alarm_mid_move()
            return 0.0
        self._phys += unit * travel
        if seg.kind != "home" and self._check_hard_limits():
            return 0.0
        if travel >= dist - 1e-9:
            self._phys = self._offset + seg.target     # land exactly on the step grid
            m.speed_mm_s = 0.0
            self._finish_segment()
        return dt - t

    def _check_hard_limits(self) -> bool:
        if self._settings[21] != 1:
            return False
        for ix, axis in zip(self._ix, self._axes):
            if self._phys[ix] <= -SWITCH_OUTSIDE_MM or self._phys[ix] >= axis.travel_mm + SWITCH_OUTSIDE_MM:
                self._phys[ix] = min(max(self._phys[ix], -SWITCH_OUTSIDE_MM), axis.travel_mm + SWITCH_OUTSIDE_MM)
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
            self._state = "Hold:0"
        else:
            return
        if self.time_scale == 0:
            self._advance(instant=True)

    def _cycle_start(self) -> None:
        if self._state.startswith("Hold"):
            self._hold = False
            self._state = "Run"
            if self.time_scale == 0:
                self._advance(instant=True)

    def _cancel_jog(self) -> None:
        if self._state == "Jog":
            self._jog_cancel = True
            if self.time_scale == 0:
                self._advance(instant=True)

    def _soft_reset(self) -> None:
        homing = self._state == "Home"
        moving = self._motion is not None and self._motion.speed_mm_s > 0 or homing
        self._planner.clear()
        self._homing_phases.clear()
        self._motion = None
        self._hold = False
        self._jog_cancel = False
        self._lines.clear()
        self._in.clear()
        self._modal_g, self._absolute, self._feed_mm_min = "G0", True, 0.0
        self._g92[:] = 0
        self._critical = False
        self._emit(BANNER)
        if moving:
            self._homed = False
            self._alarm = True
            self._emit(b"ALARM:6\r\n" if homing else b"ALARM:3\r\n")
        if self._alarm:
            self._state = "Alarm"
            self._emit(UNLOCK_MSG)
        else:
            self._state = "Idle"

    def _raise_alarm(self, code: int, critical: bool) -> None:
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
    def _start_homing(self) -> None:
        self._state = "Home"
        self._alarm = False
        self._homing_phases.clear()
        for ix, axis in reversed(list(zip(self._ix, self._axes))):   # vertical first, like Z in GRBL
            speed = axis.max_speed_mm_s / 2   # $25 is shared in GRBL; per axis here, half the max rate
            self._homing_phases.append(("seek", ix, speed))
            self._homing_phases.append(("pulloff", ix, speed / 4))
        if self.time_scale == 0:
            self._advance(instant=True)

    def _finish_homing(self) -> None:
        for ix in self._ix:
            self._offset[ix] = self._phys[ix]      # MPos 0 at the pull-off point
        self._homed = True
        self._alarm = False
        self._state = "Idle"
        self._wco_changed = True
        self._draw_repeatability()
        self._emit(b"ok\r\n")

    # -- status ------------------------------------------------------------------------------------
    def _state_text(self) -> str:
        return self._state

    def _status_report(self) -> bytes:
        self._reports += 1
        mpos = self._mpos()
        fields = [self._state_text()]
        if self._settings[10] & 1:
            fields.append("MPos:" + ",".join(f"{v:.3f}" for v in mpos))
        else:
            fields.append("WPos:" + ",".join(f"{v:.3f}" for v in self._wpos()))
        fields.append(f"Bf:{PLANNER_BLOCKS - len(self._planner)},{RX_BUFFER - len(self._in)}")
        speed = self._motion.speed_mm_s * 60.0 if self._motion is not None else 0.0
        fields.append(f"FS:{speed:.0f},0")
        pins = ""
        for ix, axis in zip(self._ix, self._axes):
            if self._phys[ix] <= -SWITCH_OUTSIDE_MM + 1e-6 or self._phys[ix] >= axis.travel_mm + SWITCH_OUTSIDE_MM - 1e-6:
                pins += AXES[ix]
        if pins:
            fields.append(f"Pn:{pins}")
        if self._wco_changed or self._reports % 10 == 0:
            self._wco_changed = False
            fields.append("WCO:" + ",".join(f"{v:.3f}" for v in self._g54 + self._g92))
        elif self._reports % 10 == 5:
            fields.append("Ov:100,100,100")
        return ("<" + "|".join(fields) + ">\r\n").encode()


