from lfstudio.cli import COMMANDS, build_parser


def test_help_lists_every_command(cli_main):
    result = cli_main("--help")
    assert result.returncode == 0
    for name in COMMANDS:
        assert name.replace("_", "-") in result.stdout


def test_version(run_cli):
    result = run_cli("--version")
    assert result.returncode == 0
    assert result.stdout.startswith("lfstudio ")


def test_unknown_command_is_usage_error(cli_main):
    result = cli_main("no-such-command")
    assert result.returncode == 2
    assert "invalid choice" in result.stderr
    assert "Traceback" not in result.stderr


def test_every_command_has_help():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert set(sub.choices) == {n.replace("_", "-") for n in COMMANDS}


def _dataset_commands() -> dict[str, list[str]]:
    """Every command whose first argument is a DATASET, with the other options it requires."""
    required = {"export": ["--format", "png", "--out", "{tmp}/out"]}
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    found = {}
    for name, p in sub.choices.items():
        if any(a.dest == "dataset" and not a.option_strings for a in p._actions):
            found[name] = required.get(name, [])
    return found


def test_a_missing_dataset_is_bad_input_for_every_command(cli_main, tmp_path):
    """One convention: a DATASET that does not exist, or is not a dataset, exits 2 with one line."""
    commands = _dataset_commands()
    assert {"info", "calibrate", "process", "export"} <= set(commands)
    (tmp_path / "empty").mkdir()
    for name, extra in commands.items():
        for dataset, words in ((tmp_path / "nowhere", ("nowhere", "not a folder")),
                               (tmp_path / "empty", ("empty", "dataset.json", "not found"))):
            proc = cli_main(name, dataset, *[a.format(tmp=tmp_path) for a in extra])
            assert proc.returncode == 2, (name, dataset, proc.stderr)
            lines = proc.stderr.strip().splitlines()
            assert len(lines) == 1 and lines[0].startswith(f"lfstudio {name}: error: "), proc.stderr
            for w in words:
                assert w in lines[0], (name, lines[0])
    assert not (tmp_path / "out").exists()


def test_every_help_states_the_exit_codes(cli_main):
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    helps = {"lfstudio": parser.format_help(), **{n: p.format_help() for n, p in sub.choices.items()}}
    for name, text in helps.items():
        flat = " ".join(text.split())
        assert "Exit codes: 0 done; 1 the work failed" in flat, name
        assert "2 bad input" in flat and "130 interrupted" in flat, name
    result = cli_main("info", "--help")
    assert "2 bad input" in " ".join(result.stdout.split())


def test_a_negative_or_malformed_spacing_gets_one_line_not_a_usage_dump(cli_main, tmp_path):
    """``--spacing-mm -4x6`` used to stop in argparse ("expected one argument") with the usage text."""
    required = {"import-images": [str(tmp_path), "--grid", "2x2", "--out", str(tmp_path / "x")],
                "virtual-dataset": [str(tmp_path / "x")],
                "scan": ["--port", "instant", "--camera", "instant", "--grid", "2x2", "--out", str(tmp_path / "x")]}
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    commands = [n for n, p in sub.choices.items() if "--spacing-mm" in p._option_string_actions]
    assert {"plan", "scan", "import-images", "virtual-dataset"} <= set(commands)
    for name in commands:
        for value, words in (("-4x6", ("-4",)), ("4x", ("4x",))):
            proc = cli_main(name, *required.get(name, []), "--spacing-mm", value)
            lines = proc.stderr.strip().splitlines()
            assert proc.returncode == 2, (name, value, proc.stderr)
            assert len(lines) == 1 and "usage:" not in proc.stderr, (name, value, proc.stderr)
            assert lines[0].startswith(f"lfstudio {name}: error: ") and "--spacing-mm: " in lines[0], lines[0]
            assert all(w in lines[0] for w in words), lines[0]
    assert not (tmp_path / "x").exists()


def test_a_value_starting_with_a_dash_is_given_to_its_option_not_taken_for_one():
    from lfstudio.cli import attach_dash_values

    parser = build_parser()
    assert attach_dash_values(parser, ["plan", "--spacing-mm", "-4x6", "--grid", "3x3"]) == \
        ["plan", "--spacing-mm=-4x6", "--grid", "3x3"]
    # an option after an option that takes a value is still an option; flags take no value
    assert attach_dash_values(parser, ["plan", "--spacing-mm", "--grid", "3x3"]) == \
        ["plan", "--spacing-mm", "--grid", "3x3"]
    assert attach_dash_values(parser, ["info", "--json", "-x"]) == ["info", "--json", "-x"]
    assert parser.parse_args(attach_dash_values(parser, ["plan", "--spacing-mm", "-4x6"])).spacing_mm == "-4x6"
