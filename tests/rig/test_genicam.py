"""The GenICam driver against aravis's own fake GigE Vision camera over the real protocol (127.0.0.1)."""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np
import pytest

from lfstudio.dataset import images
from lfstudio.errors import DeviceError, DeviceTimeout, InputError
from lfstudio.rig.camera import ArrayCamera, DescribesSettings, HasIdentity, stored
from tests.fakegv import expected_mono8, fake_gv_camera


#: the fake camera's settings at start (its pictures are expected_mono8 with them)
DEFAULTS = {"exposure_s": 0.01, "gain": 0, "pixel_format": "Mono8", "width": 512, "height": 512,
            "trigger_mode": "On", "trigger_source": "Software"}


@pytest.fixture(scope="module")
def fake():
    with fake_gv_camera() as cam:
        yield cam


@pytest.fixture
def camera(fake):
    from lfstudio.rig.genicam import GenicamCamera

    cam = GenicamCamera(fake.device_id, timeout_s=2.0)
    cam.connect()
    for name, value in DEFAULTS.items():        # the fake camera keeps what an earlier test set
        cam.set_setting(name, value)
    yield cam
    cam.disconnect()


def test_connects_and_says_what_it_is(camera):
    assert isinstance(camera, ArrayCamera) and isinstance(camera, DescribesSettings) and isinstance(camera, HasIdentity)
    ident = camera.identity()
    assert ident["model"] == "Fake" and ident["vendor"] == "Aravis" and ident["serial"] == "GV01"
    assert ident["transport"] == "GigE Vision"
    s = camera.settings()
    assert s["pixel_format"] == "Mono8" and (s["width"], s["height"]) == (512, 512)
    assert s["trigger_mode"] == "On" and s["trigger_source"] == "Software"      # connect chose software trigger


def test_settings_are_the_cameras_nodes_as_data(camera):
    described = {d.name: d for d in camera.describe_settings()}
    assert set(described) >= {"exposure_s", "gain", "pixel_format", "width", "height", "offset_x", "offset_y",
                              "frame_rate", "trigger_mode", "trigger_source", "trigger_activation"}
    assert described["trigger_source"].choices == ("Line0", "Software")
    assert "BayerRG8" in described["pixel_format"].choices and "Mono8" in described["pixel_format"].choices
    low, high, _ = described["exposure_s"].range
    assert low == pytest.approx(10e-6) and high == pytest.approx(10.0)      # ExposureTime µs on the camera
    camera.set_setting("exposure_s", 0.02)
    camera.set_setting("gain", 2)
    assert camera.settings()["exposure_s"] == pytest.approx(0.02) and camera.settings()["gain"] == 2


def test_bad_settings_are_one_line_each(camera):
    with pytest.raises(InputError, match=r"exposure_s.*out of the camera's range"):
        camera.set_setting("exposure_s", 100.0)
    with pytest.raises(InputError, match="no setting 'iso'"):
        camera.set_setting("iso", 100)
    with pytest.raises(InputError, match=r"pixel format 'Mono12Packed' cannot be stored by lfstudio.*Mono8") as err:
        camera.set_setting("pixel_format", "Mono12Packed")
    assert "\n" not in str(err.value)
    assert camera.settings()["pixel_format"] == "Mono8"


def test_software_triggered_frames_are_the_cameras_pixels_with_timestamps(camera, tmp_path):
    before = time.time_ns()
    first = camera.grab()
    second = camera.grab()
    assert first.layout == "mono" and first.pixel_format == "Mono8" and first.pixels.shape == (512, 512)
    assert np.array_equal(first.pixels, expected_mono8(first.frame_id))
    assert second.frame_id > first.frame_id
    assert first.timestamp_ns and second.timestamp_ns > first.timestamp_ns
    assert before <= first.system_timestamp_ns <= second.system_timestamp_ns
    assert first.lost == 0
    result = camera.capture(tmp_path / "r00_c000")
    assert result.files == () and result.frame is not None          # the store stage writes it
    assert result.record["camera_frame"]["frame_id"] == result.frame.frame_id
    assert result.record["camera"]["serial"] == "GV01"
    written = stored(result)
    assert written.path == tmp_path / "r00_c000.png"
    data = cv2.imread(str(written.path), cv2.IMREAD_UNCHANGED)
    assert data.dtype == np.uint16                                   # mono as 16-bit: 8-bit values x 257
    assert images.kind(written.path) == "image"                     # not taken for a camera RAW
    assert np.array_equal(data, expected_mono8(result.frame.frame_id).astype(np.uint16) * 257)


