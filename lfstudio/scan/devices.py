"""Open the rig and camera a scan runs on, from the CLI's words: ``sim``, ``instant``, a serial
port; ``sim``, ``instant``, ``gphoto2``, ``folder:PATH``."""

from __future__ import annotations

import logging
from typing import Any

from lfstudio.errors import DeviceError, InputError
from lfstudio.rig.motion import RigConfig

log = logging.getLogger(__name__)


class ScanDevices:
    """The connected rig and camera drivers, plus what must be closed after the scan."""

    def __init__(self, rig: Any, camera: Any, session: Any = None, description: str = ""):
        self.rig = rig
        self.camera = camera
        self.session = session
        self.description = description

    def close(self) -> None:
        if self.session is not None:
            self.session.close()
            return
        for dev in (self.camera, self.rig):
            try:
                dev.disconnect()
            except Exception as exc:
                log.debug("disconnecting %s: %s", dev, exc)

    def __enter__(self) -> "ScanDevices":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def open_devices(rig_spec: str, camera_spec: str, rig_config: RigConfig, *, time_scale: float = 1.0,
                 exposure_s: float = 0.5, transfer_s: float = 2.5, seed: int = 0,
                 view_region_mm: tuple[float, float, float, float] | None = None,
                 sim_width_px: int | None = None) -> ScanDevices:
    """Connect (and home, for the simulator) the devices; raise :class:`DeviceError`/:class:`InputError`."""
    if camera_spec == "sim" and rig_spec != "sim":
        raise InputError("--camera", "the simulated camera needs the simulated rig (it renders from its position)",
                         "--rig sim --camera sim")
    if rig_spec == "sim":
        from lfstudio.sim.session import SimulatedSession

        session = SimulatedSession(rig_config, time_scale=time_scale, seed=seed, exposure_s=exposure_s,
                                   transfer_s=transfer_s, view_region_mm=view_region_mm,
                                   image_width_px=sim_width_px).start()
        if camera_spec == "sim":
            return ScanDevices(session.rig, session.camera, session,
                               f"simulated rig on {session.port}, simulated camera")
        try:
            camera = open_camera(camera_spec, position_mm=session.simulator.true_position_mm)
        except BaseException:
            session.close()
            raise
        session.camera.disconnect()
        session.camera = camera
        return ScanDevices(session.rig, camera, session, f"simulated rig on {session.port}, camera {camera_spec}")
    if rig_spec == "instant":
        from lfstudio.sim.instant import InstantRig

        rig = InstantRig(rig_config)
        rig.connect()
    else:
        try:
            from lfstudio.rig.grbl import GrblController
        except ImportError as exc:
            raise DeviceError(f"--rig {rig_spec}: the GRBL driver is not available ({exc})") from None
        rig = GrblController(rig_spec, rig_config)
        rig.connect()
    try:
        camera = open_camera(camera_spec, position_mm=getattr(rig, "true_position_mm", None))
    except BaseException:
        rig.disconnect()
        raise
    return ScanDevices(rig, camera, None, f"rig {rig_spec}, camera {camera_spec}")


def open_camera(spec: str, *, position_mm: Any = None, trigger_command: Any = None) -> Any:
    """A connected camera driver: ``instant``, ``gphoto2`` or ``folder:PATH`` (``trigger_command``:
    the hot folder's trigger, an argument list)."""
    if spec == "instant":
        from lfstudio.sim.instant import InstantCamera

        cam = InstantCamera(position_mm)
    elif spec == "gphoto2":
        try:
            from lfstudio.rig.gphoto import GPhotoCamera
        except ImportError as exc:
            raise DeviceError(f"--camera gphoto2: the driver is not available ({exc})") from None
        cam = GPhotoCamera()
    elif spec.startswith("folder:") and len(spec) > len("folder:"):
        try:
            from lfstudio.rig.hotfolder import HotFolderCamera
        except ImportError as exc:
            raise DeviceError(f"--camera folder: the driver is not available ({exc})") from None
        cam = HotFolderCamera(spec.split(":", 1)[1], trigger_command)
    else:
        raise InputError("--camera", f"unknown camera {spec!r}", "sim, gphoto2, folder:PATH, instant")
    cam.connect()
    return cam
