"""Fault matrix, two commands at once (docs/dataset-format.md, "Two commands at once"): a real
``lfstudio scan`` process runs while real ``lfstudio process`` and ``lfstudio calibrate`` processes
work on the views it has captured so far. Each merges its records into the manifest under the
dataset's short lock; only the scan writes the journal. Nothing is lost either way: every view the scan
captured stays captured (same file, same checksum), the processed views and the calibration stay
recorded after the scan's own saves, and the resume takes only the views never captured."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

from lfstudio.dataset import Dataset
from lfstudio.dataset.store import read_journal
from lfstudio.support.locks import holder_of
from tests.conftest import REPO_ROOT
from tests.faults.conftest import set_pending
from tests.faults.test_kill import wait_until

T = 300
COLUMNS, ROWS = 5, 8
FIRST_ROWS = 2                     # captured before the scan under test starts: a 3x3 for calibrate, 10 to process


def start_cli(*args):
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.Popen([sys.executable, "-m", "lfstudio", *map(str, args)], cwd=REPO_ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def done_views(root):
    ds = Dataset.open(root)
    try:
        return {(v["row"], v["column"]): (v["file"], v["sha256"], v["captured_at"]) for v in ds.done_views()}
    finally:
        ds.close()


def test_process_and_calibrate_during_a_scan_lose_nothing_and_are_not_lost(run_cli, tmp_path):
    root = tmp_path / "ds"
    first = run_cli("scan", "--port", "instant", "--camera", "sim", "--sim-width-px", "256", "--grid",
                    f"{COLUMNS}x{ROWS}", "--spacing-mm", "4x6", "--time-scale", "0.01", "--out", root, timeout=T)
    assert first.returncode == 0, first.stderr
    later = {(r, c) for r in range(FIRST_ROWS, ROWS) for c in range(COLUMNS)}
    for r, c in later:                                # as an interrupted scan leaves them: not captured yet
        (root / "raw" / f"r{r:02d}_c{c:03d}.dng").unlink()
    set_pending(root, later)

    # the scan under test: 30 views at ~3 s each (the reference exposure and transfer, real time)
    scan = start_cli("scan", "--resume", "--out", root, "--time-scale", "1", "--sim-width-px", "256")
    try:
        journal = root / "journal.jsonl"
        wait_until(lambda: journal.is_file() and len(read_journal(journal)[0]) >= 1 or scan.poll() is not None,
                   T, "the scan's first view")
        assert scan.poll() is None, scan.communicate()[1]
        # beside it, as an operator would: calibrate on the first rows, then process what is captured
        for args in (("calibrate", root, "--views", "3x3"), ("process", root, "--workers", "1")):
            stage = start_cli(*args)
            _, stage_err = stage.communicate(timeout=T)
            assert stage.returncode == 0 and "Traceback" not in stage_err, stage_err
        during = done_views(root)                     # what the scan has captured by now
        assert scan.poll() is None and holder_of(root / "dataset.lock") is not None, \
            "the scan ended before the other commands: nothing was tested"
        scan.send_signal(signal.SIGINT)               # its last save comes after theirs
        _, err = scan.communicate(timeout=T)
    finally:
        if scan.poll() is None:
            scan.kill()
            scan.communicate()
    assert scan.returncode == 130, err

    after = Dataset.open(root)
    done = {(v["row"], v["column"]): (v["file"], v["sha256"], v["captured_at"]) for v in after.done_views()}
    assert all(done.get(cell) == record for cell, record in during.items())   # no captured view lost
    assert len(done) > FIRST_ROWS * COLUMNS
    assert f"the {len(done)} captured views are saved" in err, err
    assert after.verify_files() == []
    processed = {(v["row"], v["column"]) for v in after.views if (v.get("processed") or {}).get("status") == "done"}
    assert {(r, c) for r in range(FIRST_ROWS) for c in range(COLUMNS)} <= processed   # the scan kept them
    assert after.manifest.get("processing", {}).get("summary", {}).get("failed") == 0
    assert after.manifest.get("calibration", {}).get("file") == "calibration.json"
    after.close()

    again = run_cli("scan", "--resume", "--out", root, "--time-scale", "0.01", "--sim-width-px", "256", timeout=T)
    assert again.returncode == 0, again.stderr
    assert f"{len(done)} done, {COLUMNS * ROWS - len(done)} to capture" in again.stderr
    final = Dataset.open(root)
    assert final.status_counts()["done"] == COLUMNS * ROWS and final.verify_files() == []
    final_done = {(v["row"], v["column"]): (v["file"], v["sha256"], v["captured_at"]) for v in final.done_views()}
    assert all(final_done[cell] == record for cell, record in done.items())    # none captured twice
    assert "calibration" in final.manifest and processed <= {
        (v["row"], v["column"]) for v in final.views if (v.get("processed") or {}).get("status") == "done"}
    final.close()
