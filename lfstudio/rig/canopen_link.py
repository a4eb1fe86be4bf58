"""CANopen SDO access to a CiA 402 drive through python-canopen (its ``BaseNode402``) on python-can:
an :class:`lfstudio.rig.cia402.ObjectLink`.

``channel``: ``can0`` or ``socketcan:can0`` (SocketCAN on a studio machine), ``udp_multicast`` or
``udp_multicast:GROUP`` (python-can's UDP multicast bus: CAN frames between processes, e.g.
``lfstudio sim-drive --canopen udp_multicast``; group 239.74.163.2 by default; time-to-live 1, so
the frames also reach the other computers of the local network segment), or ``virtual-NAME``
(python-can's in-process ``virtual`` bus named NAME, where the emulated drives of ``--port
sim-canopen`` live). All drives on one channel share one ``canopen.Network`` in this process.
``object_dictionary``: the drive's EDS/DCF as python-canopen parsed it (else an empty one: SDO
needs none).

Deadlines: a whole SDO transfer (every segment of it) must end within the link's ``timeout_s``
(python-canopen's own timeout is per response: a node answering a segmented upload one segment at a
time would hold it for ever). STOP's quick stop (:meth:`CanopenLink.write_now`) waits at most
:data:`STALLED_AFTER_S` for an exchange in flight on the node's SDO channel (a healthy one ends well
within it), then interrupts it and takes the channel. An interrupted *read* is asked again once the
quick stop is out (a slow drive is not a lost one; a write is not repeated: it may be the very set
point STOP stopped); an interrupted write fails as :class:`ExchangeInterrupted` (the controller
takes it as the command stopped, not the drive lost). The interrupted exchange's late answer is
told apart by its command and object (an SDO answer has no transaction number) and dropped, so that
it is never taken for the quick stop's (or the next exchange's).
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from typing import Any

from lfstudio.rig.cia402 import DriveNotAnswering, ExchangeInterrupted, ObjectAccessRefused

log = logging.getLogger(__name__)

VIRTUAL_PREFIX = "virtual-"
UDP_MULTICAST = "udp_multicast"
UDP_MULTICAST_GROUP = "239.74.163.2"     # python-can's UdpMulticastBus.DEFAULT_GROUP_IPv4
_networks: dict[str, list[Any]] = {}            # channel -> [network, users]
_networks_lock = threading.Lock()
#: how long STOP waits for an SDO exchange in flight before it interrupts it (a healthy one takes ~1 ms)
STALLED_AFTER_S = 0.02
_INTERRUPT = b"interrupted"
_client_class: Any = None


def _deadline_client() -> Any:
    """python-canopen's ``SdoClient`` with one deadline for a whole transfer and :meth:`interrupt`."""
    global _client_class
    if _client_class is not None:
        return _client_class
    import struct

    from canopen.sdo.client import SdoClient
    from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

    class DeadlineSdoClient(SdoClient):
        deadline = math.inf
        whole_s = 0.0
        interrupted = False
        #: (response command, index, subindex) an initiate request in flight expects; None for segments
        expect: tuple[int, int, int] | None = None

        def interrupt(self) -> None:
            self.interrupted = True
            self.responses.put(_INTERRUPT)

        def send_request(self, request) -> None:
            command = request[0] & 0xE0
            if command in (0x20, 0x40):         # initiate download / upload: its answer names the object
                index, sub = struct.unpack_from("<HB", request, 1)
                self.expect = (0x60 if command == 0x20 else 0x40, index, sub)
            else:
                self.expect = None
            super().send_request(request)

        def _not_ours(self, response: bytes) -> bool:
            """A late answer to an exchange STOP cut short (SDO answers carry no transaction number:
            only an initiate answer's command and object tell whose it is)."""
            expect = self.expect
            if expect is None or len(response) < 4:
                return False
            index, sub = struct.unpack_from("<HB", response, 1)
            return (index, sub) != expect[1:] or (response[0] != 0x80 and response[0] & 0xE0 != expect[0])

        def read_response(self) -> bytes:
            while True:
                left = self.deadline - time.monotonic()
                if self.interrupted:
                    raise SdoCommunicationError("no answer yet; interrupted by STOP")
                if left <= 0:
                    raise SdoCommunicationError(f"no whole answer within {self.whole_s:g} s")
                try:
                    response = self.responses.get(block=True, timeout=min(self.RESPONSE_TIMEOUT, left))
                except queue.Empty:
                    if self.deadline - time.monotonic() <= 0:
                        raise SdoCommunicationError(f"no whole answer within {self.whole_s:g} s") from None
                    raise SdoCommunicationError(f"no answer within {self.RESPONSE_TIMEOUT:g} s") from None
                if response is _INTERRUPT:
                    continue                    # the flag says so (or a stale one: wait on)
                if self._not_ours(response):
                    log.debug("SDO: a late answer %s to an earlier exchange, not this one's: dropped",
                              bytes(response[:4]).hex())
                    continue
                if response[0] == 0x80:         # abort from the node
                    raise SdoAbortedError(struct.unpack_from("<L", response, 4)[0])
                return response

    _client_class = DeadlineSdoClient
    return _client_class


def bus_args(channel: str) -> dict[str, Any]:
    """python-can's ``Bus`` arguments for a channel word (see the module docstring)."""
    if channel.startswith(VIRTUAL_PREFIX):
        return {"interface": "virtual", "channel": channel[len(VIRTUAL_PREFIX):], "receive_own_messages": False}
    if channel == UDP_MULTICAST or channel.startswith(UDP_MULTICAST + ":"):
        return {"interface": "udp_multicast", "channel": channel.partition(":")[2] or UDP_MULTICAST_GROUP}
    return {"interface": "socketcan", "channel": channel.removeprefix("socketcan:")}


