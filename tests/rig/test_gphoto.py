"""The gphoto2 driver against a fake python-gphoto2 module (the library boundary only)."""

from __future__ import annotations

import types

import cv2
import numpy as np
import pytest

from lfstudio.errors import DeviceError, InputError
from lfstudio.rig.camera import Camera
from lfstudio.rig.gphoto import GPhotoCamera, gp_message


class FakeError(Exception):
    def __init__(self, code):
        super().__init__(f"[{code}] error")
        self.code = code


class FakeWidget:
    def __init__(self, value, choices):
        self.value, self.choices = value, choices

    def get_value(self):
        return self.value

    def set_value(self, v):
        self.value = v

    def get_choices(self):
        return iter(self.choices)


class FakeConfig:
    def __init__(self, widgets):
        self.widgets = widgets

    def get_child_by_name(self, name):
        if name not in self.widgets:
            raise FakeError(-2)
        return self.widgets[name]


class FakeCameraFile:
    def __init__(self, data=b""):
        self.data = data

    def save(self, path):
        with open(path, "wb") as fh:
            fh.write(self.data)

    def get_data_and_size(self):
        return self.data


class FakeCamera:
    """Behaves like a Sony body over PTP: capture to RAM as capt0000.arw, download, delete."""

    def __init__(self, world):
        self.world = world

    def init(self):
        self.world.calls.append("init")
        if self.world.init_error:
            raise FakeError(self.world.init_error)

    def exit(self):
        self.world.calls.append("exit")

    def get_summary(self):
        return "Manufacturer: Sony\nModel: ILCE-7RM2\n"

    def get_config(self):
        return self.world.config

    def set_config(self, config):
        self.world.calls.append("set_config")

    def capture(self, kind):
        self.world.calls.append("capture")
        if self.world.capture_errors:
            raise FakeError(self.world.capture_errors.pop(0))
        return types.SimpleNamespace(folder="/", name="capt0000.arw")

    def file_get_info(self, folder, name):
        return types.SimpleNamespace(file=types.SimpleNamespace(size=self.world.announced_size))

    def file_get(self, folder, name, kind, camera_file):
        self.world.calls.append(f"file_get {folder}{name}")
        return FakeCameraFile(self.world.payload)

    def file_delete(self, folder, name):
        self.world.calls.append(f"file_delete {folder}{name}")

    def capture_preview(self, camera_file):
        ok, jpg = cv2.imencode(".jpg", np.full((24, 32, 3), (0, 0, 200), np.uint8))
        return FakeCameraFile(jpg.tobytes())


def make_fake_gp():
    world = types.SimpleNamespace(calls=[], init_error=None, capture_errors=[], payload=b"ARW" * 1000,
                                  announced_size=3000,
                                  config=FakeConfig({"iso": FakeWidget("100", ["100", "200", "400"]),
                                                     "shutterspeed": FakeWidget("1/2", ["1/250", "1/2", "1"]),
                                                     "f-number": FakeWidget("f/16", ["f/8", "f/16"]),
                                                     "capturetarget": FakeWidget("Memory card",
                                                                                 ["Internal RAM", "Memory card"])}))
    gp = types.SimpleNamespace(GPhoto2Error=FakeError, GP_CAPTURE_IMAGE=0, GP_FILE_TYPE_NORMAL=1,
                               Camera=lambda: FakeCamera(world), CameraFile=FakeCameraFile)
    return gp, world


def test_one_session_capture_download_rename_delete(tmp_path):
    gp, world = make_fake_gp()
    cam = GPhotoCamera(gp)
    assert isinstance(cam, Camera)
    cam.connect()
    cam.connect()                                   # idempotent: still one session
    assert world.calls.count("init") == 1
    assert world.config.widgets["capturetarget"].value == "Internal RAM"
    assert cam.status().model == "ILCE-7RM2"
    exposed = []
    r1 = cam.capture(tmp_path / "raw" / "r00_c000", on_exposed=lambda: exposed.append(1))
    r2 = cam.capture(tmp_path / "raw" / "r00_c001")
    assert r1.path == tmp_path / "raw" / "r00_c000.arw" and r1.path.read_bytes() == world.payload
    assert r2.path.name == "r00_c001.arw"
    assert exposed == [1]
    assert world.calls.count("init") == 1 and world.calls.count("file_delete /capt0000.arw") == 2
    assert not list((tmp_path / "raw").glob(".*"))
    cam.disconnect()
    assert world.calls[-1] == "exit"


def test_incomplete_download_is_refused(tmp_path):
    gp, world = make_fake_gp()
    world.announced_size = 5000                     # the camera says more than arrived
    cam = GPhotoCamera(gp)
    cam.connect()
    with pytest.raises(DeviceError, match="incomplete"):
        cam.capture(tmp_path / "v")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("code,text", [(-105, "PC Remote"), (-53, "another program"), (-52, "cable")])
def test_connect_errors_say_what_to_do(code, text):
    gp, world = make_fake_gp()
    world.init_error = code
    cam = GPhotoCamera(gp)
    with pytest.raises(DeviceError, match=text):
        cam.connect()
    assert not cam.status().connected


def test_busy_camera_message_and_recovery(tmp_path):
    gp, world = make_fake_gp()
    world.capture_errors = [-110]
    cam = GPhotoCamera(gp)
    cam.connect()
    with pytest.raises(DeviceError, match="busy"):
        cam.capture(tmp_path / "a")
    assert "busy" in cam.status().message
    assert cam.capture(tmp_path / "a").path.exists()
    assert cam.status().message == ""


def test_settings_map_to_widgets_and_validate_choices():
    gp, world = make_fake_gp()
    cam = GPhotoCamera(gp)
    with pytest.raises(DeviceError, match="not connected"):
        cam.settings()
    cam.connect()
    assert cam.settings()["iso"] == "100"
    cam.set_setting("iso", 400)
    assert world.config.widgets["iso"].value == "400"
    cam.set_setting("shutter_s", 1 / 250)
    assert world.config.widgets["shutterspeed"].value == "1/250"
    with pytest.raises(InputError, match="not offered"):
        cam.set_setting("iso", 123)
    with pytest.raises(InputError):
        cam.set_setting("zoom", 2)
    with pytest.raises(DeviceError, match="no setting"):
        cam.set_setting("format", "RAW")


def test_preview_decodes_to_rgb():
    gp, _ = make_fake_gp()
    cam = GPhotoCamera(gp)
    cam.connect()
    img = cam.preview()
    assert img.shape == (24, 32, 3) and img[0, 0, 0] > 150 and img[0, 0, 2] < 50   # red in RGB order


def test_real_module_reports_no_camera():
    """With the real python-gphoto2 and no camera on this machine: the clear 'no camera' message."""
    pytest.importorskip("gphoto2")
    cam = GPhotoCamera()
    try:
        cam.connect()
    except DeviceError as exc:
        assert "no camera found" in str(exc) or "another program" in str(exc)
    else:
        cam.disconnect()
        pytest.skip("a real camera is connected to this machine")


def test_gp_message_unknown_code():
    assert "gphoto2 -999" in gp_message(FakeError(-999), "capture")
