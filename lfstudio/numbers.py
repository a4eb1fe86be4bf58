"""Validated numbers: every number a person or a file hands lfstudio goes through here.

A CLI option, a GUI field, a rig or processing profile, a scene plan, a manifest: each numeric
field is described once by a :class:`Number` (its range, its unit, whole or not) and checked by
:meth:`Number.check`, which refuses NaN, infinities, values out of range and non-numbers with one
:class:`~lfstudio.errors.InputError` line naming the field, the value, and the valid range with its
unit::

    SETTLE_S = Number("s", 0, 600)
    SETTLE_S.check("--settle-s", 1e300)  # InputError: --settle-s: 1e+300 s is out of range (valid: 0 … 600 s)

:func:`lfstudio.cli.args.number_option` makes one the ``type=`` of an argparse option (the parser
reports the line and exits with status 2 before any device is opened). Sizes that allocate memory are bounded here too, before
anything is allocated: :func:`check_grid` (columns, rows and their product).
"""

from __future__ import annotations

import math
import re
from dataclasses import MISSING, dataclass
from typing import Any, Callable

from lfstudio.errors import InputError

#: the most views a grid may have (a 101 x 21 reference scan has 2121; a manifest entry is ~400 bytes)
MAX_VIEWS = 200_000
#: the most columns or rows of a grid
MAX_GRID_SIDE = 20_000


def _fmt(value: float) -> str:
    return f"{value:g}"


@dataclass(frozen=True)
class Number:
    """The rules of one numeric field: ``low`` … ``high`` (None: unbounded), ``low_open``: the low end
    itself is excluded (``> 0``), ``integer``: a whole number. ``unit`` goes into every message."""

    unit: str = ""
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    integer: bool = False

    def valid(self) -> str:
        """The accepted range as an operator reads it: ``0 … 600 s``, ``> 0 mm``, ``whole number ≥ 1``."""
        unit = f" {self.unit}" if self.unit else ""
        kind = "whole number " if self.integer else ""
        if self.low is not None and self.high is not None and not self.low_open:
            text = f"{_fmt(self.low)} … {_fmt(self.high)}{unit}"
            return f"{kind}{text}" if kind else text
        parts = []
        if self.low is not None:
            parts.append(f"{'>' if self.low_open else '≥'} {_fmt(self.low)}{unit}")
        if self.high is not None:
            parts.append(f"≤ {_fmt(self.high)}{unit}")
        return (kind + " and ".join(parts)).strip() or f"a finite number{unit}"

    def problem(self, value: Any) -> str | None:
        """What is wrong with ``value`` (without the field's name), or None when it is valid."""
        unit = f" {self.unit}" if self.unit else ""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f"{value!r} is not a number"
        if isinstance(value, int) and abs(value) > 2 ** 63:      # (str() of a huge int may itself fail)
            return f"a {int(value.bit_length() * 0.30103) + 1}-digit number is out of range"
        if not math.isfinite(value):
            return f"{value!r} is not a finite number" if isinstance(value, float) else f"{value} is not a number"
        if self.integer and not float(value).is_integer():
            return f"{_fmt(value)}{unit} is not a whole number"
        if (self.low is not None and (value < self.low or (self.low_open and value == self.low))) or \
                (self.high is not None and value > self.high):
            return f"{_fmt(value)}{unit} is out of range"
        return None

    def check(self, field: str, value: Any) -> Any:
        """``value`` as an int (``integer``) or float, or :class:`InputError` naming ``field``."""
        problem = self.problem(value)
        if problem:
            raise InputError(field, problem, self.valid())
        return int(value) if self.integer else float(value)

    def parse(self, field: str, text: str) -> Any:
        """A number typed by a person (``"0.5"``, ``" 12 "``), checked."""
        try:
            value: Any = int(text) if self.integer else float(text)
        except (TypeError, ValueError):
            try:
                value = float(text)           # "2.5" for a whole number: told as not whole, not as unreadable
            except (TypeError, ValueError):
                raise InputError(field, f"{text!r} is not a number", self.valid()) from None
        return self.check(field, value)


# -- one description per parameter ---------------------------------------------------------------------
#: the key of a dataclass field's metadata that holds its :class:`Param`
PARAM = "lfstudio.param"


