"""Fault matrix, storage: a full disk (ENOSPC) at each write of each stage, a read-only disk (EROFS), on
real file systems (a small tmpfs; root only, skipped elsewhere). Every case: the run stops with one line
naming the disk (never the camera), keeps everything captured or computed, and resumes without doing it
again — every captured view kept exactly once."""

from __future__ import annotations

import inspect
import os
import shutil
import subprocess
import sys
import threading

import pytest

from lfstudio.dataset import Dataset
from lfstudio.rig.profile import load_rig
from lfstudio.scan import store as store_module
from lfstudio.scan.engine import ScanEngine
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.scan_plan import ScanPlan, grid_order
from lfstudio.studio.devices import open_studio
from lfstudio.studio.session import create_scan_dataset
from tests.faults.conftest import assert_one_line_error, manifest_of, set_pending

RIG = load_rig()
T = 60


# -- the scan engine: ENOSPC at each of its writes, EROFS between views --------------------------------------
@pytest.fixture
def disk_scan(small_disk):
    """A 4 x 3 scan of the simulated studio into a dataset on a 4 MB tmpfs."""
    disk = small_disk(4 * 2**20)
    plan = ScanPlan.centered(4, 3, (4.0, 6.0), RIG, settle_s=0.0)
    studio = open_studio("sim", "sim", RIG, time_scale=0.0, exposure_s=0.5, transfer_s=2.5,
                         view_region_mm=plan.extent_mm(), sim_width_px=96)
    ds = create_scan_dataset(disk.path / "ds", plan, rig={"name": RIG.name}, camera={"name": "sim"},
                             lens={"name": "virtual"})
    engine = ScanEngine(ds, plan, studio.rig, studio.camera, time_scale=0.0, backoff_s=0.01, checkpoint_s=0.0,
                        min_free_bytes=64 * 1024)
    events: list = []
    engine.subscribe(events.append)
    yield disk, studio, ds, engine, events
    if engine.state not in (ScanState.FINISHED, ScanState.FAILED, ScanState.IDLE):
        engine.abort()
    engine.wait(T)
    studio.close()


def _fill_before(disk, fn):
    """``fn`` preceded, the first time only, by filling the disk: its write meets a real ENOSPC."""
    state = {"armed": True}

    def wrapper(*args, **kwargs):
        if state["armed"]:
            state["armed"] = False
            disk.fill()
        return fn(*args, **kwargs)
    wrapper.__signature__ = inspect.signature(fn)
    return wrapper


def _arm(write, disk, studio, ds, monkeypatch):
    """Fill the disk just before the scan's ``write`` of the 6th view (r01_c002 in row-meander order;
    the 5 before are stored). Returns the camera's captures per view name."""
    camera = studio.camera
    real_capture = camera.capture
    captures: dict[str, int] = {}

    def capture(stem_path, on_exposed=None):
        captures[stem_path.name] = captures.get(stem_path.name, 0) + 1
        if stem_path.name != "r01_c002" or write != "capture" or captures[stem_path.name] > 1:
            return real_capture(stem_path, on_exposed=on_exposed)

        def exposed():
            disk.fill()                  # after the shutter closed, before the camera writes the file
            on_exposed()
        return real_capture(stem_path, on_exposed=exposed)
    monkeypatch.setattr(camera, "capture", capture)
    if write == "thumbnail":
        real = store_module.make_thumbnail
        filling = _fill_before(disk, real)
        monkeypatch.setattr(store_module, "make_thumbnail", lambda files, out, *a, **k: (
            filling if out.stem == "r01_c002" else real)(files, out, *a, **k))
    elif write in ("journal", "manifest"):
        name = "record_view" if write == "journal" else "save"
        ds.journal_limit_bytes = 0               # every checkpoint of the scan rewrites the manifest
        real = getattr(ds, name)
        calls = {"n": 0}

        def wrapped(*a, **k):
            calls["n"] += 1
            if calls["n"] == 6:
                disk.fill()
            return real(*a, **k)
        monkeypatch.setattr(ds, name, wrapped)
    return captures


