"""A camera setting whose value is not a number where one is needed (``lfstudio scan --set
shutter_s=abc``, ``lfstudio camera --set iso=inf``, the Camera panel's settings row) is refused by the
driver with one line naming the setting, never a ValueError/OverflowError traceback; a scan stops
before any folder is made."""

from __future__ import annotations

import pytest

from lfstudio.errors import InputError
from lfstudio.rig.hotfolder import HotFolderCamera
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.sim.instant import InstantCamera
from lfstudio.sim.sim_camera import SimulatedCamera
from lfstudio.studio.kinds import parse_settings
from lfstudio.studio.session import ScanRequest, ScanSession


@pytest.mark.parametrize("name, text", [("shutter_s", "abc"), ("iso", "inf"), ("iso", "fast"),
                                        ("aperture", "wide"), ("noise", "nan"), ("frame_rate_fps", "x")])
def test_the_simulated_camera_names_a_setting_that_is_no_number(name, text):
    value = parse_settings([f"{name}={text}"])[name]
    with pytest.raises(InputError, match=rf"^{name}: "):
        SimulatedCamera().set_setting(name, value)


def test_the_instant_and_hot_folder_cameras_name_a_setting_that_is_no_number(tmp_path):
    with pytest.raises(InputError, match=r"^shutter_s: 'abc' is not a number"):
        InstantCamera().set_setting("shutter_s", "abc")
    with pytest.raises(InputError, match=r"^timeout_s: 'soon' is not a number"):
        HotFolderCamera(tmp_path).set_setting("timeout_s", "soon")


def test_a_scan_setting_that_is_no_number_is_named_and_makes_no_folder(tmp_path):
    plan = ScanPlan(2, 1, (4.0, 6.0))
    session = ScanSession(ScanRequest(tmp_path / "ds", rig="instant", camera="instant",
                                      camera_settings=parse_settings(["shutter_s=abc"])))
    with pytest.raises(InputError, match=r"^--set shutter_s: 'abc' is not a number"):
        session.open(lambda existing, cfg: (plan, None))
    assert not (tmp_path / "ds").exists() and session.lock is None


@pytest.mark.parametrize("name, value, said", [
    ("timeout_s", 0, r"^timeout_s: 0 s is out of range \(valid: 0.1 … 86400 s\)"),
    ("stable_s", -1, r"^stable_s: -1 s is out of range \(valid: 0 … 60 s\)"),
    ("timeout_s", "1e9", r"^timeout_s: 1e\+09 s is out of range"),
    ("exposure", 1, r"^exposure: no such setting of the hot-folder camera"),
])
def test_the_hot_folder_camera_names_a_wait_out_of_range_as_its_page_does(tmp_path, name, value, said):
    """A hot folder's waits follow the rules its page and --camera-option describe (0.1 … 86400 s for the
    file, 0 … 60 s unchanged). set_setting had rules of its own (> 0, ≥ 0, no upper end) and said 'cannot
    set 0 on a hot-folder camera' for a wait out of range, as for a setting it does not have."""
    camera = HotFolderCamera(tmp_path)
    with pytest.raises(InputError, match=said):
        camera.set_setting(name, value)
    assert (camera.timeout_s, camera.stable_s) == (30.0, 0.5)
    camera.set_setting("timeout_s", "120")
    assert camera.timeout_s == 120.0
