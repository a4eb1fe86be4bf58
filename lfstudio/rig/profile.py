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
AXIS_LETTERS = ("X", "Y", "Z", "A", "B", "C")
TRAVEL_MM = Number("mm", 0, 100_000, low_open=True)
SPEED_MM_S = Number("mm/s", 0, 10_000, low_open=True)
ACCELERATION_MM_S2 = Number("mm/s²", 0, 1_000_000, low_open=True)
REPEATABILITY_UM = Number("µm", 0, 100_000)
_AXIS_KEYS = ("letter", "travel_mm", "soft_min_mm", "soft_max_mm", "max_speed_mm_s",
              "acceleration_mm_s2", "repeatability_um")


def rig_names() -> list[str]:
    return list(load_presets("rigs"))


def rig_from_dict(name: str, data: dict) -> RigConfig:
    axes = {}
    for axis in ("horizontal", "vertical"):
        a = data.get(axis)
        if not isinstance(a, dict):
            raise InputError(f"rig {name!r}", f"missing [{axis}] table", "letter, travel_mm, soft limits, speed, ...")
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
                         settle_s=SETTLE_S.check(f"{where}.settle_s", a.get("settle_s", 0.3)))
        if not (cfg.soft_min_mm < cfg.soft_max_mm):
            raise InputError(f"{where}.soft_max_mm", "must be greater than soft_min_mm")
        axes[axis] = cfg
    if axes["horizontal"].letter == axes["vertical"].letter:
        raise InputError(f"rig {name!r}", "horizontal and vertical axes need different controller letters")
    return RigConfig(name=name, horizontal=axes["horizontal"], vertical=axes["vertical"],
                     label=str(data.get("label", name)), homing=bool(data.get("homing", True)))


def load_rig(name: str = DEFAULT_RIG) -> RigConfig:
    presets = load_presets("rigs")
    if name not in presets:
        raise InputError("rig", f"unknown rig profile {name!r}", ", ".join(presets) or "none installed")
    return rig_from_dict(name, presets[name])
