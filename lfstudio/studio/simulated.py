"""The simulated studio, wired: the one door from the rest of lfstudio to :mod:`lfstudio.sim`.

Nothing outside ``lfstudio/sim/`` and ``lfstudio/studio/`` imports the simulators (an import rule
test keeps it so); whatever the CLI or the GUI needs from them is named here.

- :func:`start_simulator`: the GRBL simulator on a pseudo-terminal (its port is a real pty that the
  real GRBL driver opens, byte for byte the real protocol).
- :func:`simulated_camera`: the camera that renders the virtual studio from a position source.
- The simulated camera needs the carriage's *true* position. In this process that is the
  simulator's :meth:`~lfstudio.sim.grbl_controller.GrblSimulator.true_position_mm`; for a simulator
  in another process (``lfstudio sim-rig``), :class:`TruthServer` answers it on a Unix socket in the
  runtime folder, next to the port's lock, and :func:`truth_source` finds it from the port name.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import socketserver
import threading
from pathlib import Path
from typing import Any, Callable

from lfstudio.errors import DeviceError
from lfstudio.rig.motion import RigConfig
from lfstudio.sim.cia402_drive import LEAVE_OUT_ALLOWED, drive_pair
from lfstudio.sim.dng import write_dng
from lfstudio.sim.drive_servers import CanopenDrives, DriveServers
from lfstudio.sim.grbl_controller import GrblSimulator
from lfstudio.sim.instant import InstantCamera, InstantRig
from lfstudio.sim.sim_camera import SimulatedCamera
from lfstudio.sim.studio import (DEMO_PP_OFFSET_PX, DEMO_ROTATION_DEG, REFERENCE_REGION_MM, ViewFault, demo_studio,
                                 demo_studio_kwargs, parse_fault)
from lfstudio.sim.virtual_dataset import (GROUND_TRUTH_NAME, camera_dict, lens_dict, load_ground_truth,
                                          make_virtual_dataset)
from lfstudio.support.locks import port_device, runtime_dir

log = logging.getLogger(__name__)

__all__ = ["LEAVE_OUT_ALLOWED", "DEMO_PP_OFFSET_PX", "DEMO_ROTATION_DEG", "GROUND_TRUTH_NAME", "REFERENCE_REGION_MM", "GrblSimulator",
           "InstantCamera", "InstantRig", "SimulatedCamera", "TruthServer", "camera_dict", "demo_studio",
           "demo_studio_kwargs", "describe_simulated_camera", "lens_dict", "load_ground_truth",
           "make_virtual_dataset", "parse_fault", "simulated_camera", "start_drive_emulator", "start_simulator", "truth_source",
           "ViewFault", "write_dng"]

PositionSource = Callable[[], tuple[float, float]]


def start_simulator(rig: RigConfig, *, time_scale: float = 1.0, seed: int = 0) -> GrblSimulator:
    """A running GRBL simulator for ``rig``; ``.port`` is its pty. The caller closes it."""
    sim = GrblSimulator(rig, time_scale=time_scale, seed=seed)
    # set up for fly scanning as an operator would once: laser mode ($32=1) puts the camera's trigger
    # line on the spindle output, switched inline with the motion (the simulated camera is wired to it)
    sim.set_settings({32: 1})
    sim.start()
    return sim


_canopen_buses = iter(range(1, 1 << 30))


def start_drive_emulator(rig: RigConfig, transport: str = "modbus", *, time_scale: float = 1.0, seed: int = 0,
                         ports: tuple[int, int] = (0, 0), setup: dict | tuple[dict, dict] | None = None,
                         channel: str | None = None) -> Any:
    """Two emulated CiA 402 drives for ``rig`` (a CiA 402 profile), served over ``transport``:
    "modbus" (the gateway's Modbus TCP server on 127.0.0.1, ``ports`` or free ones) or "canopen" (LocalNodes on
    a fresh python-can virtual bus). ``.word`` is the device word that reaches them, ``.port`` the
    same, ``.true_position_mm()`` where the carriage is; the caller closes it. ``setup``: the
    emulated drives' variety (:func:`lfstudio.sim.cia402_drive.drive_pair`: objects left out, feed
    constant, enabled but not homed, ...)."""
    pair = drive_pair(rig, time_scale=time_scale, seed=seed, setup=setup)
    if transport == "canopen":
        emulator: Any = CanopenDrives(pair, channel or f"virtual-lfstudio-{os.getpid()}-{next(_canopen_buses)}")
    else:
        emulator = DriveServers(pair, ports)
    emulator.start()
    emulator.port = emulator.word
    return emulator


def serve_sim_drive(rig: RigConfig, *, time_scale: float = 1.0, seed: int = 0, ports: tuple[int, int] = (0, 0),
                    setup: dict | None = None, canopen: str | None = None) -> tuple[Any, "TruthServer | None"]:
    """``lfstudio sim-drive``: two emulated drives on Modbus TCP (or CANopen nodes on the bus
    ``canopen``) plus the true-position server."""
    if canopen:
        emulator = start_drive_emulator(rig, "canopen", time_scale=time_scale, seed=seed, setup=setup,
                                        channel=canopen)
    else:
        emulator = start_drive_emulator(rig, "modbus", time_scale=time_scale, seed=seed, ports=ports, setup=setup)
    server = None
    if hasattr(socket, "AF_UNIX"):
        try:
            server = TruthServer(emulator).start()
        except OSError as exc:
            log.warning("the emulated drives' true position is not published: %s", exc)
    return emulator, server


def studio_kwargs_for(view_region_mm: tuple[float, float, float, float] | None = None,
                      width_px: int | None = None) -> dict[str, Any]:
    """The demo virtual studio (its orientation error and principal point offset), centred on a grid
    extent ``(x_min, x_max, y_min, y_max)`` in mm, rendering ``width_px`` wide images."""
    kw = demo_studio_kwargs()
    if view_region_mm is not None:
        kw["view_region_mm"] = tuple(float(v) for v in view_region_mm)
    if width_px:
        kw["width_px"] = int(width_px) // 2 * 2
    return kw


def simulated_camera(position_mm: PositionSource, *, studio_kwargs: dict[str, Any] | None = None,
                     **options: Any) -> SimulatedCamera:
    """A (not yet connected) simulated camera photographing the virtual studio from ``position_mm()``."""
    return SimulatedCamera(None, position_mm, studio_kwargs=studio_kwargs or studio_kwargs_for(), **options)


def describe_simulated_camera(camera: Any) -> tuple[dict, dict] | None:
    """The manifest's camera and lens entries of a (connected) simulated camera; None for other cameras."""
    studio = getattr(camera, "studio", None)
    if studio is None or not isinstance(camera, SimulatedCamera):
        return None
    cam = camera_dict(studio)
    cam["name"] = getattr(camera, "name", cam.get("name"))
    return cam, lens_dict(studio)


