"""`lfstudio scan` / `lfstudio rig` as an operator runs them (real processes): homing on the simulated
controller's pty, a rig command refused during a scan, two scans of one dataset, resume rules."""

from __future__ import annotations

import hashlib
import json
import math
import signal
from pathlib import Path


from lfstudio.dataset import Dataset
from lfstudio.rig.profile import load_rig
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.studio.session import ScanRequest, ScanSession
from tests.scankill import journal_lines

FAST = ["--time-scale", "0", "--sim-width-px", "64"]
GRID = ["--grid", "3x2", "--spacing-mm", "4x6"]


def wait_for_views(proc, root: Path, n: int) -> None:
    """Poll the journal until ``n`` views are captured (or the process ended)."""
    import time

    while proc.poll() is None and journal_lines(root) < n:
        time.sleep(0.01)       # polling a file the other process writes, not synchronising on a duration
    assert journal_lines(root) >= n, proc.communicate(timeout=30)[1]


def files_of(root: Path) -> dict[str, tuple[int, str]]:
    """Every view file and thumbnail: name -> (mtime_ns, sha256)."""
    out = {}
    for sub in ("raw", "thumbs"):
        for p in sorted((root / sub).iterdir()):
            out[f"{sub}/{p.name}"] = (p.stat().st_mtime_ns, hashlib.sha256(p.read_bytes()).hexdigest())
    return out


def assert_views_where_commanded(root: Path, tolerance_mm: float = 0.5) -> int:
    """Every captured view of the simulated camera was taken at its commanded position (its ground
    truth says where the carriage really was); returns the number of views checked."""
    ds = Dataset.open(root)
    done = ds.done_views()
    for v in done:
        truth = json.loads((root / v["file"]).with_suffix(".truth.json").read_text())
        off = math.dist(truth["true_position_mm"], v["commanded_mm"])
        assert off < tolerance_mm, (v["row"], v["column"], truth["true_position_mm"], v["commanded_mm"])
    return len(done)


def one_error_line(stderr: str) -> str:
    errors = [line for line in stderr.splitlines() if "error:" in line]
    assert len(errors) == 1 and "Traceback" not in stderr, stderr
    return errors[0]


def test_scan_on_the_simulated_controllers_pty_needs_home_then_completes(sim_rig_port, run_cli, tmp_path):
    out = tmp_path / "ds"
    r = run_cli("scan", "--port", sim_rig_port, "--camera", "sim", *GRID, "--out", out, *FAST)
    assert r.returncode == 1
    line = one_error_line(r.stderr)
    assert "ALARM" in line and "--home" in line and f"lfstudio rig --port {sim_rig_port} home" in line
    assert not out.exists()                      # nothing was made for a scan that could not start

    r = run_cli("scan", "--port", sim_rig_port, "--home", "--camera", "sim", *GRID, "--out", out, *FAST)
    assert r.returncode == 0, r.stderr
    assert "rig homed" in r.stderr and "6 of 6 views captured" in r.stderr
    assert assert_views_where_commanded(out) == 6
    devices = Dataset.open(out).manifest["devices"]
    assert devices["rig"]["kind"] == "grbl" and devices["rig"]["port"] == sim_rig_port
    assert devices["rig"]["firmware"].startswith("GRBL 1.1") and devices["camera"]["kind"] == "sim"

    # homed by `lfstudio rig ... home` in another process: a new scan without --home runs
    r = run_cli("rig", "--port", sim_rig_port, "home")
    assert r.returncode == 0, r.stderr
    r = run_cli("scan", "--port", sim_rig_port, "--camera", "sim", *GRID, "--out", tmp_path / "ds2", *FAST)
    assert r.returncode == 0 and "6 of 6 views captured" in r.stderr, r.stderr


