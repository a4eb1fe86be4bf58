"""--keep-on-card's critical path (#40): the rig moves on as soon as the camera's shutter has closed, not
when the capture call returns (a body still writes the picture to its card, gphoto2 still lists the files
the shot added). A view is still done only once its file is downloaded and verified; a capture that fails
after its shutter closed is taken again."""

from __future__ import annotations

import threading

from lfstudio.dataset import Dataset
from lfstudio.errors import DeviceError
from lfstudio.rig.profile import load_rig
from lfstudio.scan.card import CardBufferEngine
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.studio.devices import open_studio
from lfstudio.studio.session import create_scan_dataset

RIG = load_rig()


def _studio(tmp_path, columns, rows):
    plan = ScanPlan.centered(columns, rows, (4.0, 6.0), RIG, settle_s=0.0)
    studio = open_studio("sim", "sim", RIG, time_scale=0.0, exposure_s=0.5, transfer_s=2.5,
                         view_region_mm=plan.extent_mm(), sim_width_px=48)
    ds = create_scan_dataset(tmp_path / "ds", plan, rig={"name": RIG.name}, camera={"name": "sim"},
                             lens={"name": "t"})
    return studio, plan, ds


def _check_all_done(root, n):
    done = Dataset.open(root)
    assert done.status_counts()["done"] == n and done.verify_files() == []
    assert all(done.path_of(v).is_file() for v in done.done_views())
    assert all(v.get("on_card") == [] for v in done.views)
    return done


def test_the_rig_moves_on_when_the_shutter_closes_not_when_the_capture_call_returns(tmp_path):
    studio, plan, ds = _studio(tmp_path, 4, 2)
    camera = studio.camera
    take = camera.capture_to_card
    next_view_started = threading.Event()
    moved_while_writing: list[bool] = []
    on_card_while_writing: list[list[str]] = []

    def writing_to_its_card(stem, on_exposed=None):
        files = take(stem, on_exposed=on_exposed)          # the shutter has closed (on_exposed called)
        if not moved_while_writing:                        # the first picture: the body is still writing it
            moved_while_writing.append(next_view_started.wait(30))
            on_card_while_writing.append(Dataset.open(ds.root).view(0, 0).get("on_card") or [])
        return files

    camera.capture_to_card = writing_to_its_card
    try:
        engine = CardBufferEngine(ds, plan, studio.rig, camera, time_scale=0.0)

        def on_event(e) -> None:
            if e.kind is EventKind.VIEW_STARTED and e.index == 1:
                next_view_started.set()

        engine.subscribe(on_event)
        engine.start()
        assert engine.wait(120) is ScanState.FINISHED, engine.message
    finally:
        studio.close()
    # the old engine waited for the call (30 s here, then False): the next view began while it ran
    assert moved_while_writing == [True]
    # its files were not yet known, so not yet journaled; they were once the call returned
    assert on_card_while_writing == [[]]
    _check_all_done(tmp_path / "ds", 8)
    assert engine.downloads == 8


def test_a_capture_that_fails_after_its_shutter_closed_is_taken_again(tmp_path):
    studio, plan, ds = _studio(tmp_path, 4, 2)
    camera = studio.camera
    take = camera.capture_to_card
    calls: list[str] = []

    def fails_once_after_exposing(stem, on_exposed=None):
        files = take(stem, on_exposed=on_exposed)
        calls.append(str(stem))
        if len(calls) == 2:     # the second picture: exposed, then the camera reports an error
            raise DeviceError("camera: the picture could not be written to the card")
        return files

    camera.capture_to_card = fails_once_after_exposing
    try:
        engine = CardBufferEngine(ds, plan, studio.rig, camera, time_scale=0.0, backoff_s=0.01)
        engine.start()
        assert engine.wait(120) is ScanState.FINISHED, engine.message
    finally:
        studio.close()
    _check_all_done(tmp_path / "ds", 8)
    assert len(calls) == 9 and calls.count(calls[1]) == 2     # that view taken again, the others once
    assert engine.downloads == 8
