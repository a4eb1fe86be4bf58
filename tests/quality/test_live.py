"""Scan-time checking: a real scan engine (instant rig, camera photographing the virtual studio with a
fault), the checker subscribed to its events, each view judged as it arrives."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from lfstudio.rig.profile import load_rig
from lfstudio.scan.engine import ScanEngine
from lfstudio.studio.session import create_scan_dataset
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.sim.instant import InstantCamera, InstantRig
from lfstudio.sim.studio import ViewFault, VirtualStudio
from lfstudio.sim.virtual_dataset import camera_dict, lens_dict

RIG = load_rig()


def faulty_scan(tmp_path, faults: list[ViewFault], cols: int = 5, rows: int = 4, width_px: int = 480):
    """An engine that scans a grid of the virtual studio; ``faults`` spoil their views."""
    plan = ScanPlan.centered(cols, rows, (4.0, 6.0), RIG, settle_s=0.0)
    x0, y0 = plan.origin_mm
    studio = VirtualStudio(width_px=width_px, rotation_deg=(1.0, -1.5, 0.7),
                           view_region_mm=(-1.0, (cols - 1) * 4.0 + 1.0, -1.0, (rows - 1) * 6.0 + 1.0), seed=7)
    by_position = {plan.position_mm(f.row, f.column): f for f in faults}

    def render(x_mm: float, y_mm: float) -> np.ndarray:
        fault = next((f for (fx, fy), f in by_position.items() if abs(fx - x_mm) < 1e-6 and abs(fy - y_mm) < 1e-6),
                     None)
        x, y = x_mm - x0, y_mm - y0
        if fault is not None:
            x, y = fault.true_position_mm((x, y), None)
        rgb = studio.render(x, y)
        if fault is not None:
            rgb = fault.spoil_image(rgb)
        return (np.clip(rgb, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)

    plan_dict = {"near_m": studio.near_m, "far_m": studio.far_m, "focal_length_mm": studio.focal_length_mm}
    ds = create_scan_dataset(tmp_path / "scan", plan, rig={"name": RIG.name}, camera=camera_dict(studio),
                             lens=lens_dict(studio), scene_plan=plan_dict)
    rig = InstantRig(RIG)
    rig.connect()
    cam = InstantCamera(rig.true_position_mm, render=render)
    cam.connect()
    return ScanEngine(ds, plan, rig, cam, time_scale=0.0), ds


@pytest.mark.parametrize("where", ["thread", "process"])
def test_the_live_checker_flags_faulty_views_as_they_arrive(tmp_path, where):
    """In a thread (``lfstudio scan --check``) or in a process of its own (the GUI): the same verdicts."""
    from lfstudio.quality.live import LiveChecker, LiveCheckerProcess

    faults = [ViewFault("blur", 2, 2, blur_px=6.0), ViewFault("displaced", 1, 3, offset_mm=(1.5, 0.0))]
    engine, ds = faulty_scan(tmp_path, faults)
    checker = LiveChecker(ds) if where == "thread" else LiveCheckerProcess(ds)
    first_entry: dict = {}
    published: list[dict] = []

    def on_verdict(entry):
        published.append(entry)
        first_entry.setdefault((entry["row"], entry["column"]), entry)
    checker.subscribe(on_verdict)
    engine.subscribe(checker.on_event)
    engine.start()
    assert engine.wait(60) is ScanState.FINISHED
    assert checker.wait_idle(120)
    checker.close()
    assert checker.errors == {}
    assert len(checker.results) == 20
    flagged = checker.flagged()
    assert set(flagged) == {(2, 2), (1, 3)}, {c: e["reasons"] for c, e in flagged.items()}
    assert flagged[(2, 2)]["checks"]["sharpness"]["verdict"] == "fail"
    assert flagged[(1, 3)]["checks"]["position"]["verdict"] == "fail"
    assert flagged[(1, 3)]["checks"]["position"]["error_mm"][0] == pytest.approx(1.5, rel=0.2)
    # flagged at once: the verdict published when the view itself was checked already says fail
    assert first_entry[(2, 2)]["verdict"] == "fail" and first_entry[(1, 3)]["verdict"] == "fail"
    doc = checker.document()
    assert len(doc["views"]) == 20 and doc["thresholds"]["position_fail_mm"] > 0
    assert doc["format"] == "lfstudio-quality" and doc["grid"] == {"columns": 5, "rows": 4}
    if where == "process":
        assert checker.process.pid != os.getpid() and not checker.process.is_alive()   # closed: it has ended


def test_a_live_check_process_that_cannot_open_the_dataset_says_why(tmp_path):
    from types import SimpleNamespace

    from lfstudio.quality.live import LiveCheckerProcess

    checker = LiveCheckerProcess(SimpleNamespace(root=tmp_path / "gone"))
    checker.submit(0, 0, "views/r000_c000.png")
    assert not checker.wait_idle(60)                 # the process ended instead of judging
    assert "gone" in checker.failed and "not a folder" in checker.failed
    assert checker.results == {}
    checker.close()


def test_the_scan_never_waits_for_the_checker(tmp_path, monkeypatch):
    """The checker's thread is held until the scan has finished: the scan finishes all the same."""
    import lfstudio.quality.live as live

    engine, ds = faulty_scan(tmp_path, [], cols=4, rows=2, width_px=160)
    release = threading.Event()
    real = live.measure_view

    def held(*args, **kwargs):
        release.wait(60)
        return real(*args, **kwargs)
    monkeypatch.setattr(live, "measure_view", held)
    checker = live.LiveChecker(ds)
    engine.subscribe(checker.on_event)
    finished = threading.Event()
    engine.subscribe(lambda ev: finished.set() if ev.kind is EventKind.STATE and ev.state is ScanState.FINISHED
                     else None)
    engine.start()
    assert finished.wait(60)
    assert checker.results == {}            # nothing judged yet: the checker is still held
    release.set()
    assert checker.wait_idle(60)
    checker.close()
    assert len(checker.results) == 8 and not checker.flagged()


def test_lfstudio_scan_check_judges_each_view_of_a_simulated_scan(tmp_path, run_cli):
    out = tmp_path / "scan"
    r = run_cli("scan", "--port", "sim", "--camera", "sim", "--grid", "5x3", "--out", out, "--time-scale", "0",
                "--sim-width-px", "480", "--check", timeout=300)
    assert r.returncode == 0, r.stderr
    assert "check: 15 views checked, none flagged" in r.stderr
    assert f"lfstudio check {out}" in r.stderr
