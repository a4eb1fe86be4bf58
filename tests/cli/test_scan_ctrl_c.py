"""Ctrl+C in a CLI scan on the simulated studio (issue 20: it took 17.8 s to act): a real
``lfstudio scan`` process gets a real SIGINT mid-scan. It exits 130 saying it stops and the exact
command that resumes; the journal holds every captured view; the view being exposed or transferred
is either captured (its file complete and checksummed) or not marked done; that command then
finishes the scan without taking a captured view again. (The time to act: benchmarks/scan_ctrl_c.py.)"""

from __future__ import annotations

import shlex
import signal
import subprocess
import sys
import time

from lfstudio.dataset import Dataset
from lfstudio.dataset.paths import view_stem
from lfstudio.dataset.store import temporary_files
from tests.conftest import REPO_ROOT
from tests.scankill import journal_lines, lfstudio_env

COLUMNS, ROWS = 6, 3
#: the grid 30 mm from home (not across 2 m of travel), views of 0.2 + 0.6 s at time scale 0.3
ARGS = ["--port", "sim", "--camera", "sim", "--grid", f"{COLUMNS}x{ROWS}", "--spacing-mm", "4x6",
        "--offset-mm=-1960x-214", "--time-scale", "0.3", "--sim-width-px", "96", "--exposure-s", "0.2",
        "--transfer-s", "0.6"]


def _plan_order() -> list[tuple[int, int]]:
    """The row-meander order of the scan."""
    return [(r, c if r % 2 == 0 else COLUMNS - 1 - c) for r in range(ROWS) for c in range(COLUMNS)]


def test_ctrl_c_stops_saves_the_journal_and_prints_the_exact_resume_command(run_cli, tmp_path):
    out = tmp_path / "ds"
    proc = subprocess.Popen([sys.executable, "-m", "lfstudio", "scan", *ARGS, "--out", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=lfstudio_env(), cwd=REPO_ROOT)
    try:
        while proc.poll() is None and journal_lines(out) < 2:
            time.sleep(0.01)        # polling the journal the scan writes, not synchronising on a duration
        assert proc.poll() is None, proc.communicate()[1]
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "Ctrl+C: stopping" in stderr, stderr
    lines = stderr.strip().splitlines()
    resume = shlex.split(lines[-1])
    assert resume == ["lfstudio", "scan", "--resume", "--out", str(out), "--port", "sim", "--camera", "sim",
                      "--time-scale", "0.3", "--exposure-s", "0.2", "--transfer-s", "0.6", "--sim-width-px", "96"], \
        lines[-1]

    ds = Dataset.open(out)                       # the journal, replayed: what the scan had captured
    done = {(v["row"], v["column"]): v["sha256"] for v in ds.done_views()}
    assert 2 <= len(done) < COLUMNS * ROWS
    assert lines[-2] == f"lfstudio scan: the {len(done)} captured views are saved in {out}; resume with:", lines
    assert ds.verify_files() == []               # every view marked done has its whole file
    # captured in plan order up to the stop: the view being exposed is captured or still pending, never
    # marked done without its file, never failed
    order = _plan_order()
    assert set(order[:len(done)]) == set(done)
    assert {v["status"] for v in ds.views if (v["row"], v["column"]) not in done} == {"pending"}
    ds.close()

    again = run_cli(*resume[1:], timeout=300)        # "lfstudio" is python -m lfstudio here
    assert again.returncode == 0, again.stderr
    assert f"{len(done)} done, {COLUMNS * ROWS - len(done)} to capture" in again.stderr
    ds = Dataset.open(out)
    assert ds.status_counts()["done"] == COLUMNS * ROWS and ds.verify_files() == []
    for cell, sha in done.items():               # what was captured before Ctrl+C is not taken again
        assert ds.view(*cell)["sha256"] == sha
    assert list(temporary_files(out)) == []
    expected = {f"{view_stem(r, c)}{suffix}" for r, c in order for suffix in (".dng", ".jpg", ".truth.json")}
    assert {p.name for p in (out / "raw").iterdir()} == expected   # a dropped capture's file left nothing behind
