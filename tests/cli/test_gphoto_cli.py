"""``lfstudio camera`` / ``lfstudio scan`` with ``--camera gphoto2``, run as an operator runs them
(subprocesses with ``VCAMERADIR``), against libgphoto2's own virtual PTP camera (tests/vcamera.py)."""

from __future__ import annotations

import json
import os

import pytest

from lfstudio.dataset import Dataset
from tests.vcamera import MODEL

# libgphoto2's virtual camera answers 'store full' after ~27 captures in one process: these files
# share one pytest-xdist worker, in order, as in a serial run
pytestmark = pytest.mark.xdist_group("vcamera")


def test_camera_test_shot(run_cli, vcamera, tmp_path):
    proc = run_cli("camera", tmp_path / "shot", "--camera", "gphoto2", "--set", "shutter_s=1/100",
                   "--set", "aperture=8")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["files"] == [str(tmp_path / "shot.jpg")]
    assert (tmp_path / "shot.jpg").read_bytes() == vcamera.jpeg.read_bytes()
    assert out["exposure_s"] == 0.01                      # the shutter time the camera reports
    assert out["settings"]["shutter_s"] == 0.01 and out["settings"]["aperture"] == 8.0
    assert "Traceback" not in proc.stderr


def test_camera_setting_the_camera_does_not_offer(run_cli, vcamera, tmp_path):
    proc = run_cli("camera", tmp_path / "shot", "--camera", "gphoto2", "--set", "shutter_s=0.003")
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"lfstudio camera: error: shutter_s: 0.003 s is not offered by {MODEL} (valid: 1.0000s, 0.1000s, "
        "0.0500s, 0.0200s, 0.0100s, 0.0050s, 0.0025s, 0.0012s, 0.0001s)"]
    assert not list(tmp_path.glob("shot*"))


def test_camera_without_a_camera(run_cli, tmp_path):
    pytest.importorskip("gphoto2", reason="python-gphoto2 is not installed")
    proc = run_cli("camera", tmp_path / "shot", "--camera", "gphoto2", env={"VCAMERADIR": None})
    if proc.returncode == 0:
        pytest.skip("a real camera is connected to this machine")
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "no camera found: connect it by USB" in lines[0] and "[gphoto2 -105]" in lines[0]


def test_scan_3x2_through_the_ptp_stack(run_cli, vcamera, tmp_path):
    out = tmp_path / "scan"
    proc = run_cli("scan", "--port", "sim", "--camera", "gphoto2", "--grid", "3x2", "--spacing-mm", "4x6",
                   "--out", out, "--time-scale", "0")
    assert proc.returncode == 0, proc.stderr
    ds = Dataset.open(out)
    assert ds.camera["model"] == MODEL and ds.camera["serial"] == "0.1" and ds.camera["driver"] == "gphoto2"
    views = ds.done_views()
    assert len(views) == 6
    source = vcamera.jpeg.read_bytes()
    for v in views:
        assert ds.path_of(v).read_bytes() == source
        assert v["file"] == f"raw/r{v['row']:02d}_c{v['column']:03d}.jpg"
        assert v["exposure_s"] == 0.01                   # vusb's shutter time, not the call's duration
        assert v["camera"] == {"model": MODEL, "serial": "0.1"}
        assert v["camera_settings"]["shutter_s"] == 0.01 and v["camera_settings"]["aperture"] == 2.8
    umask = os.umask(0)
    os.umask(umask)
    for path in (ds.manifest_path, ds.path_of(views[0])):
        assert path.stat().st_mode & 0o777 == 0o666 & ~umask
    verify = run_cli("info", out, "--verify")
    assert verify.returncode == 0, verify.stdout + verify.stderr


@pytest.mark.slow
def test_scan_stops_when_the_camera_is_full_and_resume_completes(run_cli, vcamera, tmp_path):
    """vusb's store is full after ~26 pictures a session: the scan stops with the operator's message,
    keeps every view taken, and ``--resume`` (a new camera session) captures the rest."""
    out = tmp_path / "scan"
    args = ("scan", "--port", "sim", "--camera", "gphoto2", "--out", out, "--time-scale", "0")
    proc = run_cli(*args, "--grid", "6x5", "--spacing-mm", "4x6")
    assert proc.returncode == 3, proc.stderr
    assert "card or the camera's buffer is full" in proc.stderr and "--resume" in proc.stderr
    assert "Traceback" not in proc.stderr
    ds = Dataset.open(out)
    done = len(ds.done_views())
    assert 20 <= done < 30 and ds.status_counts()["pending"] == 30 - done
    assert ds.verify_files() == []
    resumed = run_cli(*args, "--resume")
    assert resumed.returncode == 0, resumed.stderr
    ds = Dataset.open(out)
    assert len(ds.done_views()) == 30 and ds.verify_files() == []
