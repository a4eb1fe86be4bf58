"""The simulated studio, wired: a GRBL simulator on a pseudo-terminal driven by the real GRBL driver,
and a simulated camera that renders the virtual studio from the simulator's true axis position.

Used by ``lfstudio scan --rig sim --camera sim`` and by the GUI in simulated mode::

    with SimulatedSession(load_rig(), time_scale=0.1) as sim:
        sim.rig      # lfstudio.rig.grbl.GrblController, connected and homed, over a real pty
        sim.camera   # lfstudio.sim.sim_camera.SimulatedCamera, connected
        sim.simulator.true_position_mm()

``time_scale`` multiplies every simulated duration (1: real time, 0.1: ten times faster, 0: as
fast as possible).
"""

from __future__ import annotations

import logging
from typing import Any

from lfstudio.rig.motion import RigConfig

log = logging.getLogger(__name__)


class SimulatedSession:
    """Start/stop the simulated rig and camera together (also a context manager)."""

    def __init__(self, rig: RigConfig, *, time_scale: float = 1.0, seed: int = 0, exposure_s: float = 0.5,
                 transfer_s: float = 2.5, studio: Any = None, home: bool = True,
                 view_region_mm: tuple[float, float, float, float] | None = None, image_width_px: int | None = None,
                 camera_kwargs: dict[str, Any] | None = None):
        self.rig_config = rig
        self.time_scale = float(time_scale)
        self.seed = seed
        self.exposure_s = exposure_s
        self.transfer_s = transfer_s
        self.view_region_mm = view_region_mm
        self.image_width_px = image_width_px
        self.studio = studio
        self.home = home
        self.camera_kwargs = dict(camera_kwargs or {})
        self.simulator: Any = None
        self.port: str | None = None
        self.rig: Any = None
        self.camera: Any = None

    def studio_kwargs(self) -> dict[str, Any]:
        """The virtual studio of the simulated camera: the demo orientation error, centred on the grid."""
        from lfstudio.sim.studio import demo_studio_kwargs

        kw = demo_studio_kwargs()
        if self.view_region_mm is not None:
            kw["view_region_mm"] = tuple(float(v) for v in self.view_region_mm)
        if self.image_width_px:
            kw["width_px"] = int(self.image_width_px)
        return kw

    def set_view_region(self, view_region_mm: tuple[float, float, float, float]) -> None:
        """Centre the virtual scene on a (new) grid: ``(x_min, x_max, y_min, y_max)`` in mm."""
        self.view_region_mm = tuple(float(v) for v in view_region_mm)
        if self.camera is not None and self.studio is None:
            self.camera.set_view_region(self.view_region_mm)

    def start(self) -> "SimulatedSession":
        from lfstudio.rig.connect import open_rig
        from lfstudio.sim.sim_camera import SimulatedCamera

        try:
            self.rig, self.simulator = open_rig("sim", self.rig_config, time_scale=self.time_scale, seed=self.seed)
            self.port = self.simulator.port
            if self.home:
                if self.rig_config.homing:
                    self.rig.home()
                else:
                    self.rig.set_origin()
            kwargs: dict[str, Any] = dict(position_mm=self.simulator.true_position_mm, exposure_s=self.exposure_s,
                                          transfer_s=self.transfer_s, time_scale=self.time_scale, seed=self.seed,
                                          studio_kwargs=self.studio_kwargs())
            kwargs.update(self.camera_kwargs)
            self.camera = SimulatedCamera(self.studio, **kwargs)
            self.camera.connect()
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        for name in ("camera", "rig"):
            dev = getattr(self, name)
            if dev is not None:
                try:
                    dev.disconnect()
                except Exception as exc:  # closing must not hide the original problem
                    log.debug("closing simulated %s: %s", name, exc)
        if self.simulator is not None:
            try:
                self.simulator.close()
            except Exception as exc:
                log.debug("stopping the GRBL simulator: %s", exc)
        self.simulator = None

    def __enter__(self) -> "SimulatedSession":
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.close()

