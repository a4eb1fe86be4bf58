"""The GRBL 1.1 protocol as lfstudio speaks it, without any I/O (no pyserial: an import-linter
contract, ``grbl-protocol-no-serial``, keeps it so): the firmware's error and alarm tables, the
exceptions a controller's answers become, the parsers of every line it sends (status reports,
``$$`` settings, ``[G54:...]`` parameters, banners, messages) and the limits the firmware itself
enforces (:class:`FirmwareLimits`, from ``$$``). The driver (:mod:`lfstudio.rig.grbl`) talks to
the port and uses these; tests and tools may parse GRBL's lines without opening a port.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from lfstudio.errors import DeviceError
from lfstudio.rig.motion import RigState

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

STATE_MAP = {"Idle": RigState.IDLE, "Run": RigState.MOVING, "Jog": RigState.JOGGING,
              "Home": RigState.HOMING, "Hold": RigState.HOLD, "Door": RigState.HOLD,
              "Alarm": RigState.ALARM, "Check": RigState.IDLE, "Sleep": RigState.IDLE}
_STATUS_RE = re.compile(r"<([^<>]*)>")
_ERROR_RE = re.compile(r"error:(\d{1,4})")
_ALARM_RE = re.compile(r"ALARM:(\d{1,4})")
_SETTING_RE = re.compile(r"\$(\d{1,4})=(.*)")
_PARAM_RE = re.compile(r"\[(G5[4-9]|G28|G30|G92|TLO|PRB):([^\]]*)\]")
_BANNER_RE = re.compile(r"Grbl (\S+) \[.*\]")
#: no two quantifiers compete for the same digits: linear time on any line (``\d+\.?\d*`` backtracked
#: quadratically: 21 s for a 64 KiB line, holding the GIL)
_NUMBER_RE = re.compile(r"[-+]?(?:\d+(?:\.\d*)?|\.\d+)")
#: the longest line GRBL 1.1 sends is well under this (status reports, $$ settings, [MSG:...]); a longer
#: one is noise and classified as garbage without parsing it
MAX_LINE_CHARS = 512
HOLD_COMPLETE, HOLD_DECELERATING = 0, 1   # the substates of Hold in GRBL 1.1 status reports
#: set after our own $H: GRBL clears the tool number on every reset and power-up, so a homing
#: controller that still reports T1 and is not in alarm was homed by lfstudio and not reset since
HOMED_MARK = "T1"


class GrblError(DeviceError):
    """The controller refused a line with ``error:N``. ``what``: the line as the operator should read
    of it (e.g. 'line 17 of 25 of the fly row, "G1 X60.000 S0",'), said as "GRBL refused WHAT with
    error:N (meaning)"; without it the old form, "controller refused 'LINE': error N, meaning"."""

    kind = "controller-error"

    def __init__(self, code: int, line: str, after: str = "", what: str = ""):
        self.code = code
        self.line = line
        meaning = GRBL_ERRORS.get(code, "unknown error code; see the GRBL 1.1 error list")
        if what:
            text = f"GRBL refused {what} with error:{code} ({meaning})"
        else:
            text = f"controller refused {line!r}: error {code}, {meaning}"
        super().__init__(f"{text}; {after}" if after else text)


class GrblAlarm(DeviceError):
    """The controller went into alarm (``ALARM:N``): motion stopped, commands locked."""

    kind = "alarm"

    def __init__(self, code: int, context: str = ""):
        self.code = code
        text = f"ALARM {code}: {GRBL_ALARMS.get(code, 'unknown alarm; see the GRBL 1.1 alarm list')}"
        super().__init__(f"{context}: {text}" if context else text)


class ConnectionLost(DeviceError):
    """The port vanished or the controller stopped answering."""

    kind = "connection-lost"


class MotionStopped(DeviceError):
    """A move or homing was interrupted by STOP."""

    kind = "motion-stopped"


class PositionError(DeviceError):
    """The controller is Idle but not where it was sent."""

    kind = "position"


@dataclass(frozen=True)
class GrblStatus:
    """One parsed ``<State|...>`` report. Positions are tuples over the controller's axes."""

    state: str                                   # Idle, Run, Hold, Jog, Alarm, Door, Check, Home, Sleep
    substate: int | None = None                  # Hold:0 complete / Hold:1 decelerating, Door:0..3
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

    def machine_position(self, wco: tuple[float, ...] | None) -> tuple[float, ...] | None:
        """MPos from the report: given directly, or WPos + WCO (this report's or the last known)."""
        if self.mpos is not None:
            return self.mpos
        offset = self.wco or wco
        if self.wpos is None or offset is None:
            return None
        return tuple(w + o for w, o in zip(self.wpos, offset))


STATES = tuple(STATE_MAP)


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
        if state not in STATE_MAP:
            continue
        values: dict = {"state": state}
        if sub:
            if not (sub.isdigit() and len(sub) <= 2):
                continue
            values["substate"] = int(sub)
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


