"""The gphoto2 driver against libgphoto2's own virtual PTP camera (vusb): the real python-gphoto2,
libgphoto2, ptp2 camera driver and PTP protocol; only the USB wire is virtual (tests/vcamera.py).

The last tests wrap that real camera to add what vusb cannot produce (say so where they do).
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from lfstudio.errors import DeviceError, InputError
from lfstudio.rig.camera import Camera, CameraSetting
from lfstudio.rig.gphoto import GPhotoCamera
from tests.vcamera import MODEL, STORE, use_usb, use_vcamera

# libgphoto2's virtual camera answers 'store full' after ~27 captures in one process: these files
# share one pytest-xdist worker, in order, as in a serial run
pytestmark = pytest.mark.xdist_group("vcamera")


@pytest.fixture
def camera(vcamera):
    cam = GPhotoCamera()
    cam.connect()
    yield cam
    cam.disconnect()


def files_on_camera(cam: GPhotoCamera, folder: str) -> list[str]:
    """The names the camera lists in ``folder`` (through the driver's open session)."""
    try:
        listing = cam._camera.folder_list_files(folder)
    except cam.gp.GPhoto2Error as exc:
        if exc.code == -107:          # folder not there (yet)
            return []
        raise
    return [listing.get_name(i) for i in range(listing.count())]


def test_detects_the_virtual_camera_and_its_identity(vcamera):
    cam = GPhotoCamera()
    assert isinstance(cam, Camera)
    assert not cam.status().connected
    cam.connect()
    cam.connect()                                   # idempotent: still the one session
    try:
        status = cam.status()
        assert status.connected and status.model == MODEL and status.message == ""
        ident = cam.identity()
        assert ident["model"] == MODEL and ident["driver"] == "gphoto2"
        assert ident["device_model"] == "VC" and ident["manufacturer"] == "GP" and ident["serial"] == "0.1"
        assert "lens" not in ident                  # vusb reports no lens
        assert cam.settings()["capturetarget"] == "Internal RAM"
    finally:
        cam.disconnect()
    assert not cam.status().connected
    with pytest.raises(DeviceError, match="not connected"):
        cam.settings()


def test_offered_settings_are_data(camera):
    described = {s.name: s for s in camera.describe_settings()}
    assert set(described) >= {"shutter_s", "aperture", "image_size"} and "iso" not in described
    shutter = described["shutter_s"]
    assert isinstance(shutter, CameraSetting) and shutter.type == "float" and shutter.unit == "s"
    assert "0.0100s" in shutter.choices and 0.01 in shutter.values and 1.0 in shutter.values
    assert shutter.values[shutter.choices.index("0.0025s")] == pytest.approx(0.0025)
    assert shutter.value == 0.01 and not shutter.read_only
    aperture = described["aperture"]
    assert aperture.choices[0] == "f/2.8" and aperture.values[0] == 2.8 and 8.0 in aperture.values
    size = described["image_size"]
    assert size.read_only and size.value == "640x480" and "2048x1536" in size.choices
    assert camera.settings() == {**camera.settings(), "shutter_s": 0.01, "aperture": 2.8, "image_size": "640x480"}


def test_settings_are_matched_by_value_against_the_offered_choices(camera):
    for wanted, seen in ((0.1, 0.1), ("0.05 s", 0.05), ("1/100", 0.01), ("1/400", 0.0025), (1, 1.0)):
        camera.set_setting("shutter_s", wanted)
        assert camera.settings()["shutter_s"] == pytest.approx(seen), wanted
    for wanted, seen in ((8, 8.0), ("f/5.6", 5.6), (5.7, 5.6), ("11", 11.0), ("F22", 22.0)):
        camera.set_setting("aperture", wanted)
        assert camera.settings()["aperture"] == pytest.approx(seen), wanted
    camera.set_setting("exposure_compensation_ev", "+1")
    assert camera.settings()["exposure_compensation_ev"] == 1.0


def test_a_value_the_camera_does_not_offer_lists_its_choices(camera):
    with pytest.raises(InputError) as err:
        camera.set_setting("shutter_s", 0.003)
    assert err.value.field == "shutter_s" and "0.003 s is not offered by Nikon DSC D750" in str(err.value)
    assert "0.0025s" in err.value.valid and "1.0000s" in err.value.valid
    with pytest.raises(InputError, match="f/2.8, f/3.5") as err:
        camera.set_setting("aperture", 1.4)
    with pytest.raises(InputError, match="has no such setting") as err:
        camera.set_setting("iso", 100)                  # vusb has no ISO
    assert "shutter_s" in err.value.valid and "iso" not in err.value.valid
    with pytest.raises(InputError, match="does not let it be changed remotely .it is 640x480"):
        camera.set_setting("image_size", "2048x1536")
    with pytest.raises(InputError, match="unknown camera setting"):
        camera.set_setting("zoom", 2)
    assert camera.settings()["shutter_s"] == 0.01 and camera.settings()["aperture"] == 2.8   # unchanged


def test_test_shot_is_downloaded_renamed_and_deleted_on_the_camera(camera, vcamera, tmp_path):
    camera.set_setting("shutter_s", 0.1)
    camera.set_setting("aperture", 8)
    exposed = []
    result = camera.capture(tmp_path / "raw" / "r00_c000", on_exposed=lambda: exposed.append(1))
    assert exposed == [1]
    assert result.files == (tmp_path / "raw" / "r00_c000.jpg",)
    assert result.path.read_bytes() == vcamera.jpeg.read_bytes()        # the camera's file, byte for byte
    assert cv2.imread(str(result.path)).shape == (240, 320, 3)
    where = result.metadata["camera_files"][0]
    assert re.fullmatch(f"{STORE}/DCIM/1[0-9][0-9]GPHOT/GPH_[0-9]{{4}}.JPG", where)
    folder, name = where.rsplit("/", 1)
    assert files_on_camera(camera, folder) == []                        # deleted on the camera
    assert result.exposure_s == 0.1 and result.metadata["shutter_s"] == 0.1   # the shutter time
    assert result.record == {"camera": {"model": MODEL, "serial": "0.1"},
                             "camera_settings": {"shutter_s": 0.1, "aperture": 8.0,
                                                 "exposure_compensation_ev": 0.0, "image_size": "640x480"}}
    assert not [p for p in (tmp_path / "raw").iterdir() if p.name.startswith(".")]
    again = camera.capture(tmp_path / "raw" / "r00_c001")
    assert again.metadata["camera_files"] != result.metadata["camera_files"]
    assert camera.status().shots == 2


def test_pictures_stay_on_the_camera_when_asked(vcamera, tmp_path):
    cam = GPhotoCamera(delete_from_camera=False)
    cam.connect()
    try:
        for stem in ("a", "b"):
            folder, name = cam.capture(tmp_path / stem).metadata["camera_files"][0].rsplit("/", 1)
            assert name in files_on_camera(cam, folder)
    finally:
        cam.disconnect()


def test_full_store_is_the_operators_message_and_a_reconnect_recovers(vcamera, tmp_path, caplog):
    # with the driver's debug records kept (as the whole suite may configure logging), a record that
    # held a libgphoto2 error would keep the failed capture's gp.Camera, and vusb's full store, alive
    caplog.set_level(logging.DEBUG, logger="lfstudio")
    camera = GPhotoCamera(delete_from_camera=False)  # (vusb takes 0.3 s a delete; its store fills either way)
    camera.connect()
    message = ""
    for taken in range(60):
        try:
            camera.capture(tmp_path / f"v{taken:02d}")
        except DeviceError as exc:   # keep only the text: a kept traceback would keep vusb's full store
            message = str(exc)
            break
    assert 20 <= taken < 40                          # vusb's store is full after ~26 pictures a session
    assert message == camera.status().message
    assert "card or the camera's buffer is full" in message and "[gphoto2 -3]" in message
    assert "out of memory" not in message.lower()
    assert "(libgphoto2: 'Camera memorycard ran full during capture.')" in message    # libgphoto2's reason
    with pytest.raises(DeviceError, match="card or the camera's buffer is full") as again:
        camera.capture(tmp_path / "again")          # vusb (as a full card) now answers a bare PTP Store Full
    del again
    assert not (tmp_path / f"v{taken:02d}.jpg").exists() and not list(tmp_path.glob(".*"))
    assert len(list(tmp_path.glob("v*.jpg"))) == taken
    camera.disconnect()
    camera.connect()                                 # vusb empties its store for a new session
    try:
        assert camera.capture(tmp_path / "after").path.is_file() and camera.status().message == ""
    finally:
        camera.disconnect()


def test_no_camera_says_how_to_connect_one(monkeypatch):
    """The real USB port libraries and no camera on this machine: libgphoto2 answers -105."""
    use_usb(monkeypatch)
    cam = GPhotoCamera()
    try:
        cam.connect()
    except DeviceError as exc:
        if "[gphoto2 -53]" in str(exc):
            pytest.skip("a real camera on this machine is held by another program")
        assert str(exc).startswith("camera: connect failed: no camera found: connect it by USB")
        assert "'PC Remote'" in str(exc) and str(exc).endswith("[gphoto2 -105]")
        assert cam.status().message == str(exc) and not cam.status().connected
    else:
        cam.disconnect()
        pytest.skip("a real camera is connected to this machine")


def test_virtual_camera_has_no_live_view(camera):
    assert camera.preview() is None                  # vusb answers -6 (unsupported) to capture_preview()


# -- what vusb cannot produce: the real vusb camera with one thing added --------------------------
@dataclass(frozen=True)
class _Path:
    folder: str
    name: str


class _Module:
    """python-gphoto2 with its Camera class replaced by a subclass (everything else the real module)."""

    def __init__(self, gp, camera_class):
        self._gp = gp
        self.Camera = camera_class

    def __getattr__(self, name):
        return getattr(self._gp, name)


def test_raw_plus_jpeg_downloads_and_records_both(tmp_path, monkeypatch):
    """vusb cannot shoot RAW + JPEG pairs: a real body's capture() names one file and announces the
    other with a FILE_ADDED event. This test adds only that event (naming a real DNG in the virtual
    camera's storage); capture, downloads and deletes go through the real PTP stack."""
    import gphoto2 as gp

    from lfstudio.dataset.thumbs import make_thumbnail

    vcam = use_vcamera(tmp_path / "vcamera", monkeypatch, dngs=3)
    raw_names = [p.name for p in vcam.dngs]

    pending = []

    class PairingCamera(gp.Camera):
        def capture(self, kind, *context):
            where = super().capture(kind, *context)
            pending.append(_Path(f"{STORE}/DCIM/100TEST", raw_names.pop(0)))
            return where

        def wait_for_event(self, timeout_ms, *context):
            if pending:
                return gp.GP_EVENT_FILE_ADDED, pending.pop()
            return super().wait_for_event(timeout_ms, *context)

    cam = GPhotoCamera(_Module(gp, PairingCamera))
    cam.connect()
    try:
        result = cam.capture(tmp_path / "raw" / "r00_c000")
        assert [p.name for p in result.files] == ["r00_c000.dng", "r00_c000.jpg"]     # RAW first
        assert result.files[0].read_bytes() == vcam.dngs[0].read_bytes()
        assert result.files[1].read_bytes() == vcam.jpeg.read_bytes()
        assert result.metadata["camera_files"][0] == f"{STORE}/DCIM/100TEST/RAW_0001.DNG"
        assert "RAW_0001.DNG" not in files_on_camera(cam, f"{STORE}/DCIM/100TEST")   # both deleted
        assert make_thumbnail(result.files, tmp_path / "t.jpg", 64) is not None
        second = cam.capture(tmp_path / "raw" / "r00_c001")
        assert second.files[0].read_bytes() == vcam.dngs[1].read_bytes()
    finally:
        cam.disconnect()


def test_live_view_frame_is_decoded_to_rgb(vcamera):
    """vusb has no live view: this adds capture_preview() returning a real gphoto2 CameraFile holding
    a JPEG, as a body with live view does (python-gphoto2 2.5+ call style: no CameraFile passed in)."""
    import gphoto2 as gp

    ok, jpeg = cv2.imencode(".jpg", np.full((24, 32, 3), (0, 0, 200), np.uint8))

    class LiveViewCamera(gp.Camera):
        def capture_preview(self):
            frame = gp.CameraFile()
            frame.set_data_and_size(jpeg.tobytes())
            return frame

    cam = GPhotoCamera(_Module(gp, LiveViewCamera))
    cam.connect()
    try:
        img = cam.preview()
    finally:
        cam.disconnect()
    assert img.shape == (24, 32, 3) and img[0, 0, 0] > 150 and img[0, 0, 2] < 50     # red in RGB order


def test_incomplete_download_is_refused_and_nothing_is_left(vcamera, tmp_path):
    """vusb cannot cut a transfer short: the camera here announces one byte more than it sends."""
    import gphoto2 as gp

    class ShortCamera(gp.Camera):
        def file_get_info(self, folder, name, *context):
            info = super().file_get_info(folder, name, *context)
            return _Info(info.file.size + 1)

    @dataclass
    class _Size:
        size: int

    class _Info:
        def __init__(self, size):
            self.file = _Size(size)

    cam = GPhotoCamera(_Module(gp, ShortCamera))
    cam.connect()
    try:
        size = vcamera.jpeg.stat().st_size
        with pytest.raises(DeviceError, match=rf"download of GPH_\d+\.JPG incomplete \({size} of {size + 1} bytes\)"):
            cam.capture(tmp_path / "out" / "v")
    finally:
        cam.disconnect()
    assert list((tmp_path / "out").iterdir()) == []          # no file, no temporary left


def test_busy_camera_message_then_recovery(vcamera, tmp_path):
    """vusb is never busy: the camera here answers the first capture with libgphoto2's -110."""
    import gphoto2 as gp

    answers = [gp.GPhoto2Error(gp.GP_ERROR_CAMERA_BUSY)]

    class BusyOnceCamera(gp.Camera):
        def capture(self, kind, *context):
            if answers:
                raise answers.pop()
            return super().capture(kind, *context)

    cam = GPhotoCamera(_Module(gp, BusyOnceCamera))
    cam.connect()
    try:
        with pytest.raises(DeviceError, match="the camera is busy .* wait and retry .gphoto2 -110."):
            cam.capture(tmp_path / "a")
        assert "busy" in cam.status().message
        assert cam.capture(tmp_path / "a").path.is_file() and cam.status().message == ""
    finally:
        cam.disconnect()
