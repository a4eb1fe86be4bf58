"""ScenePlan: validation, derived outputs (SPEC worked check), warnings, files, manifest dicts."""

import json
import math

import pytest

from lfstudio.errors import InputError
from lfstudio import optics
from lfstudio.planning.presets import camera_names, plan_from_presets, reference_plan
from lfstudio.planning.scene_plan import PLAN_VERSION, ScenePlan, capture_time_s, load_plan, save_plan


def test_reference_plan_reproduces_spec_worked_check():
    r = reference_plan().derive()
    assert r.pixel_pitch_um == 4.53
    assert round(r.min_distance_m, 2) == 1.77 and r.min_distance_axis == "horizontal"
    assert round(r.f_number_required, 1) == 15.3
    assert r.images == 2121
    assert r.row_parallax_fraction == pytest.approx(0.20, abs=0.005)
    assert r.scene_sharp and r.dof_near_m == pytest.approx(1.77) and r.dof_far_m == pytest.approx(4.77)
    assert r.fits_travel
    # the near distance 1.77 m is just beyond Z_min = 1.766 m: no repositioning warning
    assert r.reposition_error_px["horizontal"] == pytest.approx(0.4989, abs=1e-4)
    assert r.reposition_error_px["vertical"] == pytest.approx(0.4989 * 50 / 80, abs=1e-4)
    assert not r.warnings_for("near_m")
    assert r.neighbour_disparity_px["horizontal"] == pytest.approx(15.688, abs=1e-3)
    assert r.neighbour_disparity_px["vertical"] == pytest.approx(15.688 * 1.5, abs=1e-3)
    assert r.neighbour_disparity_near_px["horizontal"] == pytest.approx(200 / 0.00453 / 1770)
    # 14-bit raw in 16-bit words
    assert r.bytes_per_image == 7952 * 5304 * 2 and r.storage_bytes == 2121 * 7952 * 5304 * 2


def test_capture_time_is_the_meander_sum():
    p = reference_plan().replace(grid_columns=5, grid_rows=3, transfer_s=0.1, exposure_s=0.2, settle_s=0.05)
    # walk the meander path view by view
    pos, total = None, 0.0
    for r in range(3):
        cols = range(5) if r % 2 == 0 else range(4, -1, -1)
        for c in cols:
            x, y = c * p.spacing_mm[0], r * p.spacing_mm[1]
            if pos is None:
                move = 0.0
            elif y != pos[1]:
                move = optics.move_time_s(y - pos[1], p.max_speed_mm_s[1], p.acceleration_mm_s2[1])
            else:
                move = optics.move_time_s(x - pos[0], p.max_speed_mm_s[0], p.acceleration_mm_s2[0])
            if pos is None:     # the first view: no earlier transfer to overlap
                total += move + p.settle_s + p.exposure_s
            else:
                total += optics.view_period_s(move, p.settle_s, p.exposure_s, p.transfer_s)
            pos = (x, y)
    total += p.transfer_s
    assert capture_time_s(p) == pytest.approx(total)
    # with the reference timing the transfer (2.5 s) dominates every step after the first (settle
    # 0.3 s + exposure 0.5 s): 3.0 s per view
    ref = reference_plan()
    assert capture_time_s(ref) == pytest.approx(0.3 + 0.5 + 3.0 * 2120 + 2.5)
    # the scan plan of the same grid estimates the same time (one estimate, lfstudio.optics.scan_duration_s)
    from lfstudio.rig.profile import load_rig
    from lfstudio.scan.scan_plan import ScanPlan

    rig = load_rig()
    scan = ScanPlan(5, 3, p.spacing_mm, settle_s=p.settle_s)
    same_rig = p.replace(max_speed_mm_s=(rig.horizontal.max_speed_mm_s, rig.vertical.max_speed_mm_s),
                         acceleration_mm_s2=(rig.horizontal.acceleration_mm_s2, rig.vertical.acceleration_mm_s2))
    assert scan.estimate_duration_s(rig, p.exposure_s, p.transfer_s) == pytest.approx(capture_time_s(same_rig))