# -- the true position across processes ----------------------------------------------------------
def truth_socket_path(port: str) -> Path:
    """Where ``lfstudio sim-rig`` on ``port`` answers the carriage's true position (a drive pair's word in
    its one spelling, as the controller names its port: :func:`lfstudio.rig.canopen_link.canonical_word`)."""
    from lfstudio.rig.canopen_link import canonical_word
    from lfstudio.support.locks import _key

    port = canonical_word(port)
    return runtime_dir() / f"sim-{_key(port_device(port) or port)}.sock"


class TruthServer:
    """Answers ``?`` with ``{"x_mm": .., "y_mm": ..}`` (the simulator's true position) on a Unix socket;
    ``? T`` with where it was at monotonic time T (both processes share the machine's monotonic clock;
    null outside the simulator's history); ``E 1 T`` / ``E 0 T`` is the simulated camera's exposure
    output going high / low at T, wired to the emulated drives' touch probe input (``{"latched": ..}``)."""

    def __init__(self, simulator: GrblSimulator):
        self.simulator = simulator
        self.path = truth_socket_path(simulator.port or "")
        self._server: socketserver.UnixStreamServer | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> "TruthServer":
        sim = self.simulator

        class Handler(socketserver.StreamRequestHandler):
            def handle(self) -> None:
                for line in self.rfile:
                    words = line.split()
                    try:
                        if words == [b"?"]:
                            x, y = sim.true_position_mm()
                            answer: dict[str, Any] = {"x_mm": x, "y_mm": y}
                        elif len(words) == 2 and words[0] == b"?":
                            at: Any = getattr(sim, "true_position_at", None)
                            where: Any = at(float(words[1])) if callable(at) else None
                            answer = {"x_mm": None, "y_mm": None} if where is None else \
                                {"x_mm": where[0], "y_mm": where[1]}
                        elif len(words) == 3 and words[0] == b"E" and words[1] in (b"0", b"1"):
                            wire = getattr(sim, "exposure_output", None)
                            answer = {"latched": bool(wire(words[1] == b"1", float(words[2]))) if callable(wire)
                                      else False}
                        else:
                            return
                    except ValueError:
                        return
                    self.wfile.write(json.dumps(answer).encode() + b"\n")
                    self.wfile.flush()

        self.path.unlink(missing_ok=True)
        self._server = socketserver.ThreadingUnixStreamServer(str(self.path), Handler)
        self._server.daemon_threads = True
        self._thread = threading.Thread(target=self._server.serve_forever, name="sim-truth", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.shutdown()
            server.server_close()
            self.path.unlink(missing_ok=True)


class _TruthClient:
    """The true position from a :class:`TruthServer` (one short exchange per call)."""

    def __init__(self, path: Path, port: str):
        self.path = path
        self.port = port

    def _ask(self, question: bytes) -> dict[str, Any]:
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
                s.settimeout(5.0)
                s.connect(str(self.path))
                s.sendall(question + b"\n")
                data = b""
                while not data.endswith(b"\n"):
                    chunk = s.recv(256)
                    if not chunk:
                        break
                    data += chunk
            answer = json.loads(data)
            if not isinstance(answer, dict):
                raise ValueError("not an answer")
            return answer
        except (OSError, ValueError) as exc:
            raise DeviceError(f"simulated camera: the simulated controller on {self.port} does not tell its "
                              f"position any more ({exc}); is 'lfstudio sim-rig' still running?") from None

    def __call__(self) -> tuple[float, float]:
        answer = self._ask(b"?")
        try:
            return float(answer["x_mm"]), float(answer["y_mm"])
        except (KeyError, TypeError, ValueError) as exc:
            raise DeviceError(f"simulated camera: the simulated controller on {self.port} answered no position "
                              f"({exc})") from None

    def true_position_at(self, t: float) -> tuple[float, float] | None:
        """Where the carriage was at monotonic time ``t`` (the other process keeps the history)."""
        answer = self._ask(f"? {t!r}".encode())
        x, y = answer.get("x_mm"), answer.get("y_mm")
        return None if x is None or y is None else (float(x), float(y))

    def exposure_output(self, level: bool, t: float) -> bool:
        """The simulated camera's exposure output, wired to the emulated drives' touch probe input."""
        return bool(self._ask(f"E {int(bool(level))} {t!r}".encode()).get("latched"))


def truth_source(port: str) -> PositionSource | None:
    """The true-position source of the ``lfstudio sim-rig`` serving ``port``; None if there is none."""
    if not hasattr(socket, "AF_UNIX"):
        return None
    path = truth_socket_path(port)
    if not path.exists():
        return None
    client = _TruthClient(path, port)
    try:
        client()
    except DeviceError:
        return None
    return client


def serve_sim_rig(rig: RigConfig, *, time_scale: float = 1.0, seed: int = 0) -> tuple[GrblSimulator, TruthServer | None]:
    """``lfstudio sim-rig``: a simulator plus its true-position server (None where Unix sockets are missing)."""
    sim = start_simulator(rig, time_scale=time_scale, seed=seed)
    server = None
    if hasattr(socket, "AF_UNIX"):
        try:
            server = TruthServer(sim).start()
        except OSError as exc:     # the port still works; only the simulated camera cannot follow it
            log.warning("the simulated controller's true position is not published: %s", exc)
    return sim, server
