"""The emulated CiA 402 drives (:mod:`lfstudio.sim.cia402_drive`) behind real protocol stacks:

- :class:`ModbusDriveServer`: pymodbus' Modbus TCP server (on 127.0.0.1 only) with the dryve D1's
  gateway telegram (function 43, MEI type 13) as a custom PDU that pymodbus frames (MBAP) and
  decodes itself: the driver's own framing (``lfstudio.rig.dryve``) meets an independent one.
  A refused access answers the Modbus exception (43 + 80h, code); a drive that lost its
  connection holds every request unanswered.
- :class:`CanopenDriveNode`: python-canopen's ``LocalNode`` (SDO server) on a python-can bus,
  its object dictionary built from the emulator's objects, every read and write passed to the
  emulator through the node's callbacks (a refused access is an SDO abort).
"""

from __future__ import annotations

import asyncio
import logging
import threading
from typing import Any

from lfstudio.sim.cia402_drive import OBJECTS, DriveAxis, DrivePair, ObjectRefused

log = logging.getLogger(__name__)

LOCALHOST = "127.0.0.1"


def _exception_code(abort: int) -> int:
    """A CiA 301 abort code as the Modbus exception the gateway answers."""
    if abort in (0x06020000, 0x06090011, 0x06010002):
        return 2                                       # illegal data address
    if abort >> 16 == 0x0609:
        return 3                                       # illegal data value
    return 4                                           # device failure (state does not allow it)


def gateway_pdu_class(axis: DriveAxis) -> type:
    """A pymodbus PDU class for the gateway telegram, served by ``axis``."""
    from pymodbus.pdu import ExceptionResponse, ModbusPDU

    class GatewayTelegram(ModbusPDU):
        function_code = 0x2B
        sub_function_code = 0x0D

        def __init__(self, dev_id: int = 0, transaction_id: int = 0, **_: Any):
            super().__init__(dev_id=dev_id, transaction_id=transaction_id)
            self.write = False
            self.index = 0
            self.sub = 0
            self.size = 0
            self.data = b""

        @classmethod
        def decode_sub_function_code(cls, data: bytes) -> int:
            return int(data[2])

        def decode(self, data: bytes) -> None:
            # data: everything after the function code (MEI type first)
            if len(data) < 11 or data[0] != 0x0D:
                raise ValueError("not a gateway telegram")
            self.sub_function_code = data[0]
            self.write = data[1] == 1
            self.index = (data[4] << 8) | data[5]
            self.sub = data[6]
            self.size = data[10]
            self.data = bytes(data[11:])
            if self.size not in (1, 2, 4) or (self.write and len(self.data) != self.size):
                raise ValueError(f"byte count {self.size}, {len(self.data)} data bytes")

        def encode(self) -> bytes:
            return bytes([0x0D, 1 if self.write else 0, 0, 0, self.index >> 8, self.index & 0xFF, self.sub,
                          0, 0, 0, self.size]) + self.data

        async def datastore_update(self, context: Any, device_id: int) -> ModbusPDU:
            while not axis.answering:                  # lost connection: nothing comes back
                await asyncio.sleep(0.02)
            answer = GatewayTelegram(dev_id=device_id, transaction_id=self.transaction_id)
            # the manual's answer to a write is the header with byte count 0; its examples write fewer
            # bytes than an object has (6040h in 1, 6099h:01 in 2), so a write may be shorter than the object
            answer.write, answer.index, answer.sub = self.write, self.index, self.sub
            answer.size = 0 if self.write else self.size
            spec = OBJECTS.get((self.index, self.sub))
            try:
                if spec is not None and (self.size > spec[0] if self.write else self.size != spec[0]):
                    raise ObjectRefused(0x06070010, f"{self.index:04X}h has {spec[0]} bytes, not {self.size}")
                if self.write:
                    signed = spec[1] if spec else False
                    axis.write(self.index, self.sub, int.from_bytes(self.data, "little", signed=signed))
                else:
                    value = axis.read(self.index, self.sub)
                    answer.data = int(value).to_bytes(self.size, "little", signed=value < 0)
            except ObjectRefused as exc:
                return ExceptionResponse(0x2B, _exception_code(exc.abort))
            return answer

    return GatewayTelegram


