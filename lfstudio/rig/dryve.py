"""Modbus TCP "gateway" telegrams as the igus dryve D1 speaks them, and an :class:`ObjectLink`
over them (one TCP connection per drive).

A telegram (igus, dryve D1 operating manual, "Byte Assignment Modbus TCP Gateway Telegram"):

====== ============================================================================================
bytes  field
====== ============================================================================================
0-1    transaction identifier (big endian; the drive answers with the same)
2-3    protocol identifier, 0 = Modbus
4-5    length: the bytes after byte 5 (13 for a read request, 13 + n for a write of n bytes)
6      unit identifier (unused, 0)
7      function code 43 (2Bh); the drive answers 43 + 80h = ABh with an exception code in byte 8
8      MEI type 13 (0Dh): CANopen general reference (the gateway)
9      protocol control: 0 read, 1 write
10     reserved, 11 node id (unused)
12-13  object index (big endian, e.g. 60h 41h for the status word 6041h)
14     subindex
15-17  starting address (unused, 0)
18     byte count (1-4)
19-    data, little endian (write requests; read answers)
====== ============================================================================================

The drive's answer to a read carries the data (length 13 + n); its answer to a write repeats the
header with byte count 0 and no data (length 13), as the manual's RX/TX telegram examples (6.5.5)
show; those examples also write fewer bytes than an object has (6040h in 1), which the drive takes. :func:`encode_request` / :func:`decode_response` are the whole
protocol; :class:`DryveLink` adds the socket, the transaction numbers and the deadlines.
"""

from __future__ import annotations

import ipaddress
import logging
import socket
import struct
import threading
import time

from lfstudio.errors import InputError
from lfstudio.rig.cia402 import DriveNotAnswering, ObjectAccessRefused

log = logging.getLogger(__name__)

FUNCTION = 0x2B
MEI_TYPE = 0x0D
DEFAULT_PORT = 502
HEADER = 19                       # bytes before the data
MIN_ANSWER_LENGTH = 3             # the MBAP length of an exception answer (unit, function, code)
MAX_ANSWER_LENGTH = HEADER - 6 + 4  # ... and of the longest answer (a read of 4 bytes): 17
#: how often :meth:`DryveLink.write_now` looks whether its second connection delivered the write while
#: it waits for the link's own connection
WRITE_NOW_POLL_S = 0.005
EXCEPTIONS = {1: "illegal function", 2: "illegal data address (no such object)", 3: "illegal data value",
              4: "device failure", 5: "acknowledge (busy)", 6: "server busy"}


class TelegramError(Exception):
    """A telegram that does not follow the gateway format."""


def encode_request(transaction: int, write: bool, index: int, sub: int, size: int, data: bytes = b"") -> bytes:
    """One gateway request (see the module docstring). ``data``: the little-endian value of a write."""
    if size not in (1, 2, 4):
        raise ValueError(f"byte count {size}")
    if write and len(data) != size:
        raise ValueError(f"a write of {size} bytes needs {size} bytes of data")
    body = bytes([0, FUNCTION, MEI_TYPE, 1 if write else 0, 0, 0, index >> 8, index & 0xFF, sub, 0, 0, 0, size])
    body += data if write else b""
    return struct.pack(">HHH", transaction & 0xFFFF, 0, len(body)) + body


def decode_request(frame: bytes) -> tuple[int, bool, int, int, int, bytes]:
    """``(transaction, write, index, sub, size, data)`` of a request (the emulator's side)."""
    if len(frame) < HEADER:
        raise TelegramError(f"{len(frame)} bytes, a gateway telegram has at least {HEADER}")
    transaction, protocol, length = struct.unpack(">HHH", frame[:6])
    if protocol != 0 or length != len(frame) - 6:
        raise TelegramError("bad MBAP header")
    if frame[7] != FUNCTION or frame[8] != MEI_TYPE:
        raise TelegramError(f"function {frame[7]} / MEI type {frame[8]} is not the gateway (43 / 13)")
    write = frame[9] == 1
    size = frame[18]
    data = frame[HEADER:]
    if write and len(data) != size or not write and data:
        raise TelegramError(f"byte count {size} but {len(data)} data bytes")
    return transaction, write, (frame[12] << 8) | frame[13], frame[14], size, bytes(data)


def decode_response(frame: bytes, transaction: int, write: bool, index: int, sub: int) -> bytes:
    """The data of the drive's answer to the request (empty for a write). Raises
    :class:`ObjectAccessRefused` for an exception answer, :class:`TelegramError` for a malformed
    one or an answer to another request."""
    if len(frame) < 9:
        raise TelegramError(f"answer of {len(frame)} bytes")
    t, protocol, length = struct.unpack(">HHH", frame[:6])
    if t != transaction & 0xFFFF or protocol != 0 or length != len(frame) - 6:
        raise TelegramError(f"answer to transaction {t}, expected {transaction & 0xFFFF}")
    if frame[7] == FUNCTION | 0x80:
        code = frame[8]
        raise ObjectAccessRefused(f"object {index:04X}h:{sub} {'write' if write else 'read'} refused: exception "
                                  f"{code} ({EXCEPTIONS.get(code, 'unknown')})")
    if len(frame) < HEADER or frame[7] != FUNCTION or frame[8] != MEI_TYPE:
        raise TelegramError("not a gateway answer")
    if ((frame[12] << 8) | frame[13], frame[14]) != (index, sub):
        raise TelegramError(f"answer for object {(frame[12] << 8) | frame[13]:04X}h:{frame[14]}, "
                            f"expected {index:04X}h:{sub}")
    data = frame[HEADER:]
    if not write and len(data) != frame[18]:
        raise TelegramError(f"byte count {frame[18]} but {len(data)} data bytes")
    return bytes(data)


