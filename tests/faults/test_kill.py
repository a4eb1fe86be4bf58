"""Fault matrix, kill -9: a scan, a processing run and an export killed at a random moment leave
nothing half-written and nothing running (a killed ``lfstudio process`` takes its worker processes and
the resource tracker with it); the next run completes, and every view captured before the kill is
kept exactly once (same file, same checksum, same capture time)."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time

import psutil
import pytest

from lfstudio.dataset import Dataset
from lfstudio.dataset.store import read_journal, temporary_files
from tests.conftest import REPO_ROOT

T = 120


def start_cli(*args):
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.Popen([sys.executable, "-m", "lfstudio", *map(str, args)], cwd=REPO_ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def wait_until(condition, timeout_s=T, what="condition"):
    """Poll ``condition`` until it holds (an event we cannot subscribe to from another process)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def captured(root):
    """(row, column) -> (file, sha256, captured_at) of every view the dataset holds as captured:
    the manifest plus the journal's records (what a kill -9 leaves)."""
    ds = Dataset.open(root)
    return {(v["row"], v["column"]): (v["file"], v["sha256"], v["captured_at"]) for v in ds.views
            if v.get("status") == "done"}


@pytest.mark.parametrize("trial", range(3))
def test_kill_9_of_a_scan_at_a_random_moment_then_resume_keeps_every_view_once(trial, tmp_path, run_cli):
    rnd = random.Random(1000 + trial)
    out = tmp_path / "ds"
    proc = start_cli("scan", "--port", "instant", "--camera", "sim", "--sim-width-px", "96", "--time-scale", "0.05",
                     "--grid", "5x3", "--out", out)
    journal = out / "journal.jsonl"
    kill_after = rnd.randint(1, 10)            # views journaled before the kill (and a random extra delay)
    wait_until(lambda: journal.is_file() and len(read_journal(journal)[0]) >= kill_after or proc.poll() is not None,
               what=f"{kill_after} views journaled")
    time.sleep(rnd.uniform(0, 0.3))            # a random moment inside the next view (move, expose, transfer, store)
    proc.send_signal(signal.SIGKILL)
    proc.wait(T)
    before = captured(out)
    assert len(before) >= kill_after or proc.returncode == 0
    again = run_cli("scan", "--resume", "--time-scale", "0", "--sim-width-px", "96", "--out", out, timeout=T)
    assert again.returncode == 0, again.stderr
    ds = Dataset.open(out)
    after = captured(out)
    assert len(after) == 15 and ds.verify_files() == []
    assert {cell: after[cell] for cell in before} == before       # nothing captured before was captured again
    assert list(temporary_files(out)) == []
    assert sorted(p.name for p in (out / "raw").glob("*.dng")) == sorted(f"r{r:02d}_c{c:03d}.dng"
                                                                         for r in range(3) for c in range(5))


def test_kill_9_of_process_takes_its_workers_and_resource_tracker_with_it(tiny_dataset_dng, run_cli):
    root = tiny_dataset_dng.root
    (root / "processing.toml").write_text("[rectify]\nenabled = false\n")
    proc = start_cli("process", root, "--workers", "2")
    parent = psutil.Process(proc.pid)
    family: dict[int, psutil.Process] = {}

    def workers_busy():
        for child in parent.children(recursive=True):
            family.setdefault(child.pid, child)
        processed = root / "processed"
        return len(family) >= 2 and processed.is_dir() and any(processed.glob("*.png")) or proc.poll() is not None
    wait_until(workers_busy, what="the worker processes at work")
    assert proc.poll() is None, "processing finished before it could be killed: make the dataset larger"
    for child in parent.children(recursive=True):
        family.setdefault(child.pid, child)
    proc.send_signal(signal.SIGKILL)
    proc.wait(T)
    gone, alive = psutil.wait_procs(list(family.values()), timeout=30)
    assert alive == [], [(p.pid, p.cmdline()) for p in alive]     # workers and the resource tracker ended
    assert len(gone) >= 2
    again = run_cli("process", root, "--workers", "2", timeout=300)
    assert again.returncode == 0, again.stderr
    ds = Dataset.open(root)
    assert all((v.get("processed") or {}).get("status") == "done" for v in ds.views)
    assert list(temporary_files(root)) == []


def test_kill_9_of_an_export_then_export_again(tiny_dataset, tmp_path, run_cli):
    out = tmp_path / "export"
    proc = start_cli("export", tiny_dataset.root, "--format", "png", "--image-bit-depth", "16", "--out", out)
    wait_until(lambda: any(p.name.startswith(".export") for p in tmp_path.iterdir()) or proc.poll() is not None,
               what="the export's partial folder")
    proc.send_signal(signal.SIGKILL)
    proc.wait(T)
    assert not out.exists() or proc.returncode == 0                  # never a half export under its name
    again = run_cli("export", tiny_dataset.root, "--format", "png", "--out", out, "--overwrite", timeout=300)
    assert again.returncode == 0, again.stderr
    assert len(list(out.rglob("*.png"))) >= 15
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".export")] == []     # stale partial gone