@pytest.mark.parametrize("write", ["capture", "thumbnail", "journal", "manifest"])
def test_a_full_disk_at_each_write_of_a_scan_stops_keeps_and_resumes(write, disk_scan, monkeypatch):
    disk, studio, ds, engine, events = disk_scan
    captures = _arm(write, disk, studio, ds, monkeypatch)
    paused = threading.Event()
    engine.subscribe(lambda ev: paused.set() if ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED else None)
    engine.start()
    assert paused.wait(T), engine.message
    assert engine.fault is not None and engine.fault.device == "disk", engine.message
    assert "is full" in engine.message and f"the disk at {disk.path} (tmpfs" in engine.message, engine.message
    assert "camera" not in engine.message.lower()
    assert not any(e.kind is EventKind.VIEW_FAILED and e.extra.get("device") == "camera" for e in events)
    stored_before = {f"r{r:02d}_c{c:03d}" for r, c in ((e.row, e.column) for e in events
                                                         if e.kind is EventKind.VIEW_DONE)}
    (disk.path / "filler.bin").unlink()          # the operator frees space
    engine.resume()
    assert engine.wait(T) is ScanState.FINISHED, engine.message
    done = [(e.row, e.column) for e in events if e.kind is EventKind.VIEW_DONE]
    assert sorted(done) == sorted(grid_order(4, 3)) and len(done) == 12     # each view exactly once
    # a view stored before the fault is never captured again; a view is captured again only when its
    # own file never arrived: the one whose capture met the full disk, and pipelined captures still in
    # flight when the disk filled up
    assert all(captures[name] == 1 for name in stored_before), (captures, stored_before)
    if write == "capture":
        assert captures["r01_c002"] == 2, captures
    # (in flight: one capture exposing, two waiting for the store thread)
    assert sum(captures.values()) <= 12 + 3, captures
    again = Dataset.open(ds.root)
    assert again.status_counts()["done"] == 12 and again.verify_files() == []
    assert all(v.get("thumb") for v in again.views)       # a thumbnail the full disk kept back is made later
    assert engine.done == 12


def test_a_folder_turning_unwritable_mid_scan_is_the_disks_fault_then_resumes(disk_scan):
    """The raw folder made immutable (``chattr +i``: every new file refused, as on a disk that turned
    read-only) while the scan runs: a disk fault, never the camera's; Resume after it is fixed."""
    disk, studio, ds, engine, events = disk_scan
    paused = threading.Event()

    def on(ev):
        if ev.kind is EventKind.VIEW_DONE and ev.done == 4:
            subprocess.run(["chattr", "+i", str(ds.root / "raw")], check=True)
        if ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED:
            paused.set()
    engine.subscribe(on)
    engine.start()
    try:
        assert paused.wait(T), engine.message
    finally:
        subprocess.run(["chattr", "-i", str(ds.root / "raw")], check=True)
    assert engine.fault.device == "disk" and "does not allow this write" in engine.message, engine.message
    assert "camera" not in engine.message.lower()
    assert not any(e.kind is EventKind.VIEW_FAILED and e.extra.get("device") == "camera" for e in events)
    engine.resume()
    assert engine.wait(T) is ScanState.FINISHED, engine.message
    done = [(e.row, e.column) for e in events if e.kind is EventKind.VIEW_DONE]
    assert sorted(done) == sorted(grid_order(4, 3)) and len(done) == 12
    assert Dataset.open(ds.root).verify_files() == []


def test_the_free_space_floor_comes_from_the_views_captured_so_far(disk_scan):
    disk, studio, ds, engine, events = disk_scan
    assert engine.need_bytes() == max(64 * 1024, 2 * 0 + 2 * ds.manifest_path.stat().st_size + 2**20)
    engine.start()
    assert engine.wait(T) is ScanState.FINISHED
    view = ds.view(0, 0)
    size = sum((ds.root / rel).stat().st_size for rel in (view["file"], *view["sidecars"], view["thumb"]))
    assert engine.need_bytes() >= 2 * size + 2 * ds.manifest_path.stat().st_size
    assert engine.need_bytes() < 2 * size + 2 * ds.manifest_path.stat().st_size + 2**20 + 4096 * 8


