"""Fault matrix, devices: the serial port vanishing mid-scan (USB unplugged) and a camera that stops
answering, through the scan session the CLI and the window use. The scan stops with a message naming
the device and the operation in words (no Python internals), within the time the operation allows, and
every view captured before is kept exactly once when the scan resumes."""

from __future__ import annotations

import threading
from pathlib import Path

from lfstudio.dataset import Dataset
from lfstudio.rig.profile import load_rig
from lfstudio.scan.engine import ScanEngine
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.scan_plan import ScanPlan, grid_order
from lfstudio.studio.devices import open_studio
from lfstudio.studio.session import ScanRequest, ScanSession, create_scan_dataset

RIG = load_rig()
T = 60


def captured(root):
    return {(v["row"], v["column"]): (v["file"], v["sha256"], v["captured_at"])
            for v in Dataset.open(root).views if v.get("status") == "done"}


def _paused(engine):
    paused = threading.Event()
    engine.subscribe(lambda ev: paused.set() if ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED else None)
    return paused


def test_the_serial_port_vanishing_mid_scan_keeps_every_view_and_a_new_session_resumes(tmp_path):
    plan = ScanPlan.centered(4, 3, (4.0, 6.0), RIG, settle_s=0.0)
    studio = open_studio("sim", "sim", RIG, time_scale=0.0, view_region_mm=plan.extent_mm(), sim_width_px=96)
    ds = create_scan_dataset(tmp_path / "ds", plan, rig={"name": RIG.name}, camera={"name": "sim"},
                             lens={"name": "virtual"})
    engine = ScanEngine(ds, plan, studio.rig, studio.camera, time_scale=0.0, backoff_s=0.01, retries=1)
    paused = _paused(engine)
    engine.subscribe(lambda ev: studio.simulator.inject("drop") if ev.kind is EventKind.VIEW_DONE and ev.done == 4
                     else None)
    try:
        engine.start()
        assert paused.wait(T), engine.message
        assert engine.fault.device == "rig" and engine.message.startswith("Rig"), engine.message
        for internal in ("Traceback", "PosixPath", "<bound", "Errno"):
            assert internal not in engine.message
        engine.resume()                             # the port is gone: reconnecting fails, said in words
        assert paused.wait(T)
        engine.abort()
        assert engine.wait(T) is ScanState.FINISHED
        assert engine.message.startswith("Aborted") and "Resume the scan" in engine.message
    finally:
        studio.close()
    before = captured(ds.root)
    assert 4 <= len(before) < 12
    again = open_studio("sim", "sim", RIG, time_scale=0.0, view_region_mm=plan.extent_mm(), sim_width_px=96)
    try:
        resumed = ScanEngine(Dataset.open(ds.root), plan, again.rig, again.camera, time_scale=0.0)
        events = []
        resumed.subscribe(events.append)
        resumed.start()
        assert resumed.wait(T) is ScanState.FINISHED, resumed.message
    finally:
        again.close()
    after = captured(ds.root)
    assert len(after) == 12 and {cell: after[cell] for cell in before} == before
    assert sorted((e.row, e.column) for e in events if e.kind is EventKind.VIEW_DONE) == \
        sorted(set(grid_order(4, 3)) - set(before))
    assert Dataset.open(ds.root).verify_files() == []


def test_a_silent_camera_stops_the_scan_within_its_capture_time_naming_it_in_words(tmp_path):
    """The simulated camera's own "silent" fault (it stops answering) through the scan session: the
    capture's timeout comes from the camera's exposure and transfer (here 0.2 + 0.3 s: 2 x 0.5 + 10 s),
    not a fixed two minutes, and the scan pauses at once (waiting again would not help)."""
    request = ScanRequest(tmp_path / "ds", rig="instant", camera="sim", time_scale=1.0, exposure_s=0.2,
                          transfer_s=0.3, sim_width_px=96, camera_options={"faults": {"silent": None}})
    session = ScanSession(request, doing="test")
    try:
        engine = session.open(lambda existing, rig: (ScanPlan.centered(2, 1, (4.0, 6.0), rig, settle_s=0.0), None))
        assert engine.capture_call_timeout_s() == 11.0
        paused = _paused(engine)
        events: list = []
        engine.subscribe(events.append)
        engine.start()
        assert paused.wait(T), engine.message
        assert engine.message.startswith("Camera does not answer: the picture of view r00 c000 did not arrive "
                                         "within 11 s"), engine.message
        for internal in ("PosixPath", "<bound", "on_exposed", "timed out after"):
            assert internal not in engine.message
        failures = [e for e in events if e.kind is EventKind.VIEW_FAILED]
        assert all(not f.will_retry for f in failures)
        engine.abort()
        assert engine.wait(T) is ScanState.FINISHED
    finally:
        session.close()
    assert Dataset.open(Path(tmp_path / "ds")).verify_files() == []



