"""--keep-on-card (#40): libgphoto2's virtual PTP camera keeps each picture on its card (its store) and
the scan downloads them at the row changes and at the end; a view is done only once its file is on
disk and verified; files a run left on the card are fetched on resume, a file gone from it is taken again."""

from __future__ import annotations

import pytest

from lfstudio.dataset import Dataset
from lfstudio.rig.profile import load_rig
from lfstudio.scan.card import CardBufferEngine
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.studio.devices import open_studio
from lfstudio.studio.session import create_scan_dataset
from tests.vcamera import SOURCE_FOLDER

pytestmark = pytest.mark.xdist_group("vcamera")


def test_scan_keeps_pictures_on_the_card_and_downloads_them(run_cli, vcamera, tmp_path):
    out = tmp_path / "scan"
    proc = run_cli("scan", "--port", "sim", "--camera", "gphoto2", "--grid", "3x2", "--spacing-mm", "4x6",
                   "--out", out, "--time-scale", "0", "--keep-on-card")
    assert proc.returncode == 0, proc.stderr
    assert "pictures stay on the camera's card" in proc.stderr
    ds = Dataset.open(out)
    assert ds.status_counts()["done"] == 6 and ds.verify_files() == []
    source = vcamera.jpeg.read_bytes()
    for v in ds.done_views():
        assert ds.path_of(v).read_bytes() == source
        assert v["on_card"] == []                   # journaled on the card first, then downloaded


def test_files_left_on_the_card_are_fetched_on_resume(vcamera, tmp_path):
    rig_cfg = load_rig()
    plan = ScanPlan.centered(3, 1, (4.0, 6.0), rig_cfg, settle_s=0.0)
    studio = open_studio("instant", "gphoto2", rig_cfg, time_scale=0.0)
    try:
        ds = create_scan_dataset(tmp_path / "ds", plan, rig={"name": rig_cfg.name}, camera={"name": "gphoto2"},
                                 lens={"name": "t"})
        # a run killed after its captures: view 0's picture on the card, view 1's no longer there
        on_card = studio.camera.capture_to_card(tmp_path / "unused")
        assert on_card and not (tmp_path / "unused.jpg").exists()
        ds.record_view(0, 0, on_card=on_card)
        ds.record_view(0, 1, on_card=[f"{SOURCE_FOLDER}/GONE_0001.JPG"])
        ds.save()
        engine = CardBufferEngine(Dataset.open(ds.root), plan, studio.rig, studio.camera, time_scale=0.0)
        logs = []
        engine.subscribe(lambda e: e.kind is EventKind.LOG and logs.append(e.message))
        engine.start()
        assert engine.wait(60) is ScanState.FINISHED, (engine.message, logs)
    finally:
        studio.close()
    assert engine.fetched_on_resume == 1
    done = Dataset.open(tmp_path / "ds")
    assert done.status_counts()["done"] == 3 and done.verify_files() == []
    assert done.path_of(done.view(0, 0)).read_bytes() == vcamera.jpeg.read_bytes()
    assert any("r00 c000" in m and "fetched from the card" in m for m in logs) or \
        any("fetched from the card" in m for m in logs)
    assert any("could not be fetched" in m for m in logs)         # view 1: taken again
    assert all(v["on_card"] == [] for v in done.views)


def test_keep_on_card_refused_for_a_camera_without_a_card(run_cli, tmp_path):
    proc = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "2x1", "--out", tmp_path / "ds",
                   "--keep-on-card")
    assert proc.returncode == 2, proc.stderr
    line = proc.stderr.strip().splitlines()[-1]
    assert "--keep-on-card" in line and "cannot keep its pictures on its card" in line
    assert not (tmp_path / "ds" / "dataset.json").exists()


def test_a_row_of_pictures_on_the_card_does_not_hold_up_the_scan(tmp_path):
    """The store stage holds two pictures at most: views whose files wait on the card are handed to it
    only once their download begins (it waited for a file that the scan would fetch only at the end)."""
    from lfstudio.rig.camera import CardBuffered

    rig_cfg = load_rig()
    plan = ScanPlan.centered(6, 2, (4.0, 6.0), rig_cfg, settle_s=0.0)
    studio = open_studio("sim", "sim", rig_cfg, time_scale=0.0, exposure_s=0.5, transfer_s=2.5,
                         view_region_mm=plan.extent_mm(), sim_width_px=48)
    try:
        assert isinstance(studio.camera, CardBuffered)
        ds = create_scan_dataset(tmp_path / "ds", plan, rig={"name": rig_cfg.name}, camera={"name": "sim"},
                                 lens={"name": "t"})
        engine = CardBufferEngine(ds, plan, studio.rig, studio.camera, time_scale=0.0)
        engine.start()
        assert engine.wait(60) is ScanState.FINISHED, engine.message
    finally:
        studio.close()
    done = Dataset.open(tmp_path / "ds")
    assert done.status_counts()["done"] == 12 and done.verify_files() == []
    assert engine.downloads == 12 and all(v["on_card"] == [] for v in done.views)