# -- the command line: scan, process, export, calibrate on a full or read-only disk ------------------------------
def test_a_scan_the_disk_cannot_hold_is_refused_before_it_starts_naming_need_free_folder_and_fix(small_disk, run_cli):
    """The simulated camera tells its frame size: 6 x 4 views of ~250 kB and the engine's 8 MB floor do not
    fit 12 MB; refused before the dataset is made (it used to run until the floor paused it)."""
    disk = small_disk(12 * 2**20)
    out = disk.path / "ds"
    args = ("scan", "--port", "instant", "--camera", "sim", "--sim-width-px", "400", "--time-scale", "0",
            "--grid", "6x4", "--out", out)
    proc = run_cli(*args, timeout=120)
    line = assert_one_line_error(proc, 1, "Disk too small for this scan: 24 views need about", str(out),
                                 f"the disk at {disk.path} has", "Fix: free space there")
    assert "400 x 266 px" in line, line           # how the need was counted
    assert not out.exists()                       # nothing written, no folder left behind
    subprocess_remount(disk, 32 * 2**20)
    again = run_cli(*args, timeout=120)
    assert again.returncode == 0, again.stderr
    assert Dataset.open(out).status_counts()["done"] == 24


def test_a_camera_of_unknown_frame_size_pauses_after_the_first_view_when_the_rest_does_not_fit(small_disk, run_cli):
    """The instant camera does not describe its frames (as a gphoto2 camera or a hot folder): the scan
    starts, the first view's files are measured, and it stops at once with the whole scan's need; the
    resume on a larger disk keeps what was captured."""
    disk = small_disk(12 * 2**20)
    out = disk.path / "ds"
    proc = run_cli("scan", "--port", "instant", "--camera", "instant", "--time-scale", "0", "--grid", "40x30",
                   "--out", out, timeout=120)
    line = assert_one_line_error(proc, 3, "stopped: Disk too small for this scan:", "measured on the first view",
                                 str(out), f"the disk at {disk.path} has", "Fix: free space there")
    assert "camera's cable" not in proc.stderr
    first = {(v["row"], v["column"]): (v["sha256"], v["captured_at"]) for v in Dataset.open(out).views
             if v["status"] == "done"}
    # the first view and those already in the pipeline when it was measured (the store queue holds 2), not hours
    assert 1 <= len(first) <= 5, line
    subprocess_remount(disk, 64 * 2**20)
    again = run_cli("scan", "--resume", "--time-scale", "0", "--out", out, timeout=300)
    assert again.returncode == 0, again.stderr
    ds = Dataset.open(out)
    assert ds.status_counts()["done"] == 1200 and ds.verify_files() == []
    kept = {(v["row"], v["column"]): (v["sha256"], v["captured_at"]) for v in ds.views if (v["row"], v["column"]) in first}
    assert kept == first                         # nothing captured before the pause was captured again


def subprocess_remount(disk, size_bytes):
    subprocess.run(["mount", "-o", f"remount,size={size_bytes}", str(disk.path)], check=True, capture_output=True)


def test_scan_resume_on_a_read_only_disk_is_one_line_and_touches_nothing(small_disk, scanned, run_cli):
    disk = small_disk(4 * 2**20)
    src = scanned(3, 2)
    m = manifest_of(src)
    shutil.copytree(src, disk.path / "ds")
    set_pending(disk.path / "ds", {(1, 0), (1, 1), (1, 2)})
    disk.read_only()
    proc = run_cli("scan", "--resume", "--out", disk.path / "ds")
    assert_one_line_error(proc, 1, "read-only", str(disk.path))
    assert manifest_of(disk.path / "ds")["views"][0] == m["views"][0]


def test_process_on_a_full_disk_stops_keeps_the_views_processed_and_resumes(small_disk, tiny_dataset, run_cli):
    disk = small_disk(64 * 2**20)
    root = disk.path / "ds"
    shutil.copytree(tiny_dataset.root, root)
    (root / "processing.toml").write_text("[rectify]\nenabled = false\n")    # not calibrated
    used = sum(p.stat().st_size for p in root.rglob("*") if p.is_file())
    filler = disk.fill(leave_bytes=1200 * 1024)          # room for a few processed views, not for all 15
    proc = run_cli("process", root, "--workers", "0", timeout=300)
    assert_one_line_error(proc, 1, "Disk problem", str(disk.path))
    kept = [v for v in Dataset.open(root).views if (v.get("processed") or {}).get("status") == "done"]
    filler.unlink()
    again = run_cli("process", root, "--workers", "0", timeout=300)
    assert again.returncode == 0, again.stderr
    assert f"{len(kept)} already done (skipped)" in again.stdout, (used, again.stdout)
    assert all((v.get("processed") or {}).get("status") == "done" for v in Dataset.open(root).views)


