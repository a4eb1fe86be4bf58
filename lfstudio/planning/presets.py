"""Scene plans from the camera, lens and rig presets in ``resources/presets`` (and the user's own)."""

from __future__ import annotations

from dataclasses import MISSING, dataclass, replace
from typing import Any

from lfstudio.errors import InputError
from lfstudio.numbers import Param, load_described, params_of
from lfstudio.optics import REFERENCE
from lfstudio.planning.scene_plan import PARAMS as PLAN_PARAMS
from lfstudio.planning.scene_plan import ScenePlan
from lfstudio.resources import load_presets, load_presets_with_files
from lfstudio.rig.profile import DEFAULT_RIG, load_rig

REFERENCE_CAMERA = "Sony A7R II (reference)"
REFERENCE_LENS = "50 mm (reference)"


def _as_plan(name: str, default: Any, **change: Any) -> Any:
    """The description of a preset key that sets the plan's field ``name``: the plan's own (same range,
    unit, label and tip, so a preset can never hold what the plan refuses), ``change`` on top."""
    from dataclasses import field as dataclass_field

    from lfstudio.numbers import PARAM

    param: Param = replace(PLAN_PARAMS[name], option="", metavar="", group="", **change)
    return dataclass_field(default=default, metadata={PARAM: param})


def _text(tip: str) -> Any:
    from lfstudio.numbers import described

    return described("", label=tip.split(":")[0], tip=tip)


@dataclass(frozen=True)
class CameraPreset:
    """A camera preset (``resources/presets/cameras.toml`` and the user's): each key described once,
    the plan's keys by the plan's own description."""

    sensor_px: tuple[int, int] = _as_plan("sensor_px", MISSING)
    sensor_mm: tuple[float, float] = _as_plan("sensor_mm", MISSING)
    pixel_pitch_um: float | None = _as_plan("pixel_pitch_um", None, optional="sensor mm / px")
    bits: int = _as_plan("raw_bits", 14)
    raw_format: str = _text("Raw format: the camera's raw file type (ARW, CR2, NEF, DNG, …)")


@dataclass(frozen=True)
class LensPreset:
    """A lens preset (``resources/presets/lenses.toml`` and the user's)."""

    focal_length_mm: float = _as_plan("focal_length_mm", MISSING)
    lensfun_maker: str = _text("Lensfun maker: the lens database's name of the maker (distortion/CA profiles)")
    lensfun_model: str = _text("Lensfun model: the lens database's name of the lens")


CAMERA_PARAMS: dict[str, Param] = params_of(CameraPreset)
LENS_PARAMS: dict[str, Param] = params_of(LensPreset)
#: how each kind of preset is read: (its class, what it is called in messages, the plan's preset field)
_KINDS = {"cameras": (CameraPreset, "camera preset", "camera_name"),
          "lenses": (LensPreset, "lens preset", "lens_name")}


def camera_names() -> list[str]:
    return list(load_presets("cameras"))


def lens_names() -> list[str]:
    return list(load_presets("lenses"))


def load_preset(kind: str, name: str) -> Any:
    """The camera or lens preset ``name`` (``kind``: "cameras", "lenses"), every key checked by its
    description; a bad value is one line naming the file, the preset, the key and its range (the fix)."""
    cls, what, field = _KINDS[kind]
    presets = load_presets_with_files(kind)
    if name not in presets:
        raise InputError(field, f"unknown {what.split()[0]} {name!r}", ", ".join(presets))
    data, path = presets[name]
    where = f"{path}: {what} {name!r}"
    values = load_described(cls, data, lambda key: f"{where}.{key}" if key else where)
    return cls(**values)


def camera_fields(name: str) -> dict[str, Any]:
    """ScenePlan fields of the camera preset ``name``."""
    camera: CameraPreset = load_preset("cameras", name)
    return {"camera_name": name, "sensor_px": camera.sensor_px, "sensor_mm": camera.sensor_mm,
            "pixel_pitch_um": camera.pixel_pitch_um, "raw_bits": camera.bits}


def lens_fields(name: str) -> dict[str, Any]:
    """ScenePlan fields of the lens preset ``name``."""
    lens: LensPreset = load_preset("lenses", name)
    return {"lens_name": name, "focal_length_mm": lens.focal_length_mm}


def rig_fields(name: str) -> dict[str, Any]:
    """ScenePlan fields of the rig profile ``name`` (repeatability, travel, speed, acceleration, settle)."""
    try:
        rig = load_rig(name)
    except InputError as exc:
        raise InputError("rig_name", str(exc).split(": ", 1)[-1]) from None
    h, v = rig.horizontal, rig.vertical
    return {"rig_name": name, "repeatability_um": (h.repeatability_um, v.repeatability_um),
            "travel_mm": (h.soft_max_mm - h.soft_min_mm, v.soft_max_mm - v.soft_min_mm),
            "max_speed_mm_s": (h.max_speed_mm_s, v.max_speed_mm_s),
            "acceleration_mm_s2": (h.acceleration_mm_s2, v.acceleration_mm_s2),
            "settle_s": max(h.settle_s, v.settle_s)}


def plan_from_presets(camera: str | None = REFERENCE_CAMERA, lens: str | None = REFERENCE_LENS,
                      rig: str | None = DEFAULT_RIG, base: ScenePlan | None = None, **overrides: Any) -> ScenePlan:
    """A plan with the named presets' fields (None: keep ``base``'s), then ``overrides``."""
    fields: dict[str, Any] = {}
    if camera is not None:
        fields.update(camera_fields(camera))
    if lens is not None:
        fields.update(lens_fields(lens))
    if rig is not None:
        fields.update(rig_fields(rig))
    fields.update(overrides)
    return (base or ScenePlan()).replace(**fields)


def reference_plan() -> ScenePlan:
    """The paper's setup: Sony A7R II with a 50 mm lens on the reference gantry, scene 1.77–4.77 m,
    c = 0.029 mm, 101 × 21 views at 4 mm × 6 mm."""
    return plan_from_presets(REFERENCE_CAMERA, REFERENCE_LENS, DEFAULT_RIG, near_m=REFERENCE.near_m,
                             far_m=REFERENCE.far_m, coc_mm=REFERENCE.coc_mm, grid_columns=REFERENCE.grid[0],
                             grid_rows=REFERENCE.grid[1], spacing_mm=REFERENCE.spacing_mm)
