"""One description per parameter, the rig profile (lfstudio.rig.motion AxisConfig / RigConfig): the
profile loader checks every value against its field's description and names the file, the rig, the
field and the allowed range; the Rig panel shows the profile with the descriptions' labels and units."""

from __future__ import annotations

import copy
import re
import dataclasses

import pytest

from lfstudio.errors import InputError
from lfstudio.resources import load_presets
from lfstudio.rig.motion import AxisConfig, RigConfig
from lfstudio.rig.profile import AXIS_PARAMS, DEFAULT_DRIVE_RIG, DEFAULT_RIG, RIG_PARAMS, load_rig, rig_from_dict


def _user_rigs(tmp_path, monkeypatch, text: str):
    monkeypatch.setenv("LFSTUDIO_CONFIG_DIR", str(tmp_path))
    (tmp_path / "presets").mkdir(exist_ok=True)
    path = tmp_path / "presets" / "rigs.toml"
    path.write_text(text)
    return path


def test_every_setting_of_a_profile_is_described():
    axis_fields = [f.name for f in dataclasses.fields(AxisConfig) if f.name != "name"]
    assert list(AXIS_PARAMS) == axis_fields
    assert set(RIG_PARAMS) == {"label", "homing", "driver"}
    for name, param in {**AXIS_PARAMS, **RIG_PARAMS}.items():
        assert param.label and param.tip, name
        assert param.number is not None or param.choices or param.flag or name in ("label", "eds_file"), name
        if param.number is not None:
            assert param.number.unit or name == "homing_method", name
    shipped = load_presets("rigs")
    keys = {k for rig in shipped.values() for axis in ("horizontal", "vertical") for k in rig[axis]}
    assert keys <= set(AXIS_PARAMS)                   # the shipped files use only described keys


@pytest.mark.parametrize("name", [n for n, p in AXIS_PARAMS.items() if p.number is not None])
def test_the_loader_enforces_each_described_range_and_names_file_field_and_range(tmp_path, monkeypatch, name):
    base = copy.deepcopy(load_presets("rigs")[DEFAULT_DRIVE_RIG])
    number = AXIS_PARAMS[name].number
    base["horizontal"][name] = number.high * 2 + 1
    import tomli_w

    path = _user_rigs(tmp_path, monkeypatch, tomli_w.dumps({"Mine": base}))
    with pytest.raises(InputError) as err:
        load_rig("Mine")
    text = str(err.value)
    assert text.startswith(f"{path}: rig 'Mine' horizontal.{name}: "), text
    assert f"(valid: {AXIS_PARAMS[name].valid()})" in text or name == "homing_method", text
    base["horizontal"][name] = number.low if not number.low_open else number.low + 1
    if name in ("travel_mm", "soft_min_mm", "soft_max_mm", "increments_per_mm", "homing_method"):
        return                                        # their lowest value breaks a rule between fields
    path.write_text(tomli_w.dumps({"Mine": base}))
    assert getattr(load_rig("Mine").horizontal, name) == pytest.approx(base["horizontal"][name])


@pytest.mark.parametrize("key, value, words", [
    ("driver", "canbus", "is not one of the choices (valid: grbl, cia402)"),
    ("homing", "yes", "is not true or false"),
    ("label", 5, "is not text"),
])
def test_the_profile_keys_are_checked_against_their_descriptions(key, value, words):
    data = {**copy.deepcopy(load_presets("rigs")[DEFAULT_RIG]), key: value}
    with pytest.raises(InputError, match=f"rig 'x'.{key}: .*{re.escape(words)}"):
        rig_from_dict("x", data)


def test_a_misspelt_or_missing_setting_is_refused_by_name(tmp_path, monkeypatch):
    data = copy.deepcopy(load_presets("rigs")[DEFAULT_RIG])
    data["vertical"]["setle_s"] = 1.0                 # once silently ignored: the settle time stayed 0.3 s
    with pytest.raises(InputError, match=r"rig 'x' vertical.setle_s: unknown setting \(valid: letter, travel_mm"):
        rig_from_dict("x", data)
    del data["vertical"]["setle_s"], data["vertical"]["travel_mm"]
    with pytest.raises(InputError, match=r"vertical.travel_mm: missing .*\(valid: > 0 mm and ≤ 100000 mm\)"):
        rig_from_dict("x", data)
    data = copy.deepcopy(load_presets("rigs")[DEFAULT_RIG])
    data["horizontal"]["letter"] = "q"
    with pytest.raises(InputError, match=r"letter: 'Q' is not one of the choices \(valid: X, Y, Z, A, B, C\)"):
        rig_from_dict("x", data)


def test_every_shipped_profile_loads_and_round_trips_its_values():
    for name, data in load_presets("rigs").items():
        rig = load_rig(name)
        assert isinstance(rig, RigConfig) and rig.label == data.get("label", name)
        for axis in ("horizontal", "vertical"):
            for key, value in data[axis].items():
                got = getattr(getattr(rig, axis), key)
                assert got == (value.upper() if isinstance(value, str) else value), (name, axis, key)
