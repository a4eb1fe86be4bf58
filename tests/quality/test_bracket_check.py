"""The quality check on exposure-bracketed scans (real DNGs of the virtual studio with a highlight
that clips at 0 EV): clipping is judged on what the merge keeps, with each frame's clipped and
crushed shares, and a bracket that does not reach the highlights is flagged with the fix."""

from __future__ import annotations

from dataclasses import replace

import pytest

from lfstudio.dataset import Dataset
from lfstudio.dataset.bracket import parse_bracket
from lfstudio.quality.check import check_dataset
from lfstudio.rig.profile import load_rig
from lfstudio.scan.engine import ScanEngine
from lfstudio.scan.events import ScanState
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.sim.instant import InstantRig
from lfstudio.sim.sim_camera import SimulatedCamera
from lfstudio.sim.studio import VirtualStudio
from lfstudio.studio.session import create_scan_dataset

RIG = load_rig()


def _bracketed_engine(root, bracket: str) -> tuple[ScanEngine, Dataset]:
    """A 3 x 2 bracketed scan of bright highlights (up to 3x white) on the instant rig and the
    simulated camera, ready to start."""
    plan = replace(ScanPlan.centered(3, 2, (4.0, 6.0), RIG, settle_s=0.0), bracket=parse_bracket(bracket))
    studio = VirtualStudio(width_px=320, view_region_mm=plan.extent_mm(), highlight_gain=3.0, seed=3)
    rig = InstantRig(RIG)
    rig.connect()
    camera = SimulatedCamera(studio, rig.true_position_mm, exposure_s=0.5, time_scale=0.0, noise=0.001)
    camera.connect()
    ds = create_scan_dataset(root, plan, rig={"name": RIG.name}, camera={"name": "sim"}, lens={"name": "virtual"})
    return ScanEngine(ds, plan, rig, camera, time_scale=0.0), ds


def bracketed_scan(root, bracket: str) -> Dataset:
    engine, _ = _bracketed_engine(root, bracket)
    engine.start()
    assert engine.wait(120) is ScanState.FINISHED, engine.message
    return Dataset.open(root)


@pytest.mark.parametrize("bracket, covers", [("-2,0,+2", True), ("0,+1", False)])
def test_clipping_is_judged_on_the_merge_and_a_short_bracket_is_flagged(tmp_path, bracket, covers):
    ds = bracketed_scan(tmp_path / "ds", bracket)
    report = check_dataset(ds, write=False)
    for v in report.views:
        c = v["checks"]["clipping"]
        frames = c["frames"]
        assert [f["exposure_s"] for f in frames] == pytest.approx(parse_bracket(bracket).shutter_times_s(0.5))
        zero_ev = next(f for f in frames if f["exposure_s"] == pytest.approx(0.5))
        assert zero_ev["clipped"] > 0.005                     # the highlight clips at the middle exposure
        assert c["covers_range"] is covers
        if covers:
            assert c["merged"]["clipped"] < 0.0005 and c["verdict"] == "pass", c
        else:
            assert c["merged"]["clipped"] == pytest.approx(zero_ev["clipped"]) and c["verdict"] != "pass"
            assert "the bracket does not cover the scene's range: the shortest frame (0.5 s) still clips" in c["why"]
            assert "add a shorter frame" in c["why"]


def _live_scan(root, bracket: str, where: str):
    """A bracketed scan (as bracketed_scan) with the scan-time check subscribed to its events."""
    from lfstudio.quality.live import LiveChecker, LiveCheckerProcess

    engine, ds = _bracketed_engine(root, bracket)
    checker = LiveChecker(ds) if where == "thread" else LiveCheckerProcess(ds)
    engine.subscribe(checker.on_event)
    engine.start()
    assert engine.wait(120) is ScanState.FINISHED, engine.message
    assert checker.wait_idle(120)
    checker.close()
    assert checker.errors == {}
    return checker, Dataset.open(root)


@pytest.mark.parametrize("bracket, covers, where", [("-2,0,+2", True, "thread"), ("0,+1", False, "thread"),
                                                    ("-2,0,+2", True, "process")])
def test_the_scan_time_check_judges_the_merge_as_lfstudio_check_does(tmp_path, bracket, covers, where):
    """Highlights clipped at 0 EV but held by the -2 EV frame are not flagged while scanning (the live
    check judged the 0 EV frame alone before); clipped in every frame of 0,+1 they are, with the fix.
    The same clipping entry as `lfstudio check` writes afterwards (one implementation)."""
    checker, ds = _live_scan(tmp_path / "ds", bracket, where)
    assert len(checker.results) == 6
    after = {(v["row"], v["column"]): v["checks"]["clipping"] for v in check_dataset(ds, write=False).views}
    for cell, entry in checker.results.items():
        live = entry["checks"]["clipping"]
        zero_ev = next(f for f in live["frames"] if f["exposure_s"] == pytest.approx(0.5))
        assert zero_ev["clipped"] > 0.005, live        # the 0 EV frame alone would be flagged
        assert live["covers_range"] is covers and (live["verdict"] == "pass") is covers, live
        assert live["frames"] == after[cell]["frames"] and live["merged"] == after[cell]["merged"]
        assert live["verdict"] == after[cell]["verdict"] and live["why"] == after[cell]["why"]
    if covers:
        assert not {c: e for c, e in checker.flagged().items() if "clipping" in " ".join(e["reasons"])}
    else:
        assert set(checker.flagged()) == set(checker.results)
        assert all("add a shorter frame" in e["checks"]["clipping"]["why"] for e in checker.results.values())
