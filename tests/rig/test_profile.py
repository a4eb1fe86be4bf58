import pytest

from lfstudio.errors import InputError
from lfstudio.resources import load_presets
from lfstudio.rig.profile import DEFAULT_RIG, load_rig, rig_names


def test_reference_rig_profile():
    rig = load_rig(DEFAULT_RIG)
    assert rig.horizontal.travel_mm == 4000 and rig.vertical.travel_mm == 500
    assert rig.horizontal.repeatability_um == 80 and rig.vertical.repeatability_um == 50
    assert rig.horizontal.contains(4000) and not rig.horizontal.contains(4000.01)


def test_reference_camera_and_lens_presets():
    cam = load_presets("cameras")["Sony A7R II (reference)"]
    assert cam["sensor_px"] == [7952, 5304] and cam["pixel_pitch_um"] == pytest.approx(4.53)
    assert load_presets("lenses")["50 mm (reference)"]["focal_length_mm"] == 50


def test_user_presets_override_and_bad_file(tmp_path, monkeypatch):
    monkeypatch.setenv("LFSTUDIO_CONFIG_DIR", str(tmp_path))
    (tmp_path / "presets").mkdir()
    (tmp_path / "presets" / "lenses.toml").write_text('["35 mm"]\nfocal_length_mm = 36.0\n["Mine"]\nfocal_length_mm = 12.0\n')
    lenses = load_presets("lenses")
    assert lenses["35 mm"]["focal_length_mm"] == 36.0 and lenses["Mine"]["focal_length_mm"] == 12.0
    (tmp_path / "presets" / "rigs.toml").write_text("not = [toml")
    with pytest.raises(InputError, match="rigs.toml"):
        rig_names()


def test_unknown_rig_names_choices():
    with pytest.raises(InputError, match="Reference gantry"):
        load_rig("nope")
