"""Rig profiles from ``resources/presets/rigs.toml`` (and the user's presets) as :class:`RigConfig`.

Every setting is described once on :class:`~lfstudio.rig.motion.AxisConfig` and
:class:`~lfstudio.rig.motion.RigConfig` (unit, range, choices, label, tip); the one loader
(:func:`lfstudio.numbers.load_described`) checks each value against its description and refuses
unknown keys (a misspelt ``setle_s`` would otherwise silently keep the default). What only the
profile as a whole can say is checked here: the soft limits inside the axis's travel (the rig's
frame runs from 0 to ``travel_mm``), so no profile can let a target beyond the travel through to
the controller; two axes on two controller letters; a CiA 402 axis's feed constant. A bad value is
one line naming the file, the rig, the field and the allowed range::

    ~/.config/lfstudio/presets/rigs.toml: rig 'Mine' horizontal.max_speed_mm_s: 0 mm/s is out of
    range (valid: 0.01 … 10000 mm/s)
"""

from __future__ import annotations

from pathlib import Path

from typing import Any

from lfstudio.errors import InputError
from lfstudio.numbers import Number, Param, load_described, params_of
from lfstudio.resources import load_presets, load_presets_with_files
from lfstudio.rig.motion import AXIS_LETTERS, DRIVERS, HOMING_METHODS, AxisConfig, RigConfig

DEFAULT_RIG = "Reference gantry"
#: the CiA 402 profile the drive emulators (sim-dryve, sim-canopen, lfstudio sim-drive) start with
DEFAULT_DRIVE_RIG = "dryve D1 gantry 4 m x 0.5 m"
#: each setting's description: {key: Param} of an axis table and of the profile's own keys
AXIS_PARAMS: dict[str, Param] = params_of(AxisConfig)
RIG_PARAMS: dict[str, Param] = params_of(RigConfig)
AXES = ("horizontal", "vertical")
__all__ = ["AXIS_LETTERS", "DRIVERS", "HOMING_METHODS", "AXIS_PARAMS", "RIG_PARAMS", "DEFAULT_RIG",
           "DEFAULT_DRIVE_RIG", "rig_names", "rig_from_dict", "load_rig", "preset_source", "profile_lines"]


def rig_names() -> list[str]:
    return list(load_presets("rigs"))


def rig_from_dict(name: str, data: dict, source: str = "") -> RigConfig:
    """A checked :class:`RigConfig` from the profile's table ``data``; ``source``: the file it comes
    from (named in every message). ``driver = "cia402"`` (one CiA 402 drive per axis): each axis names
    ``increments_per_mm`` (the feed constant, positive) and may name ``homing_method`` (6098h: 17,
    18, 35 or 37; default 17); its ``letter`` is optional (the drives are told apart by their
    addresses)."""
    prefix = f"{source}: " if source else ""
    rig_where = f"{prefix}rig {name!r}"
    if not isinstance(data, dict):
        raise InputError(rig_where, "is not a table", "a [\"Name\"] table with [\"Name\".horizontal] and .vertical")
    data = dict(data)
    if isinstance(data.get("driver"), str):
        data["driver"] = data["driver"].lower()
    top = load_described(RigConfig, data, lambda key: f"{rig_where}.{key}", skip=AXES)
    driver = top.get("driver", "grbl")
    axes = {}
    for axis in AXES:
        a = data.get(axis)
        if not isinstance(a, dict):
            raise InputError(rig_where, f"missing [{axis}] table", "letter, travel_mm, soft limits, speed, ...")
        where = f"{rig_where} {axis}"
        a = dict(a)
        if isinstance(a.get("letter"), str):
            a["letter"] = a["letter"].upper()
        if isinstance(a.get("eds_file"), str) and a["eds_file"].strip():
            eds = Path(a["eds_file"].strip()).expanduser()
            if not eds.is_absolute() and source:
                eds = Path(source).parent / eds
            a["eds_file"] = str(eds)
        if driver == "cia402":
            a.setdefault("letter", "X" if axis == "horizontal" else "Y")
            a.setdefault("homing_method", 17)
            _check_drive_fields(where, a)
        cfg = AxisConfig(name=axis, **load_described(AxisConfig, a, lambda key, w=where: f"{w}.{key}"))
        soft = Number("mm", 0, cfg.travel_mm)     # the rig's frame: 0 at one end of the travel, travel_mm at the other
        soft.check(f"{where}.soft_min_mm", cfg.soft_min_mm)
        soft.check(f"{where}.soft_max_mm", cfg.soft_max_mm)
        if not (cfg.soft_min_mm < cfg.soft_max_mm):
            raise InputError(f"{where}.soft_max_mm", "must be greater than soft_min_mm")
        axes[axis] = cfg
    if axes["horizontal"].letter == axes["vertical"].letter:
        raise InputError(rig_where, "horizontal and vertical axes need different controller letters")
    top.setdefault("label", name)
    return RigConfig(name=name, horizontal=axes["horizontal"], vertical=axes["vertical"], **top)


