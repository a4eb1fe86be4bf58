"""One description per parameter, the scan options (lfstudio.studio.scan_options.ScanOptions):
'lfstudio scan''s options are made from the descriptions, with the same names and defaults as
before, and refuse exactly what the descriptions refuse."""

from __future__ import annotations

import argparse
import dataclasses

import pytest

from lfstudio.cli import scan as scan_cli
from lfstudio.studio.scan_options import FROM_PLAN, PARAMS, ScanOptions


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lfstudio scan")
    scan_cli.add_arguments(p)
    return p


def test_every_scan_option_is_described():
    assert list(PARAMS) == [f.name for f in dataclasses.fields(ScanOptions)]
    for name, param in PARAMS.items():
        assert param.label and param.tip and param.option.startswith("--") and param.group, name
    options = ScanOptions()
    for name, param in PARAMS.items():
        param.check(name, getattr(options, name))           # every default is valid


def test_the_options_come_from_the_descriptions_with_their_old_defaults():
    p = _parser()
    actions = {a.option_strings[0]: a for a in p._actions if a.option_strings}
    for name, param in PARAMS.items():
        action = actions[param.option]
        assert param.tip in action.help, name
        expected = None if name in FROM_PLAN else getattr(ScanOptions(), name)
        assert action.default == expected, name
    args = p.parse_args(["--out", "x"])
    assert (args.time_scale, args.retries, args.seed, args.offset_mm, args.auto_resume, args.on_finish_timeout_s,
            args.grid, args.settle_s, args.bracket, args.order) == (1.0, 2, 0, (0.0, 0.0), 0, 300.0, None, None,
                                                                    None, None)
    args = p.parse_args(["--out", "x", "--grid", "9x5", "--spacing-mm", "4x6", "--order", "raster", "--settle-s",
                         "0.5", "--bracket=-2,0,+2"])
    assert args.grid == (9, 5) and args.spacing_mm == (4.0, 6.0) and args.order == "raster" and args.settle_s == 0.5
    assert args.bracket is not None


@pytest.mark.parametrize("name", [n for n, p in PARAMS.items() if p.number is not None and n != "grid_rows"])
def test_each_option_refuses_what_its_description_refuses(name, capsys):
    param = PARAMS[name]
    n = param.number
    bad = n.high * 2 + 1 if n.high is not None else n.low - 1
    text = str(int(bad)) if n.integer else f"{bad:g}"
    if name == "grid_columns":
        text = f"{int(bad)}x1"
    elif param.pair:
        text = f"{text}x1"
    with pytest.raises(SystemExit) as exit_:
        _parser().parse_args(["--out", "x", param.option, text])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {param.option}" in err and n.valid().split(" ")[-1] in err, err
    assert "Traceback" not in err


def test_help_lists_every_option(run_cli):
    r = run_cli("scan", "--help")
    assert r.returncode == 0
    for param in PARAMS.values():
        assert param.option in r.stdout
    assert "{row-meander,column-meander,raster}" in r.stdout


def test_the_unattended_options_are_described_once_for_the_command_line_and_the_scan():
    """--notify, --smtp, --status-http, --status-token and --on-finish come from ScanOptions like the
    others (--notify repeatable), and Unattended.open checks every unattended option by the same
    description the command line does: --auto-resume 101 is refused by both (open() once allowed up to
    1000 while the command line and the window stopped at 100)."""
    from lfstudio.errors import InputError
    from lfstudio.studio.unattended import CLI_NAMES, Unattended, UnattendedOptions

    assert {PARAMS[name].group for name in CLI_NAMES} == {"unattended scans"}
    assert all(CLI_NAMES[name] == PARAMS[name].option for name in CLI_NAMES)
    args = _parser().parse_args(["--out", "x", "--notify", "https://a.example/h", "--notify", "ntfy+https://n/t",
                                 "--smtp", "smtp://me@mail", "--on-finish", "lights off"])
    assert [u.reveal() for u in args.notify] == ["https://a.example/h", "ntfy+https://n/t"]
    assert [str(u) for u in args.notify] == ["https://a.example/…", "ntfy+https://n/…"]    # read as secrets
    assert (args.smtp, args.status_http, args.on_finish) == ("smtp://me@mail", "", "lights off")
    assert _parser().parse_args(["--out", "x"]).notify == []
    high = int(PARAMS["auto_resume"].number.high) + 1
    with pytest.raises(SystemExit):
        _parser().parse_args(["--out", "x", "--auto-resume", str(high)])
    with pytest.raises(InputError) as err:
        Unattended.open(UnattendedOptions(auto_resume=high))
    assert str(err.value).startswith("--auto-resume: ")
    with pytest.raises(InputError) as err:
        Unattended.open(UnattendedOptions(notify="https://a.example/h"))    # a text, not a list of them
    assert str(err.value).startswith("--notify: ") and "not a list" in str(err.value)


@pytest.mark.parametrize("command, names", [("rig", ("port", "rig_profile", "time_scale")),
                                            ("sim_drive", ("rig_profile", "time_scale", "seed"))])
def test_the_rig_and_drive_commands_take_the_scan_options_descriptions(command, names, capsys):
    """lfstudio rig's and sim-drive's --port, --rig-profile, --time-scale and --seed are the scan's
    options, made from the same descriptions: the same help and the same range."""
    import importlib

    module = importlib.import_module(f"lfstudio.cli.{command}")
    p = argparse.ArgumentParser(prog=f"lfstudio {command}")
    module.add_arguments(p)
    actions = {a.option_strings[0]: a for a in p._actions if a.option_strings}
    for name in names:
        assert PARAMS[name].tip in actions[PARAMS[name].option].help, (command, name)
    port = ["--port", "sim"] if command == "rig" else []
    too_slow = f"{PARAMS['time_scale'].number.high * 2:g}"
    with pytest.raises(SystemExit):
        p.parse_args([*port, "--time-scale", too_slow])
    assert "argument --time-scale" in capsys.readouterr().err


def test_a_described_option_whose_help_holds_a_percent_sign_still_prints_its_help():
    """argparse formats help texts with %: a tip or default saying '5 %' is escaped, not a crash."""
    from lfstudio.cli.args import described_option
    from lfstudio.numbers import Number, Param

    p = argparse.ArgumentParser(prog="x")
    described_option(p, Param(number=Number("%", 0, 100), option="--noise-pct", tip="noise in % of full scale"), 5.0,
                     said="5 %")
    assert "noise in % of full scale (default 5 %)" in " ".join(p.format_help().split())
