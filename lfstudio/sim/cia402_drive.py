"""A CiA 402 axis drive (one drive per axis, as an igus dryve D1 drives one axis): its object
dictionary, its power state machine and a motion model, without any transport.

The transports serve it: :mod:`lfstudio.sim.drive_servers` puts it behind a Modbus TCP
server (the dryve D1's gateway telegrams, function 43 / MEI type 13) and behind python-canopen's
``LocalNode`` (SDO on a CAN bus). Everything here is in the drive's own units: position
*increments* (``6064h``, ``607Ah``, ``607Dh``), increments/s, increments/s².

Model:

- **Power state machine** (CiA 402 device control): Switch on disabled → (Shutdown 06h) Ready to
  switch on → (Switch on 07h) Switched on → (Enable operation 0Fh) Operation enabled; Quick stop
  (bit 2 low) → Quick stop active (``605Ah`` = 5/6: stay there once at rest, 1/2: then Switch on
  disabled); Disable voltage (bit 1 low) → Switch on disabled; a fault → Fault reaction active →
  Fault; Fault reset (rising edge of bit 7) → Switch on disabled once the cause is gone. The status
  word is composed as the profile tables say (``0x0040``, ``0x0021``, ``0x0023``, ``0x0027``,
  ``0x0007``, ``0x000F``, ``0x0008``) plus bit 9 remote, bit 10 target reached, bit 11 internal
  limit active (down again with the move it limited), bits 12/13 mode-specific; no bit 4 (voltage
  enabled): the dryve D1 answers 0640h after power-up, 0621h/0623h/0627h, 1627h at the target
  (manual V2.4 6.4.7; igus' sample V1.2's expected answers).
- **Objects** (:data:`OBJECTS`, as the D1 has them, 60A8h/607Bh/60FDh/6067h/6068h/6092h:0 too); an
  axis can be told to lack any (``AxisSetup.leave_out``), to list its homing methods (60E3h), to
  power up enabled in profile position but never homed, to settle off its target inside 6067h.
- **Units**: the feed constant ``6092h`` (units per motor revolution, :attr:`AxisSetup.feed`) over
  the mechanics' ``mm_per_rev`` makes the drive's units per mm; writing 6092h rescales (the
  carriage stays, its counts change). ``60A8h`` says the unit (FB010000h: 0.01 mm).
- **Modes**: ``6060h`` written while homing (or moving) is taken and shown in ``6061h`` once the
  run has ended (igus' sample writes 6060h = 1 right after starting its homing run).
- **Profile position** (``6060h`` = 1): a rising edge of control word bit 4 (new set-point) takes
  ``607Ah`` (absolute, or relative with bit 6) and sets status bit 12 (set-point acknowledge) until
  bit 4 falls; bit 10 (target reached) once the demand is at the target and at rest; bit 8 (halt)
  decelerates and holds, clearing it goes on to the target. Trapezoidal profile: ``6081h`` speed,
  ``6083h``/``6084h`` acceleration/deceleration, ``6085h`` for a quick stop. A target outside the
  software limits ``607Dh`` is clamped to them and sets bit 11.
  The profile runs in real time (× the time scale): ``6064h`` read during a move is where the
  axis is at that instant, at constant ``6081h`` between the ramps (igus, dryve D1 operating manual
  V2.4 p. 93: ``6064h`` "indication of the current position of the position encoder", read-only,
  readable at any time; §6.5.5: a pendulum motion in profile position driven by the same objects).
  The axis keeps a history of where it was (:meth:`DriveAxis.true_position_at`,
  :meth:`DriveAxis.counter_at`) so that a camera's timestamps get their own truth.
- **Touch probe** (CiA 402 / IEC 61800-7-201 objects ``60B8h`` function, ``60B9h`` status,
  ``60BAh``/``60BBh`` position at the positive/negative edge of touch probe 1): only on a drive set
  up with it (``AxisSetup.touch_probe``, ``lfstudio sim-drive --touch-probe``). The dryve D1 lists no
  touch probe object (its manual's objects, as DryveD1API's AddressConst.cs transcribes them: 60FDh
  digital inputs and 60FEh digital outputs, no 60B8h–60BBh), so the emulator as the D1 comes has none.
  ``60B8h`` bit 0 enables probe 1, bit 1 continuous (else the first event only: re-armed by writing
  bit 0 low, then high), bit 4/5 latch on the positive/negative edge; ``60B9h`` bit 0 enabled, bit
  1/2 positive/negative edge value stored. :meth:`DriveAxis.probe_edge` is the wire from a camera's
  exposure output to the input: the position ``6064h`` counted at the edge's instant is latched.
- **Answer delay** (``AxisSetup.answer_delay_s``, ``lfstudio sim-drive --answer-delay-ms``): every
  answer of the transports comes this much later (× the time scale): a slow gateway or a busy bus.
- **Following error** (``60F4h``): the actual position lags the demand by ``LAG_S`` of its speed;
  beyond the window ``6065h`` the drive faults (``8611h``), bit 13 set.
- **Homing** (``6060h`` = 6, bit 4 starts it): method 17 (negative limit switch) or 18 (positive)
  searches the switch at ``6099h:01``, leaves it at ``6099h:02`` and sets the position there
  (0, or the software maximum for 18, plus ``607Ch``); 35/37 take the current position. Bit 12
  homing attained + bit 10; bit 13 homing error. Before homing the drive counts from where it was
  powered up (``start_mm`` from the seed), like an incremental encoder.
- **Limit switches** ``SWITCH_OUTSIDE`` beyond both ends of the travel: touching one outside a
  homing run faults (``8612h``).
- **Faults to inject** (:meth:`DriveAxis.inject`): ``power_stage_off`` (fault ``3220h``, the power
  stage lost its supply; a fault reset does not help until :meth:`DriveAxis.clear_faults`),
  ``following_error`` (the axis jams during the next move: the following error grows until the
  window faults it), ``limit_switch`` (the next move touches a limit switch half way), and
  ``lost_connection`` (the drive stops answering: its servers drop requests).
- Time: the emulator's clock runs ``1 / time_scale`` times real time (0: every motion is complete
  at once). :meth:`DriveAxis.true_position` is where the carriage physically is.
"""

