"""Fly scanning (#40): rows crossed at constant speed on the simulated studio (GRBL simulator on a
pty through the real driver, the simulated camera taking triggered frames with latency, jitter and
motion blur); positions interpolated from time-stamped reports; missed triggers taken again; an
interrupted row flown again on resume; refusals before the scan. No timing is asserted: a frame the
busy test machine fired late is taken again standing still, and either way the view is done."""

from __future__ import annotations

import json
import statistics
import subprocess
import sys

import pytest

from lfstudio.dataset import Dataset
from lfstudio.rig.camera import TriggeredCamera
from lfstudio.rig.motion import FlyingController, PositionReport
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.fly import FlyScanEngine, _gap_around, _predict, interpolate
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.studio.devices import open_studio
from lfstudio.studio.session import create_scan_dataset
from tests.scan.conftest import RIG

SCALE = 0.5


def fly_studio(root, columns=6, rows=2):
    """A ``columns`` x ``rows`` grid 30 mm from home (the carriage does not cross 2 m of travel to it)."""
    centred = ScanPlan.centered(columns, rows, (4.0, 6.0), RIG).origin_mm
    plan = ScanPlan.centered(columns, rows, (4.0, 6.0), RIG, settle_s=0.05,
                             offset_mm=(30.0 - centred[0], 30.0 - centred[1]))
    session = open_studio("sim", "sim", RIG, time_scale=SCALE, exposure_s=0.001, transfer_s=0.05,
                          view_region_mm=plan.extent_mm(), sim_width_px=64)
    ds = create_scan_dataset(root, plan, rig={"name": RIG.name}, camera={"name": "sim"}, lens={"name": "virtual"})
    return session, plan, ds


@pytest.fixture
def studio(tmp_path):
    session, plan, ds = fly_studio(tmp_path / "ds")
    yield session, plan, ds
    session.close()


def engine_of(session, plan, ds, **kw):
    engine = FlyScanEngine(ds, plan, session.rig, session.camera, time_scale=SCALE, backoff_s=0.01,
                           speed_mm_s=40.0, **kw)
    events = []
    engine.subscribe(events.append)
    return engine, events


def check_views(ds_root, engine):
    ds = Dataset.open(ds_root)
    assert ds.status_counts()["done"] == len(ds.views)
    assert ds.verify_files() == []
    flown = retaken = 0
    for v in ds.views:
        fly = v.get("fly") or {}
        if "recorded_mm" in fly:
            flown += 1
            assert v["reported_mm"] == fly["recorded_mm"]          # the recorded position is the view's
            assert abs(fly["recorded_mm"][0] - v["commanded_mm"][0]) <= engine.tolerance_mm + 1e-9
            assert fly["uncertainty_mm"] >= 0 and fly["speed_mm_s"] == pytest.approx(40.0)
            truth = json.loads((ds.root / v["sidecars"][1]).read_text())
            assert truth["subframes"] >= 1 and "blur_px_near" in truth
        else:
            assert "retaken" in fly or "standing_still" in fly, v   # never stored at a wrong position
            retaken += "retaken" in fly
    return flown, retaken


def test_the_devices_offer_the_capabilities(studio):
    session, _, _ = studio
    assert isinstance(session.camera, TriggeredCamera)
    assert isinstance(session.rig, FlyingController)


def test_fly_scan_end_to_end(studio):
    session, plan, ds = studio
    engine, events = engine_of(session, plan, ds)
    engine.start()
    assert engine.wait(120) is ScanState.FINISHED, engine.message
    assert engine.rows_flown >= 2
    flown, retaken = check_views(ds.root, engine)
    assert flown + retaken <= 12 and retaken == engine.retaken
    logs = [e.message for e in events if e.kind is EventKind.LOG]
    assert any("row 0: flying 6 views at 40 mm/s" in m for m in logs)


def test_a_missed_trigger_takes_the_view_again_flagged(studio):
    session, plan, ds = studio
    session.camera.inject("miss_trigger", 1)
    engine, _ = engine_of(session, plan, ds)
    engine.start()
    assert engine.wait(120) is ScanState.FINISHED, engine.message
    check_views(ds.root, engine)
    missed = [v for v in Dataset.open(ds.root).views if "missed trigger" in (v.get("fly") or {}).get("retaken", "")]
    assert len(missed) == 1 and missed[0]["status"] == "done"


