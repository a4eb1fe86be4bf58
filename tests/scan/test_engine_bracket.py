"""Exposure brackets in the scan engine, on the simulated studio (GRBL simulator on a pty, the
simulated camera writing real DNGs): every frame of a view is stored under that view with the
shutter time the camera reported, the view is done only when all its frames are, and a resume
takes an unfinished view's frames again, whole."""

from __future__ import annotations

import numpy as np
import pytest
import rawpy

from lfstudio.dataset import Dataset
from lfstudio.dataset.bracket import parse_bracket
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.scan_plan import ScanPlan, grid_order
from tests.scan.conftest import engine_with_events, fail_captures_from_setting

BRACKET = parse_bracket("-2,0,+2")


engine_for = engine_with_events


def raw_mean(path):
    with rawpy.imread(str(path)) as raw:
        return float(np.mean(raw.raw_image_visible.astype(np.float64) - 512))


def test_every_frame_of_a_view_is_stored_under_it_with_the_reported_exposure(small_studio):
    session, plan, ds = small_studio
    engine, events = engine_for(session, ScanPlan(**{**plan.__dict__, "bracket": BRACKET}), ds)
    engine.start()
    assert engine.wait(60) is ScanState.FINISHED, engine.message
    assert [(e.row, e.column) for e in events if e.kind is EventKind.VIEW_DONE] == grid_order(3, 2)
    again = Dataset.open(ds.root)
    assert again.verify_files() == []
    assert again.manifest["bracket"]["ev"] == [-2.0, 0.0, 2.0]
    assert again.manifest["bracket"]["frame_shutter_s"] == pytest.approx([0.125, 0.5, 2.0])
    v = again.view(1, 2)
    assert v["status"] == "done" and v["reference_frame"] == 1
    assert [f["file"] for f in v["frames"]] == [f"raw/r01_c002.f{k}.dng" for k in range(3)]
    assert v["file"] == "raw/r01_c002.f1.dng" and v["exposure_s"] == pytest.approx(0.5)
    assert [f["exposure_s"] for f in v["frames"]] == pytest.approx([0.125, 0.5, 2.0])
    means = [raw_mean(again.path_of(f["file"])) for f in v["frames"]]
    assert means[0] < means[1] < means[2]                  # longer shutter, brighter frame
    assert means[1] / means[0] == pytest.approx(4.0, rel=0.2)   # (the brightest may clip)
    assert session.camera.shots == 18
    assert session.camera.exposure_s == 0.5          # set back to the shutter time the scan began with


def test_a_view_is_done_only_when_all_its_frames_are_and_resume_takes_it_again_whole(small_studio):
    session, plan, ds = small_studio
    bplan = ScanPlan(**{**plan.__dict__, "bracket": BRACKET})
    engine, events = engine_for(session, bplan, ds, retries=1)
    camera = session.camera
    fail_captures_from_setting(camera, 2 * 3 + 2)   # the third view's second frame (and every shot after it)
    engine.start()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=60), engine.message
    assert "Camera failed" in engine.message
    engine.abort().result(10)
    assert engine.wait(30) is ScanState.FINISHED and engine.aborted
    half = Dataset.open(ds.root)
    assert half.status_counts()["done"] == 2
    assert all(len(v["frames"]) == 3 for v in half.done_views())
    third = half.view(*grid_order(3, 2)[2])
    assert third["status"] != "done" and [f["index"] for f in third["frames"]] == [0]   # journaled, not done
    assert (half.root / third["frames"][0]["file"]).is_file()
    camera.clear_faults()
    shots = camera.shots
    engine2, _ = engine_for(session, bplan, half)
    engine2.start()
    assert engine2.wait(60) is ScanState.FINISHED, engine2.message
    assert camera.shots - shots == 4 * 3                  # the unfinished view again whole, and the 3 not taken
    final = Dataset.open(ds.root)
    assert final.status_counts()["done"] == 6 and final.verify_files() == []
    assert all([f["index"] for f in v["frames"]] == [0, 1, 2] for v in final.views)
    assert len(list((final.root / "raw").glob("*.dng"))) == 18    # every view exactly once, 3 frames each


def test_resume_with_another_bracket_is_refused_naming_both(small_studio):
    session, plan, ds = small_studio
    engine, _ = engine_for(session, ScanPlan(**{**plan.__dict__, "bracket": BRACKET}), ds)
    engine.start()
    assert engine.wait(60) is ScanState.FINISHED
    ds2 = Dataset.open(ds.root)
    ds2.record_view(0, 0, status="pending")
    engine2, _ = engine_for(session, ScanPlan(**{**plan.__dict__, "bracket": parse_bracket("-1,0")}), ds2)
    engine2.start()
    assert engine2.wait(30) is ScanState.FAILED
    assert "--bracket" in engine2.message and "-2, 0, +2 EV" in engine2.message and "3 frames" in engine2.message