def test_rig_command_refused_while_a_scan_runs(sim_rig_port, start_cli, run_cli, tmp_path):
    out = tmp_path / "ds"
    scan = start_cli("scan", "--port", sim_rig_port, "--home", "--camera", "sim", "--grid", "6x3", "--spacing-mm",
                     "4x6", "--out", out, "--time-scale", "1", "--sim-width-px", "64")
    wait_for_views(scan, out, 1)
    r = run_cli("rig", "--port", sim_rig_port, "jog", "5", "0")
    assert r.returncode == 1
    line = one_error_line(r.stderr)
    assert f"rig port {sim_rig_port} is in use by lfstudio scan" in line and f"pid {scan.pid}" in line
    scan.send_signal(signal.SIGINT)              # Ctrl-C: stop after the current view
    _, stderr = scan.communicate(timeout=120)
    assert scan.returncode == 130, stderr
    assert assert_views_where_commanded(out) >= 1   # the jog never moved the carriage under the scan
    r = run_cli("rig", "--port", sim_rig_port, "status")   # the port is free again
    assert r.returncode == 0, r.stderr


def test_two_scans_of_one_dataset_the_second_is_refused_and_touches_nothing(start_cli, run_cli, tmp_path):
    out = tmp_path / "ds"
    # 30 views of ~1 s: the first scan still runs while the others are tried (it is stopped after that)
    first = start_cli("scan", "--port", "sim", "--camera", "sim", "--grid", "10x3", "--spacing-mm", "4x6",
                      "--out", out, "--time-scale", "0.3", "--sim-width-px", "64")
    wait_for_views(first, out, 2)
    before = files_of(out)
    lock_text = (out / "dataset.lock").read_text()
    second = run_cli("scan", "--out", out, "--resume", *FAST)
    assert second.returncode == 1
    line = one_error_line(second.stderr)
    assert f"dataset {out} is in use by lfstudio scan" in line and f"pid {first.pid}" in line
    third = run_cli("scan", "--port", "sim", "--camera", "sim", *GRID, "--out", out, *FAST)
    assert third.returncode == 2 and "already holds a dataset" in third.stderr
    after = files_of(out)
    assert {name: after.get(name) for name in before} == before      # every file of the first, untouched
    assert (out / "dataset.lock").read_text() == lock_text
    first.send_signal(signal.SIGINT)
    _, stderr = first.communicate(timeout=120)
    assert first.returncode == 130, stderr
    r = run_cli("scan", "--out", out, "--resume", *FAST)
    assert r.returncode == 0, r.stderr
    ds = Dataset.open(out)
    assert ds.status_counts()["done"] == 30 and ds.verify_files() == []


def partial_dataset(root: Path, rig: str, camera: str, cells: int, **request) -> Dataset:
    """A dataset of a 3 x 2 grid with only the first ``cells`` views (in capture order) captured, as an
    interrupted scan leaves it."""
    config = load_rig()
    plan = ScanPlan.centered(3, 2, (4.0, 6.0), config, settle_s=0.0)
    first = [v.cell for v in plan.views()[:cells]]
    session = ScanSession(ScanRequest(root, rig=rig, camera=camera, rig_config=config, recapture=first,
                                      time_scale=0.0, sim_width_px=64, **request))
    try:
        engine = session.open(lambda existing, cfg: (plan, None))
        engine.start()
        engine.wait(60)
    finally:
        session.close()
    ds = Dataset.open(root)
    assert ds.status_counts()["done"] == cells
    return ds


def test_resume_with_other_devices_is_refused_without_the_explicit_option(run_cli, tmp_path):
    out = tmp_path / "ds"
    partial_dataset(out, "instant", "instant", 2)
    manifest = (out / "dataset.json").read_bytes()
    r = run_cli("scan", "--out", out, "--resume", "--port", "sim", "--camera", "sim", *FAST)
    assert r.returncode == 1
    line = one_error_line(r.stderr)
    assert "the instant rig and the instant camera" in line and "--allow-device-change" in line
    assert (out / "dataset.json").read_bytes() == manifest

    r = run_cli("scan", "--out", out, "--resume", "--port", "sim", "--camera", "sim", "--allow-device-change", *FAST)
    assert r.returncode == 0, r.stderr
    assert "device change recorded" in r.stderr
    ds = Dataset.open(out)
    assert ds.status_counts()["done"] == 6
    assert [c["devices"]["rig"]["kind"] for c in ds.manifest["device_changes"]] == ["sim"]
    kinds = sorted((v.get("devices") or ds.manifest["devices"])["camera"]["kind"] for v in ds.views)
    assert kinds == ["instant"] * 2 + ["sim"] * 4            # each view says which camera took it