class ModbusDriveServer:
    """pymodbus' Modbus TCP server for one emulated drive on ``127.0.0.1:port`` (0: any free port;
    :attr:`port` after :meth:`start`), on a thread with its own event loop."""

    def __init__(self, axis: DriveAxis, port: int = 0):
        self.axis = axis
        self.port = int(port)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Any = None
        self._thread: threading.Thread | None = None

    @property
    def address(self) -> str:
        return f"{LOCALHOST}:{self.port}"

    def start(self) -> "ModbusDriveServer":
        from pymodbus.server import ModbusTcpServer
        from pymodbus.simulator import SimData, SimDevice

        ready = threading.Event()
        failure: list[BaseException] = []

        async def serve() -> None:
            try:
                context = SimDevice(id=0, simdata=[SimData(address=0, count=1, values=0)])   # no registers used
                self._server = ModbusTcpServer(context, address=(LOCALHOST, self.port),
                                               custom_pdu=[gateway_pdu_class(self.axis)])
                if not await self._server.listen():
                    raise OSError(f"cannot listen on {LOCALHOST}:{self.port}")
                self.port = self._server.transport.sockets[0].getsockname()[1]
            except BaseException as exc:  # noqa: BLE001 - reported to start()
                failure.append(exc)
                ready.set()
                return
            ready.set()
            await self._server.serving

        def run() -> None:
            self._loop = asyncio.new_event_loop()
            try:
                self._loop.run_until_complete(serve())
            finally:
                self._loop.close()

        self._thread = threading.Thread(target=run, name=f"drive-modbus-{self.axis.name}", daemon=True)
        self._thread.start()
        ready.wait(30)
        if failure:
            raise failure[0]
        return self

    def close(self) -> None:
        loop, server = self._loop, self._server
        if loop is not None and server is not None and not loop.is_closed():
            try:
                asyncio.run_coroutine_threadsafe(server.shutdown(), loop).result(10)
            except Exception as exc:  # noqa: BLE001
                log.debug("drive server shutdown: %s", exc)
        if self._thread is not None:
            self._thread.join(10)
        self._server = None


class _PairOnTheWire:
    """What both transports share: the emulated :class:`DrivePair` behind them (its time scale and the
    carriages' true position, for tests and the simulated studio)."""

    pair: DrivePair

    @property
    def time_scale(self) -> float:
        return self.pair.time_scale

    @time_scale.setter
    def time_scale(self, value: float) -> None:
        self.pair.time_scale = value

    def true_position_mm(self) -> tuple[float, float]:
        return self.pair.true_position_mm()


class DriveServers(_PairOnTheWire):
    """Both drives of a :class:`DrivePair` on Modbus TCP servers: :attr:`word` is the device word
    (``dryve:127.0.0.1:P1,127.0.0.1:P2``) that reaches them."""

    def __init__(self, pair: DrivePair, ports: tuple[int, int] = (0, 0)):
        self.pair = pair
        self.servers = [ModbusDriveServer(axis, port) for axis, port in zip(pair.axes, ports)]
        self.running = False

    @property
    def word(self) -> str:
        return "dryve:" + ",".join(s.address for s in self.servers)

    def start(self) -> "DriveServers":
        try:
            for s in self.servers:
                s.start()
        except BaseException:
            self.close()
            raise
        self.running = True
        return self

    def close(self) -> None:
        self.running = False
        for s in self.servers:
            s.close()


