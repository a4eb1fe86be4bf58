"""``lfstudio rig`` and ``lfstudio sim-rig`` as a user runs them (subprocesses, real ptys)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from lfstudio.cli.rig import parse_commands
from lfstudio.errors import InputError


def test_several_commands_on_one_connection(run_cli):
    r = run_cli("rig", "--port", "sim", "--time-scale", "0.01", "status", "home", "move", "10", "5",
                "jog", "-3", "2.5", "status", timeout=60)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].startswith("simulated GRBL controller on /dev/")
    assert lines[1].startswith("status") and "alarm" in lines[1] and "not homed" in lines[1]
    assert "x=10.000 y=5.000 mm" in lines[3] and lines[3].startswith("move 10 5")
    assert "x=7.000 y=7.500 mm" in lines[4] and "homed" in lines[5]


def test_errors_are_one_clear_line_and_nonzero(run_cli):
    r = run_cli("rig", "--port", "sim", "--time-scale", "0", "home", "move", "5000", "1", timeout=60)
    assert r.returncode == 2
    assert "5000 mm is outside the soft limits" in r.stderr and "Traceback" not in r.stderr
    r = run_cli("rig", "--port", "sim", "--time-scale", "0", "move", "1", "1", timeout=60)
    assert r.returncode == 1 and "home the rig" in r.stderr
    r = run_cli("rig", "--port", "/dev/does-not-exist", "status", timeout=60)
    assert r.returncode == 1 and "cannot open the rig port" in r.stderr


def test_parse_commands():
    assert parse_commands(["home", "move", "1", "-2.5", "status"]) == [("home", ()), ("move", (1.0, -2.5)),
                                                                        ("status", ())]
    with pytest.raises(InputError, match="unknown command 'fly'"):
        parse_commands(["fly"])
    with pytest.raises(InputError, match="jog DX"):
        parse_commands(["jog", "abc", "1"])


def test_sim_rig_serves_a_port_until_interrupted(run_cli):
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    proc = subprocess.Popen([sys.executable, "-m", "lfstudio", "sim-rig", "--time-scale", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        port = proc.stdout.readline().strip()
        assert port.startswith("/dev/")
        r = run_cli("rig", "--port", port, "home", "move", "12", "3", timeout=60)
        assert r.returncode == 0, r.stderr
        assert "x=12.000 y=3.000 mm" in r.stdout
        # a second client sees the same controller state (still homed position)
        r = run_cli("rig", "--port", port, "status", timeout=60)
        assert "x=12.000 y=3.000 mm" in r.stdout
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0 and "stopped" in err
