"""``lfstudio scan`` on CiA 402 drives: the emulated drives in the scanning process (``sim-dryve``,
``sim-canopen``) and in a process of their own (``lfstudio sim-drive``, Modbus TCP on 127.0.0.1),
a real ``kill -9`` of the scan, then ``--resume`` on the same drives: the reported position is
checked, nothing is lost, and a drive moved meanwhile is refused."""

from __future__ import annotations

import os
import random
import re
import shlex
import signal
import subprocess
import sys
import time

import pytest

from lfstudio.dataset import Dataset
from lfstudio.dataset.store import temporary_files
from tests.conftest import REPO_ROOT
from tests.scankill import kill_9_after, lfstudio_env

RIG = "dryve D1 gantry 4 m x 0.5 m"
GRID = ["--grid", "4x3", "--spacing-mm", "4x6", "--sim-width-px", "96", "--rig-profile", RIG]




@pytest.mark.parametrize("word", ["sim-dryve", "sim-canopen"])
def test_scan_on_emulated_drives_then_resume_is_a_no_op(run_cli, tmp_path, word):
    out = tmp_path / "ds"
    r = run_cli("scan", "--port", word, "--camera", "sim", *GRID, "--time-scale", "0", "--out", out)
    assert r.returncode == 0, r.stderr
    assert "12 of 12 views captured" in r.stderr and "emulated CiA 402 drives" in r.stderr
    ds = Dataset.open(out)
    assert ds.manifest["devices"]["rig"] == {"kind": word, "profile": RIG}
    for v in ds.views:                                    # the drives reported each commanded position
        assert v["reported_mm"] == pytest.approx(v["commanded_mm"], abs=0.011)
    ds.close()
    again = run_cli("scan", "--out", out, "--resume")
    assert again.returncode == 0 and "nothing to do" in again.stderr
    assert "no device connected" in again.stderr and "homed" not in again.stderr     # no homing for nothing


def test_a_grbl_profile_on_drives_is_refused_naming_the_profile(run_cli, tmp_path):
    r = run_cli("scan", "--port", "sim-dryve", "--camera", "sim", "--grid", "2x1", "--rig-profile", "Reference gantry",
                "--out", tmp_path / "x")
    assert r.returncode == 2
    assert "GRBL controller" in r.stderr and f"--rig-profile '{RIG}'" in r.stderr
    assert not (tmp_path / "x").exists()