@pytest.mark.parametrize("fault", ["full", "read-only"])
def test_export_to_a_full_or_read_only_disk_is_one_line_and_leaves_nothing_half_written(fault, small_disk,
                                                                                       tiny_dataset, run_cli):
    disk = small_disk(1 * 2**20)
    before = manifest_of(tiny_dataset.root)
    if fault == "read-only":
        disk.read_only()
    proc = run_cli("export", tiny_dataset.root, "--format", "png", "--out", disk.path / "export", timeout=300)
    assert_one_line_error(proc, 1, "full" if fault == "full" else "read-only", str(disk.path))
    assert not (disk.path / "export").exists()
    assert [p.name for p in disk.path.iterdir()] == []                   # no partial folder left either
    assert manifest_of(tiny_dataset.root) == before


def test_calibrate_on_a_read_only_dataset_is_one_line(small_disk, tiny_dataset, run_cli):
    disk = small_disk(64 * 2**20)
    shutil.copytree(tiny_dataset.root, disk.path / "ds")
    disk.read_only()
    proc = run_cli("calibrate", disk.path / "ds", "--views", "3x3", timeout=300)
    assert_one_line_error(proc, 1, "read-only", str(disk.path))


@pytest.mark.skipif(os.geteuid() != 0 or not shutil.which("setpriv"), reason="needs root and setpriv")
def test_a_dataset_this_user_may_not_write_is_the_folders_problem_not_the_cameras(scanned, tmp_path):
    """EACCES on a real file system: the dataset belongs to another user and the scan runs without the
    power to override file permissions (root without CAP_DAC_OVERRIDE)."""
    from tests.conftest import REPO_ROOT

    root = scanned(3, 2)
    set_pending(root, {(1, 0), (1, 1), (1, 2)})
    for p in [root, *root.rglob("*")]:
        os.chown(p, 65534, 65534)
        p.chmod(0o755 if p.is_dir() else 0o644)            # others may read, not write
    before = manifest_of(root)
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    proc = subprocess.run(["setpriv", "--bounding-set=-dac_override,-dac_read_search", "--", sys.executable, "-m",
                           "lfstudio", "scan", "--resume", "--out", str(root)], capture_output=True, text=True,
                          timeout=120, env=env, cwd=REPO_ROOT)
    assert_one_line_error(proc, 1, f"the folder {root} is not writable for this user")
    assert "camera" not in proc.stderr.lower()
    assert manifest_of(root) == before


def test_a_full_disk_at_a_new_datasets_first_write_names_that_disk_and_a_rerun_works(small_disk, run_cli):
    """ENOSPC at the first manifest write named the disk of the working folder ('the disk at / … 72.7 GB
    free is full'), and the raw/ and thumbs/ it had made refused the re-run ('not empty')."""
    disk = small_disk(16 * 2**20)            # room for the scan's free-space floor once the filler is gone
    filler = disk.fill()
    args = ("scan", "--port", "instant", "--camera", "instant", "--grid", "2x1", "--out", disk.path / "ds")
    proc = run_cli(*args)
    line = assert_one_line_error(proc, 1, str(disk.path))
    assert "the disk at / " not in line
    left = sorted(p.name for p in (disk.path / "ds").iterdir()) if (disk.path / "ds").exists() else []
    assert left in ([], ["dataset.lock"], ["dataset.lock", "manifest.lock"]), left
    filler.unlink()
    again = run_cli(*args)
    assert again.returncode == 0, again.stderr


def test_hevc_export_to_a_full_disk_is_the_disks_fault_not_the_encoders(small_disk, tiny_dataset, run_cli):
    disk = small_disk(160 * 1024)                      # the video's first packets do not fit
    proc = run_cli("export", tiny_dataset.root, "--format", "hevc", "--out", disk.path / "lf.mkv", timeout=300)
    line = assert_one_line_error(proc, 1, "full", str(disk.path))
    assert "--crf" not in line and "encoder failed" not in line
    assert [p.name for p in disk.path.iterdir()] == []                   # nothing half-written left