def test_an_interrupted_row_is_flown_again_on_resume(studio):
    session, plan, ds = studio
    engine, events = engine_of(session, plan, ds)

    def abort_on_first_frame(ev):
        if ev.kind is EventKind.VIEW_EXPOSED and ev.row == 0:
            try:
                engine.abort()
            except Exception:
                pass

    engine.subscribe(abort_on_first_frame)
    engine.start()
    assert engine.wait(120) is ScanState.FINISHED, engine.message
    counts = Dataset.open(ds.root).status_counts()
    assert 1 <= counts["done"] < 12
    again = Dataset.open(ds.root)
    engine2 = FlyScanEngine(again, plan, session.rig, session.camera, time_scale=SCALE, backoff_s=0.01,
                            speed_mm_s=40.0)
    logs = []
    engine2.subscribe(lambda e: e.kind is EventKind.LOG and logs.append(e.message))
    engine2.start()
    assert engine2.wait(120) is ScanState.FINISHED, engine2.message
    check_views(ds.root, engine2)
    assert any(m.startswith("row ") and "flying" in m for m in logs)


def test_interpolation_and_prediction():
    reports = [PositionReport(10.0, 0.0, 5.0, 0.001), PositionReport(10.1, 4.0, 5.0, 0.001),
               PositionReport(10.2, 8.0, 5.0, 0.001)]
    x, y, unc = interpolate(reports, 10.15)
    assert (x, y) == pytest.approx((6.0, 5.0)) and unc == pytest.approx(40 * 0.001)
    assert interpolate(reports, 10.3) is None
    assert _gap_around(reports, 10.15) == pytest.approx(0.1) and _gap_around(reports, 10.3) == 0.0
    assert _predict(reports, 12.0, 1.0, 40.0, 500.0) == pytest.approx(10.3)     # at speed: its own speed
    assert _predict(reports, 6.0, 1.0, 40.0, 500.0) == pytest.approx(10.15)     # passed: when it did (late)
    assert _predict(reports[:1], 12.0, 1.0, 40.0, 500.0) is None
    # a report whose answer came long after its question (a busy controller) is left out when better ones are near
    vague = [PositionReport(10.0 + 0.02 * k, 0.8 * k, 5.0, 0.0002) for k in range(11)]
    vague[5] = PositionReport(10.1, 6.0, 5.0, 0.02)                       # really taken later: 2 mm ahead
    assert interpolate(vague, 10.1)[0] == pytest.approx(4.0)
    back = [PositionReport(r.t_s, -r.x_mm, r.y_mm) for r in reports]
    assert _predict(back, -12.0, -1.0, 40.0, 500.0) == pytest.approx(10.3)


def test_the_stated_uncertainty_covers_the_reports_timing_at_its_worst():
    """Carriage at 40 mm/s, x = 40 (t - 10). Report a is stamped 10.0 with 4 ms uncertainty but was taken at
    10.004 (x = 0.16); report b at 10.1 is exact. Interpolated at 10.01 (next to the vague report) the point is
    0.144 mm off. The old uncertainty, the reports' RMS timing times their own speed (38.4 mm/s, off with a's
    timing), said 0.109 mm; a bound is v ((1 - w) ua + w ub) with the row's speed: 0.144 mm."""
    a = PositionReport(10.0, 40.0 * 0.004, 5.0, 0.004)
    b = PositionReport(10.1, 4.0, 5.0, 0.0)
    t = 10.01
    where = interpolate([a, b], t, 40.0)
    assert where is not None
    x, _, unc = where
    error = abs(x - 40.0 * (t - 10.0))
    assert error == pytest.approx(0.144)
    assert unc >= error - 1e-9 and unc == pytest.approx(0.144)
    # the reports' own speed is the floor: a row speed given too low does not shrink it
    slow = interpolate([a, b], t, 1.0)
    assert slow is not None and slow[2] == pytest.approx(38.4 * 0.9 * 0.004)