@dataclass(frozen=True)
class Param:
    """Everything about one parameter, said once: the loader and validator check it, the window builds
    its editor from it and the command line its option (ScopeFoundry's ``LoggedQuantity`` idea, without
    Qt). ``number``: the rules of each value (None: text, or a flag); ``pair``: two values (horizontal,
    vertical); ``lengths``: a list of that many numbers (one of the lengths); ``choices``: the only
    values allowed (text or numbers); ``flag``: true or false; ``optional``: None is allowed and editors
    show this text for it ("auto"); ``option``: the command line's name (shared by the fields one option
    sets, e.g. ``--grid``); ``metavar``: its placeholder; ``label``/``tip``: the editor's name and
    explanation (also the option's help); ``group``: where editors and ``--help`` list it; ``repeat``:
    a list of such values, the option given once for each (``--notify A --notify B``); ``remember``:
    False for an act on one connection rather than a setting (a form never saves it, and shows it
    unticked each time, e.g. keeping the drives' reference)."""

    number: Number | None = None
    label: str = ""
    tip: str = ""
    option: str = ""
    metavar: str = ""
    group: str = ""
    pair: bool = False
    optional: str = ""
    choices: tuple = ()
    flag: bool = False
    lengths: tuple[int, ...] = ()
    repeat: bool = False
    remember: bool = True

    def check(self, field: str, value: Any) -> Any:
        """``value`` checked (each of a pair's or list's values; None when optional), or InputError
        naming ``field``."""
        if value is None and self.optional:
            return None
        if self.repeat:
            if not isinstance(value, (tuple, list)):
                raise InputError(field, f"{value!r} is not a list", f"a list of {self.valid()}")
            return [self._one(field, v) for v in value]
        if self.pair:
            if not isinstance(value, (tuple, list)) or len(value) != 2:
                raise InputError(field, f"{value!r} is not a pair", "two numbers: horizontal, vertical")
            return tuple(self._one(field, v) for v in value)
        if self.lengths:
            if not isinstance(value, (tuple, list)):
                raise InputError(field, f"{value!r} is not a list of numbers", self.valid())
            if len(value) not in self.lengths:
                raise InputError(field, f"has {len(value)} numbers", self.valid())
            return [self._one(field, v) for v in value]
        return self._one(field, value)

    def _one(self, field: str, value: Any) -> Any:
        if self.flag:
            if not isinstance(value, bool):
                raise InputError(field, f"{value!r} is not true or false", "true or false")
            return value
        if self.number is None:
            if not isinstance(value, str):
                raise InputError(field, f"{value!r} is not text", self._choices_text() or "a name in quotes")
            checked: Any = value
        else:
            checked = self.number.check(field, value)
        if self.choices and not any(checked == c and isinstance(checked, str) == isinstance(c, str)
                                    for c in self.choices):
            raise InputError(field, f"{value!r} is not one of the choices", self._choices_text())
        return checked

    def _choices_text(self) -> str:
        return ", ".join(str(c) for c in self.choices)

    def valid(self) -> str:
        if self.flag:
            return "true or false"
        if self.choices:
            return self._choices_text()
        one = "text" if self.number is None else self.number.valid()
        if self.lengths:
            n = self.lengths
            first, last = n[0], n[-1]
            consecutive = len(n) > 2 and list(n) == list(range(first, last + 1))
            counts = f"{first} … {last}" if consecutive else " or ".join(str(k) for k in n)
            return f"{counts} numbers, each {one}" if self.number is not None else f"{counts} numbers"
        return one

    def to_text(self, value: Any) -> str:
        """``value`` as a person types it (``4x6`` for a pair, ``1 0 0`` for a list, ``auto`` for None)."""
        if value is None:
            return self.optional
        if self.repeat:
            return " ".join(str(v) for v in value)
        if self.pair:
            return "x".join(_fmt(v) for v in value)
        if self.lengths:
            return " ".join(_fmt(v) for v in value)
        if isinstance(value, bool):
            return "true" if value else "false"
        return _fmt(value) if isinstance(value, (int, float)) else str(value)


def described(default: Any = MISSING, **param: Any) -> Any:
    """A dataclass field with ``default`` (none: a field the loader requires; a list: copied for each
    value) and its :class:`Param` (``dataclasses.field(metadata=…)``)."""
    from dataclasses import field as dataclass_field

    metadata = {PARAM: Param(**param)}
    if isinstance(default, list):
        return dataclass_field(default_factory=lambda: list(default), metadata=metadata)
    return dataclass_field(default=default, metadata=metadata)


def params_of(cls_or_value: Any) -> dict[str, Param]:
    """The described fields of a dataclass, in field order: ``{name: Param}``."""
    import dataclasses

    return {f.name: f.metadata[PARAM] for f in dataclasses.fields(cls_or_value) if PARAM in f.metadata}


def check_described(value: Any, where: Callable[[str], str] = str) -> None:
    """Check every described field of the dataclass instance ``value`` (InputError for the first bad
    one, named ``where(field)``)."""
    for name, param in params_of(value).items():
        param.check(where(name), getattr(value, name))


