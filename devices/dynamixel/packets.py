"""Dynamixel Protocol 1.0 and 2.0 packets: encode, decode, find them in a byte stream.

Pure code, no I/O. This module is the codec in one place: the frame (header, length, CRC or
checksum, byte stuffing; :mod:`~hwbridge.devices.dynamixel.framing`) is plain Python with a table
CRC, as the stream parser (:mod:`~hwbridge.devices.dynamixel.parser`) runs on every received
byte; the parameter layouts of the instructions (READ, SYNC_WRITE, BULK_READ...) are declared
here with ``construct`` and reached through the typed functions below (``read_params``,
``parse_sync_write``...), never directly.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Final

import construct

from hwbridge.devices.dynamixel.framing import (
    ALERT_BIT,
    BROADCAST_ID,
    CLEAR_MULTI_TURN,
    HEADER_1,
    HEADER_2,
    MAX_ID,
    CorruptPacket,
    Error1,
    Error2,
    Instruction,
    InstructionPacket,
    Packet,
    StatusPacket,
    check_protocol,
    checksum,
    crc16,
    encode,
    error_names,
    instruction_name,
    stuff,
    unstuff,
)
from hwbridge.devices.dynamixel.parser import PacketParser, ParserStats, decode
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

# construct declares layouts with operators on its singletons (``"id" / Int8ul``), which type
# checkers cannot follow (mypy has no types for it; pyright takes the singletons for functions).
cs: Any = construct

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


def read_params(protocol: int, address: int, length: int) -> bytes:
    """READ: start address and length (one byte each in 1.0, two in 2.0)."""
    p = check_protocol(protocol)
    return _build(_READ[p], {"address": address, "length": length}, "READ")


def parse_read(protocol: int, params: bytes) -> tuple[int, int]:
    """``(address, length)`` of READ parameters."""
    p = check_protocol(protocol)
    if len(params) != 2 * p:
        raise FramingError(f"READ takes {2 * p} parameter bytes, not {len(params)}")
    parsed = _parse(_READ[p], params, "READ")
    return int(parsed.address), int(parsed.length)


def write_params(protocol: int, address: int, data: bytes) -> bytes:
    """WRITE / REG_WRITE: start address and the bytes to write there."""
    p = check_protocol(protocol)
    return _build(_WRITE[p], {"address": address, "data": bytes(data)}, "WRITE")


def parse_write(protocol: int, params: bytes) -> tuple[int, bytes]:
    """``(address, data)`` of WRITE / REG_WRITE parameters."""
    p = check_protocol(protocol)
    parsed = _parse(_WRITE[p], params, "WRITE")
    return int(parsed.address), bytes(parsed.data)


def sync_read_params(protocol: int, address: int, length: int, ids: Iterable[int]) -> bytes:
    """SYNC_READ: address, length, then the IDs that answer, in that order."""
    p = check_protocol(protocol)
    value = {"address": address, "length": length, "ids": list(ids)}
    return _build(_SYNC_READ[p], value, "SYNC_READ")


def parse_sync_read(protocol: int, params: bytes) -> tuple[int, int, list[int]]:
    """``(address, length, ids)`` of SYNC_READ parameters."""
    p = check_protocol(protocol)
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
    p = check_protocol(protocol)
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
    p = check_protocol(protocol)
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
    p = check_protocol(protocol)
    entries = [{"id": i, "address": a, "length": n} for i, a, n in items]
    return _build(_BULK_READ_2 if p == 2 else _BULK_READ_1, {"items": entries}, "BULK_READ")


def parse_bulk_read(protocol: int, params: bytes) -> list[tuple[int, int, int]]:
    """``[(id, address, length), ...]`` of BULK_READ parameters."""
    p = check_protocol(protocol)
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