def parse_address(text: str, option: str = "--port") -> tuple[str, int]:
    """``HOST[:PORT]`` -> (host, port); the port defaults to 502; an IPv6 address in brackets
    (``[fd00::10]:502``) or bare (``fd00::10``, no port). The host in one spelling (a name in lower case
    without a final dot, an IP address as :mod:`ipaddress` writes it): the address names the drive's
    lock, so two spellings of one drive must be one address."""
    word = text.strip()
    if word.startswith("["):                      # [IPv6]:PORT
        host, sep, rest = word[1:].partition("]")
        if not sep or (rest and not rest.startswith(":")):
            raise InputError(option, f"{text!r}: an IPv6 address is written [ADDRESS]:PORT", "e.g. [fd00::10]:502")
        port = rest[1:]
    elif word.count(":") > 1:                     # a bare IPv6 address: no port
        host, port = word, ""
    else:
        host, _, port = word.rpartition(":") if ":" in word else (word, "", "")
    if not host:
        raise InputError(option, f"{text!r}: no host", "dryve:HOST[:PORT],HOST[:PORT]")
    try:
        host = str(ipaddress.ip_address(host))
    except ValueError:
        if ":" in host:
            raise InputError(option, f"{text!r}: {host!r} is not an IPv6 address", "e.g. [fd00::10]:502") from None
        host = host.lower().rstrip(".") or host
    if not port:
        return host, DEFAULT_PORT
    try:
        number = int(port)
    except ValueError:
        raise InputError(option, f"{text!r}: port {port!r} is not a number", "1 … 65535") from None
    if not 1 <= number <= 65535:
        raise InputError(option, f"{text!r}: port {number} is out of range", "1 … 65535")
    return host, number


def address_text(host: str, port: int) -> str:
    """``HOST:PORT`` as :func:`parse_address` reads it back (an IPv6 address in brackets)."""
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