@dataclass(frozen=True)
class GrblLine:
    """One line from the controller, classified by :func:`parse_line`.

    ``kind``: ok, error, alarm, status, banner, msg, setting, param, info or garbage.
    ``code``: N of ``error:N``/``ALARM:N``; ``key``/``value``: a ``$N=value`` setting;
    ``name``/``values``: a ``[G54:x,y,z]`` parameter (name) or the banner's version (name);
    ``status``: the parsed report of a status line."""

    kind: str
    text: str
    code: int | None = None
    key: int | None = None
    value: float | None = None
    name: str = ""
    values: tuple[float, ...] = ()
    status: GrblStatus | None = None


def _number(text: str) -> float:
    """A finite number in GRBL's format (no exponent, no inf/nan), else ValueError."""
    if not _NUMBER_RE.fullmatch(text.strip()):
        raise ValueError(text)
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(text)
    return value


def parse_line(line: str) -> GrblLine:
    """Classify one line (without its line end) from a GRBL 1.1 controller. Never raises:
    anything malformed (``$1=.``, ``[G54:1..2,0,0]``, ``ALARM:`` with a thousand digits) is
    ``garbage``, which the driver logs and ignores."""
    text = line.strip()
    if len(text) > MAX_LINE_CHARS:
        return GrblLine("garbage", text[:80] + "…")
    try:
        if text == "ok":
            return GrblLine("ok", text)
        if m := _ERROR_RE.fullmatch(text):
            return GrblLine("error", text, code=int(m.group(1)))
        if m := _ALARM_RE.fullmatch(text):
            return GrblLine("alarm", text, code=int(m.group(1)))
        if text.startswith("<"):
            st = parse_status(text) if text.endswith(">") else None
            return GrblLine("status", text, status=st) if st is not None else GrblLine("garbage", text)
        if m := _BANNER_RE.fullmatch(text):
            return GrblLine("banner", text, name=m.group(1))
        if text.startswith("[MSG:") and text.endswith("]"):
            return GrblLine("msg", text, name=text[5:-1])
        if m := _PARAM_RE.fullmatch(text):
            name, body = m.group(1), m.group(2)
            coords, _, extra = body.partition(":")          # [PRB:x,y,z:1]
            values = tuple(_number(v) for v in coords.split(","))
            if extra and not extra.isdigit():
                raise ValueError(body)
            return GrblLine("param", text, name=name, values=values)
        if text.startswith("[") and text.endswith("]"):
            return GrblLine("info", text)
        if m := _SETTING_RE.fullmatch(text):
            return GrblLine("setting", text, key=int(m.group(1)), value=_number(m.group(2)))
        if text.startswith(">") and text.endswith(("ok", "]")) or text.startswith("$N"):
            return GrblLine("info", text)                   # startup-line echo, $N listings
    except (ValueError, OverflowError):
        pass
    return GrblLine("garbage", text)


@dataclass(frozen=True)
class FirmwareLimits:
    """What the controller itself enforces, from its ``$$`` settings (None: not reported)."""

    max_rate_mm_min: dict[str, float]            # $110.. per axis letter
    acceleration_mm_s2: dict[str, float]         # $120..
    max_travel_mm: dict[str, float]              # $130..
    soft_limits: bool                            # $20
    hard_limits: bool                            # $21
    homing: bool                                 # $22
    homing_dir_mask: int                         # $23: bit set = that axis homes towards negative
    pulloff_mm: float = 1.0                      # $27
    force_origin: bool = False                   # built with HOMING_FORCE_SET_ORIGIN (OPT flag Z)

    @classmethod
    def from_settings(cls, settings: dict[int, float], options: str = "") -> "FirmwareLimits":
        def per_axis(base: int) -> dict[str, float]:
            return {letter: float(settings[base + i]) for i, letter in enumerate(AXIS_LETTERS)
                    if base + i in settings}

        return cls(per_axis(110), per_axis(120), per_axis(130), settings.get(20, 0) == 1,
                   settings.get(21, 0) == 1, settings.get(22, 0) == 1, int(settings.get(23, 0)),
                   float(settings.get(27, 1.0)), "Z" in options)

    def machine_range(self, letter: str) -> tuple[float, float] | None:
        """(lowest, highest) machine coordinate GRBL's soft limits allow on this axis, or None."""
        travel = self.max_travel_mm.get(letter)
        if travel is None or travel <= 0:
            return None
        if self.force_origin and self.homes_low(letter):
            return 0.0, travel
        return -travel, 0.0

    def homes_low(self, letter: str) -> bool:
        """The axis homes towards its low end (``$23`` bit set); else towards its high end."""
        return bool(self.homing_dir_mask & (1 << AXIS_LETTERS.index(letter)))

    def safe_machine_range(self, letter: str) -> tuple[float, float] | None:
        """:meth:`machine_range` less the pull-off (``$27``) on the home switch's side when hard limits
        are on (``$21=1``): GRBL's envelope ends where the home switch triggers, and touching it
        then raises ALARM 1. The carriage may go as far as its home position, not further."""
        span = self.machine_range(letter)
        if span is None or not (self.homing and self.hard_limits):
            return span
        lo, hi = span
        return (lo + self.pulloff_mm, hi) if self.homes_low(letter) else (lo, hi - self.pulloff_mm)