@pytest.mark.parametrize("changes, field", [
    ({"near_m": 0}, "near_m"),
    ({"near_m": -1}, "near_m"),
    ({"far_m": 1.5}, "far_m"),
    ({"focal_length_mm": 0}, "focal_length_mm"),
    ({"coc_mm": 0}, "coc_mm"),
    ({"f_number": 0.1}, "f_number"),
    ({"grid_columns": 0}, "grid_columns"),
    ({"grid_rows": 2.5}, "grid_rows"),
    ({"spacing_mm": (4.0, 0.0)}, "spacing_mm"),
    ({"sensor_px": (0, 100)}, "sensor_px"),
    ({"pixel_pitch_um": float("nan")}, "pixel_pitch_um"),
    ({"grid_columns": 2000}, "grid_columns"),       # 7996 mm > 4000 mm travel
    ({"grid_rows": 100}, "grid_rows"),              # 594 mm > 500 mm
    ({"max_error_px": 0}, "max_error_px"),
])
def test_invalid_input_names_the_field_and_range(changes, field):
    with pytest.raises(InputError) as info:
        reference_plan().replace(**changes).derive()
    assert info.value.field == field
    assert info.value.valid


def test_grid_beyond_travel_can_be_derived_as_error_warning():
    r = reference_plan().replace(grid_columns=2000).derive(check_travel=False)
    assert not r.fits_travel
    (w,) = r.warnings_for("grid_columns")
    assert w.severity == "error" and "1001 columns" in w.message


def test_warnings_for_soft_problems():
    base = reference_plan()
    r = base.replace(near_m=1.2, far_m=3.0).derive()
    (w,) = r.warnings_for("near_m")
    assert "1.77 m" in w.message and r.reposition_error_px["horizontal"] > 0.5
    r = base.replace(f_number=8.0).derive()
    assert not r.scene_sharp
    assert any("f/15.3" in w.message for w in r.warnings_for("f_number"))
    r = base.replace(f_number=32.0).derive()              # Airy 43 µm > c 29 µm
    assert any(w.severity == "warning" and "Airy" in w.message for w in r.warnings_for("f_number"))
    r = base.replace(focus_m=8.0).derive()                 # beyond H = 5.63 m
    assert r.dof_far_m == math.inf
    assert any("hyperfocal" in w.message for w in r.warnings_for("focus_m"))
    r = base.replace(pixel_pitch_um=9.06).derive()         # the paper's "Bayer" pitch: inconsistent
    assert r.warnings_for("pixel_pitch_um")


def test_pixel_pitch_derived_from_sensor_when_not_given():
    p = reference_plan().replace(pixel_pitch_um=None)
    assert p.pixel_pitch_used_um == pytest.approx(35.9 / 7952 * 1000)
    assert p.camera_dict()["pixel_pitch_um"] == pytest.approx(4.5146, abs=1e-3)


def test_inverse_outputs():
    r = reference_plan().replace(max_disparity_px=1.0, target_parallax_fraction=0.2).derive()
    # spacing for 1 px between 1.77 m and 4.77 m: 4 mm / 15.688
    assert r.proposed_spacing_mm["horizontal"] == pytest.approx(4 / 15.688, rel=1e-4)
    assert r.proposed_grid.columns == 103    # 0.2 · 7952 / 15.688 = 101.4 steps → 102 steps
    p2 = reference_plan().replace(spacing_mm=(r.proposed_spacing_mm["horizontal"], 6.0)).derive()
    assert p2.neighbour_disparity_px["horizontal"] == pytest.approx(1.0)


def test_manifest_dicts():
    p = reference_plan()
    assert p.camera_dict() == {"name": "Sony A7R II (reference)", "sensor_px": [7952, 5304],
                               "sensor_mm": [35.9, 24.0], "pixel_pitch_um": 4.53}
    assert p.lens_dict() == {"name": "50 mm (reference)", "focal_length_mm": 50.0}
    assert p.grid_dict() == {"columns": 101, "rows": 21, "spacing_mm": [4.0, 6.0], "order": "row-meander"}


def test_dict_round_trip_and_json_safe():
    p = reference_plan().replace(f_number=11.0, focus_m=None, target_parallax_fraction=0.1)
    d = p.to_dict()
    assert d["format"] == "lfstudio-plan" and d["version"] == PLAN_VERSION and "focus_m" not in d
    assert ScenePlan.from_dict(json.loads(json.dumps(d))) == p
    json.dumps(p.derive().to_dict(), allow_nan=False)
    json.dumps(p.replace(focus_m=9.0).derive().to_dict(), allow_nan=False)   # infinite far limit → null


