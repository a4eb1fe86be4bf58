"""The CiA 402 drive-pair rig kinds (one drive per axis, the horizontal one first), registered by
:mod:`lfstudio.studio.kinds` exactly as a plugin's:

- ``dryve:HOST[:PORT],HOST[:PORT]``: two igus dryve D1 over Modbus TCP (port 502 by default;
  ``lfstudio sim-drive`` serves emulated ones);
- ``canopen:CHANNEL:NODE,NODE``: two drives over CANopen (CHANNEL can0, or virtual-NAME: python-can's
  in-process virtual bus);
- ``sim-dryve`` / ``sim-canopen``: the emulated drives in this process, over Modbus TCP on 127.0.0.1 /
  over a virtual CAN bus (the simulated studio), started from the rig profile.

Each drive address is locked for this process (:func:`lfstudio.support.locks.drive_lock`). A pair of
real drives implies no rig profile: their feed constants, homing method and limits must be the rig's own."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from lfstudio.errors import InputError
from lfstudio.numbers import Number, described
from lfstudio.rig.profile import DEFAULT_DRIVE_RIG
from lfstudio.studio.kind_types import OpenContext, OpenedRig, RigKind, close_quietly

CIA402 = "cia402"


@dataclass(frozen=True)
class DriveOptions:
    """The connection options of a CiA 402 drive pair (``--rig-option NAME=VALUE``, the Rig panel's form;
    one left out keeps the driver's own default)."""

    timeout_s: float = described(3.0, number=Number("s", 0.05, 600), label="Answer timeout",
                                 tip="how long a drive may take to answer a request or reach a state "
                                     "(each exchange with a drive: 1 s unless given)")
    poll_hz: float = described(50.0, number=Number("Hz", 1, 500), label="Status polls",
                               tip="how often the drives' positions are read while they move")
    tolerance_mm: float | None = described(None, number=Number("mm", 0.0001, 5), optional="drive",
                                           label="Arrival tolerance",
                                           tip="how close to its target a move must end; drive: the drive's own "
                                               "position window (6067h)")
    stall_s: float = described(3.0, number=Number("s", 0.1, 600), label="Stall after",
                               tip="a move whose position has not changed for this long has stalled")
    accept_reference: bool = described(False, flag=True, remember=False, label="Keep drive reference",
                                       tip="take the position the drives report as the rig's reference without "
                                           "homing (drives homed earlier that kept it); logged; for this "
                                           "connection only, never remembered")


def _parse_dryve(argument: str, option: str) -> tuple[str, tuple]:
    from lfstudio.rig.dryve import address_text, parse_address

    word = f"dryve:{argument}"
    parts = argument.split(",")
    if len(parts) != 2 or not all(p.strip() for p in parts):
        raise InputError(option, f"{word!r}: a dryve rig names two drives, the horizontal one first",
                         "dryve:HOST[:PORT],HOST[:PORT], e.g. dryve:192.168.1.10,192.168.1.11")
    addresses = tuple(address_text(*parse_address(p, option)) for p in parts)
    if addresses[0] == addresses[1]:
        raise InputError(option, f"{word!r}: both axes name the same drive {addresses[0]}",
                         "one drive per axis, each its own address")
    return "", addresses


def _parse_canopen(argument: str, option: str) -> tuple[str, tuple]:
    word = f"canopen:{argument}"
    channel, _, nodes = argument.rpartition(":")
    parts = nodes.split(",")
    if not channel or len(parts) != 2:
        raise InputError(option, f"{word!r}: a CANopen rig names its bus and two node ids",
                         "canopen:CHANNEL:NODE,NODE, e.g. canopen:can0:1,2")
    ids = []
    for p in parts:
        try:
            n = int(p)
        except ValueError:
            n = 0
        if not 1 <= n <= 127:
            raise InputError(option, f"{word!r}: node id {p!r} is not 1 … 127", "canopen:can0:1,2")
        ids.append(n)
    if ids[0] == ids[1]:
        raise InputError(option, f"{word!r}: both axes name node {ids[0]}", "one node per axis")
    return channel, tuple(ids)


def _open_pair(kind: str, port: str, addresses: tuple, ctx: OpenContext, simulator: Any = None) -> OpenedRig:
    """The links to the drives a ``kind`` ("dryve", "canopen") word names (``port``: the CANopen channel,
    ``addresses``: the drives' HOST:PORT or node ids), one lock per drive address, the driver (connected
    with ``ctx.connect``)."""
    from lfstudio.rig.canopen_link import canonical_word
    from lfstudio.rig.cia402 import Cia402Controller
    from lfstudio.support.locks import drive_lock

    config = ctx.config
    options = dict(ctx.options)                   # DriveOptions' (open_rig passes a kind its own only)
    locks: list[Any] = []
    try:
        # an EDS/DCF named by the profile: the drive's objects are the file's (python-canopen parses it)
        dictionaries: list[Any] = [None, None]
        known: list[set | None] = [None, None]
        for i, axis in enumerate((config.horizontal, config.vertical)):
            if axis.eds_file:
                from lfstudio.rig.cia402 import load_object_dictionary

                node = int(addresses[i]) if kind == "canopen" else 1
                dictionaries[i], known[i] = load_object_dictionary(
                    axis.eds_file, node, f"rig {config.name!r} {axis.name}.eds_file (drive {'xy'[i]})")
        if known != [None, None]:
            options["known_objects"] = (known[0], known[1])
        x, y = addresses
        if kind == "dryve":
            from lfstudio.rig.dryve import DryveLink, parse_address

            links: tuple[Any, Any] = (DryveLink(*parse_address(x), timeout_s=options.get("timeout_s", 1.0)),
                                      DryveLink(*parse_address(y), timeout_s=options.get("timeout_s", 1.0)))
        else:
            from lfstudio.rig.canopen_link import CanopenLink

            links = (CanopenLink(port, x, timeout_s=options.get("timeout_s", 1.0), object_dictionary=dictionaries[0]),
                     CanopenLink(port, y, timeout_s=options.get("timeout_s", 1.0), object_dictionary=dictionaries[1]))
        if ctx.lock:                 # by the drive's one name (lock_name), however the word spells it
            for link in links:
                locks.append(drive_lock(link.lock_name, ctx.doing).acquire())
        # the pair's word in one spelling: it names the rig's record of its last scan (session.note_scan_on_rig)
        controller = Cia402Controller(links, config, port=canonical_word(_text(kind, port, addresses)), **options)
        opened = OpenedRig(controller, simulator, _Locks(locks), port, addresses)
        if ctx.connect:
            controller.connect()
    except BaseException:
        for lk in locks:
            lk.release()
        if simulator is not None:
            close_quietly(simulator, "the emulated drives")
        raise
    return opened


def _text(kind: str, port: str, addresses: tuple) -> str:
    """The word of a drive pair: ``dryve:HOST:PORT,HOST:PORT``, ``canopen:CHANNEL:NODE,NODE``."""
    if kind == "dryve":
        return "dryve:" + ",".join(addresses)
    return f"canopen:{port}:{addresses[0]},{addresses[1]}"


class _Locks:
    """The locks of a rig's drives (one per address), released together."""

    def __init__(self, locks: list[Any]):
        self.locks = locks

    def release(self) -> None:
        for lk in self.locks:
            lk.release()


def _open_word(kind: str):
    def open_pair(argument: str, ctx: OpenContext) -> Any:
        port, addresses = PARSE[kind](argument, "--port")
        return _open_pair(kind, port, addresses, ctx)

    return open_pair


def _open_emulated(transport: str):
    def open_emulated(argument: str, ctx: OpenContext) -> Any:
        from lfstudio.studio.simulated import start_drive_emulator

        simulator = start_drive_emulator(ctx.config, transport, time_scale=ctx.time_scale, seed=ctx.seed)
        try:
            kind, _, rest = simulator.word.partition(":")     # the emulator's own dryve:… / canopen:… word
            port, addresses = PARSE[kind](rest, "--port")
        except BaseException:
            close_quietly(simulator, "the emulated drives")
            raise
        return _open_pair(kind, port, addresses, ctx, simulator)

    return open_emulated


PARSE = {"dryve": _parse_dryve, "canopen": _parse_canopen}


def _describe(link: Any) -> str:
    return f"CiA 402 drives {link.port}"


DRIVE_KINDS = [
    RigKind("dryve", _open_word("dryve"), "CiA 402 drives over Modbus TCP (igus dryve D1)",
            argument="HOST[:PORT],HOST[:PORT]", options=DriveOptions, parse=_parse_dryve,
            text=lambda port, addresses: _text("dryve", port, addresses), driver=CIA402, describe=_describe,
            record=lambda link: {"kind": "dryve", "port": link.spec.text},
            help="two drives over Modbus TCP (the dryve D1 gateway telegrams), the horizontal one first"),
    RigKind("canopen", _open_word("canopen"), "CiA 402 drives over CANopen", argument="CHANNEL:NODE,NODE",
            options=DriveOptions, parse=_parse_canopen,
            text=lambda port, addresses: _text("canopen", port, addresses), driver=CIA402,
            describe=_describe, record=lambda link: {"kind": "canopen", "port": link.spec.text},
            help="two drives over CANopen (CHANNEL: can0, or virtual-NAME for python-can's in-process bus)"),
    RigKind("sim-dryve", _open_emulated("modbus"), "Simulated drives", options=DriveOptions,
            driver=CIA402, profile=DEFAULT_DRIVE_RIG, simulated=True, simulates="dryve",
            text=lambda _port, _addresses: "sim-dryve",
            describe=lambda link: f"emulated CiA 402 drives ({link.port})", record=lambda link: {"kind": "sim-dryve"},
            help="two emulated CiA 402 drives (dryve D1, Modbus TCP on 127.0.0.1) with their preset rig profile"),
    RigKind("sim-canopen", _open_emulated("canopen"), "Simulated drives (CANopen)",
            options=DriveOptions, driver=CIA402, profile=DEFAULT_DRIVE_RIG, simulated=True,
            simulates="canopen", text=lambda _port, _addresses: "sim-canopen",
            describe=lambda link: f"emulated CiA 402 drives ({link.port})",
            record=lambda link: {"kind": "sim-canopen"},
            help="two emulated CiA 402 drives over a virtual CAN bus in this process, with their preset rig profile"),
]