class DryveLink:
    """One dryve D1 over Modbus TCP: :class:`lfstudio.rig.cia402.ObjectLink`. Exchanges are
    serialised (one request in flight); the drive's whole answer must arrive within ``timeout_s``
    of the request (a deadline for the answer, not for each ``recv``: a peer trickling its answer
    byte by byte ends there too), else :class:`DriveNotAnswering` and the connection is closed (the
    next access connects again). An answer whose length field exceeds the longest gateway answer
    is refused at once. :meth:`write_now` (STOP's quick stop) never waits behind an exchange in
    flight: it goes out on a connection of its own."""

    def __init__(self, host: str, port: int = DEFAULT_PORT, *, timeout_s: float = 1.0):
        self.host, self.port = host, int(port)
        self.address = address_text(host, self.port)
        self.lock_name = self.address      # the drive's one name (its lock's): parse_address spells hosts one way
        self.timeout_s = timeout_s
        self._sock: socket.socket | None = None
        self._lock = threading.Lock()
        self._transaction = 0
        self.exchanges = 0

    def open(self) -> None:
        with self._lock:
            self._open_locked()

    def _connect(self, timeout_s: float) -> socket.socket:
        try:
            sock = socket.create_connection((self.host, self.port), timeout=max(timeout_s, 1e-3))
        except OSError as exc:
            raise DriveNotAnswering(f"no Modbus TCP connection to {self.address} ({exc.strerror or exc})") from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return sock

    def _open_locked(self) -> socket.socket:
        self._close_locked()
        self._sock = self._connect(self.timeout_s)
        return self._sock

    def close(self) -> None:
        with self._lock:
            self._close_locked()

    def _close_locked(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            try:
                sock.close()
            except OSError:
                pass

    @staticmethod
    def _recv_exactly(sock: socket.socket, n: int, deadline: float, got: bytes = b"") -> bytes:
        """``n`` more bytes after ``got``, all before ``deadline`` (monotonic); :class:`_Late` else."""
        data = bytearray(got)
        end = len(got) + n
        while len(data) < end:
            left = deadline - time.monotonic()
            if left <= 0:
                raise _Late(len(data))
            sock.settimeout(left)
            try:
                chunk = sock.recv(end - len(data))
            except socket.timeout:
                raise _Late(len(data)) from None
            if not chunk:
                raise ConnectionError("the drive closed the connection")
            data += chunk
        return bytes(data)

    def _transact(self, sock: socket.socket, transaction: int, write: bool, index: int, sub: int, size: int,
                  data: bytes, deadline: float) -> bytes:
        """One request and its whole answer on ``sock`` before ``deadline``: the data (see
        :func:`decode_response`). Raises :class:`DriveNotAnswering` (the caller closes ``sock``)."""
        request = encode_request(transaction, write, index, sub, size, data)
        try:
            sock.settimeout(max(deadline - time.monotonic(), 1e-3))
            sock.sendall(request)
            head = self._recv_exactly(sock, 6, deadline)
            length = struct.unpack(">H", head[4:6])[0]
            if not MIN_ANSWER_LENGTH <= length <= MAX_ANSWER_LENGTH:
                raise TelegramError(f"the answer's length field says {length} bytes, a gateway answer has "
                                    f"{MIN_ANSWER_LENGTH} … {MAX_ANSWER_LENGTH}")
            frame = self._recv_exactly(sock, length, deadline, head)
        except _Late as late:
            raise DriveNotAnswering(f"{self.address}: no whole answer within {self.timeout_s:g} s "
                                    f"({late.got} bytes of it arrived)") from None
        except (OSError, ConnectionError, TelegramError) as exc:
            reason = f"no answer within {self.timeout_s:g} s" if isinstance(exc, socket.timeout) else str(exc)
            raise DriveNotAnswering(f"{self.address}: {reason}") from None
        try:
            return decode_response(frame, transaction, write, index, sub)
        except TelegramError as exc:
            raise DriveNotAnswering(f"{self.address}: {exc}") from None

    def _exchange(self, write: bool, index: int, sub: int, size: int, data: bytes = b"") -> bytes:
        with self._lock:
            return self._exchange_locked(write, index, sub, size, data)

    def _exchange_locked(self, write: bool, index: int, sub: int, size: int, data: bytes = b"") -> bytes:
        deadline = time.monotonic() + self.timeout_s
        sock = self._sock if self._sock is not None else self._open_locked()
        self._transaction = (self._transaction + 1) & 0xFFFF
        try:
            answer = self._transact(sock, self._transaction, write, index, sub, size, data, deadline)
        except ObjectAccessRefused:
            self.exchanges += 1
            raise
        except BaseException:
            # no answer, a broken one, or interrupted (Ctrl+C) while it was on its way: the rest of
            # it must never be read as the answer to the next request
            self._close_locked()
            raise
        self.exchanges += 1
        return answer

    def write_now(self, index: int, sub: int, value: int, size: int, signed: bool) -> None:
        """A write that never waits behind another exchange (STOP's quick stop): on the open
        connection when the link is idle, else on a new connection of its own (the exchange in
        flight, perhaps stalled, goes on to its own deadline). A gateway may serve one client only:
        it may refuse the second connection, close it, or take it and never answer. So while the
        second connection is tried, the link's own connection is waited for too, and whichever
        delivers the write first ends it (the same write twice is harmless: a control word); both
        within the link's deadline."""
        data = int(value).to_bytes(size, "little", signed=signed)
        if self._lock.acquire(blocking=False):
            try:
                self._exchange_locked(True, index, sub, size, data)
                return
            finally:
                self._lock.release()
        deadline = time.monotonic() + self.timeout_s
        delivered = threading.Event()
        second_failed: list[BaseException] = []

        def second() -> None:
            try:
                sock = self._connect(max(deadline - time.monotonic(), 1e-3))
                try:
                    self._transact(sock, 0xFFFF, True, index, sub, size, data, deadline)
                finally:
                    sock.close()
            except BaseException as exc:  # noqa: BLE001 - the own connection may still deliver it
                second_failed.append(exc)
            else:
                delivered.set()

        threading.Thread(target=second, name=f"write-now-{self.address}", daemon=True).start()
        while not delivered.is_set():
            left = deadline - time.monotonic()
            if left <= 0:
                break
            if self._lock.acquire(timeout=min(left, WRITE_NOW_POLL_S)):
                try:
                    if delivered.is_set():
                        return
                    self._exchange_locked(True, index, sub, size, data)
                    return
                finally:
                    self._lock.release()
        if delivered.is_set():
            return
        reason = f"; a second connection: {second_failed[0]}" if second_failed else ""
        raise DriveNotAnswering(f"{self.address}: the write did not go out within {self.timeout_s:g} s: the "
                                f"link's own connection stayed busy{reason}")

    def read(self, index: int, sub: int, size: int, signed: bool) -> int:
        data = self._exchange(False, index, sub, size)
        if len(data) != size:
            raise ObjectAccessRefused(f"{self.address}: object {index:04X}h:{sub} has {len(data)} bytes, "
                                      f"expected {size}")
        return int.from_bytes(data, "little", signed=signed)

    def write(self, index: int, sub: int, value: int, size: int, signed: bool) -> None:
        self._exchange(True, index, sub, size, int(value).to_bytes(size, "little", signed=signed))


class _Late(Exception):
    """The deadline of an answer passed; ``got`` bytes of it had arrived."""

    def __init__(self, got: int):
        super().__init__(got)
        self.got = got
