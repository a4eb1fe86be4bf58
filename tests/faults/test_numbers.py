"""Fault matrix, numbers: NaN, infinities, huge, negative and malformed values in every numeric field
(CLI options, rig and processing profiles, scene plans, the manifest) are refused with one line naming
the field and the valid range with its unit, exit status 2 for bad input, before any device is
opened, any file written or anything allocated."""

from __future__ import annotations

import json
import os
import select
import tty

import pytest

from lfstudio.numbers import MAX_VIEWS, Number, check_grid, non_finite_fields, parse_numbers
from lfstudio.errors import InputError
from tests.faults.conftest import assert_one_line_error, manifest_of, write_manifest

BAD = {"nan": "nan", "inf": "inf", "-inf": "-inf", "huge": "1e300", "negative": "-3"}


@pytest.fixture
def pty_port():
    """A real pseudo-terminal handed to ``--port``: ``sent()`` is every byte lfstudio wrote to it."""
    master, slave = os.openpty()
    tty.setraw(slave)
    name = os.ttyname(slave)

    class Port:
        path = name

        @staticmethod
        def sent() -> bytes:
            data = b""
            while select.select([master], [], [], 0)[0]:
                chunk = os.read(master, 4096)
                if not chunk:
                    break
                data += chunk
            return data

    yield Port
    os.close(master)
    os.close(slave)


# -- CLI options: (command and its other arguments, option, value, what the line must name) ------------------
SCAN = ("scan", "--camera", "instant")
CLI_CASES = [
    (SCAN, "--time-scale", "nan"), (SCAN, "--time-scale", "inf"), (SCAN, "--time-scale", "-1"),
    (SCAN, "--time-scale", "1e300"),
    (SCAN, "--retries", "-3"), (SCAN, "--retries", "1e9"), (SCAN, "--retries", "nan"), (SCAN, "--retries", "2.5"),
    (SCAN, "--exposure-s", "nan"), (SCAN, "--exposure-s", "-1"), (SCAN, "--exposure-s", "inf"),
    (SCAN, "--transfer-s", "nan"), (SCAN, "--transfer-s", "1e300"),
    (SCAN, "--settle-s", "1e300"), (SCAN, "--settle-s", "nan"), (SCAN, "--settle-s", "-1"),
    (SCAN, "--sim-width-px", "0"), (SCAN, "--sim-width-px", "1000000000"), (SCAN, "--seed", "-1"),
    (SCAN, "--grid", "100000000x1"), (SCAN, "--grid", "0x3"), (SCAN, "--grid", "nanx2"),
    (SCAN, "--spacing-mm", "1e-9x6"), (SCAN, "--spacing-mm", "nanx6"), (SCAN, "--spacing-mm", "infx6"),
    (SCAN, "--spacing-mm", "-4x6"), (SCAN, "--offset-mm", "nanx0"), (SCAN, "--offset-mm", "1e300x0"),
    (("rig",), "--timeout-s", "inf"), (("rig",), "--timeout-s", "nan"), (("rig",), "--timeout-s", "0"),
    (("rig",), "--time-scale", "nan"), (("rig",), "--baud", "-1"),
    (("plan",), "--focal-length-mm", "nan"), (("plan",), "--near-m", "inf"), (("plan",), "--settle-s", "1e300"),
    (("plan",), "--raw-bits", "-3"), (("plan",), "--grid", "100000000x1"),
    (("process", "DATASET"), "--workers", "-1"), (("process", "DATASET"), "--workers", "1e9"),
    (("process", "DATASET"), "--workers", "4096"), (("process", "DATASET"), "--cluster", "nonsense"),
    (("calibrate", "DATASET"), "--focal-length-px", "nan"), (("calibrate", "DATASET"), "--work-width-px", "-5"),
    (("calibrate", "DATASET"), "--threads", "0"),
    (("export", "DATASET", "--format", "hevc", "--out", "OUT"), "--crf", "1e9"),
    (("export", "DATASET", "--format", "hevc", "--out", "OUT"), "--crf", "-1"),
    (("camera", "STEM"), "--width", "0"), (("camera", "STEM"), "--position-mm", "nan,0"),
    (("virtual-dataset", "NEW"), "--width", "-1"), (("virtual-dataset", "NEW"), "--grid", "100000000x1"),
    (("virtual-dataset", "NEW"), "--near-m", "nan"), (("virtual-dataset", "NEW"), "--workers", "-2"),
    (("sim-rig",), "--time-scale", "nan"),
    (("import-images", "FOLDER", "--grid", "3x2", "--spacing-mm", "4x6", "--out", "NEW"), "--focal-length-mm",
     "nan"),
    (("import-images", "FOLDER", "--grid", "100000000x1", "--spacing-mm", "4x6", "--out", "NEW"),
     "--pixel-pitch-um", "-1"),
]


