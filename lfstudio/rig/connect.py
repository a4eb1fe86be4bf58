"""The serial ports of this machine, for choosing the rig's port (opening it: :func:`lfstudio.studio.devices.open_rig`)."""

from __future__ import annotations

from dataclasses import dataclass


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