def test_bayer_is_kept_raw_as_dng_and_rgb_as_16_bit(camera, tmp_path):
    rawpy = pytest.importorskip("rawpy")
    camera.set_setting("pixel_format", "BayerBG8")
    result = stored(camera.capture(tmp_path / "bayer"))
    assert result.path.suffix == ".dng"
    with rawpy.imread(str(result.path)) as raw:
        assert raw.raw_image.shape == (512, 512)
        colours = raw.color_desc.decode()
        assert "".join(colours[i] for i in raw.raw_pattern.ravel()) == "BGGR"    # B G / G R
    camera.set_setting("pixel_format", "RGB8")
    camera.set_setting("width", 256)
    result = stored(camera.capture(tmp_path / "rgb"))
    data = cv2.imread(str(result.path), cv2.IMREAD_UNCHANGED)
    assert result.path.suffix == ".png" and data.dtype == np.uint16 and data.shape == (512, 256, 3)
    camera.set_setting("pixel_format", "Mono8")
    camera.set_setting("width", 512)


def test_hardware_trigger_waits_for_the_line_and_says_so(camera):
    camera.timeout_s = 0.3
    camera.set_setting("trigger_source", "Line0")        # the fake camera has no line: nothing arrives
    try:
        with pytest.raises(DeviceTimeout, match=r"no frame within .* of arming: is the trigger line \(Line0\)"):
            camera.grab()
    finally:
        camera.set_setting("trigger_source", "Software")


def test_free_running_takes_a_frame_sent_after_the_request(camera):
    camera.set_setting("trigger_mode", "Off")
    try:
        camera.grab()                                    # frames keep arriving meanwhile
        asked = time.time_ns()
        frame = camera.grab()
        assert frame.system_timestamp_ns >= asked         # a stale frame is not this capture's
    finally:
        camera.set_setting("trigger_mode", "On")


def test_stop_cuts_a_wait_for_the_line_short(camera):
    camera.timeout_s = 30.0
    camera.set_setting("trigger_source", "Line0")
    started = threading.Event()
    original = camera._pop

    def pop(deadline):
        started.set()
        return original(deadline)

    camera._pop = pop
    threading.Thread(target=lambda: (started.wait(10), camera.stop()), daemon=True).start()
    try:
        with pytest.raises(DeviceError, match="stopped while waiting for the frame"):
            camera.grab()
    finally:
        camera._pop = original
        camera.set_setting("trigger_source", "Software")


def test_a_camera_that_does_not_answer_is_named_with_those_found():
    from tests.fakegv import need_aravis
    from lfstudio.rig.genicam import GenicamCamera

    need_aravis()
    with pytest.raises(DeviceError, match=r"genicam:No-Such-Camera: no camera answers .*cameras aravis finds now"):
        GenicamCamera("No-Such-Camera").connect()


def test_triggered_frames_for_fly_scanning_arrive_in_trigger_order(camera, tmp_path):
    from lfstudio.rig.camera import TriggeredCamera

    assert isinstance(camera, TriggeredCamera)
    camera.arm(3)
    sent = [camera.trigger()]
    first = camera.fetch(tmp_path / "f0", timeout_s=2)
    sent += [camera.trigger()]
    second = camera.fetch(tmp_path / "f1", timeout_s=2)
    assert first.frame is not None and second.frame is not None
    assert second.frame.frame_id == first.frame.frame_id + 1
    assert np.array_equal(first.frame.pixels, expected_mono8(first.frame.frame_id))
    assert first.metadata["exposure_start_s"] == sent[0] and first.metadata["exposure_end_s"] > sent[0]
    with pytest.raises(DeviceError, match="triggered frame 3 did not arrive within 0.3 s"):
        camera.fetch(tmp_path / "f2", timeout_s=0.3)          # no trigger: missed, never a stale frame
    camera.disarm()
    assert not list(tmp_path.glob("f2*"))
