"""Scene plans from the camera, lens and rig presets in ``resources/presets`` (and the user's own)."""

from __future__ import annotations

from typing import Any

from lfstudio.errors import InputError
from lfstudio.optics import REFERENCE
from lfstudio.planning.scene_plan import ScenePlan
from lfstudio.resources import load_presets
from lfstudio.rig.profile import DEFAULT_RIG, load_rig

REFERENCE_CAMERA = "Sony A7R II (reference)"
REFERENCE_LENS = "50 mm (reference)"


def camera_names() -> list[str]:
    return list(load_presets("cameras"))


def lens_names() -> list[str]:
    return list(load_presets("lenses"))


def camera_fields(name: str) -> dict[str, Any]:
    """ScenePlan fields of the camera preset ``name``."""
    presets = load_presets("cameras")
    if name not in presets:
        raise InputError("camera_name", f"unknown camera {name!r}", ", ".join(presets))
    c = presets[name]
    try:
        return {"camera_name": name, "sensor_px": (int(c["sensor_px"][0]), int(c["sensor_px"][1])),
                "sensor_mm": (float(c["sensor_mm"][0]), float(c["sensor_mm"][1])),
                "pixel_pitch_um": float(c["pixel_pitch_um"]) if "pixel_pitch_um" in c else None,
                "raw_bits": int(c.get("bits", 14))}
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise InputError(f"camera preset {name!r}", f"incomplete ({exc})",
                         "sensor_px = [w, h], sensor_mm = [w, h], pixel_pitch_um, bits")


def lens_fields(name: str) -> dict[str, Any]:
    """ScenePlan fields of the lens preset ``name``."""
    presets = load_presets("lenses")
    if name not in presets:
        raise InputError("lens_name", f"unknown lens {name!r}", ", ".join(presets))
    try:
        return {"lens_name": name, "focal_length_mm": float(presets[name]["focal_length_mm"])}
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"lens preset {name!r}", f"incomplete ({exc})", "focal_length_mm")


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
