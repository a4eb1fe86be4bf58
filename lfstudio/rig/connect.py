"""Choosing and opening the rig's port: a serial device, a pyserial URL, or "sim" (built-in simulator)."""

from __future__ import annotations

from dataclasses import dataclass

from lfstudio.rig.grbl import GrblController
from lfstudio.rig.motion import RigConfig

SIM_PORT = "sim"


@dataclass(frozen=True)
class PortInfo:
    device: str          # what to pass as --port
    description: str     # what the operator sees in a list


def available_ports() -> list[PortInfo]:
    """Serial ports on this machine (``serial.tools.list_ports``), most likely candidates first."""
    from serial.tools import list_ports

    ports = []
    for p in list_ports.comports():
        text = p.description if p.description and p.description != "n/a" else ""
        if p.manufacturer and p.manufacturer not in text:
            text = f"{text} ({p.manufacturer})" if text else p.manufacturer
        ports.append(PortInfo(p.device, text or p.device))
    usb_first = sorted(ports, key=lambda p: (not ("USB" in p.device or "ACM" in p.device), p.device))
    return usb_first


def open_rig(port: str, rig: RigConfig, *, time_scale: float = 1.0, seed: int = 0,
             connect: bool = True, **controller_options):
    """Return ``(controller, simulator_or_None)``. ``port == "sim"`` starts a
    :class:`lfstudio.sim.grbl_controller.GrblSimulator` in this process and connects to its pty.
    The caller closes both (``controller.disconnect()``, ``simulator.close()``)."""
    simulator = None
    if port.strip().lower() == SIM_PORT:
        from lfstudio.sim.grbl_controller import GrblSimulator

        simulator = GrblSimulator(rig, time_scale=time_scale, seed=seed)
        port = simulator.start()
    controller = GrblController(port, rig, **controller_options)
    if connect:
        try:
            controller.connect()
        except Exception:
            if simulator is not None:
                simulator.close()
            raise
    return controller, simulator
