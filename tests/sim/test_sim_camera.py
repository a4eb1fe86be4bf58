"""The simulated camera: real DNG + JPEG + truth files, position asked at the shot, faults, timings."""

from __future__ import annotations

import json
import threading

import cv2
import numpy as np
import pytest
import rawpy

from lfstudio.errors import DeviceError, InputError
from lfstudio.rig.camera import Camera, supports_on_exposed
from lfstudio.rig.worker import DeviceWorker
from lfstudio.sim.dng import DEFAULT_NEUTRAL, rgb_from_mosaic_nearest
from lfstudio.sim.sim_camera import SimulatedCamera
from lfstudio.sim.studio import VirtualStudio


@pytest.fixture(scope="module")
def studio():
    return VirtualStudio(width_px=192, view_region_mm=(0, 20, 0, 10), rotation_deg=(0.5, -1.0, 0.3),
                         pp_offset_px=(3.0, -2.0), seed=9)


@pytest.fixture
def camera(studio):
    position = {"xy": (0.0, 0.0)}
    cam = SimulatedCamera(studio, lambda: position["xy"], time_scale=0.0, noise=0.0)
    cam.position = position          # the test moves the "rig" through this dict
    cam.connect()
    yield cam
    cam.disconnect()


def _develop_half(path) -> np.ndarray:
    with rawpy.imread(str(path)) as raw:
        mosaic = raw.raw_image.copy()
    return rgb_from_mosaic_nearest(mosaic, 512, 16383, DEFAULT_NEUTRAL)


def test_implements_the_camera_protocol(camera):
    assert isinstance(camera, Camera)
    assert supports_on_exposed(camera)
    assert camera.status().connected


def test_capture_writes_dng_preview_and_truth_at_the_asked_position(camera, studio, tmp_path):
    camera.position["xy"] = (12.5, 4.0)
    result = camera.capture(tmp_path / "r00_c001")
    dng, jpg, truth_path = result.files
    assert result.path == dng == tmp_path / "r00_c001.dng"
    assert jpg.name == "r00_c001.jpg" and truth_path.name == "r00_c001.truth.json"
    truth = json.loads(truth_path.read_text())
    assert truth["true_position_mm"] == [12.5, 4.0]
    assert truth["rotation_deg"] == [0.5, -1.0, 0.3] and truth["pp_offset_px"] == [3.0, -2.0]
    assert result.metadata["ground_truth"]["true_position_mm"] == [12.5, 4.0]
    assert result.metadata["iso"] == 100
    expected = studio.render(12.5, 4.0)[::2, ::2]
    got = _develop_half(dng)
    assert np.abs(got - np.clip(expected, 0, 1)).mean() < 0.02
    other = studio.render(0.0, 0.0)[::2, ::2]
    assert np.abs(got - other).mean() > 2 * np.abs(got - expected).mean()
    preview = cv2.imread(str(jpg))
    assert preview.shape[1] == 192 and preview.dtype == np.uint8


def test_on_exposed_comes_before_the_files(camera, tmp_path):
    seen = []
    camera.capture(tmp_path / "a", on_exposed=lambda: seen.append((tmp_path / "a.dng").exists()))
    assert seen == [False]
    assert (tmp_path / "a.dng").exists()


def test_capture_fails_fault_then_recovers(camera, tmp_path):
    camera.inject("capture_fails", count=1)
    with pytest.raises(DeviceError, match="capture failed"):
        camera.capture(tmp_path / "x")
    assert not (tmp_path / "x.dng").exists()
    assert camera.capture(tmp_path / "x").path.exists()
    with pytest.raises(ValueError):
        camera.inject("explodes")