def _check_drive_fields(where: str, a: dict) -> None:
    """What a CiA 402 axis needs beyond its description: a feed constant, positive."""
    if "increments_per_mm" not in a:
        raise InputError(f"{where}.increments_per_mm", "missing: the feed constant (drive position units per mm) "
                         "converts mm to the drive's increments", "a positive number, e.g. 100")
    k = a["increments_per_mm"]
    if isinstance(k, (int, float)) and not isinstance(k, bool):
        if k == 0:
            raise InputError(f"{where}.increments_per_mm", "0: no position could be converted to the drive's "
                             "increments", "a positive number, e.g. 100 for a drive counting 0.01 mm")
        if k < 0:
            raise InputError(f"{where}.increments_per_mm", f"{k:g} is negative: the axis would run the wrong way",
                             "a positive number; invert the axis with the drive's polarity (607Eh)")
    if a.get("homing_method") == 0:
        raise InputError(f"{where}.homing_method", "0 is not a homing method lfstudio uses",
                         ", ".join(str(m) for m in HOMING_METHODS))


def load_rig(name: str = DEFAULT_RIG) -> RigConfig:
    presets = load_presets_with_files("rigs")
    if name not in presets:
        raise InputError("rig", f"unknown rig profile {name!r}", ", ".join(presets) or "none installed")
    data, path = presets[name]
    return rig_from_dict(name, data, str(path))


def preset_source(name: str) -> str:
    """The file the rig profile ``name`` comes from ("" when none holds it, or the files cannot be read)."""
    from lfstudio.resources import preset_file

    try:
        return preset_file("rigs", name)
    except InputError:
        return ""


def profile_lines(rig: RigConfig) -> list[str]:
    """The profile as a person reads it, one line per setting, labels and units from the
    descriptions: ``Travel: 4000 mm × 500 mm``, ``Driver: grbl`` (the Rig panel's tooltip)."""
    lines = [f"{RIG_PARAMS[key].label}: {_shown(RIG_PARAMS[key], getattr(rig, key))}"
             for key in ("driver", "homing")]
    h, v = rig.horizontal, rig.vertical
    for key, param in AXIS_PARAMS.items():
        if param.group != "motion" and rig.driver != "cia402":
            continue
        if key == "letter" and rig.driver == "cia402":
            continue
        values = (getattr(h, key), getattr(v, key))
        if values == ("", ""):                     # a file not named (eds_file)
            continue
        lines.append(f"{param.label}: {_shown(param, values[0])} × {_shown(param, values[1])}")
    return lines


def _shown(param: Param, value: Any) -> str:
    if param.flag:
        return "yes" if value else "no"
    text = param.to_text(value)
    unit = param.number.unit if param.number is not None else ""
    return f"{text} {unit}" if unit else text