def test_resume_without_device_options_uses_the_datasets_own_devices(run_cli, tmp_path):
    out = tmp_path / "ds"
    partial_dataset(out, "instant", "instant", 3)
    r = run_cli("scan", "--out", out, "--resume", *FAST)
    assert r.returncode == 0, r.stderr
    assert "resuming with the dataset's own devices: the instant rig and the instant camera" in r.stderr
    ds = Dataset.open(out)
    assert ds.status_counts()["done"] == 6 and "device_changes" not in ds.manifest
    assert all("devices" not in v for v in ds.views)


def test_a_dataset_without_a_device_record_still_resumes_with_a_warning(run_cli, tmp_path):
    out = tmp_path / "ds"
    partial_dataset(out, "instant", "instant", 2)
    manifest = json.loads((out / "dataset.json").read_text())
    del manifest["devices"]
    manifest["rig"].pop("port")
    manifest["camera"].pop("driver")
    (out / "dataset.json").write_text(json.dumps(manifest))
    r = run_cli("scan", "--out", out, "--resume", "--port", "instant", "--camera", "instant", *FAST)
    assert r.returncode == 0, r.stderr
    assert "does not record which devices captured it" in r.stderr
    assert Dataset.open(out).manifest["devices"]["rig"]["kind"] == "instant"


def test_resume_checks_the_rig_stands_where_the_last_view_left_it(sim_rig_port, run_cli, tmp_path):
    out = tmp_path / "ds"
    ds = partial_dataset(out, sim_rig_port, "sim", 3, home=True)
    last = max(ds.done_views(), key=lambda v: v["captured_at"])
    r = run_cli("rig", "--port", sim_rig_port, "move", "1", "1")          # someone moved the carriage
    assert r.returncode == 0, r.stderr
    r = run_cli("scan", "--out", out, "--resume", *FAST)
    assert r.returncode == 1
    line = one_error_line(r.stderr)
    assert "moved or lost its position" in line and "--home" in line
    assert Dataset.open(out).status_counts()["done"] == 3
    x, y = last["reported_mm"]
    r = run_cli("rig", "--port", sim_rig_port, "move", x, y)              # put it back
    assert r.returncode == 0, r.stderr
    r = run_cli("scan", "--out", out, "--resume", *FAST)
    assert r.returncode == 0, r.stderr
    assert "where the last run left it" in r.stderr
    assert assert_views_where_commanded(out) == 6
    r = run_cli("scan", "--out", out, "--resume", "--home", *FAST)         # finished: no device is even connected
    assert r.returncode == 0 and "nothing to do" in r.stderr and "rig homed" not in r.stderr, r.stderr


def test_a_resume_where_another_datasets_scan_left_the_rig_is_not_taken_for_its_own(sim_rig_port, run_cli, tmp_path):
    """The position rule let a resume 'continue' because an unrelated scan had ended at the same spot:
    the numbers matched, but nothing tied them to this dataset's own last capture."""
    mine, other = tmp_path / "mine", tmp_path / "other"
    ds = partial_dataset(mine, sim_rig_port, "sim", 3, home=True)
    last = max(ds.done_views(), key=lambda v: v["captured_at"])
    ds.close()
    partial_dataset(other, sim_rig_port, "sim", 2)                    # another dataset scanned on this rig
    x, y = last["reported_mm"]
    r = run_cli("rig", "--port", sim_rig_port, "move", x, y)            # and the rig stands where mine stopped
    assert r.returncode == 0, r.stderr
    r = run_cli("scan", "--out", mine, "--resume", *FAST)
    assert r.returncode == 1
    line = one_error_line(r.stderr)
    assert f"the last scan on it was {other.resolve()}" in line and "--home" in line, line
    assert Dataset.open(mine).status_counts()["done"] == 3
    r = run_cli("scan", "--out", mine, "--resume", "--home", *FAST)    # from a known reference: goes on
    assert r.returncode == 0 and "rig homed" in r.stderr, r.stderr
    assert assert_views_where_commanded(mine) == 6
