"""One description per parameter, the camera and lens presets (lfstudio.planning.presets CameraPreset,
LensPreset): each key is checked by its description (the scene plan's own for the keys that set the
plan), and a bad preset is one line naming the file, the preset, the key and what it may hold."""

from __future__ import annotations

import dataclasses
import re

import pytest
import tomli_w

from lfstudio.errors import InputError
from lfstudio.planning.presets import (CAMERA_PARAMS, LENS_PARAMS, CameraPreset, LensPreset, camera_fields,
                                       camera_names, lens_fields, lens_names, load_preset)
from lfstudio.planning.scene_plan import PARAMS as PLAN_PARAMS
from lfstudio.resources import load_presets

#: preset key -> the plan field it sets
PLAN_FIELD = {"sensor_px": "sensor_px", "sensor_mm": "sensor_mm", "pixel_pitch_um": "pixel_pitch_um",
              "bits": "raw_bits", "focal_length_mm": "focal_length_mm"}


def _user(tmp_path, monkeypatch, kind: str, presets: dict):
    monkeypatch.setenv("LFSTUDIO_CONFIG_DIR", str(tmp_path))
    (tmp_path / "presets").mkdir(exist_ok=True)
    path = tmp_path / "presets" / f"{kind}.toml"
    path.write_text(tomli_w.dumps(presets))
    return path


def test_every_preset_key_is_described_and_agrees_with_the_plan():
    assert list(CAMERA_PARAMS) == [f.name for f in dataclasses.fields(CameraPreset)]
    assert list(LENS_PARAMS) == [f.name for f in dataclasses.fields(LensPreset)]
    for key, param in {**CAMERA_PARAMS, **LENS_PARAMS}.items():
        assert param.label and param.tip, key
        if key in PLAN_FIELD:          # a preset holds exactly what the plan accepts
            plan = PLAN_PARAMS[PLAN_FIELD[key]]
            assert (param.number, param.pair, param.label) == (plan.number, plan.pair, plan.label), key
    for kind, params in (("cameras", CAMERA_PARAMS), ("lenses", LENS_PARAMS)):
        for name, data in load_presets(kind).items():
            assert set(data) <= set(params), (kind, name)          # the shipped files use described keys only
    for name in camera_names():
        fields = camera_fields(name)
        assert PLAN_PARAMS["sensor_px"].check("sensor_px", fields["sensor_px"]) == fields["sensor_px"]
    assert [lens_fields(n)["focal_length_mm"] for n in lens_names()] == \
        [load_presets("lenses")[n]["focal_length_mm"] for n in lens_names()]


@pytest.mark.parametrize("key", [k for k, p in CAMERA_PARAMS.items() if p.number is not None])
def test_a_bad_camera_value_names_file_preset_key_and_range(tmp_path, monkeypatch, key):
    data = dict(load_presets("cameras")["Sony A7R II (reference)"])
    param = CAMERA_PARAMS[key]
    bad = param.number.high * 2 + 1
    data[key] = [bad, bad] if param.pair else bad
    path = _user(tmp_path, monkeypatch, "cameras", {"Mine": data})
    with pytest.raises(InputError) as err:
        camera_fields("Mine")
    assert str(err.value).startswith(f"{path}: camera preset 'Mine'.{key}: "), str(err.value)
    assert f"(valid: {param.valid()})" in str(err.value)


@pytest.mark.parametrize("data, words", [
    ({"sensor_px": [7952, 5304]}, "camera preset 'Mine'.sensor_mm: missing (Sensor size in mm"),
    ({"sensor_px": "7952x5304", "sensor_mm": [35.9, 24.0]}, "sensor_px: '7952x5304' is not a pair"),
    ({"sensor_px": [7952, 5304.5], "sensor_mm": [35.9, 24.0]}, "sensor_px: 5304.5 px is not a whole number"),
    ({"sensor_px": [7952, 5304], "sensor_mm": [35.9, 24.0], "bit": 14}, "'Mine'.bit: unknown setting (valid: sensor_px"),
    ({"sensor_px": [7952, 5304], "sensor_mm": [35.9, 24.0], "raw_format": 3}, "raw_format: 3 is not text"),
])
def test_a_bad_camera_preset_is_one_line_with_the_fix(tmp_path, monkeypatch, data, words):
    _user(tmp_path, monkeypatch, "cameras", {"Mine": data})
    with pytest.raises(InputError, match=re.escape(words)):
        load_preset("cameras", "Mine")


def test_a_bad_lens_preset_is_one_line_with_the_fix(tmp_path, monkeypatch):
    path = _user(tmp_path, monkeypatch, "lenses", {"Mine": {"focal_length_mm": 0.5}, "Other": {"focal_mm": 50}})
    with pytest.raises(InputError, match=re.escape(f"{path}: lens preset 'Mine'.focal_length_mm: 0.5 mm is out of "
                                                   "range (valid: 1 … 2000 mm)")):
        lens_fields("Mine")
    with pytest.raises(InputError, match=r"'Other'.focal_mm: unknown setting \(valid: focal_length_mm, lensfun_maker"):
        lens_fields("Other")
    with pytest.raises(InputError, match="lens_name: unknown lens 'Nope'"):
        lens_fields("Nope")
