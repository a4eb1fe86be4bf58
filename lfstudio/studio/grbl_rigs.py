"""The GRBL rig kinds, registered by :mod:`lfstudio.studio.kinds` exactly as a plugin's:

- ``PORT`` (also ``grbl:PORT``): a GRBL 1.1 controller on a serial port (``/dev/ttyUSB0``, ``COM3``, the
  ``/dev/pts/N`` of ``lfstudio sim-rig`` or of the GRBL firmware's own simulator, a pyserial URL);
  any word no other kind claims is a port;
- ``sim``: the GRBL simulator on a pseudo-terminal in this process, driven by the real GRBL driver;
- ``instant``: a rig that takes no time (tests, benchmarks).

The serial port is locked for this process (:func:`lfstudio.support.locks.port_lock`): a second
lfstudio process asking for it is refused with the holder's name."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from lfstudio.errors import DeviceError
from lfstudio.numbers import Number, described
from lfstudio.studio.kind_types import OpenContext, OpenedRig, RigKind, close_quietly


@dataclass(frozen=True)
class GrblOptions:
    """The connection options of a GRBL controller (``--rig-option NAME=VALUE``, the Rig panel's form)."""

    baudrate: int = described(115200, number=Number("baud", 1200, 4_000_000, integer=True), label="Baud rate",
                              tip="the serial line's speed (GRBL 1.1: 115200)")
    timeout_s: float = described(3.0, number=Number("s", 0.05, 600), label="Answer timeout",
                                 tip="how long a command may wait for the controller's answer")
    poll_hz: float = described(20.0, number=Number("Hz", 1, 200), label="Status polls",
                               tip="how often the controller's position is asked for while it moves")
    tolerance_mm: float = described(0.02, number=Number("mm", 0.0001, 5), label="Arrival tolerance",
                                    tip="how close to its target a move must end to have arrived")
    stall_s: float = described(3.0, number=Number("s", 0.1, 600), label="Stall after",
                               tip="a move whose position has not changed for this long has stalled")


def _open_grbl(port: str, ctx: OpenContext, simulator: Any = None) -> OpenedRig:
    from lfstudio.rig.grbl import GrblController
    from lfstudio.support.locks import port_lock

    port_lk = None
    try:
        if ctx.lock:
            port_lk = port_lock(port, ctx.doing).acquire()
        controller = GrblController(port, ctx.config, **ctx.options)
        opened = OpenedRig(controller, simulator, port_lk)
        if ctx.connect:
            controller.connect()
    except BaseException:
        if port_lk is not None:
            port_lk.release()
        raise
    return opened


def _open_serial(argument: str, ctx: OpenContext) -> Any:
    return _open_grbl(argument, ctx)


def _open_sim(argument: str, ctx: OpenContext) -> Any:
    from lfstudio.studio.simulated import start_simulator

    simulator = start_simulator(ctx.config, time_scale=ctx.time_scale, seed=ctx.seed)
    try:
        if simulator.port is None:                    # start() opens it, or raises
            raise DeviceError("the simulated rig did not open its serial port")
        return _open_grbl(simulator.port, ctx, simulator)
    except BaseException:
        close_quietly(simulator, "the GRBL simulator")
        raise


def _open_instant(argument: str, ctx: OpenContext) -> Any:
    from lfstudio.studio.simulated import InstantRig

    return InstantRig(ctx.config)


def _firmware(link: Any) -> dict[str, Any]:
    from lfstudio.rig.motion import HasFirmware

    version = str(link.controller.version or "").rstrip(":") if isinstance(link.controller, HasFirmware) else ""
    return {"firmware": f"GRBL {version}"} if version else {}


GRBL_KINDS = [
    RigKind("sim", _open_sim, "Simulated GRBL", options=GrblOptions, driver="grbl", simulated=True, simulates="grbl",
            describe=lambda link: f"simulated rig on {link.port}",
            record=lambda link: {"kind": "sim", **_firmware(link)},
            help="the GRBL controller simulator on a pseudo-terminal (the simulated studio)"),
    RigKind("instant", _open_instant, "Instant rig (tests)", driver="grbl",
            describe=lambda link: "instant rig", record=lambda link: {"kind": "instant"},
            help="a rig that takes no time (tests, benchmarks)"),
    RigKind("grbl", _open_serial, "GRBL controller on a serial port", argument="PORT", options=GrblOptions,
            catch_all=True, driver="grbl",
            describe=lambda link: f"rig on {link.port}",
            record=lambda link: {"kind": "grbl", "port": link.spec.port, **_firmware(link)},
            help="a GRBL 1.1 controller on a serial port: /dev/ttyUSB0, COM3, the port 'lfstudio sim-rig' printed"),
]
