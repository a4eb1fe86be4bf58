"""Fixtures for the studio tests: lfstudio processes started in the background, a ``lfstudio sim-rig``."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

from tests.conftest import REPO_ROOT


def cli_env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO_ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.fixture
def start_cli():
    """Start ``python -m lfstudio ARGS`` in the background (stderr piped, text); killed after the test."""
    procs: list[subprocess.Popen] = []

    def start(*args: str) -> subprocess.Popen:
        proc = subprocess.Popen([sys.executable, "-m", "lfstudio", *map(str, args)], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=cli_env(), cwd=REPO_ROOT)
        procs.append(proc)
        return proc

    yield start
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=30)


@pytest.fixture
def sim_rig_port(start_cli):
    """The pty of a ``lfstudio sim-rig`` process (reference gantry, time scale 0.05): the simulated
    controller as an operator starts it; its first output line is the port."""
    proc = start_cli("sim-rig", "--time-scale", "0.05", "--seed", "3")
    port = proc.stdout.readline().strip()
    assert port.startswith("/dev/"), proc.stderr.read() if proc.poll() is not None else port
    yield port
    proc.send_signal(signal.SIGTERM)
    proc.wait(30)