# -- CANopen -----------------------------------------------------------------------------------------
def object_dictionary() -> Any:
    """A python-canopen object dictionary with the emulator's objects."""
    import canopen
    from canopen.objectdictionary import INTEGER8, INTEGER16, INTEGER32, UNSIGNED8, UNSIGNED16, UNSIGNED32, \
        ODArray, ODRecord, ODVariable

    types = {(1, True): INTEGER8, (2, True): INTEGER16, (4, True): INTEGER32, (1, False): UNSIGNED8,
             (2, False): UNSIGNED16, (4, False): UNSIGNED32}
    od = canopen.ObjectDictionary()
    by_index: dict[int, list[int]] = {}
    for index, sub in OBJECTS:
        by_index.setdefault(index, []).append(sub)
    for index, subs in sorted(by_index.items()):
        if subs == [0]:
            size, signed, writable = OBJECTS[(index, 0)]
            var = ODVariable(f"obj{index:04X}", index)
            var.data_type = types[(size, signed)]
            var.access_type = "rw" if writable else "ro"
            var.default = 0
            od.add_object(var)
            continue
        record = ODRecord(f"obj{index:04X}", index)
        count = ODVariable("count", index, 0)
        count.data_type = UNSIGNED8
        count.access_type = "ro"
        count.default = max(subs)
        record.add_member(count)
        for sub in subs:
            size, signed, writable = OBJECTS[(index, sub)]
            var = ODVariable(f"sub{sub}", index, sub)
            var.data_type = types[(size, signed)]
            var.access_type = "rw" if writable else "ro"
            var.default = 0
            record.add_member(var)
        od.add_object(record)
    _ = ODArray
    return od


class CanopenDriveNode:
    """One emulated drive as a python-canopen ``LocalNode`` (``node_id``) on ``network``."""

    def __init__(self, axis: DriveAxis, network: Any, node_id: int):
        import canopen
        from canopen.sdo.exceptions import SdoAbortedError

        self.axis = axis
        self.node_id = node_id
        self.network = network
        self.node = canopen.LocalNode(node_id, object_dictionary())

        def on_read(index: int, subindex: int, od: Any) -> int | None:
            if (index, subindex) not in OBJECTS:
                return None
            try:
                return axis.read(index, subindex)
            except ObjectRefused as exc:
                raise SdoAbortedError(exc.abort) from None

        def on_write(index: int, subindex: int, od: Any, data: bytes) -> None:
            spec = OBJECTS.get((index, subindex))
            if spec is None:
                return
            try:
                axis.write(index, subindex, int.from_bytes(data, "little", signed=spec[1]))
            except ObjectRefused as exc:
                raise SdoAbortedError(exc.abort) from None

        self.node.add_read_callback(on_read)
        self.node.add_write_callback(on_write)
        network.add_node(self.node)
        self._attached = True

    def sync_answering(self) -> None:
        """Leave the bus while the drive has lost its connection, come back when it answers."""
        if self.axis.answering and not self._attached:
            self.node.associate_network(self.network)
            self._attached = True
        elif not self.axis.answering and self._attached:
            self.node.remove_network()
            self._attached = False


class CanopenDrives(_PairOnTheWire):
    """Both drives of a :class:`DrivePair` as CANopen nodes on python-can's in-process ``virtual``
    bus ``channel`` (node ids ``nodes``); :attr:`word` reaches them (``canopen:virtual-NAME:1,2``)."""

    def __init__(self, pair: DrivePair, channel: str, nodes: tuple[int, int] = (1, 2)):
        self.pair = pair
        self.channel = channel
        self.nodes = nodes
        self.network: Any = None
        self.drives: list[CanopenDriveNode] = []
        self.running = False

    @property
    def word(self) -> str:
        return f"canopen:virtual-{self.channel}:{self.nodes[0]},{self.nodes[1]}"

    def start(self) -> "CanopenDrives":
        import canopen

        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.1
        self.network.connect(interface="virtual", channel=self.channel, receive_own_messages=False)
        self.drives = [CanopenDriveNode(axis, self.network, node) for axis, node in zip(self.pair.axes, self.nodes)]
        for axis, drive in zip(self.pair.axes, self.drives):
            axis.on_answering = drive.sync_answering
        self.running = True
        return self

    def close(self) -> None:
        self.running = False
        if self.network is not None:
            try:
                self.network.disconnect()
            except Exception as exc:  # noqa: BLE001
                log.debug("CAN network disconnect: %s", exc)
            self.network = None