@pytest.mark.parametrize("command,option,value", CLI_CASES, ids=[f"{c[0]} {o} {v}" for c, o, v in CLI_CASES])
def test_a_bad_number_in_an_option_is_one_line_exit_2_before_any_device(command, option, value, run_cli,
                                                                        tmp_path, pty_port):
    args = [{"DATASET": tmp_path / "ds", "OUT": tmp_path / "out", "STEM": tmp_path / "shot", "NEW": tmp_path / "new",
             "FOLDER": tmp_path}.get(a, a) for a in command]
    if args[0] in ("scan", "rig"):
        args += ["--port", pty_port.path]
    if args[0] == "scan":
        args += ["--out", tmp_path / "new"]
    if args[0] == "rig":
        args += ["status"]
    proc = run_cli(*args[:1], *args[1:], f"{option}={value}", timeout=60)
    assert_one_line_error(proc, 2, option)
    assert pty_port.sent() == b"", "bytes reached the rig before the option was checked"
    assert not (tmp_path / "new").exists() and not (tmp_path / "out").exists() and not (tmp_path / "shot.dng").exists()


# -- profiles, plans and the manifest ------------------------------------------------------------------------------
def _user_rig(config_dir, **axis_changes):
    """A user rig profile 'Bad' (the reference gantry with ``axis_changes`` on its horizontal axis)."""
    import tomli_w

    from lfstudio.resources import load_presets

    rig = json.loads(json.dumps(load_presets("rigs")["Reference gantry"]))
    rig["horizontal"].update(axis_changes)
    folder = config_dir / "presets"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "rigs.toml").write_text(tomli_w.dumps({"Bad": rig}))


RIG_CASES = {"soft_max_mm 1e300 on 4000 mm of travel": {"soft_max_mm": 1e300},
             "soft_min_mm negative": {"soft_min_mm": -40.0},
             "travel_mm nan": {"travel_mm": float("nan")},
             "max_speed_mm_s inf": {"max_speed_mm_s": float("inf")},
             "max_speed_mm_s 1e-300 (homing never ends)": {"max_speed_mm_s": 1e-300},
             "acceleration_mm_s2 1e-300": {"acceleration_mm_s2": 1e-300},
             "acceleration_mm_s2 0": {"acceleration_mm_s2": 0.0},
             "settle_s 1e300": {"settle_s": 1e300},
             "letter not an axis": {"letter": "X$H"}}


@pytest.mark.parametrize("case", list(RIG_CASES))
def test_a_bad_rig_profile_is_refused_before_any_move(case, run_cli, tmp_path, pty_port):
    config = tmp_path / "config"
    _user_rig(config, **RIG_CASES[case])
    field = next(iter(RIG_CASES[case]))
    proc = run_cli("rig", "--port", pty_port.path, "--rig-profile", "Bad", "move", "5000", "-40",
                   env={"LFSTUDIO_CONFIG_DIR": str(config)}, timeout=60)
    assert_one_line_error(proc, 2, "'Bad'", field)
    assert pty_port.sent() == b""


PROFILE_CASES = {"nan": "[color]\nwhite_output = nan\n", "inf list": "[lens]\ndist_coeffs = [inf, 0, 0, 0, 0]\n",
                 "huge int": "[deflicker]\nsize_px = 100000000000\n",
                 "negative patch": "[color]\npatch_px = -3\n",
                 "not UTF-8": b"[color]\nmode = \"\xff\xfe\"\n", "huge float": "[resample]\nscale = 1e300\n"}


@pytest.mark.parametrize("case", list(PROFILE_CASES))
def test_a_bad_processing_profile_is_one_line_exit_2(case, run_cli, tiny_dataset, tmp_path):
    text = PROFILE_CASES[case]
    path = tmp_path / "bad.toml"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    proc = run_cli("process", tiny_dataset.root, "--workers", "0", "--profile", path)
    assert_one_line_error(proc, 2, "bad.toml")
    assert not (tiny_dataset.root / "processed").exists()


PLAN_CASES = {"grid_columns huge": ("grid_columns", 100000000), "spacing nan": ("spacing_mm", [float("nan"), 6.0]),
              "settle 1e300": ("settle_s", 1e300), "focal length inf": ("focal_length_mm", float("inf")),
              "huge int": ("grid_rows", 10 ** 30)}


