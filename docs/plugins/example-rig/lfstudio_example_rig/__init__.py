"""An example lfstudio rig plugin: a motorised sled simulated in memory.

lfstudio finds it through the entry point in pyproject.toml (group ``lfstudio.rigs``, name ``sled``),
which names :data:`KIND`, a :class:`lfstudio.studio.kinds.RigKind`: its label, what follows ``sled:`` in
the device word (the bench's name), its connection options as a described dataclass (``--rig-option
NAME=VALUE`` and the Rig panel's form are checked against it) and its lock key (a second lfstudio
process asking for the same bench is refused, naming the holder). ``open(argument, context)`` returns
the controller, which implements :class:`lfstudio.rig.motion.MotionController`; lfstudio connects it.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

from lfstudio.errors import DeviceError
from lfstudio.numbers import Number, described
from lfstudio.rig.motion import RigConfig, RigState, RigStatus, check_target
from lfstudio.studio.kinds import OpenContext, RigKind


@dataclass(frozen=True)
class SledOptions:
    """The sled's connection options: each field's description is its check, its form field and its help."""

    speed_mm_s: float = described(500.0, number=Number("mm/s", 1, 10_000), label="Speed",
                                  tip="how fast the sled travels (moves and homing)")
    timeout_s: float = described(60.0, number=Number("s", 0.1, 3600), label="Move timeout",
                                 tip="longest a move may take before it is stopped and refused")


class Sled:
    """Two axes in memory moving at ``speed_mm_s``; ``stop()`` from any thread ends a move where it is."""

    def __init__(self, bench: str, config: RigConfig, speed_mm_s: float = 500.0, timeout_s: float = 60.0):
        self.bench, self.config = bench or "sled", config
        self.speed_mm_s, self.timeout_s = speed_mm_s, timeout_s
        self.port = f"sled:{bench}"
        self._pos = (config.horizontal.soft_min_mm, config.vertical.soft_min_mm)
        self._state = RigState.DISCONNECTED
        self._homed = False
        self._lock = threading.Lock()
        self._stop = threading.Event()

    def connect(self) -> None:
        with self._lock:
            self._state = RigState.IDLE

    def disconnect(self) -> None:
        self.stop()
        with self._lock:
            self._state = RigState.DISCONNECTED

    def _need_connection(self) -> None:
        if self._state is RigState.DISCONNECTED:
            raise DeviceError(f"sled {self.bench}: not connected (connect first)")

    def home(self) -> None:
        self._travel(self.config.horizontal.soft_min_mm, self.config.vertical.soft_min_mm, RigState.HOMING)
        self._homed = True

    def set_origin(self) -> None:
        self._need_connection()
        with self._lock:
            self._pos, self._homed = (0.0, 0.0), True

    def move_to(self, x_mm: float, y_mm: float, timeout_s: float | None = None) -> RigStatus:
        x_mm, y_mm = check_target(self.config, x_mm, y_mm)     # outside the soft limits: refused, nothing moves
        self._travel(x_mm, y_mm, RigState.MOVING, timeout_s)
        return self.status()

    def _travel(self, x_mm: float, y_mm: float, state: RigState, timeout_s: float | None = None) -> None:
        self._need_connection()
        self._stop.clear()
        with self._lock:
            start, self._state = self._pos, state
        distance = max(abs(x_mm - start[0]), abs(y_mm - start[1]))
        duration = distance / self.speed_mm_s
        if duration > (timeout_s or self.timeout_s):
            with self._lock:
                self._state = RigState.IDLE
            raise DeviceError(f"sled {self.bench}: the move would take {duration:.0f} s, longer than its timeout")
        began = time.monotonic()
        while True:
            share = min(1.0, (time.monotonic() - began) / duration) if duration else 1.0
            with self._lock:
                self._pos = (start[0] + (x_mm - start[0]) * share, start[1] + (y_mm - start[1]) * share)
            if share >= 1.0 or self._stop.wait(0.005):
                break
        with self._lock:
            self._state = RigState.IDLE if self._state is not RigState.DISCONNECTED else self._state
        if share < 1.0:
            raise DeviceError(f"sled {self.bench}: stopped at {self._pos[0]:.1f}, {self._pos[1]:.1f} mm")

    def jog(self, dx_mm: float, dy_mm: float, speed_mm_s: float | None = None) -> None:
        x, y = self._pos
        self.move_to(x + dx_mm, y + dy_mm)

    def jog_cancel(self) -> None:
        self.stop()

    def feed_hold(self) -> None:
        self.stop()

    def resume(self) -> None:
        pass

    def stop(self) -> None:
        self._stop.set()

    def reset(self) -> None:
        self.stop()

    def status(self) -> RigStatus:
        with self._lock:
            if self._state is RigState.DISCONNECTED:
                return RigStatus(RigState.DISCONNECTED)
            return RigStatus(self._state, self._pos, homed=self._homed)


def open_sled(argument: str, context: OpenContext) -> Any:
    """``sled:BENCH``: a sled for the rig profile ``context.config`` with the options given."""
    return Sled(argument, context.config, **context.options)


KIND = RigKind("sled", open_sled, label="Sled (example plugin)", argument="BENCH", options=SledOptions,
               lock_key=lambda bench: f"sled-{bench or 'sled'}",
               help="a motorised sled simulated in memory (the example of a rig plugin)")
