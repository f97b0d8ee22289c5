"""Dynamixel Protocol 1.0 and 2.0 packets: encode, decode, find them in a byte stream.

Pure code, no I/O. The frame (header, length, CRC or checksum, byte stuffing) is plain Python
with a table CRC, as the stream parser runs on every received byte; the parameter layouts of the
instructions (READ, SYNC_WRITE, BULK_READ...) are declared with ``construct`` and reached through
the typed functions below (``read_params``, ``parse_sync_write``...), never directly.

Protocol 2.0 (ROBOTIS e-manual)::

    instruction  FF FF FD 00 | ID | LEN_L LEN_H | INST | params        | CRC_L CRC_H
    status       FF FF FD 00 | ID | LEN_L LEN_H | 55   | ERR | params  | CRC_L CRC_H

LEN counts INST (and ERR), the parameters after byte stuffing and the CRC. CRC-16: polynomial
0x8005, init 0, not reflected, no final XOR, over everything from the first FF to the last
parameter, after stuffing. Stuffing: from INST to the last parameter, every ``FF FF FD`` gets an
extra ``FD``. ERR: bit 7 Alert (read Hardware Error Status), bits 6-0 an error number.

Protocol 1.0::

    instruction  FF FF | ID | LEN | INST | params | CHK
    status       FF FF | ID | LEN | ERR  | params | CHK

LEN = parameters + 2; CHK = ~(ID + LEN + INST/ERR + params) & 0xFF. ERR is a set of bits.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final, Literal

import construct as cs

from hwbridge.errors import FramingError

__all__ = [
    "ALERT_BIT",
    "BROADCAST_ID",
    "CLEAR_MULTI_TURN",
    "HEADER_1",
    "HEADER_2",
    "MAX_ID",
    "CorruptPacket",
    "Error1",
    "Error2",
    "Instruction",
    "InstructionPacket",
    "Packet",
    "PacketParser",
    "ParserStats",
    "StatusPacket",
    "action_packet",
    "bulk_read_packet",
    "bulk_read_params",
    "bulk_write_packet",
    "bulk_write_params",
    "checksum",
    "clear_packet",
    "crc16",
    "decode",
    "encode",
    "error_names",
    "factory_reset_packet",
    "instruction_name",
    "parse_bulk_read",
    "parse_bulk_write",
    "parse_ping_status",
    "parse_read",
    "parse_sync_read",
    "parse_sync_write",
    "parse_write",
    "ping_packet",
    "ping_status_params",
    "read_packet",
    "read_params",
    "reboot_packet",
    "stuff",
    "sync_read_packet",
    "sync_read_params",
    "sync_write_packet",
    "sync_write_params",
    "unstuff",
    "write_packet",
    "write_params",
]

HEADER_2: Final = b"\xff\xff\xfd\x00"
"""Protocol 2.0 header with its reserved byte (0x00, never 0xFD)."""
HEADER_1: Final = b"\xff\xff"
"""Protocol 1.0 header."""
BROADCAST_ID: Final = 0xFE
"""Every servo executes; only PING (Protocol 2.0) and SYNC/BULK READ get status replies."""
MAX_ID: Final[Mapping[int, int]] = {1: 253, 2: 252}
"""Highest servo ID per protocol (0xFD and 0xFF are not IDs in Protocol 2.0)."""
ALERT_BIT: Final = 0x80
"""Protocol 2.0 ERR bit 7: the servo has a hardware error (read Hardware Error Status)."""
CLEAR_MULTI_TURN: Final = b"\x01\x44\x58\x4c\x22"
"""CLEAR parameters that reset Present Position to within one turn (X series, firmware 42+)."""
STATUS_INSTRUCTION: Final = 0x55


class Instruction(enum.IntEnum):
    """Instruction codes (the same numbers in both protocols where both have them)."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    """Called RESET in Protocol 1.0 (no parameter); Protocol 2.0 takes an option byte."""
    REBOOT = 0x08
    CLEAR = 0x10
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    BULK_READ = 0x92
    BULK_WRITE = 0x93


class Error2(enum.IntEnum):
    """Protocol 2.0 error numbers (ERR bits 6-0)."""

    NONE = 0
    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


class Error1(enum.IntFlag):
    """Protocol 1.0 error bits."""

    INPUT_VOLTAGE = 0x01
    ANGLE_LIMIT = 0x02
    OVERHEATING = 0x04
    RANGE = 0x08
    CHECKSUM = 0x10
    OVERLOAD = 0x20
    INSTRUCTION = 0x40


ERROR_NAMES_2: Final[Mapping[int, str]] = {
    1: "Result Fail",
    2: "Instruction Error",
    3: "CRC Error",
    4: "Data Range Error",
    5: "Data Length Error",
    6: "Data Limit Error",
    7: "Access Error",
}
ERROR_NAMES_1: Final[Mapping[int, str]] = {
    0x01: "Input Voltage Error",
    0x02: "Angle Limit Error",
    0x04: "Overheating Error",
    0x08: "Range Error",
    0x10: "Checksum Error",
    0x20: "Overload Error",
    0x40: "Instruction Error",
}


def error_names(protocol: int, error: int) -> list[str]:
    """The names of what ``error`` (a status packet's ERR byte) reports, in bit order."""
    if protocol == 2:
        names = []
        number = error & 0x7F
        if number:
            names.append(ERROR_NAMES_2.get(number, f"Error {number}"))
        if error & ALERT_BIT:
            names.append("Alert (hardware error, read Hardware Error Status)")
        return names
    names = [name for bit, name in ERROR_NAMES_1.items() if error & bit]
    if error & 0x80:
        names.append("bit 7")
    return names


def instruction_name(code: int) -> str:
    """``READ`` for 2, ``0x77`` for an unknown code."""
    try:
        return Instruction(code).name
    except ValueError:
        return f"0x{code:02X}"


# ----------------------------------------------------------------------------- packets


@dataclass(frozen=True)
class InstructionPacket:
    """A packet from the host: ``instruction`` with ``params`` (unstuffed) for servo ``id``."""

    id: int
    instruction: int
    params: bytes = b""
    protocol: int = 2

    def __bytes__(self) -> bytes:
        return encode(self)

    @property
    def name(self) -> str:
        return instruction_name(self.instruction)


@dataclass(frozen=True)
class StatusPacket:
    """A servo's reply: ``error`` (the ERR byte) and ``params`` (unstuffed)."""

    id: int
    error: int = 0
    params: bytes = b""
    protocol: int = 2

    def __bytes__(self) -> bytes:
        return encode(self)

    @property
    def alert(self) -> bool:
        """Protocol 2.0 Alert bit: a hardware error is pending on the servo."""
        return self.protocol == 2 and bool(self.error & ALERT_BIT)

    @property
    def error_names(self) -> list[str]:
        return error_names(self.protocol, self.error)


@dataclass(frozen=True)
class CorruptPacket:
    """Something shaped like a packet whose CRC/checksum or content was wrong.

    Real servos answer such a packet addressed to them with a CRC (2.0) or Checksum (1.0)
    error; hosts count it and retry.
    """

    protocol: int
    id: int
    raw: bytes
    reason: str


Packet = InstructionPacket | StatusPacket


# ------------------------------------------------------------------- checksums, stuffing


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE: Final = _crc_table()


def crc16(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16 of Protocol 2.0 (poly 0x8005, init 0, MSB first, no final XOR)."""
    table = _CRC_TABLE
    for byte in bytes(data):
        crc = ((crc << 8) & 0xFFFF) ^ table[((crc >> 8) ^ byte) & 0xFF]
    return crc


def checksum(body: bytes | bytearray | memoryview) -> int:
    """Protocol 1.0 checksum of ID, LEN, INST/ERR and params: ``~sum & 0xFF``."""
    return ~sum(bytes(body)) & 0xFF


_PATTERN: Final = b"\xff\xff\xfd"


def stuff(data: bytes | bytearray | memoryview) -> bytes:
    """Protocol 2.0 byte stuffing: an ``FD`` after every ``FF FF FD``."""
    raw = bytes(data)
    if _PATTERN not in raw:
        return raw
    return raw.replace(_PATTERN, _PATTERN + b"\xfd")


def unstuff(data: bytes | bytearray | memoryview) -> bytes:
    """Undo :func:`stuff`; FramingError when an ``FF FF FD`` is not followed by ``FD``."""
    raw = bytes(data)
    if _PATTERN not in raw:
        return raw
    out = bytearray()
    start = 0
    while True:
        index = raw.find(_PATTERN, start)
        if index < 0:
            out += raw[start:]
            return bytes(out)
        end = index + 3
        if end >= len(raw) or raw[end] != 0xFD:
            raise FramingError(
                f"FF FF FD at byte {index} of the packet body is not stuffed (no FD after it)"
            )
        out += raw[start:end]
        start = end + 1


# ----------------------------------------------------------------------------- encoding


def _check_id(protocol: int, id_: int, *, status: bool) -> None:
    top = MAX_ID[_protocol(protocol)]
    if not (0 <= id_ <= top or (id_ == BROADCAST_ID and not status)):
        extra = "" if status else f" or {BROADCAST_ID} (broadcast)"
        raise ValueError(f"Protocol {protocol}.0 IDs are 0-{top}{extra}, not {id_}")


def encode(packet: Packet) -> bytes:
    """The bytes of ``packet`` on the wire (header, stuffing, length, CRC or checksum)."""
    protocol = packet.protocol
    status = isinstance(packet, StatusPacket)
    _check_id(protocol, packet.id, status=status)
    if isinstance(packet, StatusPacket):
        if not 0 <= packet.error <= 0xFF:
            raise ValueError(f"error must be a byte, not {packet.error}")
        code = packet.error
        lead = bytes((STATUS_INSTRUCTION, code)) if protocol == 2 else b""
    else:
        if not 0 <= packet.instruction <= 0xFF:
            raise ValueError(f"instruction must be a byte, not {packet.instruction}")
        code, lead = packet.instruction, bytes((packet.instruction,))
    params = bytes(packet.params)
    if protocol == 2:
        body = stuff(lead + params)
        length = len(body) + 2
        if length > 0xFFFF:
            raise ValueError(f"{len(params)} parameter bytes do not fit a Protocol 2.0 packet")
        frame = HEADER_2 + bytes((packet.id, length & 0xFF, length >> 8)) + body
        crc = crc16(frame)
        return frame + bytes((crc & 0xFF, crc >> 8))
    length = len(params) + 2
    if length > 0xFF:
        raise ValueError(f"{len(params)} parameter bytes do not fit a Protocol 1.0 packet")
    body = bytes((packet.id, length, code)) + params
    return HEADER_1 + body + bytes((checksum(body),))


def decode(
    data: bytes | bytearray | memoryview,
    protocol: int = 2,
    kind: Literal["instruction", "status"] = "status",
) -> Packet:
    """Decode exactly one packet; FramingError says what is wrong with anything else.

    ``kind`` matters for Protocol 1.0 only (its status and instruction packets look alike);
    Protocol 2.0 status packets are recognised by their 0x55 instruction byte.
    """
    raw = bytes(data)
    parser = PacketParser(protocol, expect=kind)
    items = parser.feed(raw)
    for item in items:
        if isinstance(item, CorruptPacket):
            raise FramingError(f"not a valid Protocol {protocol}.0 packet: {item.reason}")
    if len(items) != 1 or parser.stats.skipped_bytes or parser.buffered:
        if not items:
            raise FramingError(
                f"no complete Protocol {protocol}.0 packet in {len(raw)} bytes: {raw.hex(' ')}"
            )
        raise FramingError(
            f"expected exactly one Protocol {protocol}.0 packet, found {len(items)} with "
            f"{parser.stats.skipped_bytes + parser.buffered} other bytes"
        )
    item = items[0]
    assert not isinstance(item, CorruptPacket)
    return item


# ------------------------------------------------------------------------ stream parser


@dataclass
class ParserStats:
    """Counters of one :class:`PacketParser` (they only grow)."""

    packets: int = 0
    corrupt: int = 0
    """Packet-shaped byte runs with a wrong CRC/checksum or broken stuffing."""
    skipped_bytes: int = 0
    """Bytes that were not part of any packet (noise, echoes of nothing, stale partials)."""


@dataclass
class PacketParser:
    """Finds packets of one protocol in a byte stream cut anywhere (sans-I/O).

    ``feed(data)`` returns the packets completed by ``data``, in order, and a
    :class:`CorruptPacket` for each packet-shaped run whose CRC/checksum fails (the parser then
    resynchronises one byte further, so a corrupt or fake header cannot hide a good packet).
    ``expect`` says what Protocol 1.0 packets are (status on the host, instructions on a servo).
    ``max_length`` bounds Protocol 2.0 LEN: a longer one is taken for noise. With ``stale_after``
    (seconds) a partial packet older than that is dropped when the next bytes come, as a
    servo's receiver does after a gap on the line (give ``now`` to :meth:`feed` for this).
    """

    protocol: int = 2
    expect: Literal["instruction", "status"] = "status"
    max_length: int = 1024
    stale_after: float | None = None
    stats: ParserStats = field(default_factory=ParserStats)
    _buffer: bytearray = field(default_factory=bytearray, repr=False)
    _last_rx: float | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        _protocol(self.protocol)

    @property
    def buffered(self) -> int:
        """Bytes kept for a packet not complete yet."""
        return len(self._buffer)

    def reset(self) -> None:
        """Forget buffered bytes (counted as skipped)."""
        self.stats.skipped_bytes += len(self._buffer)
        self._buffer.clear()

    def feed(
        self, data: bytes | bytearray | memoryview, now: float | None = None
    ) -> list[Packet | CorruptPacket]:
        """Add ``data`` and return the packets it completes (see the class documentation)."""
        if now is not None:
            if (
                self.stale_after is not None
                and self._buffer
                and self._last_rx is not None
                and now - self._last_rx > self.stale_after
            ):
                self.reset()
            self._last_rx = now
        self._buffer += data
        return self._scan(final=False)

    def flush(self) -> list[Packet | CorruptPacket]:
        """End of input: give up on a partial packet, return what the bytes after it hold."""
        return self._scan(final=True)

    def _scan(self, final: bool) -> list[Packet | CorruptPacket]:
        out: list[Packet | CorruptPacket] = []
        scan = self._scan2 if self.protocol == 2 else self._scan1
        while True:
            done = scan(out)
            if done:
                if final and self._buffer:
                    self._skip(1)  # the partial packet will not complete: look past its header
                    continue
                return out

    def _skip(self, count: int) -> None:
        del self._buffer[:count]
        self.stats.skipped_bytes += count

    def _keep_header_prefix(self, header: bytes) -> None:
        """No header in the buffer: drop it all except a trailing partial header."""
        buf = self._buffer
        keep = 0
        for size in range(min(len(header) - 1, len(buf)), 0, -1):
            if buf.endswith(header[:size]):
                keep = size
                break
        self._skip(len(buf) - keep)

    def _scan2(self, out: list[Packet | CorruptPacket]) -> bool:
        """One step of the Protocol 2.0 scan; True when it needs more bytes."""
        buf = self._buffer
        index = buf.find(_PATTERN)
        if index < 0:
            self._keep_header_prefix(_PATTERN)
            return True
        if index:
            self._skip(index)
        if len(buf) < 7:
            return True
        id_ = buf[4]
        length = buf[5] | (buf[6] << 8)
        if buf[3] != 0x00 or id_ in (0xFD, 0xFF) or not 3 <= length <= self.max_length:
            self._skip(1)  # a stuffed FF FF FD FD, noise, or a header with a bad field
            return False
        total = 7 + length
        if len(buf) < total:
            return True
        frame = bytes(buf[:total])
        crc = frame[-2] | (frame[-1] << 8)
        fits = crc16(frame[:-2])
        if fits != crc:
            self._corrupt(out, id_, frame, f"CRC {crc:04X} where {fits:04X} fits")
            return False
        try:
            body = unstuff(frame[7:-2])
        except FramingError as exc:
            self._corrupt(out, id_, frame, str(exc))
            return False
        if body[0] == STATUS_INSTRUCTION:
            if len(body) < 2:
                self._corrupt(out, id_, frame, "status packet without an ERR byte")
                return False
            packet: Packet = StatusPacket(id_, body[1], body[2:], 2)
        else:
            packet = InstructionPacket(id_, body[0], body[1:], 2)
        self._take(out, packet, total)
        return False

    def _scan1(self, out: list[Packet | CorruptPacket]) -> bool:
        """One step of the Protocol 1.0 scan; True when it needs more bytes."""
        buf = self._buffer
        index = buf.find(HEADER_1)
        if index < 0:
            self._keep_header_prefix(HEADER_1)
            return True
        if index:
            self._skip(index)
        if len(buf) < 4:
            return True
        id_ = buf[2]
        length = buf[3]
        if id_ == 0xFF or length < 2:
            self._skip(1)  # FF FF FF: the header starts one byte later
            return False
        total = 4 + length
        if len(buf) < total:
            return True
        frame = bytes(buf[:total])
        fits = checksum(frame[2:-1])
        if fits != frame[-1]:
            self._corrupt(out, id_, frame, f"checksum {frame[-1]:02X} where {fits:02X} fits")
            return False
        code, params = frame[4], frame[5:-1]
        packet: Packet = (
            StatusPacket(id_, code, params, 1)
            if self.expect == "status"
            else InstructionPacket(id_, code, params, 1)
        )
        self._take(out, packet, total)
        return False

    def _take(self, out: list[Packet | CorruptPacket], packet: Packet, size: int) -> None:
        """``packet`` was the first ``size`` bytes of the buffer."""
        del self._buffer[:size]
        self.stats.packets += 1
        out.append(packet)

    def _corrupt(
        self, out: list[Packet | CorruptPacket], id_: int, frame: bytes, reason: str
    ) -> None:
        self.stats.corrupt += 1
        out.append(CorruptPacket(self.protocol, id_, frame, reason))
        self._skip(1)


# --------------------------------------------------------------- parameter layouts (construct)

_ADDR: Final[Mapping[int, Any]] = {1: cs.Int8ul, 2: cs.Int16ul}

_READ: Final[Mapping[int, Any]] = {
    p: cs.Struct("address" / _ADDR[p], "length" / _ADDR[p]) for p in (1, 2)
}
_WRITE: Final[Mapping[int, Any]] = {
    p: cs.Struct("address" / _ADDR[p], "data" / cs.GreedyBytes) for p in (1, 2)
}
_SYNC_READ: Final[Mapping[int, Any]] = {
    p: cs.Struct("address" / _ADDR[p], "length" / _ADDR[p], "ids" / cs.GreedyRange(cs.Int8ul))
    for p in (1, 2)
}
_SYNC_WRITE: Final[Mapping[int, Any]] = {
    p: cs.Struct(
        "address" / _ADDR[p],
        "length" / _ADDR[p],
        "items" / cs.GreedyRange(cs.Struct("id" / cs.Int8ul, "data" / cs.Bytes(cs.this._.length))),
        cs.Terminated,
    )
    for p in (1, 2)
}
_BULK_READ_2: Final = cs.Struct(
    "items"
    / cs.GreedyRange(cs.Struct("id" / cs.Int8ul, "address" / cs.Int16ul, "length" / cs.Int16ul)),
    cs.Terminated,
)
_BULK_READ_1: Final = cs.Struct(
    cs.Const(b"\x00"),
    "items"
    / cs.GreedyRange(cs.Struct("length" / cs.Int8ul, "id" / cs.Int8ul, "address" / cs.Int8ul)),
    cs.Terminated,
)
_BULK_WRITE_2: Final = cs.Struct(
    "items"
    / cs.GreedyRange(
        cs.Struct(
            "id" / cs.Int8ul,
            "address" / cs.Int16ul,
            "length" / cs.Int16ul,
            "data" / cs.Bytes(cs.this.length),
        )
    ),
    cs.Terminated,
)
_PING_STATUS_2: Final = cs.Struct("model" / cs.Int16ul, "firmware" / cs.Int8ul, cs.Terminated)


def _build(layout: Any, value: Mapping[str, Any], what: str) -> bytes:
    try:
        return bytes(layout.build(value))
    except (cs.ConstructError, ValueError, TypeError) as exc:
        raise ValueError(f"cannot build {what} parameters: {exc}") from exc


def _parse(layout: Any, params: bytes, what: str) -> Any:
    try:
        return layout.parse(bytes(params))
    except cs.ConstructError as exc:
        raise FramingError(
            f"malformed {what} parameters ({len(params)} bytes: {bytes(params).hex(' ')}): "
            f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
        ) from exc


def _protocol(protocol: int) -> int:
    if protocol not in (1, 2):
        raise ValueError(f"protocol must be 1 or 2, not {protocol!r}")
    return protocol


def read_params(protocol: int, address: int, length: int) -> bytes:
    """READ: start address and length (one byte each in 1.0, two in 2.0)."""
    p = _protocol(protocol)
    return _build(_READ[p], {"address": address, "length": length}, "READ")


def parse_read(protocol: int, params: bytes) -> tuple[int, int]:
    """``(address, length)`` of READ parameters."""
    p = _protocol(protocol)
    if len(params) != 2 * p:
        raise FramingError(f"READ takes {2 * p} parameter bytes, not {len(params)}")
    parsed = _parse(_READ[p], params, "READ")
    return int(parsed.address), int(parsed.length)


def write_params(protocol: int, address: int, data: bytes) -> bytes:
    """WRITE / REG_WRITE: start address and the bytes to write there."""
    p = _protocol(protocol)
    return _build(_WRITE[p], {"address": address, "data": bytes(data)}, "WRITE")


def parse_write(protocol: int, params: bytes) -> tuple[int, bytes]:
    """``(address, data)`` of WRITE / REG_WRITE parameters."""
    p = _protocol(protocol)
    parsed = _parse(_WRITE[p], params, "WRITE")
    return int(parsed.address), bytes(parsed.data)


def sync_read_params(protocol: int, address: int, length: int, ids: Iterable[int]) -> bytes:
    """SYNC_READ: address, length, then the IDs that answer, in that order."""
    p = _protocol(protocol)
    value = {"address": address, "length": length, "ids": list(ids)}
    return _build(_SYNC_READ[p], value, "SYNC_READ")


def parse_sync_read(protocol: int, params: bytes) -> tuple[int, int, list[int]]:
    """``(address, length, ids)`` of SYNC_READ parameters."""
    p = _protocol(protocol)
    if len(params) < 2 * p:
        raise FramingError(f"SYNC_READ needs at least {2 * p} parameter bytes")
    parsed = _parse(_SYNC_READ[p], params, "SYNC_READ")
    return int(parsed.address), int(parsed.length), [int(i) for i in parsed.ids]


def sync_write_params(
    protocol: int,
    address: int,
    length: int,
    data: Mapping[int, bytes] | Iterable[tuple[int, bytes]],
) -> bytes:
    """SYNC_WRITE: address, length, then ``length`` bytes for each ID."""
    p = _protocol(protocol)
    pairs = list(data.items()) if isinstance(data, Mapping) else list(data)
    for id_, chunk in pairs:
        if len(chunk) != length:
            raise ValueError(f"SYNC_WRITE data for ID {id_} is {len(chunk)} bytes, not {length}")
    value = {
        "address": address,
        "length": length,
        "items": [{"id": i, "data": bytes(d)} for i, d in pairs],
    }
    return _build(_SYNC_WRITE[p], value, "SYNC_WRITE")


def parse_sync_write(protocol: int, params: bytes) -> tuple[int, int, list[tuple[int, bytes]]]:
    """``(address, length, [(id, data), ...])`` of SYNC_WRITE parameters."""
    p = _protocol(protocol)
    if len(params) < 2 * p:
        raise FramingError(f"SYNC_WRITE needs at least {2 * p} parameter bytes")
    length = params[p] if p == 1 else params[2] | (params[3] << 8)
    if length == 0 or (len(params) - 2 * p) % (length + 1):
        raise FramingError(
            f"SYNC_WRITE parameters: {len(params) - 2 * p} bytes after the header do not split "
            f"into (ID + {length} bytes) items"
        )
    parsed = _parse(_SYNC_WRITE[p], params, "SYNC_WRITE")
    items = [(int(item.id), bytes(item.data)) for item in parsed["items"]]
    return int(parsed.address), int(parsed.length), items


def bulk_read_params(protocol: int, items: Iterable[tuple[int, int, int]]) -> bytes:
    """BULK_READ: ``(id, address, length)`` per servo (Protocol 1.0: MX series only)."""
    p = _protocol(protocol)
    entries = [{"id": i, "address": a, "length": n} for i, a, n in items]
    return _build(_BULK_READ_2 if p == 2 else _BULK_READ_1, {"items": entries}, "BULK_READ")


def parse_bulk_read(protocol: int, params: bytes) -> list[tuple[int, int, int]]:
    """``[(id, address, length), ...]`` of BULK_READ parameters."""
    p = _protocol(protocol)
    parsed = _parse(_BULK_READ_2 if p == 2 else _BULK_READ_1, params, "BULK_READ")
    return [(int(e.id), int(e.address), int(e.length)) for e in parsed["items"]]


def bulk_write_params(items: Iterable[tuple[int, int, bytes]]) -> bytes:
    """BULK_WRITE (Protocol 2.0 only): ``(id, address, data)`` per servo."""
    entries = [{"id": i, "address": a, "length": len(d), "data": bytes(d)} for i, a, d in items]
    return _build(_BULK_WRITE_2, {"items": entries}, "BULK_WRITE")


def parse_bulk_write(params: bytes) -> list[tuple[int, int, bytes]]:
    """``[(id, address, data), ...]`` of BULK_WRITE parameters."""
    parsed = _parse(_BULK_WRITE_2, params, "BULK_WRITE")
    return [(int(e.id), int(e.address), bytes(e.data)) for e in parsed["items"]]


def ping_status_params(model: int, firmware: int) -> bytes:
    """Protocol 2.0 PING reply parameters: model number and firmware version."""
    return _build(_PING_STATUS_2, {"model": model, "firmware": firmware}, "PING status")


def parse_ping_status(params: bytes) -> tuple[int, int]:
    """``(model_number, firmware)`` of a Protocol 2.0 PING reply."""
    parsed = _parse(_PING_STATUS_2, params, "PING status")
    return int(parsed.model), int(parsed.firmware)


# ------------------------------------------------------------------------------- builders


def ping_packet(protocol: int, id_: int) -> InstructionPacket:
    return InstructionPacket(id_, Instruction.PING, b"", protocol)


def read_packet(protocol: int, id_: int, address: int, length: int) -> InstructionPacket:
    return InstructionPacket(
        id_, Instruction.READ, read_params(protocol, address, length), protocol
    )


def write_packet(
    protocol: int, id_: int, address: int, data: bytes, *, registered: bool = False
) -> InstructionPacket:
    """WRITE, or REG_WRITE with ``registered=True`` (executed by a later ACTION)."""
    code = Instruction.REG_WRITE if registered else Instruction.WRITE
    return InstructionPacket(id_, code, write_params(protocol, address, data), protocol)


def action_packet(protocol: int, id_: int = BROADCAST_ID) -> InstructionPacket:
    return InstructionPacket(id_, Instruction.ACTION, b"", protocol)


def reboot_packet(protocol: int, id_: int) -> InstructionPacket:
    return InstructionPacket(id_, Instruction.REBOOT, b"", protocol)


def factory_reset_packet(protocol: int, id_: int, option: int = 0xFF) -> InstructionPacket:
    """Protocol 2.0 ``option``: 0xFF all, 0x01 all but ID, 0x02 all but ID and baud rate.
    Protocol 1.0 RESET has no option (everything is reset)."""
    params = bytes((option,)) if protocol == 2 else b""
    return InstructionPacket(id_, Instruction.FACTORY_RESET, params, protocol)


def clear_packet(id_: int, params: bytes = CLEAR_MULTI_TURN) -> InstructionPacket:
    """Protocol 2.0 CLEAR (default: reset the multi-turn count)."""
    return InstructionPacket(id_, Instruction.CLEAR, bytes(params), 2)


def sync_read_packet(
    protocol: int, address: int, length: int, ids: Sequence[int]
) -> InstructionPacket:
    params = sync_read_params(protocol, address, length, ids)
    return InstructionPacket(BROADCAST_ID, Instruction.SYNC_READ, params, protocol)


def sync_write_packet(
    protocol: int,
    address: int,
    length: int,
    data: Mapping[int, bytes] | Iterable[tuple[int, bytes]],
) -> InstructionPacket:
    params = sync_write_params(protocol, address, length, data)
    return InstructionPacket(BROADCAST_ID, Instruction.SYNC_WRITE, params, protocol)


def bulk_read_packet(protocol: int, items: Iterable[tuple[int, int, int]]) -> InstructionPacket:
    params = bulk_read_params(protocol, items)
    return InstructionPacket(BROADCAST_ID, Instruction.BULK_READ, params, protocol)


def bulk_write_packet(items: Iterable[tuple[int, int, bytes]]) -> InstructionPacket:
    return InstructionPacket(BROADCAST_ID, Instruction.BULK_WRITE, bulk_write_params(items), 2)