from __future__ import annotations

import bisect
import math
import threading
import time
from dataclasses import dataclass
from typing import Callable

# -- the objects (index, subindex) -> (bytes, signed, writable) -------------------------------------
OBJECTS: dict[tuple[int, int], tuple[int, bool, bool]] = {
    (0x1000, 0): (4, False, False),      # device type (402 drive profile)
    (0x603F, 0): (2, False, False),      # error code
    (0x6040, 0): (2, False, True),       # control word
    (0x6041, 0): (2, False, False),      # status word
    (0x605A, 0): (2, True, True),        # quick stop option code
    (0x6060, 0): (1, True, True),        # modes of operation
    (0x6061, 0): (1, True, False),       # modes of operation display
    (0x6064, 0): (4, True, False),       # position actual value
    (0x6065, 0): (4, False, True),       # following error window
    (0x6067, 0): (4, False, True),       # position window
    (0x6068, 0): (2, False, True),       # position window time (ms)
    (0x606C, 0): (4, True, False),       # velocity actual value
    (0x607A, 0): (4, True, True),        # target position
    (0x607B, 1): (4, True, True),        # position range limit: minimum
    (0x607B, 2): (4, True, True),        # position range limit: maximum
    (0x607C, 0): (4, True, True),        # home offset
    (0x607D, 1): (4, True, True),        # software position limit: minimum
    (0x607D, 2): (4, True, True),        # software position limit: maximum
    (0x6081, 0): (4, False, True),       # profile velocity
    (0x6083, 0): (4, False, True),       # profile acceleration
    (0x6084, 0): (4, False, True),       # profile deceleration
    (0x6085, 0): (4, False, True),       # quick stop deceleration
    (0x6092, 0): (1, False, False),      # feed constant: highest subindex (2)
    (0x6092, 1): (4, False, True),       # feed constant: feed
    (0x6092, 2): (4, False, True),       # feed constant: shaft revolutions
    (0x6098, 0): (1, True, True),        # homing method
    (0x6099, 1): (4, False, True),       # homing speed: search for switch
    (0x6099, 2): (4, False, True),       # homing speed: search for zero
    (0x609A, 0): (4, False, True),       # homing acceleration
    (0x60A8, 0): (4, False, True),       # SI unit position (FB010000h: 0.01 mm; DryveD1API reads it at connect)
    (0x60F4, 0): (4, True, False),       # following error actual value
    (0x60FD, 0): (4, False, False),      # digital inputs
    (0x6502, 0): (4, False, False),      # supported drive modes
}
#: CiA 402 touch probe 1 (IEC 61800-7-201): only on a drive set up with it (the dryve D1 has none)
TOUCH_PROBE_OBJECTS: dict[tuple[int, int], tuple[int, bool, bool]] = {
    (0x60B8, 0): (2, False, True),       # touch probe function
    (0x60B9, 0): (2, False, False),      # touch probe status
    (0x60BA, 0): (4, True, False),       # touch probe 1 position value at the positive edge
    (0x60BB, 0): (4, True, False),       # touch probe 1 position value at the negative edge
}
TP_ENABLE, TP_CONTINUOUS, TP_POSITIVE, TP_NEGATIVE = 0x01, 0x02, 0x10, 0x20
TP_ENABLED, TP_POSITIVE_STORED, TP_NEGATIVE_STORED = 0x01, 0x02, 0x04
HISTORY_DT = 0.001             # the axis' history of where it was: an entry at most every ms (emulator time)
HISTORY_STEPS = 50_000         # ... and at least the last 50 000 entries (50 s of emulator time or more)
#: supported homing methods (60E3h, an array): only on an emulator told to list them (AxisSetup.supported_homing)
SUPPORTED_HOMING = 0x60E3
#: objects a drive can be told to lack (``lfstudio sim-drive --leave-out``): every one CiA 402 leaves optional
#: and the mandatory ones (to test that the driver refuses them by name)
LEAVE_OUT_ALLOWED = sorted({index for index, _ in OBJECTS} - {0x1000, 0x6041})

NOT_READY, SWITCH_ON_DISABLED, READY, SWITCHED_ON, ENABLED, QUICK_STOP, FAULT_REACTION, FAULT = (
    "NOT READY TO SWITCH ON", "SWITCH ON DISABLED", "READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED",
    "QUICK STOP ACTIVE", "FAULT REACTION ACTIVE", "FAULT")
_STATE_BITS = {NOT_READY: 0x0000, SWITCH_ON_DISABLED: 0x0040, READY: 0x0021, SWITCHED_ON: 0x0023,
               ENABLED: 0x0027, QUICK_STOP: 0x0007, FAULT_REACTION: 0x000F, FAULT: 0x0008}
