"""Frames of the native protocol: the types, the header, the CRC and the encoder (sans-I/O).

A frame travels as ``COBS(header + payload + crc16) 0x00`` on a stream link, or as
``header + payload + crc16`` alone in one datagram; PROTOCOL.md, Part 1, is the specification.
This module holds what both framings share: :class:`Frame` and the other frame events, the
header table, the check of one decoded body (:func:`_parse_body`) and the sizes. The encoders
are in :mod:`.encoder`, the stream decoder in :mod:`.decoder`, fragmentation in
:mod:`.fragment`, the two framings in :mod:`.links`; the public names are re-exported by
:mod:`hwbridge.protocols.native.framing`.
"""

from __future__ import annotations

from binascii import crc_hqx
from dataclasses import dataclass, fields
from enum import Enum, IntEnum
from typing import Final, TypeAlias

from hwbridge.protocols.errors import FramingError
from hwbridge.protocols.native import cobs
from hwbridge.protocols.native.cobs import decode_or_none as _cobs_decode_run

VERSION: Final = 1
"""Protocol version carried in bits 7-6 of header byte 0."""
DELIMITER: Final = 0x00
"""Byte that ends every frame (and that COBS removes from the body)."""
HEADER_SIZE: Final = 3
CRC_SIZE: Final = 2
CRC_INIT: Final = 0xFFFF
"""CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final xor."""
LENGTH_PREFIX_SIZE: Final = 4
"""Bytes of the uint32 total message length at the start of a FIRST fragment's payload."""
MIN_FRAGMENT_PAYLOAD: Final = LENGTH_PREFIX_SIZE + 1
"""Smallest per-frame payload limit :func:`fragment` accepts (one data byte per FIRST)."""
DEFAULT_MAX_PAYLOAD: Final = 1024
"""Largest payload a :class:`FrameDecoder` accepts unless told otherwise."""

_ENVELOPE: Final = HEADER_SIZE + CRC_SIZE
_ZERO: Final = b"\x00"
ACK_FLAG: Final = 0x01
"""Header byte 0, bit 0, on a BEST_EFFORT or RELIABLE frame: the body's byte before the CRC is
a cumulative ACK (PROTOCOL.md 1.4). On an ACK frame the bit stays reserved (ignored)."""


class FrameType(IntEnum):
    """Header bits 5-4: what a frame carries. The value 3 is reserved (a bad frame)."""

    BEST_EFFORT = 0
    RELIABLE = 1
    ACK = 2


class Frag(IntEnum):
    """Header bits 3-2: where a frame's payload sits in its message."""

    WHOLE = 0
    FIRST = 1
    MIDDLE = 2
    LAST = 3


class BadFrameReason(str, Enum):
    """Why a run of bytes between delimiters was rejected."""

    CRC = "crc"
    """COBS decoded, but the CRC-16 does not match."""
    COBS = "cobs"
    """A COBS code byte points past the end of the run."""
    TOO_SHORT = "too_short"
    """The decoded body is shorter than header + CRC (5 bytes)."""
    VERSION = "version"
    """A valid frame of another protocol version (bits 7-6 of byte 0 are not 1)."""
    RESERVED_TYPE = "reserved_type"
    """A valid version-1 frame whose type is the reserved value 3."""
    OVERSIZE = "oversize"
    """A run too long to be a frame, or a payload above ``max_payload``."""


@dataclass(frozen=True, slots=True)
class Frame:
    """One frame. Fields are checked when it is encoded, not when it is built."""

    type: FrameType
    channel: int
    """0..255; channel 0 is the session's control channel."""
    seq: int
    """0..255; for ACK frames, the acknowledged RELIABLE sequence number."""
    payload: bytes
    frag: Frag = Frag.WHOLE
    ack: int | None = None
    """A BEST_EFFORT or RELIABLE frame only: the cumulative ACK of the other direction's
    reliable stream it carries (PROTOCOL.md 1.4, flag bit 0 and one byte before the CRC), or
    None. Never part of ``payload``; sent only when both ends have the ACK_IN_DATA feature."""


@dataclass(frozen=True, slots=True)
class NonFrameBytes:
    """Bytes on the line that are not a frame but look like text (e.g. a board's debug print)."""

    data: bytes


@dataclass(frozen=True, slots=True)
class BadFrame:
    """A rejected run of bytes, as received (COBS-encoded, without the delimiter).

    For :attr:`BadFrameReason.OVERSIZE`, ``data`` holds at most ``FrameDecoder.max_buffer`` bytes.
    For :attr:`BadFrameReason.VERSION`, ``cobs_decode(data)[0] >> 6`` is the peer's version.
    """

    reason: BadFrameReason
    data: bytes


FrameEvent: TypeAlias = Frame | NonFrameBytes | BadFrame