@pytest.mark.parametrize("name", ["plan.toml", "plan.json"])
def test_plan_file_round_trip(tmp_path, name):
    p = plan_from_presets("Nikon Z7 II", "85 mm", "Desktop slider 1 m", near_m=2.5, far_m=6.0,
                          grid_columns=31, grid_rows=5, spacing_mm=(2.0, 3.0), f_number=16.0)
    save_plan(tmp_path / name, p)
    assert load_plan(tmp_path / name) == p
    assert not list(tmp_path.glob(".*tmp*"))    # atomic write left no temporary behind


def test_bad_plan_files_name_the_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("near_m = [1, 2]\n")
    with pytest.raises(InputError, match="bad.toml"):
        load_plan(bad).derive()
    newer = tmp_path / "newer.json"
    newer.write_text(json.dumps({"format": "lfstudio-plan", "version": PLAN_VERSION + 1}))
    with pytest.raises(InputError, match="newer"):
        load_plan(newer)
    with pytest.raises(InputError, match="missing.toml"):
        load_plan(tmp_path / "missing.toml")


def test_presets_fill_the_plan():
    assert "Sony A7R II (reference)" in camera_names()
    p = plan_from_presets("Fujifilm GFX 100S", "35 mm", "Desktop slider 1 m")
    assert p.sensor_px == (11648, 8736) and p.raw_bits == 16 and p.focal_length_mm == 35.0
    assert p.repeatability_um == (20.0, 20.0) and p.travel_mm == (1000.0, 300.0) and p.settle_s == 0.5
    with pytest.raises(InputError) as info:
        plan_from_presets(camera="No such camera")
    assert info.value.field == "camera_name"


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

pos = st.floats(min_value=1e-3, max_value=1e5, allow_nan=False)
pair = st.tuples(pos, pos)


@settings(max_examples=80, deadline=None)
@given(near=pos, far=pos, f=st.floats(min_value=1, max_value=2000), coc=st.floats(min_value=0.001, max_value=1),
       fnum=st.one_of(st.none(), st.floats(min_value=0, max_value=128)), focus=st.one_of(st.none(), pos),
       cols=st.integers(min_value=1, max_value=100_000), rows=st.integers(min_value=1, max_value=100_000),
       spacing=pair, travel=pair, speed=pair, accel=pair)
def test_any_input_derives_or_names_a_field(near, far, f, coc, fnum, focus, cols, rows, spacing, travel, speed, accel):
    plan = ScenePlan(near_m=near, far_m=far, focal_length_mm=f, coc_mm=coc, f_number=fnum, focus_m=focus,
                     grid_columns=cols, grid_rows=rows, spacing_mm=spacing, travel_mm=travel,
                     max_speed_mm_s=speed, acceleration_mm_s2=accel)
    try:
        r = plan.derive(check_travel=False)
    except InputError as exc:
        assert exc.field in {f.name for f in __import__("dataclasses").fields(ScenePlan)}
        return
    json.dumps(r.to_dict(), allow_nan=False)
    assert r.images == cols * rows and r.capture_time_s > 0


def test_the_shipped_presets_describe_the_reference_setup():
    """ScenePlan's defaults are lfstudio.optics.REFERENCE; the reference camera, lens and gantry
    presets (resources/presets) must say the same, field by field."""
    import dataclasses

    from lfstudio.optics import REFERENCE

    ref, defaults = reference_plan(), ScenePlan()
    assert {f.name: getattr(ref, f.name) for f in dataclasses.fields(ScenePlan)} == \
        {f.name: getattr(defaults, f.name) for f in dataclasses.fields(ScenePlan)}
    assert (defaults.sensor_px, defaults.focal_length_mm, defaults.grid_columns, defaults.grid_rows,
            defaults.transfer_s) == (REFERENCE.sensor_px, REFERENCE.focal_length_mm, *REFERENCE.grid, REFERENCE.transfer_s)


def test_the_proposed_grid_is_the_dataset_model_at_the_plan_spacing():
    from lfstudio.dataset.grid import Grid

    plan = reference_plan().replace(target_parallax_fraction=0.2)
    r = plan.derive()
    assert isinstance(r.proposed_grid, Grid)
    assert (r.proposed_grid.columns, r.proposed_grid.spacing_mm, r.proposed_grid.order) == \
        (103, plan.grid.spacing_mm, plan.grid.order)
    assert plan.replace(grid_columns=r.proposed_grid.columns, grid_rows=r.proposed_grid.rows).derive() \
        .row_parallax_fraction >= 0.2
    out = r.to_dict()["proposed_grid"]
    assert Grid.from_manifest(out) == r.proposed_grid and out["columns"] == 103
    assert reference_plan().derive().to_dict()["proposed_grid"] is None
