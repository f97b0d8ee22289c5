"""Dynamixel Protocol 1.0 and 2.0 frames: packet types, CRC-16, checksum, byte stuffing, encoding.

Pure code, no I/O; :mod:`~hwbridge.devices.dynamixel.parser` finds these packets in a byte
stream and :mod:`~hwbridge.devices.dynamixel.packets` gathers the whole codec.

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
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

from hwbridge.errors import FramingError

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


STUFF_PATTERN: Final = b"\xff\xff\xfd"
"""Protocol 2.0 bytes that get an extra FD when they occur in a packet body."""


def stuff(data: bytes | bytearray | memoryview) -> bytes:
    """Protocol 2.0 byte stuffing: an ``FD`` after every ``FF FF FD``."""
    raw = bytes(data)
    if STUFF_PATTERN not in raw:
        return raw
    return raw.replace(STUFF_PATTERN, STUFF_PATTERN + b"\xfd")


def unstuff(data: bytes | bytearray | memoryview) -> bytes:
    """Undo :func:`stuff`; FramingError when an ``FF FF FD`` is not followed by ``FD``."""
    raw = bytes(data)
    if STUFF_PATTERN not in raw:
        return raw
    out = bytearray()
    start = 0
    while True:
        index = raw.find(STUFF_PATTERN, start)
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
    top = MAX_ID[check_protocol(protocol)]
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


def check_protocol(protocol: int) -> int:
    """``protocol`` if it is 1 or 2, else ValueError."""
    if protocol not in (1, 2):
        raise ValueError(f"protocol must be 1 or 2, not {protocol!r}")
    return protocol