@dataclass(slots=True)
class FramingStats:
    """Counters of a :class:`FrameDecoder`; every rejected byte run is counted once."""

    frames: int = 0
    """Valid frames returned."""
    bytes: int = 0
    """Bytes fed, delimiters and garbage included."""
    crc_errors: int = 0
    cobs_errors: int = 0
    too_short: int = 0
    version_errors: int = 0
    reserved_type: int = 0
    oversize: int = 0
    non_frame_bytes: int = 0
    """Bytes reported as :class:`NonFrameBytes` (a count of bytes, not of events)."""

    def as_dict(self) -> dict[str, int]:
        """Counters by name, for logs and JSON."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (``crc16(b"123456789") == 0x29B1``)."""
    return crc_hqx(data, CRC_INIT)


def wire_size(payload_size: int) -> int:
    """Most wire bytes of a frame with ``payload_size`` payload bytes (exact if no 0x00 in body)."""
    body = payload_size + _ENVELOPE
    return body + max(1, -(-body // cobs.MAX_GROUP)) + 1


def frame_overhead(payload_size: int) -> int:
    """Wire bytes added to a payload of ``payload_size``: 7 up to 249 bytes, 8 up to 503."""
    return wire_size(payload_size) - payload_size


def max_run_size(max_payload: int) -> int:
    """Longest run between delimiters a decoder with this payload limit must accept."""
    return cobs.max_encoded_size(max_payload + _ENVELOPE)


def _header_table() -> tuple[tuple[FrameType, Frag, bool] | None, ...]:
    table: list[tuple[FrameType, Frag, bool] | None] = []
    for byte0 in range(256):
        type_bits = (byte0 >> 4) & 3
        if byte0 >> 6 != VERSION or type_bits == 3:
            table.append(None)
        else:
            acked = bool(byte0 & ACK_FLAG) and type_bits != FrameType.ACK
            table.append((FrameType(type_bits), Frag((byte0 >> 2) & 3), acked))
    return tuple(table)


_HEADER: Final = _header_table()
"""Header byte 0 -> (type, frag, carries an ACK byte), or None for another version or the
reserved type."""


def body_frame(kind: tuple[FrameType, Frag, bool], body: bytes | bytearray, o: int = 0) -> Frame:
    """The frame of a checked body ``body[o:]`` whose byte 0 maps to ``kind`` in ``_HEADER``;
    a body with the ACK flag but no byte for it must have been refused (``_ACKED_ENVELOPE``)."""
    if kind[2]:
        return Frame(kind[0], body[o + 1], body[o + 2], bytes(body[o + 3 : -3]), kind[1], body[-3])
    return Frame(kind[0], body[o + 1], body[o + 2], bytes(body[o + 3 : -2]), kind[1])


_ACKED_ENVELOPE: Final = _ENVELOPE + 1
"""The smallest body of a frame with the ACK flag: header, the ACK byte, CRC."""


def _parse_body(body: bytes, max_payload: int) -> Frame | BadFrameReason:
    """Check one decoded body (header, payload, CRC) and build its frame, or say why not."""
    if len(body) < _ENVELOPE:
        return BadFrameReason.TOO_SHORT
    if crc_hqx(body[:-2], CRC_INIT) != body[-2] | body[-1] << 8:
        return BadFrameReason.CRC
    kind = _HEADER[body[0]]
    if kind is None:
        if body[0] >> 6 != VERSION:
            return BadFrameReason.VERSION
        return BadFrameReason.RESERVED_TYPE
    if len(body) - _ENVELOPE > max_payload:
        return BadFrameReason.OVERSIZE
    if kind[2] and len(body) < _ACKED_ENVELOPE:
        return BadFrameReason.TOO_SHORT  # the ACK flag, and no byte for the ACK
    return body_frame(kind, body)


def _parse_run(run: bytes, max_payload: int) -> Frame | BadFrameReason:
    """Decode one run between delimiters into a frame, or say why it is not one."""
    body = _cobs_decode_run(run)
    if body is None:
        return BadFrameReason.COBS
    return _parse_body(body, max_payload)


def decode_frame(data: bytes | bytearray | memoryview, max_payload: int = 1 << 32) -> Frame:
    """Decode exactly one frame (with or without its trailing 0x00, no leading 0x00).

    Raises:
        FramingError: ``data`` is not exactly one valid frame; the message names the reason.
    """
    run = bytes(data)
    if run.endswith(_ZERO):
        run = run[:-1]
    if not run:
        raise FramingError("no frame to decode: the data is empty or only a delimiter")
    zero_at = run.find(_ZERO)
    if zero_at >= 0:
        raise FramingError(
            f"expected one frame, but a 0x00 at offset {zero_at} splits the data: "
            "use FrameDecoder for a stream"
        )
    result = _parse_run(run, max_payload)
    if isinstance(result, BadFrameReason):
        raise FramingError(f"not a valid frame ({result.value}): {run.hex(' ')}")
    return result


def decode_datagram(data: bytes | bytearray | memoryview, max_payload: int = 1 << 32) -> Frame:
    """Decode one datagram that holds exactly one frame (no COBS).

    Raises:
        FramingError: ``data`` is not a valid frame; the message names the reason.
    """
    result = _parse_body(bytes(data), max_payload)
    if isinstance(result, BadFrameReason):
        raise FramingError(f"not a valid frame ({result.value}): {bytes(data).hex(' ')}")
    return result
