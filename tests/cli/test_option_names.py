"""Issue 20, command line: option names agree across commands, every grid-shaped value is
COLUMNSxROWS and every position COLUMN,ROW (said once in ``lfstudio --help``), and an old spelling
whose meaning changed is refused with one line showing the new form instead of being misread."""

from __future__ import annotations

import json
import re

from lfstudio.cli import build_parser
from lfstudio.cli.args import CONVENTIONS


def _helps() -> dict[str, str]:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return {"lfstudio": parser.format_help(), **{n: p.format_help() for n, p in sub.choices.items()}}


def _options(name: str) -> set[str]:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return {o for a in sub.choices[name]._actions if a.help != "==SUPPRESS==" for o in a.option_strings}


def _one_line(proc, *words):
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "usage:" not in proc.stderr, proc.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


def test_devices_are_port_and_camera_and_profiles_rig_profile_in_every_command():
    assert "--port" in _options("scan") and "--port" in _options("rig")
    for name in ("scan", "plan", "rig", "sim-rig"):
        assert "--rig-profile" in _options(name), name
    assert "--camera-preset" in _options("plan") and "--camera" not in _options("plan")
    for name, text in _helps().items():        # the old spellings are gone from every --help
        assert not re.search(r"--rig\b(?!-)", text.replace(CONVENTIONS, "")), name
        assert "ROW,COL" not in text and "ROWSxCOLUMNS" not in text, name


def test_scan_refuses_rig_for_the_port_showing_the_new_form(cli_main, tmp_path):
    proc = cli_main("scan", "--rig", "/dev/ttyUSB0", "--camera", "instant", "--out", tmp_path / "ds")
    _one_line(proc, "lfstudio scan: error: --rig", "--port /dev/ttyUSB0", "--rig-profile NAME")
    assert not (tmp_path / "ds").exists()


def test_the_old_rig_and_camera_spellings_keep_their_meaning_where_it_did_not_change(cli_main):
    new = cli_main("plan", "--json", "--rig-profile", "Desktop slider 1 m", "--camera-preset", "Nikon Z7 II")
    old = cli_main("plan", "--json", "--rig", "Desktop slider 1 m", "--camera", "Nikon Z7 II")
    assert new.returncode == 0 and old.returncode == 0, (new.stderr, old.stderr)
    assert json.loads(new.stdout) == json.loads(old.stdout)
    assert json.loads(new.stdout)["capture_time_s"] != json.loads(cli_main("plan", "--json").stdout)["capture_time_s"]
    parser = build_parser()
    for name in ("rig", "sim-rig"):
        extra = ["--port", "sim"] if name == "rig" else []
        assert parser.parse_args([name, *extra, "--rig", "Desktop slider 1 m"]).rig_profile == "Desktop slider 1 m"
    bad = cli_main("plan", "--rig-profile", "Nope")
    assert bad.returncode == 2 and "--rig-profile" in bad.stderr


def test_help_says_the_conventions_once(cli_main):
    top = " ".join(cli_main("--help").stdout.split())
    assert CONVENTIONS in top and top.count("COLUMNSxROWS") == 1
    assert "COLUMN,ROW" in CONVENTIONS and "array:3x2" in CONVENTIONS and "--port" in CONVENTIONS
    helps = _helps()
    # every grid-shaped option is written CxR, every position COLUMN,ROW
    for name, text in helps.items():
        for metavar in re.findall(r"--(?:grid|hci-size) ([^\s\]]+)", text):
            assert metavar == "CxR", (name, metavar)
    assert "--hci-centre-view COLUMN,ROW" in helps["export"]


def test_export_format_lists_its_choices_and_scan_spacing_says_its_default(cli_main, tmp_path):
    proc = cli_main("export", tmp_path, "--out", tmp_path / "x")
    _one_line(proc, "--format (one of png, hevc, hci, colmap, nerfstudio)")
    spacing = " ".join(cli_main("scan", "--help").stdout.split())
    assert re.search(r"--spacing-mm HxV distance between neighbouring views in mm, horizontal x vertical, "
                     r"e\.g\. 4x6 \(default from --plan, else 4x6", spacing), spacing


def test_hci_centre_view_is_column_row_and_the_old_row_column_option_is_refused(make_tiny_dataset, cli_main,
                                                                               tmp_path):
    ds = make_tiny_dataset("png")                              # 5 columns x 3 rows
    base = ["export", ds.root, "--format", "hci", "--hci-size", "3x3", "--estimate", "--out", tmp_path / "h"]
    ok = cli_main(*base, "--hci-centre-view", "3,1")             # column 3, row 1: columns 2-4, rows 0-2
    assert ok.returncode == 0 and ok.stdout.startswith("9 views"), ok.stderr
    off = cli_main(*base, "--hci-centre-view", "1,3")            # column 1, row 3: no row 3 in this grid
    _one_line(off, "--hci-centre-view", "row 3, column 1")
    old = cli_main(*base, "--hci-center", "1,3")                 # row 1, column 3 in the old spelling
    _one_line(old, "--hci-center took ROW,COLUMN", "write --hci-centre-view 3,1")
    assert not (tmp_path / "h").exists()


def test_views_array_is_columns_by_rows_and_a_bare_rows_by_columns_is_refused(make_tiny_dataset, cli_main, tmp_path):
    ds = make_tiny_dataset("png")                              # 5 columns x 3 rows
    base = ["export", ds.root, "--format", "png", "--estimate", "--out", tmp_path / "p"]
    wide = cli_main(*base, "--views", "array:5x2")               # 5 columns of 2 rows
    assert wide.returncode == 0 and wide.stdout.startswith("10 views"), wide.stderr
    for command in (base, ["calibrate", ds.root, "--no-save"]):
        old = cli_main(*command, "--views", "2x5")
        _one_line(old, "--views", "'2x5': an array is written array:COLUMNSxROWS", "array:5x2")
    assert not (tmp_path / "p").exists() and not (ds.root / "calibration.json").exists()
