"""Bracketed views whose frame failed, taken again (review findings on the bracket path of the scan
engine, on the simulated studio: GRBL simulator on a pty, the simulated camera writing real DNGs).

Found by the review: (1) after a fault and Resume the attempt numbers start again, so a view whose
frame failed in its transfer was taken again under an attempt number already marked failed and all
its new frames were dropped (the scan finished with the view pending): fixed, the store forgets a
view's failed take when a new take's first frame arrives (``scan/store.py``). (2) a re-capture
journaled the new frames of a done view one by one over its done record, so a failure after the first
left a done view with one frame and ``dataset.json`` that no longer opened (validate_manifest: 1
frame(s), the bracket has 3): fixed, the view turns pending with its first new frame (its old files
are being replaced) and is done again with its last."""

from __future__ import annotations


from lfstudio.dataset import Dataset
from lfstudio.dataset.bracket import parse_bracket
from lfstudio.scan.events import ScanState
from lfstudio.scan.scan_plan import ScanPlan
from tests.scan.conftest import engine_with_events, fail_captures_from_setting

BRACKET = parse_bracket("-2,0,+2")


def test_a_view_whose_frame_failed_is_stored_when_resume_takes_it_again_in_the_same_engine(small_studio):
    session, plan, ds = small_studio
    engine, events = engine_with_events(session, ScanPlan(**{**plan.__dict__, "bracket": BRACKET}), ds, retries=0)
    camera = session.camera
    fail_captures_from_setting(camera, 2 * 3 + 2)   # the third view's second frame (and every shot after it)
    engine.start()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=60), engine.message
    camera.clear_faults()
    engine.resume().result(10)
    assert engine.wait(60) is ScanState.FINISHED, engine.message
    final = Dataset.open(ds.root)
    assert final.status_counts()["done"] == 6, [(v["row"], v["column"], v["status"]) for v in final.views]
    assert final.verify_files() == []


def test_a_frame_whose_transfer_failed_is_taken_again_and_stored_after_resume_in_the_same_engine(small_studio):
    from lfstudio.errors import DeviceError

    session, plan, ds = small_studio
    engine, events = engine_with_events(session, ScanPlan(**{**plan.__dict__, "bracket": BRACKET}), ds, retries=0)
    camera = session.camera
    real_capture = camera.capture
    shots = []

    def capture(stem, on_exposed=None):   # the third view's second frame: exposed, then its transfer fails
        result = real_capture(stem, on_exposed=on_exposed)
        shots.append(stem)
        if len(shots) == 2 * 3 + 2:
            raise DeviceError("transfer failed (review test)")
        return result

    camera.capture = capture
    engine.start()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=60), engine.message
    assert "transfer failed" in engine.message
    engine.resume().result(10)
    assert engine.wait(60) is ScanState.FINISHED, engine.message
    final = Dataset.open(ds.root)
    assert final.status_counts()["done"] == 6, [(v["row"], v["column"], v["status"]) for v in final.views]
    assert final.verify_files() == []


def test_a_recapture_whose_second_frame_fails_leaves_the_view_with_all_its_frames(small_studio):
    from lfstudio.dataset.manifest import validate_manifest
    from lfstudio.errors import DeviceError

    session, plan, ds = small_studio
    bplan = ScanPlan(**{**plan.__dict__, "bracket": BRACKET})
    engine, _ = engine_with_events(session, bplan, ds)
    engine.start()
    assert engine.wait(60) is ScanState.FINISHED, engine.message
    done = Dataset.open(ds.root)
    camera = session.camera
    real_capture = camera.capture
    shots = []

    def capture(stem, on_exposed=None):    # the re-captured view's second frame: its transfer fails
        result = real_capture(stem, on_exposed=on_exposed)
        shots.append(stem)
        if len(shots) == 2:
            raise DeviceError("transfer failed (review test)")
        return result

    camera.capture = capture
    engine2, _ = engine_with_events(session, bplan.with_subset([(0, 0)]), done, recapture=True, retries=0)
    engine2.start()
    assert engine2.wait_for_state(ScanState.PAUSED, timeout_s=60), engine2.message
    engine2.abort().result(10)
    assert engine2.wait(30) is ScanState.FINISHED
    after = Dataset.open(ds.root)
    v = after.view(0, 0)
    assert validate_manifest(after.manifest, after.root) == []
    assert v["status"] != "done" or len(v["frames"]) == 3, v