PROFILE_POSITION, HOMING = 1, 6
HOMING_METHODS = (17, 18, 35, 37)
FAULTS = ("power_stage_off", "following_error", "limit_switch", "lost_connection")
FAULT_CODES = {"power_stage_off": 0x3220, "following_error": 0x8611, "limit_switch": 0x8612}
LAG_S = 0.002                  # the actual position lags the demand by this much of its speed
SWITCH_OUTSIDE_MM = 1.0        # the limit switches trigger this far beyond each end of the travel
STEP_S = 0.005                 # the motion model's integration step (emulator time)


class ObjectRefused(Exception):
    """An access the drive refuses; ``abort`` is the CiA 301 SDO abort code (the transports map it)."""

    def __init__(self, abort: int, text: str):
        super().__init__(text)
        self.abort = abort


@dataclass
class AxisSetup:
    """One emulated axis in the drive's units. ``increments_per_mm``: the feed constant the rig
    profile names; ``travel_mm``; ``start_mm``: where the carriage stands at power-up."""

    increments_per_mm: float
    travel_mm: float
    start_mm: float
    max_speed_mm_s: float
    acceleration_mm_s2: float
    soft_min_mm: float
    soft_max_mm: float
    homing_method: int = 17
    mm_per_rev: float = 70.0                 # the mechanics: mm the carriage travels per motor revolution
    feed: int | None = None                  # 6092h:01 at power-up (None: increments_per_mm x mm_per_rev)
    leave_out: frozenset[int] = frozenset()  # object indices this drive lacks
    enabled_unhomed: bool = False            # powered up in operation enabled, profile position, never homed
    supported_homing: tuple[int, ...] | None = None   # 60E3h's list, when the drive has that object
    settle_error_mm: float = 0.0             # where a move comes to rest, beyond its target (inside 6067h)
    touch_probe: bool = False                # CiA 402 touch probe 1 (60B8h-60BBh), which the dryve D1 lacks
    answer_delay_s: float = 0.0              # every answer comes this much later (x the time scale)

    def feed_constant(self) -> int:
        return int(round(self.increments_per_mm * self.mm_per_rev)) if self.feed is None else int(self.feed)


def si_position_of(units_per_mm: float) -> int:
    """60A8h for a position unit of 1/units_per_mm mm (a power of ten; else 0.01 mm's FB010000h)."""
    exponent = math.log10(units_per_mm) if units_per_mm > 0 else 2.0
    if abs(exponent - round(exponent)) > 1e-9:
        exponent = 2.0
    return (((-3 - round(exponent)) & 0xFF) << 24) | (0x01 << 16)


