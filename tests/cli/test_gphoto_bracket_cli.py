"""`lfstudio scan --camera gphoto2 --bracket` against libgphoto2's own virtual PTP camera (vusb,
tests/vcamera.py): each frame's shutter time is set by value from the camera's own choices and the
exposure the camera reports is recorded per frame; a time it does not offer is refused before the
scan, listing its choices. Three captures in all (vusb says 'store full' after ~26 per process)."""

from __future__ import annotations

import pytest

from lfstudio.dataset import Dataset
from tests.vcamera import MODEL

pytestmark = pytest.mark.xdist_group("vcamera")


def test_bracket_through_the_ptp_stack(run_cli, vcamera, tmp_path):
    out = tmp_path / "scan"
    proc = run_cli("scan", "--port", "instant", "--camera", "gphoto2", "--grid", "1x1", "--bracket", "-1,0,+1",
                   "--out", out, "--time-scale", "0")
    assert proc.returncode == 0, proc.stderr
    ds = Dataset.open(out)
    assert ds.manifest["bracket"]["frame_shutter_s"] == pytest.approx([0.005, 0.01, 0.02])
    v = ds.view(0, 0)
    assert [f["exposure_s"] for f in v["frames"]] == pytest.approx([0.005, 0.01, 0.02])   # as the camera said
    assert [f["camera_settings"]["shutter_s"] for f in v["frames"]] == pytest.approx([0.005, 0.01, 0.02])
    assert [f["file"] for f in v["frames"]] == [f"raw/r00_c000.f{k}.jpg" for k in range(3)]
    assert v["file"] == "raw/r00_c000.f1.jpg" and v["exposure_s"] == 0.01
    source = vcamera.jpeg.read_bytes()
    assert all(ds.path_of(f["file"]).read_bytes() == source for f in v["frames"])
    assert ds.verify_files() == []


def test_a_shutter_time_the_camera_does_not_offer_is_refused_with_its_choices(run_cli, vcamera, tmp_path):
    out = tmp_path / "scan"
    proc = run_cli("scan", "--port", "instant", "--camera", "gphoto2", "--grid", "1x1", "--bracket", "-2,0,+2",
                   "--out", out, "--time-scale", "0")
    assert proc.returncode == 2, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert "--bracket" in last and f"{MODEL} cannot set a shutter time of 1/25 s (frame 3 of -2, 0, +2 EV)" in last, last
    assert "its choices: 1.0000s, 0.1000s, 0.0500s, 0.0200s, 0.0100s" in last and "Traceback" not in proc.stderr
    assert not (out / "dataset.json").exists()
