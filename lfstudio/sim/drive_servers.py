"""The emulated CiA 402 drives (:mod:`lfstudio.sim.cia402_drive`) behind real protocol stacks:

- :class:`ModbusDriveServer`: a Modbus TCP server (on 127.0.0.1 only) answering the dryve D1's
  gateway telegram (function 43, MEI type 13) as the manual V2.4 describes it
  (:func:`gateway_answer`, written from the manual's byte table, not from ``lfstudio.rig.dryve``).
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
import time
from typing import Any

from lfstudio.rig.canopen_link import bus_args
from lfstudio.sim.cia402_drive import DriveAxis, DrivePair, ObjectRefused

log = logging.getLogger(__name__)

LOCALHOST = "127.0.0.1"


def _exception_code(abort: int) -> int:
    """A CiA 301 abort code as the Modbus exception the gateway answers (manual V2.4 6.5.6: 01 illegal
    function, 02 illegal data address, 03 illegal data value, 04 device failure, 05 acknowledge, 06 busy)."""
    if abort in (0x06020000, 0x06090011, 0x06010002):
        return 2                                       # illegal data address
    if abort >> 16 in (0x0609, 0x0607):
        return 3                                       # illegal data value
    return 4                                           # device failure (state does not allow it)


def gateway_answer(axis: DriveAxis, request: bytes) -> bytes:
    """The drive's answer to one gateway request (the whole telegram, MBAP header first), as the
    manual V2.4 (6.5.4 byte assignment, 6.5.5 RX/TX examples, 6.5.6 exception codes) shows it:

    - a read is answered with the object's own size, whatever byte count it asked for (igus' sample
      reads 6061h with byte count 1 and gets 1 byte; public clients read 6064h with 4);
    - a write is answered with the request's header, length 13 and byte count 0, no data; it may carry
      fewer bytes than the object has (the manual writes 6040h in 1 byte, 6099h:01 in 2);
    - a refused access is 9 bytes: the header with length 3, byte 7 = ABh (43 + 80h), byte 8 = the code.
    """
    head = request[:6]
    transaction = request[:2]

    def exception(code: int) -> bytes:
        return transaction + bytes([0, 0, 0, 3, request[6] if len(request) > 6 else 0, 0xAB, code])

    if len(request) < 9 or request[7] != 0x2B:
        return transaction + bytes([0, 0, 0, 3, request[6] if len(request) > 6 else 0,
                                    (request[7] if len(request) > 7 else 0) | 0x80, 1])
    if request[8] != 0x0D or len(request) < 19:
        return exception(1)
    write = request[9] == 1
    index, sub, size = (request[12] << 8) | request[13], request[14], request[18]
    data = request[19:]
    if size not in (1, 2, 3, 4) or (write and len(data) != size) or (not write and data):
        return exception(3)
    spec = axis.objects.get((index, sub))
    try:
        if write:
            if spec is not None and size > spec[0]:
                raise ObjectRefused(0x06070012, f"{index:04X}h has {spec[0]} bytes, not {size}")
            # a shorter write is the low bytes of the value (the manual's 1-byte 6040h, 2-byte 6099h:01)
            signed = spec is not None and spec[1] and len(data) == spec[0]
            axis.write(index, sub, int.from_bytes(data, "little", signed=signed))
            answer = bytes(request[6:18]) + bytes([0])
        else:
            value = axis.read(index, sub)
            n = spec[0] if spec is not None else size
            answer = bytes(request[6:18]) + bytes([n]) + int(value).to_bytes(n, "little", signed=value < 0)
    except ObjectRefused as exc:
        return exception(_exception_code(exc.abort))
    del head
    return transaction + bytes([0, 0]) + len(answer).to_bytes(2, "big") + answer


class ModbusDriveServer:
    """One emulated drive's Modbus TCP gateway on ``127.0.0.1:port`` (0: any free port; :attr:`port`
    after :meth:`start`), an asyncio stream server on a thread with its own event loop. It frames
    telegrams by their MBAP length field, so two requests in one TCP segment get two answers (pymodbus'
    server, used before, answered only the first: its send() drops the rest of its receive buffer).
    A drive that lost its connection holds every request unanswered.

    ``extra_clients``: what a connection does while another is open, for gateways that serve one
    client only (whether a dryve D1 serves several is not documented where we could read it):
    "serve" (default) answers it too, "refuse" closes it at once, "ignore" reads its requests and
    never answers. :attr:`clients_seen` counts the connections accepted."""

    def __init__(self, axis: DriveAxis, port: int = 0, extra_clients: str = "serve"):
        if extra_clients not in ("serve", "refuse", "ignore"):
            raise ValueError(f"extra_clients {extra_clients!r}: serve, refuse or ignore")
        self.axis = axis
        self.port = int(port)
        self.extra_clients = extra_clients
        self.clients_seen = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: asyncio.AbstractServer | None = None
        self._thread: threading.Thread | None = None
        self._stopped: asyncio.Event | None = None
        self._clients: set[asyncio.Task] = set()

    @property
    def address(self) -> str:
        return f"{LOCALHOST}:{self.port}"

    async def _serve_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        extra = bool(self._clients)
        self.clients_seen += 1
        if task is not None:
            self._clients.add(task)
        try:
            if extra and self.extra_clients == "refuse":
                return
            if extra and self.extra_clients == "ignore":
                while await reader.read(4096):
                    pass
                return
            while True:
                head = await reader.readexactly(6)
                length = int.from_bytes(head[4:6], "big")
                if head[2:4] != b"\0\0" or not 2 <= length <= 260:
                    break                                  # not Modbus TCP: the drive closes the connection
                body = await reader.readexactly(length)
                while not self.axis.answering:             # lost connection: nothing comes back
                    await asyncio.sleep(0.02)
                delay = self.axis.answer_delay_s          # a slow gateway: the value taken half way
                if delay > 0:
                    await asyncio.sleep(delay / 2)
                answer = gateway_answer(self.axis, head + body)
                if delay > 0:
                    await asyncio.sleep(delay / 2)
                writer.write(answer)
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError, asyncio.CancelledError):
            pass
        finally:
            writer.close()
            if task is not None:
                self._clients.discard(task)

    def start(self) -> "ModbusDriveServer":
        ready = threading.Event()
        failure: list[BaseException] = []

        async def serve() -> None:
            self._stopped = asyncio.Event()
            try:
                self._server = await asyncio.start_server(self._serve_client, LOCALHOST, self.port)
                self.port = self._server.sockets[0].getsockname()[1]
            except BaseException as exc:  # noqa: BLE001 - reported to start()
                failure.append(exc)
                ready.set()
                return
            ready.set()
            await self._stopped.wait()
            self._server.close()
            clients = list(self._clients)
            for task in clients:
                task.cancel()
            await asyncio.gather(*clients, return_exceptions=True)
            await self._server.wait_closed()

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
        loop, stopped = self._loop, self._stopped
        if loop is not None and stopped is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(stopped.set)
            except RuntimeError as exc:                     # the loop ended meanwhile
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

    def true_position_at(self, t: float) -> tuple[float, float] | None:
        """Where the carriage was at monotonic time ``t`` (the simulated camera's exposure timestamps)."""
        return self.pair.true_position_at(t)

    def exposure_output(self, level: bool, t: float) -> bool:
        """The simulated camera's exposure output (high while it exposes; ``level`` from monotonic time
        ``t``), wired to both drives' touch probe 1 input."""
        return self.pair.probe_edge(bool(level), t)


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
def object_dictionary(objects: dict[tuple[int, int], tuple[int, bool, bool]]) -> Any:
    """A python-canopen object dictionary with an emulated drive's objects."""
    import canopen
    from canopen.objectdictionary import INTEGER8, INTEGER16, INTEGER32, UNSIGNED8, UNSIGNED16, UNSIGNED32, \
        ODArray, ODRecord, ODVariable

    types = {(1, True): INTEGER8, (2, True): INTEGER16, (4, True): INTEGER32, (1, False): UNSIGNED8,
             (2, False): UNSIGNED16, (4, False): UNSIGNED32}
    od = canopen.ObjectDictionary()
    by_index: dict[int, list[int]] = {}
    for index, sub in objects:
        by_index.setdefault(index, []).append(sub)
    for index, subs in sorted(by_index.items()):
        if subs == [0]:
            size, signed, writable = objects[(index, 0)]
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
        if (index, 0) in objects:
            count.data_type = types[(objects[(index, 0)][0], objects[(index, 0)][1])]
        record.add_member(count)
        for sub in subs:
            if sub == 0:
                continue
            size, signed, writable = objects[(index, sub)]
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
        self.node = canopen.LocalNode(node_id, object_dictionary(axis.objects))

        def on_read(index: int, subindex: int, od: Any) -> int | None:
            if (index, subindex) not in axis.objects:
                return None
            delay = axis.answer_delay_s                    # a busy bus: the value taken half way
            if delay > 0:
                time.sleep(delay / 2)
            try:
                return axis.read(index, subindex)
            except ObjectRefused as exc:
                raise SdoAbortedError(exc.abort) from None
            finally:
                if delay > 0:
                    time.sleep(delay / 2)

        def on_write(index: int, subindex: int, od: Any, data: bytes) -> None:
            spec = axis.objects.get((index, subindex))
            if spec is None:
                return
            delay = axis.answer_delay_s                    # every answer late, a write's too
            if delay > 0:
                time.sleep(delay / 2)
            try:
                axis.write(index, subindex, int.from_bytes(data, "little", signed=spec[1]))
            except ObjectRefused as exc:
                raise SdoAbortedError(exc.abort) from None
            finally:
                if delay > 0:
                    time.sleep(delay / 2)

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
    """Both drives of a :class:`DrivePair` as CANopen nodes on the bus ``channel`` (a channel word of
    :func:`lfstudio.rig.canopen_link.bus_args`: ``virtual-NAME`` in this process, ``udp_multicast``
    between processes) with node ids ``nodes``; :attr:`word` reaches them (``canopen:CHANNEL:1,2``)."""

    def __init__(self, pair: DrivePair, channel: str, nodes: tuple[int, int] = (1, 2)):
        self.pair = pair
        self.channel = channel
        self.nodes = nodes
        self.network: Any = None
        self.drives: list[CanopenDriveNode] = []
        self.running = False

    @property
    def word(self) -> str:
        return f"canopen:{self.channel}:{self.nodes[0]},{self.nodes[1]}"

    def start(self) -> "CanopenDrives":
        import canopen

        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.1
        self.network.connect(**bus_args(self.channel))
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


def eds_text(objects: dict[tuple[int, int], tuple[int, bool, bool]], name: str = "lfstudio emulated CiA 402 drive"
             ) -> str:
    """An EDS (CiA 306) listing an emulated drive's objects, as a drive maker ships one: what a rig
    profile's ``eds_file`` names (tests, and a template for a drive without one)."""
    types = {(1, True): 0x0002, (2, True): 0x0003, (4, True): 0x0004, (1, False): 0x0005, (2, False): 0x0006,
             (4, False): 0x0007}
    by_index: dict[int, list[int]] = {}
    for index, sub in sorted(objects):
        by_index.setdefault(index, []).append(sub)
    lines = ["[FileInfo]", f"FileName={name}.eds", "FileVersion=1", "EDSVersion=4.0", "",
             "[DeviceInfo]", "VendorName=lfstudio", f"ProductName={name}", "BaudRate_1000=1", "SimpleBootUpSlave=1",
             "Granularity=8", "NrOfRXPDO=0", "NrOfTXPDO=0", "LSS_Supported=0", "",
             "[MandatoryObjects]", "SupportedObjects=1", "1=0x1000", "",
             "[OptionalObjects]", f"SupportedObjects={len([i for i in by_index if i != 0x1000])}"]
    lines += [f"{n}=0x{index:04X}" for n, index in enumerate((i for i in by_index if i != 0x1000), 1)]
    lines.append("")

    def variable(section: str, title: str, spec: tuple[int, bool, bool], default: int | None = None) -> list[str]:
        size, signed, writable = spec
        out = [f"[{section}]", f"ParameterName={title}", "ObjectType=0x7", f"DataType=0x{types[(size, signed)]:04X}",
               f"AccessType={'rw' if writable else 'ro'}", "PDOMapping=0"]
        if default is not None:
            out.append(f"DefaultValue={default}")
        return out + [""]

    for index, subs in by_index.items():
        if subs == [0]:
            lines += variable(f"{index:04X}", f"Object {index:04X}h", objects[(index, 0)])
            continue
        highest = max(subs)
        lines += [f"[{index:04X}]", f"ParameterName=Object {index:04X}h", "ObjectType=0x9", f"SubNumber={highest + 1}", ""]
        lines += variable(f"{index:04X}sub0", "Highest sub-index supported", (1, False, False), highest)
        for sub in subs:
            if sub:
                lines += variable(f"{index:04X}sub{sub:X}", f"Sub-index {sub}", objects[(index, sub)])
    return "\n".join(lines) + "\n"
