"""An exposure bracket: the frames a scan takes at every view, and how they are told and recorded.

A bracket is written as EV steps around the camera's shutter time (``-2,0,+2``: a quarter, the
same and four times the shutter time) or as explicit shutter times (``1/500,1/125,1/30s`` or
``0.002s,0.008s,0.033s``: a value with a ``/`` or an ``s`` is a time in seconds). Every view of a
bracketed scan has one frame per step, taken in the order given, with the same aperture and ISO.
The *reference frame* is the one at 0 EV (or, for explicit times, the middle one): the view's
``file`` is that frame, so every stage that reads one picture per view (thumbnails, calibration,
the quality check, exports of one exposure) reads it unchanged.

The manifest records the bracket as ``{"ev": [-2, 0, 2]}`` or ``{"shutter_s": [0.002, 0.008, 0.033]}``
(``dataset.json`` → ``bracket``; see docs/dataset-format.md); a view's frames in ``frames``.
Below ``planning`` and ``scan`` (both describe it) and ``processing`` (which merges the frames).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from fractions import Fraction
from typing import Any, Iterable

from lfstudio.errors import InputError

#: the most frames a view may have (a 9-frame bracket covers ±8 EV at 2 EV steps)
MAX_FRAMES = 9
#: EV steps further than this from the camera's shutter time are refused (±10 EV = 1:1024)
MAX_EV = 10.0
#: shutter times a bracket may ask for
MIN_SHUTTER_S = 1e-5
MAX_SHUTTER_S = 3600.0
#: how an operator writes one (the valid text of every message)
VALID = ("EV steps like -2,0,+2 or shutter times like 1/500,1/125,1/30s "
         f"(1 to {MAX_FRAMES} frames, each different)")


def _fmt_ev(ev: float) -> str:
    return f"{ev:+g}" if ev else "0"


def shutter_text(seconds: float) -> str:
    """A shutter time as a photographer reads it: ``1/125 s``, ``0.3 s``, ``2 s``."""
    if seconds <= 0 or not math.isfinite(seconds):
        return f"{seconds:g} s"
    if seconds < 0.3:
        inverse = 1.0 / seconds
        if abs(inverse - round(inverse)) < 0.02 * inverse:
            return f"1/{round(inverse)} s"
    return f"{seconds:.3g} s"


@dataclass(frozen=True)
class Bracket:
    """The frames of every view: ``ev`` (steps around the camera's shutter time) or ``shutter_s``
    (explicit times), exactly one of them, in capture order."""

    ev: tuple[float, ...] = ()
    shutter_s: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        check_bracket(self, "bracket")

    @property
    def frames(self) -> int:
        return len(self.ev) or len(self.shutter_s)

    @property
    def reference_index(self) -> int:
        """The frame the view's ``file`` is: 0 EV (else the one nearest to it), or for explicit
        times the middle one (of an even count the longer of the two middle ones)."""
        if self.ev:
            return min(range(len(self.ev)), key=lambda i: (abs(self.ev[i]), -self.ev[i]))
        order = sorted(range(len(self.shutter_s)), key=lambda i: self.shutter_s[i])
        return order[len(order) // 2]

    def shutter_times_s(self, base_shutter_s: float | None) -> tuple[float, ...]:
        """Each frame's shutter time: explicit, or the camera's ``base_shutter_s`` × 2^EV."""
        if self.shutter_s:
            return self.shutter_s
        if base_shutter_s is None or not base_shutter_s > 0 or not math.isfinite(base_shutter_s):
            raise InputError("bracket", "EV steps need the camera's shutter time, which it did not tell",
                             "set the camera's shutter time, or give explicit shutter times like 1/500,1/125,1/30s")
        return tuple(float(base_shutter_s) * 2.0 ** ev for ev in self.ev)

    def relative_exposures(self) -> tuple[float, ...]:
        """Each frame's exposure relative to the reference frame (1 for the reference)."""
        if self.ev:
            ref = self.ev[self.reference_index]
            return tuple(2.0 ** (ev - ref) for ev in self.ev)
        ref = self.shutter_s[self.reference_index]
        return tuple(t / ref for t in self.shutter_s)

    def describe(self) -> str:
        """``-2, 0, +2 EV`` or ``1/500 s, 1/125 s, 1/30 s``."""
        if self.ev:
            return ", ".join(_fmt_ev(v) for v in self.ev) + " EV"
        return ", ".join(shutter_text(t) for t in self.shutter_s)

    def text(self) -> str:
        """The form :func:`parse_bracket` reads back (``-2,0,+2``; ``0.002s,0.008s``)."""
        if self.ev:
            return ",".join(_fmt_ev(v) for v in self.ev)
        return ",".join(_time_text(t) for t in self.shutter_s)

    def to_manifest(self) -> dict[str, Any]:
        out: dict[str, Any] = {"ev": list(self.ev)} if self.ev else {"shutter_s": list(self.shutter_s)}
        out["reference_frame"] = self.reference_index
        return out

    @classmethod
    def from_manifest(cls, data: Any, field: str = "bracket") -> "Bracket":
        if not isinstance(data, dict) or ("ev" in data) == ("shutter_s" in data):
            raise InputError(field, "needs exactly one of 'ev' and 'shutter_s' (a list of numbers)", VALID)
        try:
            if "ev" in data:
                return _checked(cls, field, ev=tuple(float(v) for v in data["ev"]))
            return _checked(cls, field, shutter_s=tuple(float(v) for v in data["shutter_s"]))
        except (TypeError, ValueError, OverflowError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(field, f"not a list of numbers ({exc})", VALID) from None


def _time_text(t: float) -> str:
    """A shutter time that reads back exactly: ``1/30s`` when it is 1/N, else the float's own repr."""
    if t < 1:
        n = round(1 / t)
        if n > 0 and float(Fraction(1, n)) == t:
            return f"1/{n}s"
    return f"{t!r}s"


def _checked(cls: type, field: str, **kw: Any) -> Bracket:
    try:
        return cls(**kw)
    except InputError as exc:
        raise InputError(field, str(exc).split(": ", 1)[-1].split(" (valid:")[0], exc.valid) from None


def check_bracket(bracket: Bracket, field: str = "bracket") -> None:
    """Raise :class:`InputError` naming ``field`` for a bracket no camera could take."""
    if bool(bracket.ev) == bool(bracket.shutter_s):
        raise InputError(field, "give either EV steps or shutter times, not both and not neither", VALID)
    values = bracket.ev or bracket.shutter_s
    if len(values) > MAX_FRAMES:
        raise InputError(field, f"{len(values)} frames are too many", VALID)
    for v in values:
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
            raise InputError(field, f"{v!r} is not a finite number", VALID)
    if bracket.ev:
        far = [v for v in bracket.ev if abs(v) > MAX_EV]
        if far:
            raise InputError(field, f"{_fmt_ev(far[0])} EV is too far from the camera's exposure",
                             f"-{MAX_EV:g} … +{MAX_EV:g} EV")
    else:
        bad = [t for t in bracket.shutter_s if not MIN_SHUTTER_S <= t <= MAX_SHUTTER_S]
        if bad:
            raise InputError(field, f"a shutter time of {bad[0]:g} s is out of range",
                             f"{MIN_SHUTTER_S:g} … {MAX_SHUTTER_S:g} s")
    if len(set(values)) != len(values):
        twice = next(v for v in values if values.count(v) > 1)
        what = f"{_fmt_ev(twice)} EV" if bracket.ev else shutter_text(twice)
        raise InputError(field, f"{what} is given twice (each frame must differ)", VALID)


_NUMBER = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$")


def _parse_time(word: str, field: str) -> float:
    text = word[:-1].strip() if word.lower().endswith("s") else word
    try:
        if "/" in text:
            num, den = text.split("/", 1)
            value = float(Fraction(num.strip()) / Fraction(den.strip()))
        elif _NUMBER.match(text):
            value = float(text)
        else:
            raise ValueError(text)
    except (ValueError, ZeroDivisionError, OverflowError):
        raise InputError(field, f"{word!r} is not a shutter time", VALID) from None
    return value


def parse_bracket(text: "str | Iterable[Any] | None", field: str = "--bracket") -> Bracket | None:
    """Read a bracket as the operator typed it; None for nothing (one frame per view, as before).

    ``"-2,0,+2"`` → EV steps; ``"1/500,1/125,1/30s"`` → shutter times. One value (``"0"``) means a
    single frame: None. Raises :class:`InputError` naming ``field`` with the valid forms.
    """
    if text is None:
        return None
    if not isinstance(text, str):
        text = ",".join(str(v) for v in text)
    words = [w.strip() for w in text.replace(";", ",").split(",")]
    if words == [""]:
        return None
    if any(not w for w in words):
        raise InputError(field, f"{text!r} has an empty value", VALID)
    times = [("/" in w or w.lower().endswith("s")) for w in words]
    if any(times) and not all(times):
        raise InputError(field, f"{text!r} mixes EV steps and shutter times", VALID)
    if all(times):
        values = tuple(_parse_time(w, field) for w in words)
        bracket = _checked(Bracket, field, shutter_s=values)
    else:
        evs = []
        for w in words:
            if not _NUMBER.match(w.replace("EV", "").replace("ev", "").strip()):
                raise InputError(field, f"{w!r} is not an EV step", VALID)
            evs.append(float(w.replace("EV", "").replace("ev", "").strip()))
        bracket = _checked(Bracket, field, ev=tuple(evs))
    if bracket.frames == 1 and bracket.ev == (0.0,):
        return None
    return bracket


#: half a third of a stop: a camera's nominal times (1/60, 1/125) stand for 1/64, 1/128, ... and are
#: up to 4.2 % from the powers of two an EV bracket asks for; the merge uses the time the camera reports
CHOICE_TOLERANCE = 2 ** (1 / 6) - 1


def nearest_choice(seconds: float, choices: Iterable[float], tolerance: float = CHOICE_TOLERANCE) -> float | None:
    """The camera's own shutter time that is ``seconds`` (within ``tolerance`` relative, half a third
    of a stop: cameras list 1/125 as 0.008, and 1/60 for 1/62.5), else None."""
    best = None
    for c in choices:
        if isinstance(c, (int, float)) and not isinstance(c, bool) and c > 0:
            if abs(math.log(c / seconds)) <= math.log1p(tolerance):
                if best is None or abs(c - seconds) < abs(best - seconds):
                    best = float(c)
    return best


def frame_times_on_camera(bracket: Bracket, base_shutter_s: float | None, values: Iterable[Any] = (),
                          texts: Iterable[str] = (), camera: str = "the camera",
                          field: str = "--bracket", range_s: tuple[float, float] | None = None) -> tuple[float, ...]:
    """Each frame's shutter time as the camera can set it: the bracket's times (``base_shutter_s`` ×
    2^EV for EV steps) matched to the camera's own choices (``values`` in seconds, ``texts`` as it
    names them; none given: any time is taken) and within its continuous ``range_s`` (min, max s).
    :class:`InputError` naming ``field`` and listing the camera's choices, or its range and the EV
    steps that fit it, when a frame's time is not among them."""
    times = bracket.shutter_times_s(base_shutter_s)
    if range_s is not None:
        low, high = float(range_s[0]), float(range_s[1])
        for k, t in enumerate(times):
            if not low * (1 - 1e-9) <= t <= high * (1 + 1e-9):
                lo_ev = max(-MAX_EV, math.log2(low / base_shutter_s)) if base_shutter_s else 0.0
                hi_ev = min(MAX_EV, math.log2(high / base_shutter_s)) if base_shutter_s else 0.0
                fits = (f"EV steps from {lo_ev:+.1f} to {hi_ev:+.1f}"
                        f" at its shutter time of {shutter_text(base_shutter_s)}, or times within the range"
                        if bracket.ev and base_shutter_s else "shutter times within the range")
                raise InputError(field, f"frame {k + 1} of {bracket.describe()} needs a shutter time of "
                                 f"{shutter_text(t)}, beyond {camera}'s range of {shutter_text(low)} … "
                                 f"{shutter_text(high)}", fits)
    numbers = [float(v) for v in values if isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0]
    if not numbers:
        return times
    out = []
    for t in times:
        got = nearest_choice(t, numbers)
        if got is None:
            listed = [s for s in texts if s] or [shutter_text(v) for v in sorted(numbers)]
            raise InputError(field, f"{camera} cannot set a shutter time of {shutter_text(t)} "
                             f"(frame {times.index(t) + 1} of {bracket.describe()})",
                             "its choices: " + ", ".join(listed))
        out.append(got)
    return tuple(out)
