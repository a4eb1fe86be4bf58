"""Rig profiles from ``resources/presets/rigs.toml`` (and the user's presets) as :class:`RigConfig`."""

from __future__ import annotations

from lfstudio.errors import InputError
from lfstudio.resources import load_presets
from lfstudio.rig.motion import AxisConfig, RigConfig

DEFAULT_RIG = "Reference gantry"
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
        cfg = AxisConfig(name=axis, letter=str(a["letter"]).upper(), travel_mm=float(a["travel_mm"]),
                         soft_min_mm=float(a["soft_min_mm"]), soft_max_mm=float(a["soft_max_mm"]),
                         max_speed_mm_s=float(a["max_speed_mm_s"]),
                         acceleration_mm_s2=float(a["acceleration_mm_s2"]),
                         repeatability_um=float(a["repeatability_um"]), settle_s=float(a.get("settle_s", 0.3)))
        if not (cfg.soft_min_mm < cfg.soft_max_mm):
            raise InputError(f"rig {name!r} {axis}.soft_max_mm", "must be greater than soft_min_mm")
        if cfg.max_speed_mm_s <= 0 or cfg.acceleration_mm_s2 <= 0 or cfg.travel_mm <= 0:
            raise InputError(f"rig {name!r} {axis}", "travel, speed and acceleration must be positive")
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