class DriveAxis:
    """One CiA 402 drive and its axis (thread-safe: every access takes the drive's lock)."""

    def __init__(self, setup: AxisSetup, *, time_scale: float = 1.0, name: str = "drive"):
        self.setup = setup
        self.name = name
        self._scale = float(time_scale)
        feed = setup.feed_constant()
        k = feed / setup.mm_per_rev             # position units per mm: what 6092h makes of the mechanics
        self._k = k
        self.objects = {key: spec for key, spec in OBJECTS.items() if key[0] not in setup.leave_out}
        if setup.touch_probe:
            self.objects.update({key: spec for key, spec in TOUCH_PROBE_OBJECTS.items() if key[0] not in setup.leave_out})
        if setup.supported_homing is not None and SUPPORTED_HOMING not in setup.leave_out:
            self.objects[(SUPPORTED_HOMING, 0)] = (1, False, False)
            for n in range(1, len(setup.supported_homing) + 1):
                self.objects[(SUPPORTED_HOMING, n)] = (1, True, False)
        self._lock = threading.RLock()
        self._t0 = time.monotonic()
        self._last = 0.0
        self.journal: list | None = None        # every accepted write (name, index, sub, value), when a list
        self.answering = True
        self.on_answering: Callable[[], None] | None = None     # called when ``answering`` changes (the CANopen node)
        self._power = True
        self._jam = False
        self._limit_trip_at: float | None = None
        self._pending_limit = False
        # the object dictionary's stored values
        self.od: dict[tuple[int, int], int] = {
            (0x1000, 0): 0x00040192, (0x603F, 0): 0, (0x6040, 0): 0, (0x605A, 0): 6, (0x6060, 0): 0,
            (0x6065, 0): int(5 * k), (0x607A, 0): 0, (0x607C, 0): 0,
            (0x607D, 1): int(round(setup.soft_min_mm * k)), (0x607D, 2): int(round(setup.soft_max_mm * k)),
            (0x6081, 0): int(setup.max_speed_mm_s * k / 2), (0x6083, 0): int(setup.acceleration_mm_s2 * k),
            (0x6084, 0): int(setup.acceleration_mm_s2 * k), (0x6085, 0): int(4 * setup.acceleration_mm_s2 * k),
            (0x6092, 0): 2, (0x6092, 1): feed, (0x6092, 2): 1, (0x6098, 0): setup.homing_method,
            (0x6067, 0): max(1, int(round(0.05 * k))), (0x6068, 0): 10, (0x60A8, 0): si_position_of(k),
            (0x607B, 1): -(1 << 31), (0x607B, 2): (1 << 31) - 1, (0x60FD, 0): 0,
            (0x6099, 1): int(setup.max_speed_mm_s * k / 4), (0x6099, 2): int(setup.max_speed_mm_s * k / 20),
            (0x609A, 0): int(setup.acceleration_mm_s2 * k), (0x6502, 0): (1 << 0) | (1 << 5),
        }
        for key in TOUCH_PROBE_OBJECTS:
            self.od[key] = 0
        self.probe_latches = 0                  # edges latched (tests)
        if setup.supported_homing is not None:
            self.od[(SUPPORTED_HOMING, 0)] = len(setup.supported_homing)
            for n, method in enumerate(setup.supported_homing, 1):
                self.od[(SUPPORTED_HOMING, n)] = method
        self.state = SWITCH_ON_DISABLED
        self.mode = 0
        self.error_code = 0
        # motion, in increments of the drive's counter; phys = counter + offset (offset unknown until homed)
        self._offset = setup.start_mm * k       # power-up: the counter reads 0 where the carriage stands
        self._demand = 0.0
        self._actual = 0.0
        self._v = 0.0
        self._target: float | None = None      # profile-position target being driven to
        self._halt = False
        self._ack = False
        self._reached = True
        self._limit_active = False
        self._fe_bit = False
        self._homing: dict | None = None       # the homing run's phase
        self._homed_flag = False
        self._homing_error = False
        self._quick_stop_at_rest = False
        self._pending_mode: int | None = None   # 6060h written during homing: taken when the homing ends
        self.homed = False                      # this power cycle has a reference (not visible on the bus)
        # (monotonic time, position counter 6064h, physical mm) after each motion step
        self._history: list[tuple[float, float, float]] = []
        if setup.enabled_unhomed:               # another program enabled it in profile position, never homed
            self.state = ENABLED
            self.mode = PROFILE_POSITION
            self.od[(0x6060, 0)] = PROFILE_POSITION
            self.od[(0x6040, 0)] = 0x0F

    # -- clock -----------------------------------------------------------------------------------
    @property
    def time_scale(self) -> float:
        return self._scale

    @time_scale.setter
    def time_scale(self, value: float) -> None:
        """Another speed from now on; the emulator's clock goes on from where it is."""
        with self._lock:
            self._advance()
            self._scale = float(value)
            self._t0 = time.monotonic() - self._last * self._scale

    def _now(self) -> float:
        if self._scale <= 0:
            return self._last
        return (time.monotonic() - self._t0) / self._scale

    @property
    def answer_delay_s(self) -> float:
        """How long (real time) each answer of the transports waits: the set-up's delay x the time scale."""
        return max(0.0, self.setup.answer_delay_s) * max(self._scale, 0.0)

    # -- bus access ------------------------------------------------------------------------------
    def read(self, index: int, sub: int) -> int:
        with self._lock:
            spec = self.objects.get((index, sub))
            if spec is None:
                raise ObjectRefused(0x06020000 if not any(i == index for i, _ in self.objects) else 0x06090011,
                                    f"object {index:04X}h:{sub} does not exist")
            self._advance()
            if index == 0x6041:
                return self.statusword()
            if index == 0x603F:
                return self.error_code
            if index == 0x6061:
                return self.mode
            if index == 0x6064:
                return int(round(self._actual))
            if index == 0x606C:
                return int(round(self._v))
            if index == 0x60F4:
                return int(round(self._demand - self._actual))
            if index == 0x6060:
                return self.od[(0x6060, 0)]
            return self.od[(index, sub)]

    def write(self, index: int, sub: int, value: int) -> None:
        with self._lock:
            spec = self.objects.get((index, sub))
            if spec is None:
                raise ObjectRefused(0x06020000, f"object {index:04X}h:{sub} does not exist")
            size, signed, writable = spec
            if not writable:
                raise ObjectRefused(0x06010002, f"object {index:04X}h:{sub} is read-only")
            lo, hi = (-(1 << (8 * size - 1)), (1 << (8 * size - 1)) - 1) if signed else (0, (1 << (8 * size)) - 1)
            if not lo <= int(value) <= hi:
                raise ObjectRefused(0x06090030, f"{value} is out of range for {index:04X}h:{sub}")
            value = int(value)
            if self.journal is not None:
                self.journal.append((self.name, index, sub, value))
            self._advance()
            if index == 0x6040:
                self._control(value)
                return
            if index == 0x6060:
                if value not in (0, PROFILE_POSITION, HOMING):
                    raise ObjectRefused(0x06090030, f"mode {value} is not supported")
                self.od[(0x6060, 0)] = value
                if self._homing is not None or self._moving():
                    # igus' sample V1.2 writes 6060h = 1 right after starting the homing run: the D1 takes
                    # it and its 6061h shows 6 until the run has ended, then 1 (the sample's expected answers)
                    self._pending_mode = value
                else:
                    self._change_mode(value)
                return
            elif index == 0x6098 and value not in HOMING_METHODS:
                raise ObjectRefused(0x06090030, f"homing method {value} is not supported (17, 18, 35, 37)")
            elif index in (0x6081, 0x6083, 0x6084, 0x6085, 0x6099, 0x609A) and value <= 0:
                raise ObjectRefused(0x06090032, f"{index:04X}h must be positive")
            elif index == 0x6092 and value <= 0:
                raise ObjectRefused(0x06090032, "the feed constant must be positive")
            elif index == 0x60B8:
                # enabling probe 1 (bit 0 rising) starts afresh: no value stored; bit 0 low switches it off
                old = self.od[(0x60B8, 0)]
                if not value & TP_ENABLE:
                    self.od[(0x60B9, 0)] = 0
                elif not old & TP_ENABLE:
                    self.od[(0x60B9, 0)] = TP_ENABLED
            elif index == 0x607D and sub == 1 and value > self.od[(0x607D, 2)] or \
                    index == 0x607D and sub == 2 and value < self.od[(0x607D, 1)]:
                raise ObjectRefused(0x06090036, "software limit minimum above maximum")
            self.od[(index, sub)] = value
            if index == 0x6092:
                self._rescale(self.od[(0x6092, 1)] / max(1, self.od[(0x6092, 2)]) / self.setup.mm_per_rev)

    def _change_mode(self, value: int) -> None:
        self.mode = value
        self._pending_mode = None
        self._ack = False
        self._homing = None
        self._homing_error = False
        self._homed_flag = False
        self._limit_active = False
        self._reached = True

    def _rescale(self, k: float) -> None:
        """A new feed constant: the same carriage position counts in the new units from now on
        (6064h, 607Ah, speeds); the stored parameters keep their numbers (now in the new units)."""
        ratio = k / self._k
        self._offset *= ratio
        self._demand *= ratio
        self._actual *= ratio
        self._v *= ratio
        if self._target is not None:
            self._target *= ratio
        if self._limit_trip_at is not None:
            self._limit_trip_at *= ratio
        self._k = k

    def power_cycle(self) -> None:
        """The drive switched off and on where it stands (a power cut, its gateway restarted): its
        counter ``6064h`` reads 0 there, the reference is gone, it is switch on disabled, no mode."""
        with self._lock:
            self._advance()
            self._offset += self._actual
            self._demand = self._actual = self._v = 0.0
            self._target, self._homing, self._pending_mode = None, None, None
            self._homed_flag = self._halt = self._ack = self._quick_stop_at_rest = False
            self._reached = True
            self.homed = False
            self.state = SWITCH_ON_DISABLED
            self.mode = 0
            self.od[(0x6060, 0)] = 0
            self.od[(0x6040, 0)] = 0

    # -- faults ----------------------------------------------------------------------------------
    def inject(self, fault: str) -> None:
        with self._lock:
            self._advance()
            if fault not in FAULTS:
                raise ValueError(f"unknown fault {fault!r} ({', '.join(FAULTS)})")
            if fault == "lost_connection":
                self.answering = False
            elif fault == "power_stage_off":
                self._power = False
                self._fault(FAULT_CODES[fault])
            elif fault == "following_error":
                self._jam = True
            elif fault == "limit_switch":
                self._pending_limit = True
        if fault == "lost_connection" and self.on_answering is not None:
            self.on_answering()

    def clear_faults(self) -> None:
        """The cause of every injected fault is gone (power back, obstruction removed, answering);
        a fault the drive latched still needs a fault reset."""
        with self._lock:
            self._advance()
            self.answering = True
            self._power = True
            self._jam = False
            self._pending_limit = False
            self._limit_trip_at = None
        if self.on_answering is not None:
            self.on_answering()

    def _fault(self, code: int) -> None:
        self.error_code = code
        self.state = FAULT
        self._target = None
        self._homing = None
        self._v = 0.0                    # the brake holds: the axis stands where it is
        self._demand = self._actual
        self._reached = False
        self.homed = self.homed and code != FAULT_CODES["limit_switch"]
        self._homed_flag = False

    # -- state machine ---------------------------------------------------------------------------
    def statusword(self) -> int:
        # bit 9 remote; no bit 4 (voltage enabled): the dryve D1 answers 0640h after power-up, 0621h,
        # 0623h, 0627h through the state machine and 1627h at the target (manual V2.4 6.4.7; igus' sample
        # V1.2 waits for exactly [.., 2, 33, 6], [.., 2, 35, 6], [.., 2, 39, 6] and [.., 2, 39, 22])
        sw = _STATE_BITS[self.state] | 0x0200
        if self.state in (ENABLED, SWITCHED_ON, READY, SWITCH_ON_DISABLED):
            sw |= 0x0020 if self.state != SWITCH_ON_DISABLED else 0
        if self._reached and self.state in (SWITCH_ON_DISABLED, READY, SWITCHED_ON, ENABLED, QUICK_STOP):
            sw |= 0x0400
        if self._limit_active:
            sw |= 0x0800
        if self.mode == PROFILE_POSITION:
            sw |= (0x1000 if self._ack else 0) | (0x2000 if self._fe_bit else 0)
        elif self.mode == HOMING:
            sw |= (0x1000 if self._homed_flag else 0) | (0x2000 if self._homing_error else 0)
        return sw

    def _control(self, cw: int) -> None:
        old = self.od[(0x6040, 0)]
        self.od[(0x6040, 0)] = cw
        if self.state == FAULT:
            if cw & 0x80 and not old & 0x80 and self._power:
                self.error_code = 0
                self.state = SWITCH_ON_DISABLED
                self._fe_bit = False
                self._reached = True
            return
        if self.state == FAULT_REACTION:
            return
        cmd = cw & 0x8F
        if not cw & 0x02:                                    # disable voltage
            self._to(SWITCH_ON_DISABLED)
        elif not cw & 0x04:                                  # quick stop
            if self.state == ENABLED:
                self.state = QUICK_STOP
                self._quick_stop_at_rest = False
                self._target = None
                self._homing = None
                self._reached = abs(self._v) < 1e-9
            elif self.state in (READY, SWITCHED_ON):
                self.state = SWITCH_ON_DISABLED
        elif cmd & 0x0F == 0x06:                             # shutdown
            if self.state in (SWITCH_ON_DISABLED, SWITCHED_ON, ENABLED) and self._power:
                self._to(READY)
        elif cmd & 0x0F == 0x07:                             # switch on
            if self.state in (READY, ENABLED) and self._power:
                self._to(SWITCHED_ON)
        elif cmd & 0x0F == 0x0F:                             # enable operation
            if self.state in (READY, SWITCHED_ON) and self._power:
                self.state = ENABLED
                self._demand = self._actual
                self._reached = True
            elif self.state == QUICK_STOP and self.od[(0x605A, 0)] in (5, 6, 7, 8) and abs(self._v) < 1e-9:
                self.state = ENABLED
                self._reached = True
        if self.state != ENABLED:
            return
        self._halt = bool(cw & 0x100)
        rising = cw & 0x10 and not old & 0x10
        if self.mode == PROFILE_POSITION:
            if rising:
                target = self.od[(0x607A, 0)] + (self._demand if cw & 0x40 else 0)
                lo, hi = self.od[(0x607D, 1)], self.od[(0x607D, 2)]
                self._limit_active = not lo <= target <= hi
                self._target = float(min(max(target, lo), hi))
                self._ack = True
                self._reached = False
                self._fe_bit = False
                if self._pending_limit:
                    self._pending_limit = False
                    self._limit_trip_at = (self._demand + self._target) / 2
            elif not cw & 0x10:
                self._ack = False
        elif self.mode == HOMING and rising:
            method = self.od[(0x6098, 0)]
            self._homed_flag = False
            self._homing_error = False
            self._reached = False
            if method in (35, 37):
                self._set_home(self._demand)
            else:
                self._homing = {"phase": "search", "dir": -1.0 if method == 17 else 1.0}

    def _to(self, state: str) -> None:
        if state != ENABLED and self._moving():
            self._v = 0.0                                    # power off: the brake stops the axis
            self._demand = self._actual
        self._target = None
        self._homing = None
        self.state = state
        self._reached = True

    def _moving(self) -> bool:
        return abs(self._v) > 1e-9 or self._target is not None or self._homing is not None

    def _set_home(self, counter_at_home: float) -> None:
        """The homing position becomes the counter's reference (``607Ch`` added)."""
        method = self.od[(0x6098, 0)]
        home_value = self.od[(0x607C, 0)]
        if method == 18:
            home_value += self.od[(0x607D, 2)]
        shift = home_value - counter_at_home
        self._offset -= shift
        self._demand += shift
        self._actual += shift
        self._homing = None
        self._homed_flag = True
        self._reached = True
        self.homed = True

    # -- motion ----------------------------------------------------------------------------------
    def _phys_mm(self, counter: float) -> float:
        return (counter + self._offset) / self._k

    def true_position(self) -> float:
        """Where the carriage physically is, mm from the low end of the travel."""
        with self._lock:
            self._advance()
            return self._phys_mm(self._actual)

    def position_mm(self) -> float:
        """The position the drive reports (``6064h``), in mm."""
        with self._lock:
            self._advance()
            return self._actual / self._k

    def _advance(self) -> None:
        now = self._now()
        dt_total = now - self._last
        if self._scale <= 0:
            self._finish_instantly()
        else:
            steps = 0
            t = self._last
            while dt_total > 1e-12 and steps < 2_000_000:
                dt = min(STEP_S, dt_total)
                self._step(dt)
                dt_total -= dt
                t += dt
                steps += 1
                self._remember(t)
            self._last = now
        if self._pending_mode is not None and not self._moving():
            self._change_mode(self._pending_mode)

    def _remember(self, t_emulator: float) -> None:
        t = self._t0 + t_emulator * self._scale
        hist = self._history
        if hist and t - hist[-1][0] < HISTORY_DT * self._scale:
            return
        hist.append((t, self._actual, self._phys_mm(self._actual)))
        if len(hist) > 2 * HISTORY_STEPS:
            del hist[:HISTORY_STEPS]

    def _at(self, t: float, column: int) -> float | None:
        """Column 1 (counter) or 2 (mm) of the history at monotonic time ``t`` (linear between
        steps); None outside it."""
        with self._lock:
            if self._scale > 0:
                self._advance()
            hist = self._history
            if self._scale > 0 and (not hist or t > hist[-1][0]):
                # after the last entry (they come at most every HISTORY_DT): between it and where it is now
                now = (self._t0 + self._last * self._scale, self._actual, self._phys_mm(self._actual))
                hist = [*hist[-1:], now]
            if not hist or t < hist[0][0] or t > hist[-1][0] + 1e-9:
                return None
            i = bisect.bisect_left(hist, (t,))
            if i <= 0:
                return hist[0][column]
            if i >= len(hist):
                return hist[-1][column]
            a, b = hist[i - 1], hist[i]
            w = 0.0 if b[0] <= a[0] else (t - a[0]) / (b[0] - a[0])
            return a[column] + w * (b[column] - a[column])

    def true_position_at(self, t: float) -> float | None:
        """Where the carriage physically was at monotonic time ``t`` (mm), None outside the history."""
        return self._at(t, 2)

    def counter_at(self, t: float) -> float | None:
        """The position counter (``6064h``, unrounded) at monotonic time ``t``, None outside the history."""
        return self._at(t, 1)

    def probe_edge(self, rising: bool, t: float) -> bool:
        """The touch probe 1 input went high (``rising``) or low at monotonic time ``t`` (a camera's
        exposure output): an edge the probe function ``60B8h`` enables latches ``6064h`` at its instant
        into ``60BAh`` (rising) / ``60BBh`` (falling), the first event only unless continuous. True if latched."""
        with self._lock:
            if (0x60B8, 0) not in self.objects:
                return False
            self._advance()
            fn, status = self.od[(0x60B8, 0)], self.od[(0x60B9, 0)]
            enable, stored, value = ((TP_POSITIVE, TP_POSITIVE_STORED, (0x60BA, 0)) if rising else
                                     (TP_NEGATIVE, TP_NEGATIVE_STORED, (0x60BB, 0)))
            if not fn & TP_ENABLE or not fn & enable or (status & stored and not fn & TP_CONTINUOUS):
                return False
            counter = self.counter_at(t)
            self.od[value] = int(round(self._actual if counter is None else counter))
            self.od[(0x60B9, 0)] = status | stored | TP_ENABLED
            self.probe_latches += 1 if rising else 0
            return True

    def _finish_instantly(self) -> None:
        for _ in range(4):
            if self._homing is not None:
                self._run_homing_instantly(self._homing)
            elif self.state == QUICK_STOP or self._halt:
                self._v = 0.0
                self._reached = True
                self._after_quick_stop()
            elif self._target is not None and self.state == ENABLED:
                if self._limit_trip_at is not None:
                    self._demand = self._actual = self._limit_trip_at
                    self._limit_trip_at = None
                    self._fault(FAULT_CODES["limit_switch"])
                elif self._jam:
                    self._demand = self._target
                    self._fault(FAULT_CODES["following_error"])
                    self._fe_bit = True
                else:
                    self._demand = self._actual = self._target
                    self._v = 0.0
                    self._arrived()

    def _run_homing_instantly(self, h: dict) -> None:
        k = self._k
        switch = (-SWITCH_OUTSIDE_MM if h["dir"] < 0 else self.setup.travel_mm + SWITCH_OUTSIDE_MM) * k
        counter_at_switch = switch - self._offset
        pulloff = counter_at_switch - h["dir"] * SWITCH_OUTSIDE_MM * k
        self._demand = self._actual = pulloff
        self._v = 0.0
        self._set_home(pulloff)

    def _arrived(self) -> None:
        """The profile-position target is reached: bit 10 up; bit 11 (internal limit: the target was
        clamped to 607Dh) goes down with the move it limited."""
        if self.setup.settle_error_mm and self._target is not None:
            self._demand = self._actual = self._target + self.setup.settle_error_mm * self._k
        self._target = None
        self._reached = True
        self._limit_active = False

    def _quick_stop_deceleration(self) -> float:
        """605Ah 1/5: the profile deceleration 6084h; 2/6 (and a drive without 6085h): 6085h / 6084h."""
        if self.od[(0x605A, 0)] in (1, 5) or (0x6085, 0) not in self.objects:
            return self.od[(0x6084, 0)]
        return self.od[(0x6085, 0)]

    def _after_quick_stop(self) -> None:
        if self.state == QUICK_STOP and abs(self._v) < 1e-9 and self.od[(0x605A, 0)] in (0, 1, 2, 3):
            self.state = SWITCH_ON_DISABLED

    def _step(self, dt: float) -> None:
        if self.state not in (ENABLED, QUICK_STOP):
            return
        if self.state == QUICK_STOP:
            self._brake(self._quick_stop_deceleration(), dt)
            if abs(self._v) < 1e-9:
                self._reached = True
                self._after_quick_stop()
            self._follow(dt)
            return
        if self._homing is not None:
            self._step_homing(self._homing, dt)
        elif self._halt:
            self._brake(self.od[(0x6084, 0)], dt)
            if abs(self._v) < 1e-9 and self._target is None:
                self._reached = True
        elif self._target is not None:
            self._drive_to(self._target, self.od[(0x6081, 0)], self.od[(0x6083, 0)], self.od[(0x6084, 0)], dt)
            if self._limit_trip_at is not None and \
                    (self._demand - self._limit_trip_at) * (self._target - self._limit_trip_at) <= 0:
                self._limit_trip_at = None
                self._actual = self._demand
                self._fault(FAULT_CODES["limit_switch"])
                return
            if self._demand == self._target and self._v == 0.0:
                self._arrived()
        self._follow(dt)
        self._check_switches()

    def _follow(self, dt: float) -> None:
        if self._jam:
            pass                                              # the axis is stuck: the actual stays
        else:
            self._actual = self._demand - self._v * LAG_S
        if abs(self._demand - self._actual) > self.od[(0x6065, 0)] and self.state in (ENABLED, QUICK_STOP):
            self._fe_bit = True
            self._fault(FAULT_CODES["following_error"])
            self._fe_bit = True

    def _check_switches(self) -> None:
        if self._homing is not None or self.state != ENABLED:
            return
        phys = self._phys_mm(self._actual)
        if phys < -SWITCH_OUTSIDE_MM or phys > self.setup.travel_mm + SWITCH_OUTSIDE_MM:
            self._fault(FAULT_CODES["limit_switch"])

    def _brake(self, decel: float, dt: float) -> None:
        if self._v == 0.0:
            return
        dv = decel * dt
        if abs(self._v) <= dv:
            self._demand += self._v * dt / 2
            self._v = 0.0
        else:
            v_new = self._v - math.copysign(dv, self._v)
            self._demand += (self._v + v_new) * dt / 2
            self._v = v_new

    def _drive_to(self, target: float, vmax: float, acc: float, dec: float, dt: float) -> None:
        """One step of a trapezoidal profile towards ``target``: never faster than ``vmax``, speeding
        up at ``acc``, and slowing down in time to stop on the target at ``dec``."""
        d = target - self._demand
        if d == 0.0:
            if self._v != 0.0:
                self._brake(dec, dt)
            return
        direction = 1.0 if d > 0 else -1.0
        v_along = self._v * direction
        if v_along < 0:                                      # moving away (a new target behind): brake first
            self._brake(dec, dt)
            return
        v_new = min(vmax, v_along + acc * dt, math.sqrt(2 * dec * abs(d)))
        v_new = max(v_new, v_along - dec * dt, 0.0)
        ds = (v_along + v_new) * dt / 2
        if ds >= abs(d) or abs(d) < 1e-3:
            self._demand = target
            self._v = 0.0
            return
        self._demand += direction * ds
        self._v = direction * v_new

    def _step_homing(self, h: dict, dt: float) -> None:
        k = self._k
        acc = self.od[(0x609A, 0)]
        if h["phase"] == "search":
            speed = self.od[(0x6099, 1)]
            phys = self._phys_mm(self._demand)
            switch_mm = -SWITCH_OUTSIDE_MM if h["dir"] < 0 else self.setup.travel_mm + SWITCH_OUTSIDE_MM
            if (phys - switch_mm) * h["dir"] >= 0:
                h["phase"] = "leave"
                self._brake(4 * acc, dt)
                if self._v == 0.0:
                    h["phase"] = "leave"
                return
            v_new = min(speed, abs(self._v) + acc * dt)
            self._v = h["dir"] * v_new
            self._demand += self._v * dt
        elif h["phase"] == "leave":
            if self._v != 0.0:
                self._brake(4 * acc, dt)
                return
            switch_mm = -SWITCH_OUTSIDE_MM if h["dir"] < 0 else self.setup.travel_mm + SWITCH_OUTSIDE_MM
            leave_at = (switch_mm - h["dir"] * SWITCH_OUTSIDE_MM) * k - self._offset
            self._drive_to(leave_at, self.od[(0x6099, 2)], acc, acc, dt)
            if self._demand == leave_at and self._v == 0.0:
                self._actual = self._demand
                self._set_home(self._demand)
                return
        self._actual = self._demand - self._v * LAG_S


