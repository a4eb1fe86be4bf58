"""What `lfstudio scan` says (real subprocesses): what it does while the simulated rig homes (it was
silent for ~12 s), "did you mean" for a mistyped option, exit code 3 in its --help, a progress bar
that fits the terminal (it padded every update to 160 columns: each one a new line on 80), and an
unknown serial port's error without the errno twice."""

from __future__ import annotations

import io

from lfstudio.jobs import TerminalProgress


def test_a_mistyped_option_gets_did_you_mean(cli_main, tmp_path):
    out = cli_main("scan", "--gird", "3x2", "--out", tmp_path / "ds")
    assert out.returncode == 2
    assert "--gird: did you mean --grid?" in out.stderr and "'lfstudio scan --help'" in out.stderr
    assert not (tmp_path / "ds").exists()


def test_scan_help_lists_exit_code_3(cli_main, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    out = cli_main("scan", "--help")
    assert out.returncode == 0 and "Exit code 3: a device fault stopped the scan" in " ".join(out.stdout.split())


def test_scan_says_what_it_does_before_the_simulated_rig_homes(run_cli, tmp_path):
    out = run_cli("scan", "--grid", "2x1", "--time-scale", "0", "--sim-width-px", "64", "--out", tmp_path / "ds")
    assert out.returncode == 0, out.stderr
    lines = out.stderr.splitlines()
    first = next(i for i, line in enumerate(lines) if "homes first" in line)
    grid = next(i for i, line in enumerate(lines) if "2x1 grid" in line)
    assert first < grid and lines[first].startswith("lfstudio scan: connecting the rig (sim)")


def test_an_unknown_serial_port_names_its_errno_once(run_cli, tmp_path):
    out = run_cli("rig", "--port", str(tmp_path / "ttyNOPE"), "status")
    assert out.returncode != 0
    assert out.stderr.count("No such file or directory") == 1 and out.stderr.lower().count("errno") == 1, out.stderr


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_the_progress_bar_fits_the_terminal(monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    stream = _Terminal()
    bar = TerminalProgress("scan", stream=stream)
    for done in range(1, 6):
        bar(done, 5, "view r00 c00%d with a long message " % done + "x" * (done * 30))
    updates = stream.getvalue().rstrip("\n").split("\r")[1:]
    assert len(updates) == 5
    assert all(len(u) <= 79 for u in updates), [len(u) for u in updates]
    assert "ETA" in updates[0]
