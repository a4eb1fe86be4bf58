"""The GenICam camera as a line-triggered camera for a fly scan's hardware trigger (#40,
``lfstudio.rig.camera.LineTriggered``), against aravis's own fake GigE Vision camera over the real
protocol. What the fake camera has (its src/arv-fake-camera.xml): TriggerMode Off/On, TriggerSource
Line0/Software, TriggerActivation RisingEdge; no TriggerDelay and no timestamp latch; with TriggerSource
Line0 it sends no frame at all (its stream thread sends frames free-running or on a software trigger
only: src/arvgvfakecamera.c). So what is tested here: the trigger nodes are set and read back, no frame
comes without an edge (never a stale or free-running frame), the software trigger works again after,
and a camera that cannot date its frames on this computer's clock is refused for the hardware trigger
with the reason (the session then fires it by software). A real line's frames and their dating through
the camera's timestamp latch cannot be tested without a camera that has both; the latch's arithmetic is
tested on a stand-in for the camera's nodes."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest

from lfstudio.errors import DeviceError
from lfstudio.rig.camera import LineTriggered
from tests.fakegv import expected_mono8, fake_gv_camera
from tests.rig.test_genicam import DEFAULTS


@pytest.fixture(scope="module")
def fake_gv():
    with fake_gv_camera() as cam:
        yield cam


@pytest.fixture
def camera(fake_gv):
    from lfstudio.rig.genicam import GenicamCamera

    cam = GenicamCamera(fake_gv.device_id, timeout_s=2.0)
    cam.connect()
    for name, value in DEFAULTS.items():        # the fake camera keeps what an earlier test set
        cam.set_setting(name, value)
    yield cam
    cam.disconnect()


def test_the_fake_camera_has_a_line_but_no_clock_so_the_hardware_trigger_is_refused_with_why(camera, tmp_path):
    from lfstudio.rig.genicam import GenicamCamera
    from lfstudio.rig.grbl import GrblController
    from lfstudio.rig.profile import load_rig
    from lfstudio.scan.scan_plan import ScanPlan
    from lfstudio.sim.grbl_controller import GrblSimulator
    from lfstudio.studio.session import ScanSession

    assert camera._line_source() == ("Line0", "")
    assert isinstance(camera, GenicamCamera) and isinstance(camera, LineTriggered)
    problem = camera.line_trigger_problem()
    assert problem is not None and "genicam:Aravis-Fake-GV01: its frames cannot be dated" in problem
    assert "no timestamp latch" in problem
    # a rig that can pulse (the GRBL simulator in laser mode): the camera alone decides, software trigger
    rig = dataclasses.replace(load_rig(), homing=False)
    sim = GrblSimulator(rig, time_scale=1.0)
    sim.set_settings({32: 1})
    controller = GrblController(sim.start(), rig, timeout_s=5.0)
    try:
        controller.connect()
        plan = ScanPlan(columns=6, rows=2, spacing_mm=(5.0, 6.0), origin_mm=(20.0, 10.0))
        assert controller.pulse_problem(5.0, 40.0) is None
        assert ScanSession._fly_trigger(controller, camera, plan, 40.0) == ("software", problem)
    finally:
        controller.disconnect()
        sim.close()


def test_arm_line_sets_the_line_and_rising_edge_and_takes_no_frame_without_an_edge(camera, tmp_path):
    camera.arm_line(2)
    try:
        live = camera.settings()                      # read from the camera's registers
        assert (live["trigger_mode"], live["trigger_source"], live["trigger_activation"]) == \
            ("On", "Line0", "RisingEdge")
        assert camera.line_trigger_latency_s == 0.0   # the fake camera has no TriggerDelay
        with pytest.raises(DeviceError, match=r"no frame 1 within 0.5 s: no rising edge on Line0 took one \(missed\)"):
            camera.fetch(tmp_path / "f0", timeout_s=0.5)
    finally:
        camera.disarm()
    assert not list(tmp_path.iterdir())
    # back to the software trigger (a fly scan's software-triggered row): frames on demand again
    camera.arm(1)
    sent = camera.trigger()
    frame = camera.fetch(tmp_path / "f1", timeout_s=2)
    camera.disarm()
    assert frame.frame is not None and np.array_equal(frame.frame.pixels, expected_mono8(frame.frame.frame_id))
    assert frame.metadata["exposure_start_s"] == sent
    assert camera.settings()["trigger_source"] == "Software"


class _Nodes:
    """A stand-in for a camera's nodes with a timestamp latch: its clock runs ``ticks_per_s`` from an
    origin ``behind_s`` before this computer's monotonic zero."""

    def __init__(self, latch: tuple[str, str, str | None], ticks_per_s: int, behind_s: float):
        self.latch, self.ticks_per_s, self.behind_s = latch, ticks_per_s, behind_s
        self.latched = 0

    def get_device(self):
        return self

    def get_feature(self, name):
        return name if name in self.latch else None

    def is_feature_available(self, name):
        return name in self.latch

    def execute_command(self, name):
        assert name == self.latch[0]
        self.latched = int((time.monotonic() + self.behind_s) * self.ticks_per_s)

    def get_integer(self, name):
        return self.ticks_per_s if name == self.latch[2] else self.latched


@pytest.mark.parametrize("latch, ticks_per_s", [(("TimestampLatch", "TimestampLatchValue", None), 1_000_000_000),
                                                (("GevTimestampControlLatch", "GevTimestampValue",
                                                  "GevTimestampTickFrequency"), 125_000_000)])
def test_the_camera_clock_is_read_through_its_latch(latch, ticks_per_s):
    from lfstudio.rig.genicam import GenicamCamera

    cam = GenicamCamera("stand-in", aravis=object())
    cam._cam = _Nodes(latch, ticks_per_s, behind_s=1234.5)
    clock = cam._read_clock()
    assert clock is not None
    offset, uncertainty = clock
    # a frame stamped t on the camera's clock was exposed at t + offset on this computer's
    assert offset == pytest.approx(-1234.5, abs=uncertainty + 2.0 / ticks_per_s + 1e-6)
    assert 0.0 <= uncertainty < 0.01