class DrivePair:
    """The two drives of a rig (horizontal, vertical) built from a rig profile's drive settings."""

    def __init__(self, horizontal: DriveAxis, vertical: DriveAxis):
        self.axes = (horizontal, vertical)
        self.journal: list = []                 # the writes both drives received, in order
        for axis in self.axes:
            axis.journal = self.journal

    def true_position_mm(self) -> tuple[float, float]:
        return self.axes[0].true_position(), self.axes[1].true_position()

    def true_position_at(self, t: float) -> tuple[float, float] | None:
        """Where the carriage was at monotonic time ``t`` (mm), None outside the axes' history."""
        x, y = self.axes[0].true_position_at(t), self.axes[1].true_position_at(t)
        return None if x is None or y is None else (x, y)

    def probe_edge(self, rising: bool, t: float) -> bool:
        """A camera's exposure output wired to both drives' touch probe 1 input (see DriveAxis.probe_edge)."""
        return any([axis.probe_edge(rising, t) for axis in self.axes])

    @property
    def time_scale(self) -> float:
        return self.axes[0].time_scale

    @time_scale.setter
    def time_scale(self, value: float) -> None:
        for axis in self.axes:
            axis.time_scale = value


def drive_pair(rig, *, time_scale: float = 1.0, seed: int = 0, setup: dict | tuple[dict, dict] | None = None
               ) -> DrivePair:
    """Two emulated drives for the rig profile ``rig`` (a :class:`lfstudio.rig.motion.RigConfig`
    whose axes name their ``increments_per_mm``, ``feed_mm_per_rev`` and ``homing_method``), powered
    up somewhere inside the travel (from ``seed``). ``setup``: further :class:`AxisSetup` fields
    (``leave_out``, ``feed``, ``enabled_unhomed``, ...) for both drives, or a pair (horizontal, vertical)."""
    import random

    rnd = random.Random(seed)
    extras = setup if isinstance(setup, tuple) else (setup or {}, setup or {})
    axes = []
    for axis, extra in zip((rig.horizontal, rig.vertical), extras):
        extra = dict(extra)
        if "leave_out" in extra:
            extra["leave_out"] = frozenset(extra["leave_out"])
        setup_ = AxisSetup(increments_per_mm=axis.increments_per_mm or 100.0, travel_mm=axis.travel_mm,
                           start_mm=rnd.uniform(0.1, 0.6) * axis.travel_mm, max_speed_mm_s=axis.max_speed_mm_s,
                           acceleration_mm_s2=axis.acceleration_mm_s2, soft_min_mm=axis.soft_min_mm,
                           soft_max_mm=axis.soft_max_mm, homing_method=axis.homing_method or 17,
                           mm_per_rev=getattr(axis, "feed_mm_per_rev", 0.0) or 70.0, **extra)
        axes.append(DriveAxis(setup_, time_scale=time_scale, name=axis.name))
    return DrivePair(*axes)