def test_a_hot_folder_that_gets_no_file_stops_the_scan_at_once_with_its_own_words(tmp_path):
    """A hot-folder camera (the vendor software never drops the picture) is a silent camera too: its
    own wait ends the capture, and the scan pauses at once with the folder's words, not after retries."""
    folder = tmp_path / "incoming"
    folder.mkdir()
    request = ScanRequest(tmp_path / "ds", rig="instant", camera=f"folder:{folder}", time_scale=0.0)
    session = ScanSession(request, doing="test")
    try:
        engine = session.open(lambda existing, rig: (ScanPlan.centered(2, 1, (4.0, 6.0), rig, settle_s=0.0), None))
        engine.camera.call("set_setting", "timeout_s", 0.3)
        paused = _paused(engine)
        events: list = []
        engine.subscribe(events.append)
        engine.start()
        assert paused.wait(T), engine.message
        assert engine.message.startswith(f"Camera does not answer (view r00 c000): hot folder {folder}: no new "
                                         "complete file within 0.3 s"), engine.message
        assert [e.will_retry for e in events if e.kind is EventKind.VIEW_FAILED] == [False]
        engine.abort()
        assert engine.wait(T) is ScanState.FINISHED
    finally:
        session.close()


# -- Ctrl+C of 'lfstudio rig ... move' on the real GRBL 1.1h firmware ------------------------------------
from tests.faults.conftest import assert_one_line_error  # noqa: E402


def test_ctrl_c_during_rig_move_holds_then_resets_so_nothing_stays_queued(grbl_firmware, tmp_path):
    """A feed hold alone leaves the move queued in GRBL (a Cycle Start finishes it) and the held
    controller answers no later connection; like 'lfstudio scan', Ctrl+C holds, then soft-resets."""
    import os
    import signal
    import subprocess
    import sys

    from lfstudio.rig.grbl import GrblController
    from tests.conftest import REPO_ROOT
    from tests.faults.test_kill import wait_until

    fw = grbl_firmware(speedup=1.0)               # GRBL's defaults: 500 mm/min, so 150 mm take 18 s
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen([sys.executable, "-m", "lfstudio", "rig", "--port", fw.port, "--timeout-s", "5",
                             "origin", "move", "150", "150"], cwd=REPO_ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: any(line.startswith(("G0", "G1", "G90")) and "150" in line for line in fw.lines_received)
                   or proc.poll() is not None, T, "the move sent to the controller")
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=T)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130 and "Traceback" not in err, err
    assert b"!" in fw.realtime_received and b"\x18" in fw.realtime_received, fw.realtime_received
    assert fw.realtime_received.index(b"\x18") > fw.realtime_received.index(b"!")   # hold first, then reset
    c = GrblController(fw.port, RIG, timeout_s=3.0)
    c.connect()                                   # answers: not stuck in a hold
    try:
        first = c.status()
        assert first.state.value in ("idle", "alarm"), first
        c.resume()                                # Cycle Start: nothing left to finish
        wait_until(lambda: c.status().state.value in ("idle", "alarm"), T, "the controller at rest")
        x, y = c.status().position_mm
        assert x < 149.0 and y < 149.0            # the rest of the move was dropped
    finally:
        c.disconnect()


def test_a_grid_beyond_the_controllers_own_travel_is_refused_after_connecting(grbl_firmware, tmp_path, run_cli):
    """GRBL 1.1h at its default travel ($130 = $131 = 200 mm) with soft limits on, on the reference
    gantry's 4 m profile: a grid reaching 300 mm is refused once the controller is connected and homed,
    naming $130, before the first view (each view used to be refused, retried three times and the scan
    stopped with advice about the cable, exit 3)."""
    from tests.rig.test_grbl_firmware import SWITCHES

    fw = grbl_firmware(switches=SWITCHES, reset_on_open=True)
    fw.configure({22: 1, 20: 1})
    proc = run_cli("scan", "--port", fw.port, "--camera", "instant", "--home", "--grid", "3x1", "--spacing-mm",
                   "150x6", "--out", tmp_path / "ds", timeout=300)
    assert_one_line_error(proc, 2, "--grid", "$130 = 200 mm")
    assert not list((tmp_path / "ds" / "raw").glob("*")) if (tmp_path / "ds" / "raw").exists() else True
    assert not any(line.startswith("G90 G54 G0") for line in fw.lines_received)     # no move was sent