def load_described(cls: Any, data: Any, where: Callable[[str], str] = str, *, skip: tuple[str, ...] = ()) -> dict:
    """The one loader of a described dataclass from a file's table ``data`` (TOML/JSON): every key
    known and checked by its field's :class:`Param`, every field without a default present. Returns
    the checked keyword arguments (``cls(**them)`` builds it). ``where(key)`` names a key in messages
    (e.g. ``rigs.toml: ["Reference gantry".horizontal] travel_mm``); ``skip``: keys the caller reads
    itself (sub-tables)."""
    import dataclasses

    if not isinstance(data, dict):
        raise InputError(where(""), f"{data!r} is not a table", "a table of settings")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    params = params_of(cls)
    known = [name for name in fields if name in params or name in skip]
    out: dict[str, Any] = {}
    for key, value in data.items():
        if key in skip:
            continue
        if key not in params:
            raise InputError(where(str(key)), "unknown setting", ", ".join(known))
        out[key] = params[key].check(where(key), value)
    missing = [name for name, f in fields.items() if name in params and name not in out and
               f.default is MISSING and f.default_factory is MISSING]
    if missing:
        first = params[missing[0]]
        raise InputError(where(missing[0]), "missing" + (f" ({first.tip})" if first.tip else ""), first.valid())
    return out


# -- fields several places share (CLI, GUI, profiles, plans, the engine) -----------------------------------------
TIME_SCALE = Number("", 0, 1000)                    # factor on every simulated duration (0: as fast as possible)
SETTLE_S = Number("s", 0, 3600)
EXPOSURE_S = Number("s", 0, 3600)
TRANSFER_S = Number("s", 0, 3600)
TIMEOUT_S = Number("s", 0, 86400, low_open=True)
RETRIES = Number("", 0, 100, integer=True)
FILE_WAIT_S = Number("s", 0.1, 86400)                # a hot folder's wait for the camera software's new file
FILE_STABLE_S = Number("s", 0, 60)                   # ... and for its size to stay unchanged
SPACING_MM = Number("mm", 0.001, 100_000)          # below a micrometre no rig repeats
OFFSET_MM = Number("mm", -100_000, 100_000)
WIDTH_PX = Number("px", 16, 100_000, integer=True)
SEED = Number("", 0, 2 ** 32 - 1, integer=True)
WORKERS = Number("", 0, 256, integer=True)     # worker processes; also at most 4 per core (processing.executors)



def parse_numbers(field: str, text: str, number: Number, count: int = 2, example: str = "4x6",
                  one_for_all: bool = False) -> tuple:
    """``count`` numbers typed as one word (``4x6``, ``4×6``, ``4,6``), each checked by ``number``;
    ``one_for_all``: a single number stands for all of them (``5`` is ``5x5``)."""
    parts = re.split(r"[x×,]", str(text).strip().lower())
    if one_for_all and len(parts) == 1:
        parts = parts * count
    if len(parts) != count or not all(_is_number(p) for p in parts):
        raise InputError(field, f"cannot read {text!r}", f"{count} numbers like {example}")
    return tuple(number.parse(field, p.strip()) for p in parts)


def _is_number(text: str) -> bool:
    """``text`` reads as a number at all (NaN and infinities too: :meth:`Number.check` tells them)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def parse_grid(field: str, text: str, example: str = "101x21") -> tuple[int, int]:
    """A grid typed as ``COLUMNSxROWS`` (:func:`parse_numbers`), bounded by :func:`check_grid`."""
    return check_grid(field, *parse_numbers(field, text, Number("", integer=True), 2, example))


def check_number(field: str, value: Any, *, unit: str = "", low: float | None = None, high: float | None = None,
                 low_open: bool = False, integer: bool = False) -> Any:
    """:meth:`Number.check` for a field described in place."""
    return Number(unit, low, high, low_open, integer).check(field, value)


def check_grid(field: str, columns: Any, rows: Any) -> tuple[int, int]:
    """A grid's ``columns`` x ``rows``: whole numbers ≥ 1, each ≤ :data:`MAX_GRID_SIDE` and at most
    :data:`MAX_VIEWS` views together. Call before anything is allocated per view."""
    side = Number("", 1, MAX_GRID_SIDE, integer=True)
    for name, value in (("columns", columns), ("rows", rows)):
        problem = side.problem(value)
        if problem:
            raise InputError(field, f"{name}: {problem}", side.valid())
    c, r = int(columns), int(rows)
    if c * r > MAX_VIEWS:
        raise InputError(field, f"{c} x {r} is {c * r} views, more than lfstudio handles in one dataset",
                         f"at most {MAX_VIEWS} views; split the scan into several datasets")
    return c, r


def non_finite_fields(value: Any, where: str = "") -> list[str]:
    """Dotted names of the NaN/infinite numbers in a JSON-like value (``lens.focal_length_mm``), in
    document order; any depth (no recursion)."""
    found: list[str] = []
    stack: list[tuple[Any, str]] = [(value, where)]
    while stack:
        item, name = stack.pop()
        if isinstance(item, float):
            if not math.isfinite(item):
                found.append(name or "(value)")
        elif isinstance(item, dict):
            stack.extend((v, f"{name}.{k}" if name else str(k)) for k, v in reversed(list(item.items())))
        elif isinstance(item, (list, tuple)):
            stack.extend((v, f"{name}[{i}]") for i, v in reversed(list(enumerate(item))))
    return found