def _scan(tmp_path, *args):
    return subprocess.run([sys.executable, "-m", "lfstudio", "scan", "--out", str(tmp_path / "ds"), "--grid", "4x2",
                           "--sim-width-px", "64", "--time-scale", str(SCALE), "--fly", *args],
                          capture_output=True, text=True, timeout=300)


def test_cli_fly_scan(tmp_path):
    out = _scan(tmp_path, "--exposure-s", "0.001", "--transfer-s", "0.05")
    assert out.returncode == 0, out.stderr
    assert "fly scan: rows at" in out.stderr and "binds" in out.stderr
    ds = Dataset.open(tmp_path / "ds")
    assert ds.manifest["acquisition"]["mode"] == "fly" and ds.status_counts()["done"] == 8
    # calibration and check take each view where it was really taken, as for an import with positions
    from lfstudio.calibration.calibrate import recorded_positions

    assert ds.positions_recorded
    cells = [(v["row"], v["column"]) for v in ds.views]
    where = recorded_positions(ds, cells)
    assert where is not None
    assert all(list(where[c]) == ds.view(*c)["reported_mm"] for c in cells)


def test_cli_refuses_a_camera_without_triggers(tmp_path):
    out = _scan(tmp_path, "--camera", "instant")
    assert out.returncode == 2, out.stderr
    line = out.stderr.strip().splitlines()[-1]
    assert "--fly" in line and "no triggered frames" in line and "Traceback" not in out.stderr
    assert not (tmp_path / "ds" / "dataset.json").exists()


def test_cli_refuses_a_blur_limit_no_speed_meets(tmp_path):
    out = _scan(tmp_path, "--exposure-s", "0.5", "--blur-limit-px", "0.01")
    assert out.returncode == 2, out.stderr
    line = out.stderr.strip().splitlines()[-1]
    assert "--fly" in line and "no fly speed keeps within blur ≤ 0.01 px" in line and "mm/s" in line
    assert not (tmp_path / "ds" / "dataset.json").exists()


# -- hardware trigger: the controller's output on the camera's trigger line -----------------------------
def test_hardware_trigger_fly_scan_records_where_the_line_rose(studio):
    session, plan, ds = studio
    assert session.rig.pulse_problem(plan.spacing_mm[0], 40.0) is None          # laser mode ($32=1)
    assert session.camera.line_trigger_problem() is None                          # wired to its output
    engine, events = engine_of(session, plan, ds, trigger="hardware")
    engine.start()
    assert engine.wait(120) is ScanState.FINISHED, engine.message
    flown, retaken = check_views(ds.root, engine)
    assert flown + retaken == 12 and flown >= 1
    lead_mm = 40.0 * (session.camera.line_trigger_latency_s + 0.5 * session.camera.exposure_s)
    offsets: dict[int, list[float]] = {}
    d = Dataset.open(ds.root)
    for v in d.views:
        fly = v.get("fly") or {}
        if "recorded_mm" not in fly:
            continue
        assert fly["trigger"] == "hardware" and fly["trigger_late_ms"] is None
        direction = 1 if v["row"] % 2 == 0 else -1                               # meander
        assert fly["recorded_mm"][0] == pytest.approx(v["commanded_mm"][0] + direction * lead_mm, abs=1e-3)
        truth = json.loads((d.root / v["sidecars"][1]).read_text())
        offsets.setdefault(v["row"], []).append(truth["true_position_mm"][0] - fly["recorded_mm"][0])
    # what is left is the rig's own repeatability, one draw for the row, which no report sees
    for row, errs in offsets.items():
        assert max(errs) - min(errs) < 0.03, (row, errs)
        assert abs(statistics.mean(errs)) < 5 * RIG.horizontal.repeatability_um / 1000


def test_hardware_trigger_edges_faster_than_the_camera_are_taken_again(studio):
    session, plan, ds = studio
    session.camera.frame_rate_fps = 0.5          # one frame per 2 s: the line rises every 0.1 s
    engine, _ = engine_of(session, plan, ds, trigger="hardware")
    engine.start()
    assert engine.wait(180) is ScanState.FINISHED, engine.message
    check_views(ds.root, engine)
    views = Dataset.open(ds.root).views
    missed = [v for v in views if "frames/s allow" in (v.get("fly") or {}).get("retaken", "")]
    assert missed and all(v["status"] == "done" for v in views)


