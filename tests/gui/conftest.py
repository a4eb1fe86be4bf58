"""Fixtures the window's tests share: the instant simulated devices behind Qt workers, and the
processing tests' small real datasets (for the Process dialog)."""

from __future__ import annotations

import pytest

from lfstudio.gui.devices import QtDevice
from lfstudio.rig.profile import load_rig
from lfstudio.rig.worker import DeviceWorker
from lfstudio.sim.instant import InstantCamera, InstantRig
from tests.processing.conftest import make_dataset  # noqa: F401  (the fixture, for the Process dialog's tests)
from tests.faults.conftest import small_disk  # noqa: F401  (the fixture: a real small tmpfs, for the Planner)
from tests.processing.test_hdr import bracketed  # noqa: F401  (the fixture: a real bracketed scan, for the Process dialog)


def window_devices(rig, camera) -> dict:
    """The window's devices for a connected ``rig`` and ``camera``: each behind its Qt worker."""
    return {"rig": QtDevice(DeviceWorker(rig, name="rig")),
            "camera": QtDevice(DeviceWorker(camera, name="camera", status_method=None))}


def close_devices(devices: dict) -> None:
    for d in devices.values():
        d.close(disconnect=False)


@pytest.fixture
def instant_devices():
    """({"rig": QtDevice, "camera": QtDevice}, rig, camera): the instant devices, closed afterwards."""
    rig = InstantRig(load_rig())
    rig.connect()
    cam = InstantCamera(rig.true_position_mm)
    cam.connect()
    devices = window_devices(rig, cam)
    yield devices, rig, cam
    close_devices(devices)


@pytest.fixture
def scan_requests(monkeypatch):
    """The list of every ``ScanRequest`` the session makes while the test runs (the real class, recorded)."""
    import lfstudio.studio.session as session_module

    requests = []
    real = session_module.ScanRequest

    def recording(*args, **kwargs):
        requests.append(real(*args, **kwargs))
        return requests[-1]

    monkeypatch.setattr(session_module, "ScanRequest", recording)
    return requests
