"""Fly scanning on emulated CiA 402 drives (#40): the dryve D1 emulator (Modbus TCP gateway telegrams;
CANopen SDO on the virtual bus) moving each row at its profile velocity, the simulated camera taking
triggered frames. As the D1 comes (no touch probe) every frame's position is interpolated from
time-stamped 6064h reads; with touch probes (a generic CiA 402 drive, ``sim-drive --touch-probe``) the
drives latch it on the camera's exposure output. No timing is asserted: a frame fired late on the busy
machine is taken again standing still, and either way the view is done at a position within its
tolerance; the recorded positions are compared with the emulator's truth at each exposure."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import pytest

from lfstudio.dataset import Dataset
from lfstudio.rig.profile import load_rig
from lfstudio.scan.events import ScanState
from lfstudio.scan.fly import FlyScanEngine
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.studio.devices import open_studio
from lfstudio.studio.session import create_scan_dataset
from tests.conftest import REPO_ROOT
from tests.scankill import lfstudio_env

RIG_NAME = "dryve D1 gantry 4 m x 0.5 m"
RIG = load_rig(RIG_NAME)
SCALE = 0.5


def fly_on_drives(root, port: str, setup: dict | None = None, columns: int = 6, rows: int = 2,
                  exposure_s: float = 0.001):
    """Homed at once (time scale 0), then flown at SCALE: the drives' long homing run is not the test."""
    plan = ScanPlan(columns, rows, (4.0, 6.0), (40.0, 20.0), settle_s=0.05)
    from lfstudio.studio import simulated

    real = simulated.start_drive_emulator

    def with_setup(*a, **kw):
        kw["setup"] = setup
        return real(*a, **kw)

    simulated.start_drive_emulator = with_setup
    try:
        session = open_studio(port, "sim", RIG, time_scale=0.0, exposure_s=exposure_s, transfer_s=0.05,
                              view_region_mm=plan.extent_mm(), sim_width_px=64, timeout_s=2.0)
    finally:
        simulated.start_drive_emulator = real
    session.simulator.time_scale = SCALE
    session.camera.time_scale = SCALE
    ds = create_scan_dataset(root, plan, rig={"name": RIG.name}, camera={"name": "sim"}, lens={"name": "virtual"})
    return session, plan, ds


def run_fly(session, plan, ds, speed: float = 40.0):
    engine = FlyScanEngine(ds, plan, session.rig, session.camera, time_scale=SCALE, backoff_s=0.01, speed_mm_s=speed)
    engine.start()
    assert engine.wait(300) is ScanState.FINISHED, engine.message
    return engine


def recorded_views(root):
    """(view, fly record, truth at the exposure's centre) of every view taken on the fly."""
    ds = Dataset.open(root)
    assert ds.status_counts()["done"] == len(ds.views)
    assert ds.verify_files() == []
    out = []
    for v in ds.views:
        fly = v.get("fly") or {}
        if "recorded_mm" in fly:
            truth = json.loads((ds.root / v["sidecars"][1]).read_text())
            out.append((v, fly, truth["true_position_mm"]))
        else:
            assert "retaken" in fly or "standing_still" in fly, v
    return out


@pytest.mark.parametrize("port", ["sim-dryve", "sim-canopen"])
def test_fly_scan_on_the_dryve_emulator_interpolates_6064h_reads(tmp_path, port):
    session, plan, ds = fly_on_drives(tmp_path / "ds", port)
    try:
        engine = run_fly(session, plan, ds)
        warnings = session.rig.status().extra["warnings"]
    finally:
        session.close()
    views = recorded_views(ds.root)
    assert views, "no view was taken on the fly"
    for v, fly, truth in views:
        assert fly["source"] == "reports"
        assert v["reported_mm"] == fly["recorded_mm"]
        assert abs(fly["recorded_mm"][0] - v["commanded_mm"][0]) <= engine.tolerance_mm + 1e-9
        # the interpolated position is where the carriage was at the exposure's centre: a position unit,
        # the reports' timing uncertainty, and the exposure (1 ms at 40 mm/s: 0.04 mm, centre to centre)
        assert abs(fly["recorded_mm"][0] - truth[0]) <= 0.011 + fly["uncertainty_mm"] + 0.05, (fly, truth)
        assert fly["recorded_mm"][1] == pytest.approx(truth[1], abs=0.011)
    assert sum("no touch probe" in w for w in warnings) == 1       # said once for the D1


