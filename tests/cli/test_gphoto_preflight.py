"""The scan's pre-flight space checks with a gphoto2 camera, through libgphoto2's own virtual PTP camera
(vusb, tests/vcamera.py): its card's free space and picture count as the camera reports them
(``get_storageinfo``: 150 pictures, about 530 MB on 'GPVCS Label'), and a frame size nobody knows
before the first picture (the disk is checked right after the first view, on a real small tmpfs).
A handful of captures in all (vusb says 'store full' after ~26 per process)."""

from __future__ import annotations

import pytest

from lfstudio.dataset import Dataset
from lfstudio.scan.preflight import ScanTooLarge
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.studio.session import ScanRequest, ScanSession
from tests.faults.conftest import assert_one_line_error

pytestmark = pytest.mark.xdist_group("vcamera")


def _open(folder, columns, rows, **camera_options):
    session = ScanSession(ScanRequest(folder, rig="instant", camera="gphoto2", time_scale=0.0,
                                      camera_options=camera_options), doing="test")
    try:
        return session.open(lambda existing, rig: (ScanPlan.centered(columns, rows, (1.0, 1.0), rig,
                                                                     settle_s=0.0), None)), session
    except BaseException:
        session.close()
        raise


def test_a_camera_that_keeps_every_picture_on_its_card_is_checked_against_the_cards_own_count(vcamera, tmp_path):
    keep = {"delete_from_camera": False, "capture_target": "Memory card"}
    with pytest.raises(ScanTooLarge) as refused:
        _open(tmp_path / "big", 13, 12, **keep)                   # 156 pictures, the card holds 150 more
    text = str(refused.value)
    assert text.startswith("Camera card too small for this scan: it keeps 156 pictures on the camera's card "
                           "'GPVCS Label', which has room for 150 more by the camera's count."), text
    assert "Fix: free the card" in text and "delete each picture from the camera after its download" in text
    assert not (tmp_path / "big").exists()                       # refused before the dataset was made
    for folder, options in ((tmp_path / "fits", keep), (tmp_path / "ram", {})):
        columns, rows = (15, 10) if options else (13, 12)          # 150 kept fits; in the camera's RAM nothing stays
        engine, session = _open(folder, columns, rows, **options)
        try:
            assert engine.remaining == columns * rows
            card = engine.camera.call("card_space", timeout_s=30)
            assert card["keeps"] == ("all" if options else "none") and card["free_images"] == 150
            assert card["free_bytes"] > 100e6
        finally:
            session.close()


def test_a_camera_of_unknown_frame_size_is_checked_right_after_its_first_view(vcamera, small_disk, run_cli):
    """The floor (8 MB) and 99 more views of the first one's size do not fit 9 MB: the scan stops after
    its first view (not after the 26 the virtual camera can take), naming the measured need."""
    disk = small_disk(9 * 2**20)
    out = disk.path / "ds"
    proc = run_cli("scan", "--port", "instant", "--camera", "gphoto2", "--grid", "10x10", "--out", out,
                   "--time-scale", "0")
    line = assert_one_line_error(proc, 3, "stopped: Disk too small for this scan:", "measured on the first view",
                                 str(out), f"the disk at {disk.path} has", "Fix: free space there")
    assert "picture size is not known before its first picture" in proc.stderr    # said when it started
    done = Dataset.open(out).status_counts()["done"]
    assert 1 <= done <= 5, line                                   # the first view and those in the pipeline
