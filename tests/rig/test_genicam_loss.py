"""The GenICam driver when packets are lost: aravis's fake GigE Vision camera dropping 1 % of them (``-r 10``)."""

from __future__ import annotations

import numpy as np
import pytest

from lfstudio.errors import DeviceError
from tests.fakegv import expected_mono8, fake_gv_camera


def test_lost_packets_lose_frames_that_are_taken_again_never_stored_as_good():
    from lfstudio.rig.genicam import GenicamCamera

    with fake_gv_camera(lost_per_thousand=10) as fake:
        cam = GenicamCamera(fake.device_id, timeout_s=2.0, retries=20, packet_size=8000)
        cam.connect()
        try:
            frames = [cam.grab() for _ in range(30)]
            assert cam.lost > 0 and sum(f.lost for f in frames) == cam.lost
            for f in frames:                              # every frame returned is whole and right
                assert np.array_equal(f.pixels, expected_mono8(f.frame_id))
            assert any(f.record().get("lost_before") for f in frames)
            cam.retries = 0
            with pytest.raises(DeviceError, match=r"1 frames in a row lost \((timed out|packets lost)"):
                for _ in range(60):
                    cam.grab()
        finally:
            cam.disconnect()