@pytest.mark.parametrize("port", ["sim-dryve", "sim-canopen"])
def test_fly_scan_with_touch_probes_records_the_latched_positions(tmp_path, port):
    session, plan, ds = fly_on_drives(tmp_path / "ds", port, setup={"touch_probe": True})
    try:
        run_fly(session, plan, ds)
        latched = session.simulator.pair.axes[0].probe_latches
    finally:
        session.close()
    views = recorded_views(ds.root)
    by_probe = [(v, fly, truth) for v, fly, truth in views if fly["source"] == "touch probe"]
    assert latched >= len(by_probe) >= 1
    for _v, fly, truth in by_probe:
        # latched on both edges of the exposure output: the mean is the exposure's centre, to a position unit
        assert fly["recorded_mm"][0] == pytest.approx(truth[0], abs=0.011)
        assert fly["uncertainty_mm"] == pytest.approx(0.01)


@pytest.fixture
def sim_drive():
    """``lfstudio sim-drive --time-scale SCALE`` with the given options in its own process; yields a
    function starting one (its device word)."""
    procs = []

    def start(*options: str) -> str:
        proc = subprocess.Popen([sys.executable, "-m", "lfstudio", "sim-drive", "--time-scale", str(SCALE), "--seed",
                                 "5", *options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env=lfstudio_env(), cwd=REPO_ROOT)
        procs.append(proc)
        word = proc.stdout.readline().strip()
        assert word.startswith("dryve:127.0.0.1:"), proc.stderr.read() if proc.poll() is not None else word
        return word

    yield start
    for proc in procs:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
        proc.stdout.close()
        proc.stderr.close()


def _scan(word: str, out, *args: str):
    # the drives' own reference (--keep-drive-reference; their homing run would take the test's time), the
    # grid shifted next to where they count from
    return subprocess.run([sys.executable, "-m", "lfstudio", "scan", "--port", word, "--rig-profile", RIG_NAME,
                           "--camera", "sim", "--keep-drive-reference", "--fly", "--grid", "4x2", "--offset-mm",
                           "-1950x-200", "--sim-width-px", "64", "--time-scale", str(SCALE), "--exposure-s", "0.001",
                           "--transfer-s", "0.05", "--out", str(out), *args],
                          capture_output=True, text=True, timeout=300, env=lfstudio_env(), cwd=REPO_ROOT)


def test_a_drive_latching_only_the_rising_edge_gives_the_exposure_centre(tmp_path):
    """Touch probe without 60BBh (no negative edge): the latch is the exposure's start, and the recorded
    position its centre, half the exposure's travel on (5 ms at 40 mm/s: 0.1 mm)."""
    session, plan, ds = fly_on_drives(tmp_path / "ds", "sim-dryve", setup={"touch_probe": True, "leave_out": {0x60BB}},
                                      exposure_s=0.005)
    try:
        run_fly(session, plan, ds)
    finally:
        session.close()
    by_probe = [(fly, truth) for _v, fly, truth in recorded_views(ds.root) if fly["source"] == "touch probe"]
    assert by_probe
    for fly, truth in by_probe:
        assert fly["recorded_mm"][0] == pytest.approx(truth[0], abs=0.011)


def test_a_latch_pairs_with_its_frame_one_to_one_and_only_when_its_edges_are_one_exposure_apart():
    """A frame's latch: its window holds the exposure, its edges lie the exposure's travel apart, and it
    fits no other frame. Two frames' edges mixed (one came while the probe was being armed again) lie a
    spacing apart: not taken. Two frames 5 ms apart (a late trigger, then one on time) in one latch's
    window (the benchmark's 101x21 grid under load stored 0.77 mm off that way): neither takes it."""
    from lfstudio.rig.motion import Latch
    from lfstudio.scan.fly import _pair_latches

    good = Latch(10.0, 10.02, 44.0, 20.0, 0.01, "both", 0.04)
    mixed = Latch(10.03, 10.08, 46.0, 20.0, 0.01, "both", 3.96)
    rising = Latch(10.03, 10.08, 48.0, 20.0, 0.01, "rising", 0.0)
    frame, later, missing = (10.005, 10.006, 0.04), (10.05, 10.051, 0.04), None
    assert _pair_latches([good, mixed], [frame, later, missing]) == [good, None, None]
    assert _pair_latches([good, rising], [frame, later]) == [good, rising]
    assert _pair_latches([good], [(10.5, 10.501, 0.04)]) == [None]            # no window holds it: the reports
    twin = Latch(10.0, 10.02, 44.1, 20.0, 0.01, "both", 0.04)
    assert _pair_latches([good, twin], [frame]) == [None]                      # two fit: neither is taken
    close = (10.0195, 10.0205, 0.04)                                           # inside the window's slack
    assert _pair_latches([good], [frame, close]) == [None, None]               # one latch, two frames: neither


def test_cli_fly_scan_on_drives_in_another_process(tmp_path, sim_drive):
    """``lfstudio sim-drive --touch-probe`` in its own process, ``lfstudio scan --fly`` on its device word:
    the camera's exposure output reaches the other process' drives, which latch the positions."""
    word = sim_drive("--touch-probe")
    r = _scan(word, tmp_path / "ds")
    assert r.returncode == 0, r.stderr
    assert "fly scan: rows at" in r.stderr
    ds = Dataset.open(tmp_path / "ds")
    assert ds.manifest["acquisition"]["mode"] == "fly" and ds.status_counts()["done"] == 8
    sources = [(v.get("fly") or {}).get("source") for v in ds.views]
    assert "touch probe" in sources, sources
    for v in ds.views:
        fly = v.get("fly") or {}
        if fly.get("source") == "touch probe":
            assert v["reported_mm"] == fly["recorded_mm"]
            assert abs(fly["recorded_mm"][0] - v["commanded_mm"][0]) <= 1.0 + 1e-9     # a quarter spacing


def test_cli_refuses_a_speed_slow_drives_cannot_report_with_the_numbers(tmp_path, sim_drive):
    word = sim_drive("--answer-delay-ms", "100")       # a slow gateway: 100 ms per answer
    r = _scan(word, tmp_path / "ds", "--fly-speed-mm-s", "60")
    assert r.returncode == 2, r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert "--fly" in line and "60 mm/s is faster than the controller's" in line and "position reports/s" in line
    assert "Traceback" not in r.stderr and not (tmp_path / "ds" / "dataset.json").exists()


def test_stop_during_a_row_quick_stops_the_drives_and_resume_flies_the_rest(tmp_path):
    """STOP pressed while a row is flown on the drives (at its second trigger, from another thread as the
    window's button would): both drives get their quick stop, the scan pauses with the STOP line, no
    further trigger; Resume flies the row's other views again from a new run-up and the scan completes."""
    import threading

    from lfstudio.scan.events import EventKind

    session, plan, ds = fly_on_drives(tmp_path / "ds", "sim-dryve")
    try:
        engine = FlyScanEngine(ds, plan, session.rig, session.camera, time_scale=SCALE, backoff_s=0.01,
                               speed_mm_s=40.0)
        cam = session.camera
        real_trigger = cam.trigger
        triggers: list[float] = []
        stopper: list[threading.Thread] = []
        mark = len(session.simulator.pair.journal)

        def trigger():
            t = real_trigger()
            triggers.append(t)
            if len(triggers) == 2:
                stopper.append(threading.Thread(target=engine.rig.stop_now))
                stopper[0].start()
            return t

        cam.trigger = trigger
        engine.start()
        assert engine.wait_for_state(ScanState.PAUSED, timeout_s=120), engine.message
        stopper[0].join(30)
        assert engine.message.startswith("STOP pressed")
        quick = {name for name, index, _s, value in session.simulator.pair.journal[mark:]
                 if index == 0x6040 and value == 0x0B}
        assert quick == {"horizontal", "vertical"}
        assert Dataset.open(ds.root).status_counts()["done"] < 12
        logs: list[str] = []
        engine.subscribe(lambda e: e.kind is EventKind.LOG and logs.append(e.message))
        engine.resume()
        assert engine.wait(300) is ScanState.FINISHED, engine.message
        assert any(m.startswith("row 0: flying") for m in logs)     # the row's rest flown again
    finally:
        session.close()
    assert recorded_views(ds.root)
