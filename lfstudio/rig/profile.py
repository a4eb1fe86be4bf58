"""Rig profiles from ``resources/presets/rigs.toml`` (and the user's presets) as :class:`RigConfig`.

Every number is checked (:mod:`lfstudio.numbers`): finite, in range, and the soft limits inside the
axis's travel (the rig's frame runs from 0 to ``travel_mm``), so no profile can let a target beyond
the travel through to the controller."""

from __future__ import annotations

from lfstudio.errors import InputError
from lfstudio.numbers import SETTLE_S, Number
from lfstudio.resources import load_presets
from lfstudio.rig.motion import AxisConfig, RigConfig

DEFAULT_RIG = "Reference gantry"
#: the CiA 402 profile the drive emulators (sim-dryve, sim-canopen, lfstudio sim-drive) start with
DEFAULT_DRIVE_RIG = "dryve D1 gantry 4 m x 0.5 m"
AXIS_LETTERS = ("X", "Y", "Z", "A", "B", "C")
TRAVEL_MM = Number("mm", 0, 100_000, low_open=True)
#: from a crawl (homing at 1e-300 mm/s never ended) to faster than any gantry
SPEED_MM_S = Number("mm/s", 0.01, 10_000)
ACCELERATION_MM_S2 = Number("mm/s²", 0.01, 1_000_000)
REPEATABILITY_UM = Number("µm", 0, 100_000)
DRIVERS = ("grbl", "cia402")
#: CiA 402 homing methods (6098h) lfstudio drives: limit switch at the low / high end, current position
HOMING_METHODS = (17, 18, 35, 37)
INCREMENTS_PER_MM = Number("increments/mm", -1e9, 1e9)
_AXIS_KEYS = ("letter", "travel_mm", "soft_min_mm", "soft_max_mm", "max_speed_mm_s",
              "acceleration_mm_s2", "repeatability_um")


def rig_names() -> list[str]:
    return list(load_presets("rigs"))


def rig_from_dict(name: str, data: dict) -> RigConfig:
    """A checked :class:`RigConfig`. ``driver = "cia402"`` (one CiA 402 drive per axis): each axis
    names ``increments_per_mm`` (the feed constant, positive) and ``homing_method`` (6098h: 17, 18,
    35 or 37); its ``letter`` is optional (the drives are told apart by their addresses)."""
    driver = str(data.get("driver", "grbl")).lower()
    if driver not in DRIVERS:
        raise InputError(f"rig {name!r}.driver", f"unknown driver {data.get('driver')!r}", ", ".join(DRIVERS))
    axes = {}
    for axis in ("horizontal", "vertical"):
        a = data.get(axis)
        if not isinstance(a, dict):
            raise InputError(f"rig {name!r}", f"missing [{axis}] table", "letter, travel_mm, soft limits, speed, ...")
        if driver == "cia402":
            a = {"letter": "X" if axis == "horizontal" else "Y", **a}
        missing = [k for k in _AXIS_KEYS if k not in a]
        if missing:
            raise InputError(f"rig {name!r} {axis}", f"missing {', '.join(missing)}")
        where = f"rig {name!r} {axis}"
        letter = str(a["letter"]).upper()
        if letter not in AXIS_LETTERS:
            raise InputError(f"{where}.letter", f"{a['letter']!r} is not a controller axis", ", ".join(AXIS_LETTERS))
        travel = TRAVEL_MM.check(f"{where}.travel_mm", a["travel_mm"])
        soft = Number("mm", 0, travel)           # the rig's frame: 0 at one end of the travel, travel_mm at the other
        cfg = AxisConfig(name=axis, letter=letter, travel_mm=travel,
                         soft_min_mm=soft.check(f"{where}.soft_min_mm", a["soft_min_mm"]),
                         soft_max_mm=soft.check(f"{where}.soft_max_mm", a["soft_max_mm"]),
                         max_speed_mm_s=SPEED_MM_S.check(f"{where}.max_speed_mm_s", a["max_speed_mm_s"]),
                         acceleration_mm_s2=ACCELERATION_MM_S2.check(f"{where}.acceleration_mm_s2",
                                                                     a["acceleration_mm_s2"]),
                         repeatability_um=REPEATABILITY_UM.check(f"{where}.repeatability_um", a["repeatability_um"]),
                         settle_s=SETTLE_S.check(f"{where}.settle_s", a.get("settle_s", 0.3)),
                         **(_drive_fields(where, a) if driver == "cia402" else {}))
        if not (cfg.soft_min_mm < cfg.soft_max_mm):
            raise InputError(f"{where}.soft_max_mm", "must be greater than soft_min_mm")
        axes[axis] = cfg
    if axes["horizontal"].letter == axes["vertical"].letter:
        raise InputError(f"rig {name!r}", "horizontal and vertical axes need different controller letters")
    return RigConfig(name=name, horizontal=axes["horizontal"], vertical=axes["vertical"],
                     label=str(data.get("label", name)), homing=bool(data.get("homing", True)), driver=driver)


def _drive_fields(where: str, a: dict) -> dict:
    """A CiA 402 axis's feed constant and homing method, checked."""
    if "increments_per_mm" not in a:
        raise InputError(f"{where}.increments_per_mm", "missing: the feed constant (drive position units per mm) "
                         "converts mm to the drive's increments", "a positive number, e.g. 100")
    k = INCREMENTS_PER_MM.check(f"{where}.increments_per_mm", a["increments_per_mm"])
    if k == 0:
        raise InputError(f"{where}.increments_per_mm", "0: no position could be converted to the drive's "
                         "increments", "a positive number, e.g. 100 for a drive counting 0.01 mm")
    if k < 0:
        raise InputError(f"{where}.increments_per_mm", f"{k:g} is negative: the axis would run the wrong way",
                         "a positive number; invert the axis with the drive's polarity (607Eh)")
    method = a.get("homing_method", 17)
    if isinstance(method, bool) or method not in HOMING_METHODS:
        raise InputError(f"{where}.homing_method", f"{method!r} is not a homing method lfstudio uses",
                         "17 (negative limit switch), 18 (positive limit switch), 35/37 (current position)")
    return {"increments_per_mm": k, "homing_method": int(method)}


def load_rig(name: str = DEFAULT_RIG) -> RigConfig:
    presets = load_presets("rigs")
    if name not in presets:
        raise InputError("rig", f"unknown rig profile {name!r}", ", ".join(presets) or "none installed")
    return rig_from_dict(name, presets[name])
