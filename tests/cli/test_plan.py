"""``lfstudio plan``: table, JSON keys and values, inverse options, bad input (in-process: parsing, figures and messages)."""

import json
import re

import pytest

KEYS = {"min_distance_m", "f_number_required", "focus_distance_m", "hyperfocal_m", "dof_near_m", "dof_far_m",
        "images", "row_parallax_px", "row_parallax_fraction", "neighbour_disparity_px", "reposition_error_px",
        "fits_travel", "capture_time_s", "storage_bytes", "warnings"}


def test_json_has_the_keys_and_the_worked_check(cli_main):
    proc = cli_main("plan", "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert KEYS <= set(out)
    assert round(out["min_distance_m"], 2) == 1.77
    assert round(out["f_number_required"], 1) == 15.3
    assert out["images"] == 2121
    assert out["row_parallax_fraction"] == pytest.approx(0.20, abs=0.005)
    assert set(out["neighbour_disparity_px"]) == {"horizontal", "vertical"}
    assert all({"field", "message", "severity"} <= set(w) for w in out["warnings"])


def test_options_change_the_figures(cli_main, tmp_path):
    plan_file = tmp_path / "p.toml"
    proc = cli_main("plan", "--json", "--camera-preset", "Nikon Z7 II", "--focal-length-mm", "35", "--near-m", "1",
                   "--far-m", "3", "--f-number", "8", "--grid", "11x3", "--spacing-mm", "2x3",
                   "--repeatability-um", "40x40", "--max-disparity-px", "0.5", "--exposure-s", "1",
                   "--transfer-s", "0.5", "--settle-s", "0.1", "--save", plan_file)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["images"] == 33
    # Z_min = 35 · 40 / (0.5 · 4.35) mm = 0.644 m
    assert out["min_distance_m"] == pytest.approx(35 * 40 / (0.5 * 4.35) / 1000)
    # f/8 < f/22.6 needed: warned on the f-number
    assert out["f_number_required"] == pytest.approx(35 ** 2 / 0.029 * 2000 / (2 * 3000 * 1000) , rel=1e-6)
    assert any(w["field"] == "f_number" for w in out["warnings"])
    # spacing for 0.5 px: 0.5 · s_p / (f · (1/near − 1/far))
    assert out["proposed_spacing_mm"]["horizontal"] == pytest.approx(0.5 * 0.00435 / (35 * (1 / 1000 - 1 / 3000)))
    assert plan_file.is_file() and 'camera_name = "Nikon Z7 II"' in plan_file.read_text()
    again = cli_main("plan", "--json", "--plan", plan_file)
    assert json.loads(again.stdout)["images"] == 33


def test_table_is_readable(cli_main):
    proc = cli_main("plan", "--grid", "51x11")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert any(line.strip().startswith("images") and "51 × 11 = 561" in line for line in lines)
    assert any("f/15.3" in line for line in lines)
    # values start in one column
    rows = [re.match(r"^  (\S.*?)\s{2,}(\S)", line) for line in lines if not line.startswith("  [")]
    starts = {m.start(2) for m in rows if m}
    assert len(starts) == 1


@pytest.mark.parametrize("args, option", [
    (["--near-m", "0"], "--near-m"),
    (["--far-m", "1"], "--far-m"),
    (["--grid", "2000x21"], "--grid"),
    (["--grid", "ten"], "--grid"),
    (["--spacing-mm", "4x-1"], "--spacing-mm"),
    (["--f-number", "nan"], "--f-number"),
    (["--camera", "Nope"], "--camera"),
    (["--near-m", "abc"], "--near-m"),
])
def test_bad_input_exits_2_naming_the_option(cli_main, args, option):
    proc = cli_main("plan", *args)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and option in lines[0]
    assert "Traceback" not in proc.stderr


def test_pairs_are_read_like_every_other_option_and_one_number_sets_both(cli_main):
    """Every AxB option of the plan is read by numbers.parse_numbers: 11x3, 11×3 and 11,3 are the
    same grid; one number sets both values; a value that is not two numbers names the option."""
    from lfstudio.cli import build_parser
    from lfstudio.cli.plan import build_plan

    parser = build_parser()
    for text in ("11x3", "11×3", "11,3"):
        plan = build_plan(parser.parse_args(["plan", "--grid", text]))
        assert (plan.grid_columns, plan.grid_rows) == (11, 3), text
    plan = build_plan(parser.parse_args(["plan", "--spacing-mm", "3", "--repeatability-um", "40x20",
                                         "--sensor-px", "4000x3000"]))
    assert plan.spacing_mm == (3.0, 3.0) and plan.repeatability_um == (40.0, 20.0)
    assert plan.sensor_px == (4000, 3000) and plan.camera_name == "custom camera"
    for option, value, example in (("--grid", "ten", "101x21"), ("--sensor-px", "100x", "7952x5304"),
                                   ("--travel-mm", "1x2x3", "4x6"), ("--grid", "11.5x3", "")):
        proc = cli_main("plan", option, value)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1 and option in lines[0], proc.stderr
        assert example in lines[0]