def test_the_device_word_implies_the_emulators_profile_and_real_drives_need_theirs_named(run_cli, tmp_path):
    """'rig'/'scan' on a drive word without --rig-profile were refused for the default GRBL gantry."""
    r = run_cli("rig", "--port", "sim-dryve", "--time-scale", "0", "home", "status")
    assert r.returncode == 0, r.stderr
    assert f"(rig {RIG!r})" in r.stdout and "x: operation enabled" in r.stdout
    for command in (["rig", "status"], ["scan", "--camera", "sim", "--grid", "2x1", "--out", tmp_path / "y"]):
        # real drives: refused before anything connects, with exactly what to add
        word = "dryve:127.0.0.1:1,127.0.0.1:2"
        r = run_cli(command[0], "--port", word, *command[1:])
        assert r.returncode == 2, r.stderr
        lines = [line for line in r.stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and f"--rig-profile '{RIG}'" in lines[0] and "pair of CiA 402 drives" in lines[0]
        assert "answer" not in lines[0] and not (tmp_path / "y").exists()


def test_drives_that_do_not_answer_are_one_line_naming_the_address(run_cli, tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    r = run_cli("rig", "--port", f"dryve:127.0.0.1:{port},127.0.0.1:{port + 1}", "--rig-profile", RIG, "--timeout-s",
                "0.5", "status")
    assert r.returncode == 1
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and f"127.0.0.1:{port}" in lines[0] and "Traceback" not in r.stderr


@pytest.fixture
def sim_drive(tmp_path):
    """``lfstudio sim-drive`` in its own process; yields its device word."""
    proc = subprocess.Popen([sys.executable, "-m", "lfstudio", "sim-drive", "--time-scale", "0.02", "--seed", "5"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=lfstudio_env(), cwd=REPO_ROOT)
    try:
        word = proc.stdout.readline().strip()
        assert word.startswith("dryve:127.0.0.1:"), proc.stderr.read() if proc.poll() is not None else word
        yield word
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
        proc.stdout.close()
        proc.stderr.close()


@pytest.mark.parametrize("seed", [1])
def test_kill_9_of_a_scan_on_the_drive_emulator_resumes_with_nothing_lost(run_cli, tmp_path, sim_drive, seed):
    rng = random.Random(seed * 7919 + os.getpid())
    out = tmp_path / "ds"
    args = ["scan", "--port", sim_drive, "--camera", "sim", *GRID, "--time-scale", "0.02"]
    r = run_cli(*args, "--out", tmp_path / "not-homed")
    assert r.returncode == 1 and "not homed" in r.stderr and "--home" in r.stderr     # a fresh drive pair
    kill_9_after([*args, "--home", "--out", out], out, rng.randint(1, 9), rng, jitter_s=0.05, timeout_s=90)
    crashed = Dataset.open(out)
    before = {(v["row"], v["column"]): v["sha256"] for v in crashed.views if v["status"] == "done"}
    last = max((v for v in crashed.views if v["status"] == "done"), key=lambda v: v["captured_at"])
    assert crashed.manifest["devices"]["rig"] == {"kind": "dryve", "profile": RIG, "port": sim_drive}
    crashed.close()
    if len(before) == 12:
        pytest.skip("the scan finished before the kill")

    # moved meanwhile: the resume compares the drives' reported position with the dataset and refuses
    # each process establishes its own reference on drives: the crashed scan's is not taken by itself
    refused = run_cli("rig", "--port", sim_drive, "--rig-profile", RIG, "move", "300", "200")
    assert refused.returncode == 1 and "home the rig first" in refused.stderr
    moved = run_cli("rig", "--port", sim_drive, "--rig-profile", RIG, "--time-scale", "0.02", "--keep-drive-reference",
                    "move", "300", "200", "status")
    assert moved.returncode == 0, moved.stderr
    assert "x: operation enabled 0000h, y: operation enabled 0000h" in moved.stdout
    resume = ["scan", "--out", out, "--resume", "--time-scale", "0.02", "--sim-width-px", "96"]
    r = run_cli(*resume)
    assert r.returncode == 1 and "not homed" in r.stderr and "--keep-drive-reference" in r.stderr
    resume.append("--keep-drive-reference")
    r = run_cli(*resume)
    assert r.returncode == 1 and "reports (300.000, 200.000) mm" in r.stderr and "moved or lost" in r.stderr
    # back where the last run left it with the command the line names (the drives' profile in it): the
    # drives kept their reference, the resume goes on without homing
    x, y = last["reported_mm"]
    command = re.search(r"\((lfstudio rig [^)]*)\)", r.stderr)
    assert command is not None, r.stderr
    words = shlex.split(command.group(1))
    assert words[1:] == ["rig", "--port", sim_drive, "--rig-profile", RIG, "--keep-drive-reference", "move", f"{x:g}",
                         f"{y:g}"]
    back = run_cli(*words[1:])
    assert back.returncode == 0, back.stderr
    r = run_cli(*resume, timeout=180)
    assert r.returncode == 0, r.stderr
    assert "where the last run left it" in r.stderr
    ds = Dataset.open(out)
    assert ds.status_counts()["done"] == 12 and ds.verify_files() == [] and list(temporary_files(out)) == []
    for cell, sha in before.items():
        assert ds.view(*cell)["sha256"] == sha
    for v in ds.views:
        assert v["reported_mm"] == pytest.approx(v["commanded_mm"], abs=0.011)


def test_ctrl_c_during_a_long_move_quick_stops_the_drives(run_cli, tmp_path, sim_drive):
    from lfstudio.studio.simulated import truth_source

    out = tmp_path / "ds"
    truth = truth_source(sim_drive)
    assert truth is not None                              # 'lfstudio sim-drive' publishes the true position
    r = run_cli("rig", "--port", sim_drive, "--rig-profile", RIG, "--time-scale", "0.02", "home")
    assert r.returncode == 0, r.stderr
    assert truth() == pytest.approx((0.0, 0.0), abs=0.011)
    # the grid is centred on the travel: its first view is ~2 m away, 10 s at 200 mm/s
    proc = subprocess.Popen([sys.executable, "-m", "lfstudio", "scan", "--port", sim_drive, "--camera", "sim",
                             *GRID, "--grid", "2x1", "--time-scale", "1", "--keep-drive-reference", "--out", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=lfstudio_env(), cwd=REPO_ROOT)
    try:
        deadline = time.monotonic() + 60
        while proc.poll() is None and truth()[0] < 50 and time.monotonic() < deadline:
            time.sleep(0.01)        # polling the carriage's true position, not synchronising on a duration
        assert proc.poll() is None and truth()[0] >= 50, proc.stderr.read() if proc.poll() is not None else ""
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, stderr
    status = run_cli("rig", "--port", sim_drive, "--rig-profile", RIG, "status")
    assert status.returncode == 0, status.stderr
    x = truth()[0]
    assert 50 <= x < 1900                                 # stopped on its way
    words = status.stdout.split()
    assert words[1] == "idle"                                                    # at rest
    assert float(words[2].removeprefix("x=")) == pytest.approx(x, abs=0.011)      # where it truly is
    assert "x: operation enabled 0000h" in status.stdout
