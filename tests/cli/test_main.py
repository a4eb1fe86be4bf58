from lfstudio.cli import COMMANDS, build_parser


def test_help_lists_every_command(run_cli):
    result = run_cli("--help")
    assert result.returncode == 0
    for name in COMMANDS:
        assert name.replace("_", "-") in result.stdout


def test_version(run_cli):
    result = run_cli("--version")
    assert result.returncode == 0
    assert result.stdout.startswith("lfstudio ")


def test_unknown_command_is_usage_error(run_cli):
    result = run_cli("no-such-command")
    assert result.returncode == 2
    assert "invalid choice" in result.stderr
    assert "Traceback" not in result.stderr


def test_every_command_has_help():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert set(sub.choices) == {n.replace("_", "-") for n in COMMANDS}