@pytest.mark.parametrize("command", ["plan", "scan"])
@pytest.mark.parametrize("case", list(PLAN_CASES))
def test_a_bad_plan_file_is_one_line_exit_2(case, command, run_cli, tmp_path, pty_port):
    from lfstudio.planning.presets import reference_plan

    field, value = PLAN_CASES[case]
    data = reference_plan().to_dict()
    data[field] = value
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))                   # Python's json writes NaN and Infinity
    args = ["plan", "--plan", path] if command == "plan" else \
        ["scan", "--plan", path, "--port", pty_port.path, "--camera", "instant", "--out", tmp_path / "new"]
    proc = run_cli(*args, timeout=60)
    assert_one_line_error(proc, 2, field)
    assert pty_port.sent() == b"" and not (tmp_path / "new").exists()


MANIFEST_CASES = {"lens.focal_length_mm": lambda m: m["lens"].__setitem__("focal_length_mm", float("nan")),
                  "grid.spacing_mm": lambda m: m["grid"].__setitem__("spacing_mm", [float("inf"), 6.0]),
                  "views[0].commanded_mm": lambda m: m["views"][0].__setitem__("commanded_mm", [float("nan"), 1.0]),
                  "camera.sensor_px": lambda m: m["camera"].__setitem__("sensor_px", [float("-inf"), 10])}


@pytest.mark.parametrize("command", ["info", "process", "calibrate", "export"])
@pytest.mark.parametrize("case", list(MANIFEST_CASES))
def test_a_non_finite_number_in_the_manifest_is_refused_naming_it(case, command, run_cli, tiny_dataset, tmp_path):
    root = tiny_dataset.root
    m = manifest_of(root)
    MANIFEST_CASES[case](m)
    write_manifest(root, m)
    before = (root / "dataset.json").read_bytes()
    args = {"info": ("info", root), "process": ("process", root, "--workers", "0"), "calibrate": ("calibrate", root),
            "export": ("export", root, "--format", "png", "--out", tmp_path / "ex")}[command]
    proc = run_cli(*args)
    assert_one_line_error(proc, 1, case, "not a finite number")
    assert (root / "dataset.json").read_bytes() == before


# -- the helper itself -----------------------------------------------------------------------------------------------
def test_number_check_names_the_field_the_value_and_the_range_with_its_unit():
    settle = Number("s", 0, 600)
    with pytest.raises(InputError) as info:
        settle.check("--settle-s", 1e300)
    assert str(info.value) == "--settle-s: 1e+300 s is out of range (valid: 0 … 600 s)"
    assert "nan is not a finite number" in str(pytest.raises(InputError, settle.check, "x", float("nan")).value)
    assert "not a number" in str(pytest.raises(InputError, settle.check, "x", True).value)
    assert "4301-digit number" in str(pytest.raises(InputError, settle.check, "x", 10 ** 4300).value)
    assert settle.check("x", 3) == 3.0 and isinstance(Number(integer=True).check("x", 3.0), int)
    assert Number("mm", 0, low_open=True).valid() == "> 0 mm"
    assert "2.5 is not a whole number" in str(pytest.raises(InputError, Number(integer=True).parse, "n", "2.5").value)


def test_grid_bounds_are_checked_before_anything_is_allocated():
    assert check_grid("--grid", 101, 21) == (101, 21)
    with pytest.raises(InputError, match=f"at most {MAX_VIEWS} views"):
        check_grid("--grid", 1000, 1000)
    with pytest.raises(InputError, match="columns"):
        check_grid("--grid", 100_000_000, 1)


def test_numbers_typed_as_one_word_read_every_separator_and_say_what_they_expect():
    whole = Number("", 1, integer=True)
    for text in ("11x3", "11×3", "11,3", " 11 X 3 "):
        assert parse_numbers("--grid", text, whole, 2, "101x21") == (11, 3), text
    assert parse_numbers("--spacing-mm", "3", Number(), 2, one_for_all=True) == (3.0, 3.0)
    for text in ("ten", "11x", "11x3x2", "", "3"):
        with pytest.raises(InputError) as info:
            parse_numbers("--grid", text, whole, 2, "101x21")
        assert str(info.value) == f"--grid: cannot read {text!r} (valid: 2 numbers like 101x21)"
    assert "ten" in str(pytest.raises(InputError, parse_numbers, "--g", "ten", whole, 2, one_for_all=True).value)
    assert "11.5 is not a whole number" in str(pytest.raises(InputError, parse_numbers, "--g", "11.5x3", whole).value)
    assert "0 is out of range" in str(pytest.raises(InputError, parse_numbers, "--g", "0x3", whole).value)
    assert "nan is not a finite" in str(pytest.raises(InputError, parse_numbers, "--g", "nanx3", Number()).value)


def test_non_finite_fields_names_every_nan_at_any_depth():
    deep: dict = {"x": float("nan")}
    for _ in range(5000):
        deep = {"d": deep}
    assert non_finite_fields(deep) == [".".join(["d"] * 5000 + ["x"])]
    assert non_finite_fields({"a": [1.0, float("inf")], "b": {"c": float("-inf")}}) == ["a[1]", "b.c"]