def test_silent_camera_hangs_until_stop_through_the_worker(studio, tmp_path):
    cam = SimulatedCamera(studio, time_scale=0.0, noise=0.0, silent_hang_s=60)
    cam.connect()
    cam.inject("silent", count=None)
    with DeviceWorker(cam, name="camera", status_method="status") as worker:
        started = threading.Event()
        offer = cam.status_listener                   # the worker listens for fresh status

        def listen(snapshot):
            offer(snapshot)
            if snapshot.message:
                started.set()
        cam.status_listener = listen
        fut = worker.submit("capture", tmp_path / "s")
        assert started.wait(10)                       # the status says the camera does not answer
        assert "does not answer" in worker.latest.message
        assert not fut.done()
        worker.stop_now()
        with pytest.raises(DeviceError, match="stopped"):
            fut.result(timeout=10)
        cam.clear_faults()
        assert worker.call("capture", tmp_path / "t").path.exists()


def test_disconnected_camera_refuses(studio, tmp_path):
    cam = SimulatedCamera(studio, time_scale=0.0)
    with pytest.raises(DeviceError, match="not connected"):
        cam.capture(tmp_path / "n")


def test_simulated_delays_are_respected(studio, tmp_path):
    cam = SimulatedCamera(studio, exposure_s=0.2, transfer_s=0.3, time_scale=0.1, noise=0.0)
    cam.connect()
    result = cam.capture(tmp_path / "d")
    assert result.exposure_s >= 0.02 and result.transfer_s >= 0.03       # lower bounds only


def test_settings_validate_and_exposure_scales_brightness(camera):
    assert camera.settings()["format"] == "DNG"
    base = camera.preview().astype(float)
    camera.set_setting("shutter_s", 0.25)
    darker = camera.preview().astype(float)
    assert darker.mean() < 0.85 * base.mean()
    for name, value in (("iso", 123), ("shutter_s", 0), ("aperture", 64), ("format", "JPEG"), ("zoom", 2)):
        with pytest.raises(InputError):
            camera.set_setting(name, value)
    camera.set_setting("iso", 200)
    assert camera.exposure_factor() == pytest.approx(1.0)


def test_flicker_varies_per_shot_and_is_recorded(studio, tmp_path):
    cam = SimulatedCamera(studio, time_scale=0.0, noise=0.0, flicker=0.05, seed=4)
    cam.connect()
    means, gains = [], []
    for i in range(4):
        result = cam.capture(tmp_path / f"f{i}")
        gains.append(result.metadata["ground_truth"]["gain"])
        means.append(_develop_half(result.path).mean())
    assert len(set(gains)) == 4
    np.testing.assert_allclose(np.array(means) / means[0], np.array(gains) / gains[0], rtol=0.01)


def test_faults_given_at_construction(studio, tmp_path):
    cam = SimulatedCamera(studio, time_scale=0.0, faults={"capture_fails": 2})
    cam.connect()
    for _ in range(2):
        with pytest.raises(DeviceError):
            cam.capture(tmp_path / "q")
    assert cam.capture(tmp_path / "q").path.exists()
    cam2 = SimulatedCamera(studio, time_scale=0.0, faults=["capture_fails"])
    cam2.connect()
    with pytest.raises(DeviceError):
        cam2.capture(tmp_path / "r")
    assert cam2.capture(tmp_path / "r").path.exists()


def test_set_view_region_recentres_the_scene(tmp_path):
    cam = SimulatedCamera(None, lambda: (2000.0, 200.0), time_scale=0.0, noise=0.0,
                          studio_kwargs={"width_px": 96, "rotation_deg": (0.5, 0, 0), "view_region_mm": (0, 8, 0, 6)})
    cam.connect()
    before = cam.studio
    cam.set_view_region((0, 8, 0, 6))
    assert cam.studio is before                     # same region: no rebuild
    cam.set_view_region((1980.0, 2020.0, 180.0, 220.0))
    assert cam.studio.view_region_mm == (1980.0, 2020.0, 180.0, 220.0)
    assert cam.studio.rotation_deg == [0.5, 0.0, 0.0] and cam.studio.width_px == 96
    depth = cam.studio.depth_map(2000.0, 200.0)
    assert depth.min() < cam.studio.far_m           # the scene's layers are in view at the new grid