def canonical_channel(channel: str) -> str:
    """The one spelling of a channel word (what names its drives' locks): ``can0`` for
    ``socketcan:can0``, ``udp_multicast:GROUP`` for ``udp_multicast`` (the default group); two spellings
    of one bus are one bus."""
    args = bus_args(channel.strip())
    if args["interface"] == "virtual":
        return VIRTUAL_PREFIX + args["channel"]
    if args["interface"] == "udp_multicast":
        return f"{UDP_MULTICAST}:{args['channel']}"
    return args["channel"]


def canonical_word(word: str) -> str:
    """A rig's device word with a CANopen channel in its one spelling (``canopen:socketcan:can0:1,2`` →
    ``canopen:can0:1,2``); any other word as it is."""
    if not word.startswith("canopen:"):
        return word
    channel, sep, nodes = word[len("canopen:"):].rpartition(":")
    return f"canopen:{canonical_channel(channel)}:{nodes}" if sep and channel else word


def _network(channel: str) -> Any:
    import canopen

    with _networks_lock:
        entry = _networks.get(channel)
        if entry is None:
            network = canopen.Network()
            network.NOTIFIER_CYCLE = 0.1              # closing waits at most this long for its reader
            try:
                network.connect(**bus_args(channel))
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

    def __init__(self, channel: str, node_id: int, *, timeout_s: float = 1.0, object_dictionary: Any = None):
        self.channel = channel
        self.object_dictionary = object_dictionary
        self.node_id = int(node_id)
        self.address = f"{channel} node {self.node_id}"
        #: the drive's one name (its lock's): the channel in one spelling (:func:`canonical_channel`)
        self.lock_name = f"{canonical_channel(channel)} node {self.node_id}"
        self.timeout_s = timeout_s
        self.node: Any = None
        self._lock = threading.Lock()
        self._stop_out = threading.Event()        # cleared while STOP's quick stop takes the channel
        self._stop_out.set()

    def open(self) -> None:
        from canopen import BaseNode402, ObjectDictionary

        with self._lock:
            if self.node is not None:
                return
            network = _network(self.channel)
            node = BaseNode402(self.node_id, self.object_dictionary if self.object_dictionary is not None
                               else ObjectDictionary())
            client = _deadline_client()(node.sdo.rx_cobid, node.sdo.tx_cobid, node.object_dictionary)
            node.sdo_channels[node.sdo_channels.index(node.sdo)] = client
            node.sdo = client
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

    def _sdo(self, fn, *args, again_after_stop: bool = False) -> Any:
        if self.node is None:
            self.open()
        with self._lock:
            try:
                return self._sdo_locked(fn, *args)
            except ExchangeInterrupted:
                if not again_after_stop:
                    raise
        # STOP took the channel for its quick stop: once that is out, the read is asked again
        self._stop_out.wait(self.timeout_s)
        with self._lock:
            return self._sdo_locked(fn, *args)

    def _sdo_locked(self, fn, *args) -> Any:
        from canopen import SdoAbortedError, SdoCommunicationError

        node = self.node
        if node is None:                     # closed meanwhile by another thread
            raise DriveNotAnswering(f"{self.address}: the connection was closed")
        sdo = node.sdo
        sdo.deadline, sdo.whole_s, sdo.interrupted = time.monotonic() + self.timeout_s, self.timeout_s, False
        try:
            return fn(sdo, *args)
        except SdoAbortedError as exc:
            raise ObjectAccessRefused(f"{self.address}: {exc}") from None
        except (SdoCommunicationError, OSError) as exc:
            if sdo.interrupted:
                raise ExchangeInterrupted(f"{self.address}: {exc}") from None
            raise DriveNotAnswering(f"{self.address}: {exc}") from None
        finally:
            sdo.deadline, sdo.interrupted = math.inf, False

    def write_now(self, index: int, sub: int, value: int, size: int, signed: bool) -> None:
        """A write that never waits behind a stalled exchange (STOP's quick stop): an SDO exchange
        still in flight after :data:`STALLED_AFTER_S` is interrupted (it fails) and this write
        takes the node's SDO channel (one per node: a second transfer on it would take the first's
        answers)."""
        data = int(value).to_bytes(size, "little", signed=signed)
        if self.node is None:
            self.open()
        if not self._lock.acquire(timeout=STALLED_AFTER_S):
            self._stop_out.clear()
            node = self.node
            if node is not None:
                node.sdo.interrupt()
            if not self._lock.acquire(timeout=self.timeout_s):
                self._stop_out.set()
                raise DriveNotAnswering(f"{self.address}: the SDO channel stayed busy")
        try:
            self._sdo_locked(lambda sdo: sdo.download(index, sub, data))
        finally:
            self._lock.release()
            self._stop_out.set()

    def read(self, index: int, sub: int, size: int, signed: bool) -> int:
        data = self._sdo(lambda sdo: sdo.upload(index, sub), again_after_stop=True)
        if len(data) < size:
            raise ObjectAccessRefused(f"{self.address}: object {index:04X}h:{sub} has {len(data)} bytes, "
                                      f"expected {size}")
        return int.from_bytes(bytes(data[:size]), "little", signed=signed)

    def write(self, index: int, sub: int, value: int, size: int, signed: bool) -> None:
        data = int(value).to_bytes(size, "little", signed=signed)
        self._sdo(lambda sdo: sdo.download(index, sub, data))