def test_cli_fly_scan_with_the_hardware_trigger(tmp_path):
    out = _scan(tmp_path, "--exposure-s", "0.001", "--transfer-s", "0.05", "--trigger", "hardware")
    assert out.returncode == 0, out.stderr
    ds = Dataset.open(tmp_path / "ds")
    assert ds.manifest["acquisition"]["trigger"] == "hardware" and ds.status_counts()["done"] == 8
    assert any((v.get("fly") or {}).get("trigger") == "hardware" for v in ds.views)


def test_cli_refuses_the_hardware_trigger_without_laser_mode(tmp_path, monkeypatch, capsys):
    import lfstudio.studio.simulated as simulated
    from lfstudio.cli import main

    real = simulated.start_simulator

    def without_laser_mode(*args, **kwargs):
        sim = real(*args, **kwargs)
        sim.set_settings({32: 0})
        return sim

    monkeypatch.setattr(simulated, "start_simulator", without_laser_mode)
    code = main(["scan", "--out", str(tmp_path / "ds"), "--grid", "4x2", "--sim-width-px", "64", "--time-scale",
                 str(SCALE), "--fly", "--exposure-s", "0.001", "--transfer-s", "0.05", "--trigger", "hardware"])
    err = capsys.readouterr().err
    assert code == 2, err
    line = err.strip().splitlines()[-1]
    assert "--trigger" in line and "laser mode is off ($32 = 0)" in line and "$32=1" in line
    assert "Traceback" not in err and not (tmp_path / "ds" / "dataset.json").exists()


def test_hardware_trigger_abort_takes_effect_at_the_row_end_and_resume_flies_the_rest(studio):
    """The controller holds the whole row's G-code: an abort during the row lets its frames all come
    (never a frame at a wrong position), the next row is flown on resume."""
    session, plan, ds = studio
    engine, events = engine_of(session, plan, ds, trigger="hardware")

    def abort_on_first_frame(ev):
        if ev.kind is EventKind.VIEW_EXPOSED and ev.row == 0:
            try:
                engine.abort()
            except Exception:
                pass

    engine.subscribe(abort_on_first_frame)
    engine.start()
    assert engine.wait(120) is ScanState.FINISHED, engine.message
    cut = Dataset.open(ds.root)
    done = {(v["row"], v["column"]) for v in cut.done_views()}
    assert done and all(row == 0 for row, _ in done)               # row 1 never started
    assert all(cut.path_of(v).is_file() for v in cut.done_views())
    again = FlyScanEngine(Dataset.open(ds.root), plan, session.rig, session.camera, time_scale=SCALE,
                          backoff_s=0.01, speed_mm_s=40.0, trigger="hardware")
    again.start()
    assert again.wait(120) is ScanState.FINISHED, again.message
    check_views(ds.root, again)


def test_hardware_trigger_an_edge_the_camera_never_saw_stores_no_view_a_spacing_off(studio):
    """Frames pair with views in order; one edge the camera silently misses puts every later frame of the
    row a spacing further than its view. Each such frame is taken again; no view is stored where it was
    not (the simulator's truth beside each stored view lies within half a spacing of its position)."""
    session, plan, ds = studio
    session.camera.inject("miss_trigger", 1)          # in line mode: an edge never seen, nothing said
    engine, _ = engine_of(session, plan, ds, trigger="hardware")
    engine.start()
    assert engine.wait(180) is ScanState.FINISHED, engine.message
    check_views(ds.root, engine)
    d = Dataset.open(ds.root)
    spacing = plan.spacing_mm[0]
    retaken = [v for v in d.views if (v.get("fly") or {}).get("retaken")]
    assert retaken, "the missed edge went unnoticed"
    for v in d.views:
        truth = json.loads((d.root / v["sidecars"][1]).read_text())
        assert abs(truth["true_position_mm"][0] - v["commanded_mm"][0]) < 0.5 * spacing, (v["row"], v["column"])
