"""CANopen SDO access to a CiA 402 drive through python-canopen (its ``BaseNode402``) on python-can:
an :class:`lfstudio.rig.cia402.ObjectLink`.

``channel``: ``can0`` (SocketCAN on a studio machine) or ``virtual-NAME`` (python-can's in-process
``virtual`` bus named NAME, where the emulated drives of ``--port sim-canopen`` and the tests
live). All drives on one channel share one ``canopen.Network`` in this process.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from lfstudio.rig.cia402 import DriveNotAnswering, ObjectAccessRefused

log = logging.getLogger(__name__)

VIRTUAL_PREFIX = "virtual-"
_networks: dict[str, list[Any]] = {}            # channel -> [network, users]
_networks_lock = threading.Lock()


def _bus_args(channel: str) -> dict[str, Any]:
    if channel.startswith(VIRTUAL_PREFIX):
        return {"interface": "virtual", "channel": channel[len(VIRTUAL_PREFIX):], "receive_own_messages": False}
    return {"interface": "socketcan", "channel": channel}


def _network(channel: str) -> Any:
    import canopen

    with _networks_lock:
        entry = _networks.get(channel)
        if entry is None:
            network = canopen.Network()
            network.NOTIFIER_CYCLE = 0.1              # closing waits at most this long for its reader
            try:
                network.connect(**_bus_args(channel))
            except Exception as exc:  # noqa: BLE001 - python-can raises many kinds
                raise DriveNotAnswering(f"cannot open the CAN bus {channel!r} ({exc})") from None
            entry = _networks[channel] = [network, 0]
        entry[1] += 1
        return entry[0]


def _release(channel: str) -> None:
    with _networks_lock:
        entry = _networks.get(channel)
        if entry is None:
            return
        entry[1] -= 1
        if entry[1] <= 0:
            del _networks[channel]
            try:
                entry[0].disconnect()
            except Exception as exc:  # noqa: BLE001
                log.debug("CAN bus %s: %s", channel, exc)


class CanopenLink:
    """One drive (``node_id``) on ``channel``; SDO upload/download through ``BaseNode402.sdo``."""

    def __init__(self, channel: str, node_id: int, *, timeout_s: float = 1.0):
        self.channel = channel
        self.node_id = int(node_id)
        self.address = f"{channel} node {self.node_id}"
        self.timeout_s = timeout_s
        self.node: Any = None
        self._lock = threading.Lock()

    def open(self) -> None:
        from canopen import BaseNode402, ObjectDictionary

        with self._lock:
            if self.node is not None:
                return
            network = _network(self.channel)
            node = BaseNode402(self.node_id, ObjectDictionary())
            node.sdo.RESPONSE_TIMEOUT = self.timeout_s
            node.sdo.MAX_RETRIES = 1                  # one attempt (0 would retry for ever)
            network.add_node(node)
            self.node = node

    def close(self) -> None:
        with self._lock:
            node, self.node = self.node, None
            if node is not None:
                try:
                    node.network.nodes.pop(self.node_id, None)
                    node.remove_network()
                except Exception as exc:  # noqa: BLE001
                    log.debug("closing %s: %s", self.address, exc)
                _release(self.channel)

    def _sdo(self, fn, *args) -> Any:
        from canopen import SdoAbortedError, SdoCommunicationError

        if self.node is None:
            self.open()
        with self._lock:
            node = self.node
            if node is None:                     # closed meanwhile by another thread
                raise DriveNotAnswering(f"{self.address}: the connection was closed")
            try:
                return fn(node.sdo, *args)
            except SdoAbortedError as exc:
                raise ObjectAccessRefused(f"{self.address}: {exc}") from None
            except (SdoCommunicationError, OSError) as exc:
                raise DriveNotAnswering(f"{self.address}: {exc}") from None

    def read(self, index: int, sub: int, size: int, signed: bool) -> int:
        data = self._sdo(lambda sdo: sdo.upload(index, sub))
        if len(data) < size:
            raise ObjectAccessRefused(f"{self.address}: object {index:04X}h:{sub} has {len(data)} bytes, "
                                      f"expected {size}")
        return int.from_bytes(bytes(data[:size]), "little", signed=signed)

    def write(self, index: int, sub: int, value: int, size: int, signed: bool) -> None:
        data = int(value).to_bytes(size, "little", signed=signed)
        self._sdo(lambda sdo: sdo.download(index, sub, data))
