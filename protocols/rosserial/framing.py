"""Framing of rosserial protocol v2 ("hydro and later"): encoder and stream parser (sans-I/O).

A frame is ``FF FE | len (uint16 LE) | len checksum | topic id (uint16 LE) | payload | checksum``:
the length checksum makes ``len_lo + len_hi + chk`` sum to 255 modulo 256, the last checksum does
the same for the topic id and payload bytes. There is no escaping, so a ``FF FE`` inside a
payload looks like a frame start; the parser copes by rescanning.

:class:`FrameParser` turns any byte stream into events and never raises:

- :class:`RosFrame` for each frame whose two checksums are right;
- :class:`BadFrame` when a ``FF FE`` header fails its length checksum, announces a payload above
  ``max_payload``, or the frame fails its final checksum;
- :class:`NonFrameBytes` for everything outside frames (a board's debug prints, bootloader noise);
- :class:`OldProtocol` for ``FF FF`` followed by anything but ``FE``: the header of rosserial
  protocol version 1 (pre-hydro firmware), or line noise.

:class:`RosserialFraming` is the :class:`hwbridge.protocols.base.Framing` of a rosserial session:
a :class:`FrameParser` for what the link delivers and :func:`encode_frame` for what goes out.

Resynchronisation: a frame can only start at a ``0xFF``. When a candidate fails, the parser
reports the bytes from its sync byte up to the next ``0xFF`` inside the candidate (or the whole
candidate if there is none) and resumes scanning there. A corrupted or truncated frame therefore
never hides a valid frame that follows it, and every byte fed is reported exactly once: in a
frame, a bad frame, an old-protocol marker (its two ``FF`` bytes) or non-frame bytes. Memory is
bounded by ``max_payload`` + 8 bytes.

How a stream is split into chunks changes nothing but how non-frame bytes are split across
:class:`NonFrameBytes` events (they are reported as soon as they are known not to start a frame).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, fields
from enum import Enum
from typing import Final, TypeAlias

from hwbridge.protocols.errors import FramingError

__all__ = [
    "DEFAULT_MAX_PAYLOAD",
    "FRAME_OVERHEAD",
    "HEADER_SIZE",
    "MAX_PAYLOAD",
    "SYNC",
    "VERSION_V1",
    "VERSION_V2",
    "BadFrame",
    "BadFrameReason",
    "FrameParser",
    "NonFrameBytes",
    "OldProtocol",
    "ParserEvent",
    "ParserStats",
    "RosFrame",
    "RosserialFraming",
    "checksum",
    "decode_frame",
    "encode_frame",
]

SYNC: Final = 0xFF
"""First byte of every frame."""
VERSION_V2: Final = 0xFE
"""Second byte of a protocol v2 frame (rosserial 0.5 and later, ROS hydro onwards)."""
VERSION_V1: Final = 0xFF
"""Second byte of a protocol v1 frame (rosserial 0.4 and earlier): not supported."""
HEADER_SIZE: Final = 7
"""Bytes before the payload: sync, version, length (2), length checksum, topic id (2)."""
FRAME_OVERHEAD: Final = HEADER_SIZE + 1
"""Bytes a frame adds to its payload (header plus the final checksum)."""
MAX_PAYLOAD: Final = 0xFFFF
"""Largest payload the 16-bit length field can describe."""
DEFAULT_MAX_PAYLOAD: Final = 4096
"""Largest payload a :class:`FrameParser` accepts unless told otherwise."""

_HEADER: Final = struct.Struct("<BBHBH")
_SYNC_BYTE: Final = b"\xff"


def checksum(data: bytes | bytearray | memoryview) -> int:
    """The rosserial checksum of ``data``: ``255 - sum(data) % 256``."""
    return 255 - sum(data) % 256


@dataclass(frozen=True, slots=True)
class RosFrame:
    """One valid frame: a topic id and its payload (ROS 1 serialized bytes)."""

    topic_id: int
    payload: bytes

    def encode(self) -> bytes:
        """The frame's wire bytes (see :func:`encode_frame`)."""
        return encode_frame(self.topic_id, self.payload)


class BadFrameReason(str, Enum):
    """Why a candidate frame was rejected."""

    LENGTH_CHECKSUM = "length_checksum"
    """The header's length checksum is wrong."""
    OVERSIZE = "oversize"
    """The header is consistent but announces a payload above the parser's ``max_payload``."""
    CHECKSUM = "checksum"
    """The frame's final checksum (topic id and payload) is wrong."""


@dataclass(frozen=True, slots=True)
class BadFrame:
    """A rejected candidate: ``data`` runs from its sync byte up to the next ``0xFF`` in it."""

    reason: BadFrameReason
    data: bytes


@dataclass(frozen=True, slots=True)
class NonFrameBytes:
    """Bytes outside any frame, e.g. text a board printed on the same serial port."""

    data: bytes


@dataclass(frozen=True, slots=True)
class OldProtocol:
    """``FF FF`` then not ``FE``: a rosserial protocol v1 header (pre-hydro), or noise."""


ParserEvent: TypeAlias = RosFrame | BadFrame | NonFrameBytes | OldProtocol


@dataclass(slots=True)
class ParserStats:
    """Counters of a :class:`FrameParser`."""

    frames: int = 0
    """Valid frames returned."""
    bytes: int = 0
    """Bytes fed."""
    frame_bytes: int = 0
    """Bytes inside valid frames (headers and checksums included)."""
    length_checksum_errors: int = 0
    checksum_errors: int = 0
    oversize: int = 0
    bad_frame_bytes: int = 0
    """Bytes reported in :class:`BadFrame` events."""
    old_protocol: int = 0
    """``FF FF`` headers seen (protocol v1, or noise)."""
    non_frame_bytes: int = 0
    """Bytes reported as :class:`NonFrameBytes` (a count of bytes, not of events)."""

    def as_dict(self) -> dict[str, int]:
        """Counters by name, for logs and JSON."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def encode_frame(topic_id: int, payload: bytes | bytearray | memoryview = b"") -> bytes:
    """The wire bytes of one frame carrying ``payload`` on ``topic_id``.

    Raises:
        FramingError: ``topic_id`` is not 0..65535 or the payload is longer than 65535 bytes.
    """
    body = bytes(payload)
    if not 0 <= topic_id <= 0xFFFF:
        raise FramingError(f"rosserial topic id {topic_id} is out of range: it is a uint16")
    if len(body) > MAX_PAYLOAD:
        raise FramingError(
            f"rosserial frame payload of {len(body)} bytes is too long: the length field is a "
            f"uint16 (at most {MAX_PAYLOAD} bytes)"
        )
    size = len(body)
    length_check = 255 - ((size & 0xFF) + (size >> 8)) % 256
    header = _HEADER.pack(SYNC, VERSION_V2, size, length_check, topic_id)
    final = 255 - ((topic_id & 0xFF) + (topic_id >> 8) + sum(body)) % 256
    return header + body + bytes((final,))


def decode_frame(data: bytes | bytearray | memoryview) -> RosFrame:
    """Decode exactly one frame (no bytes before or after it).

    Raises:
        FramingError: ``data`` is not exactly one valid frame; the message says why.
    """
    raw = bytes(data)
    parser = FrameParser(max_payload=MAX_PAYLOAD)
    events = parser.feed(raw)
    if len(events) == 1 and isinstance(events[0], RosFrame) and parser.buffered == 0:
        return events[0]
    kinds = ", ".join(type(e).__name__ for e in events) or "nothing (incomplete)"
    raise FramingError(f"expected one rosserial frame, got {kinds}: {raw.hex(' ')}")


class FrameParser:
    """Stream parser for rosserial v2 frames; see the module docstring for its rules."""

    __slots__ = ("_buf", "_max_payload", "stats")

    def __init__(self, max_payload: int = DEFAULT_MAX_PAYLOAD) -> None:
        self._max_payload = _check_max(max_payload)
        self._buf = bytearray()
        self.stats = ParserStats()

    @property
    def max_payload(self) -> int:
        """Largest payload accepted; a header announcing more is refused and rescanned."""
        return self._max_payload

    @max_payload.setter
    def max_payload(self, value: int) -> None:
        self._max_payload = _check_max(value)

    @property
    def buffered(self) -> int:
        """Bytes held of an unfinished candidate frame (at most ``max_payload`` + 8)."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget any unfinished frame (e.g. after reopening the link). Counters are kept."""
        self._buf.clear()

    def feed(self, data: bytes | bytearray | memoryview) -> list[ParserEvent]:
        """Consume ``data``; return the events it completes, in stream order."""
        if not data:
            return []
        self.stats.bytes += len(data)
        buf = self._buf
        buf += data
        events: list[ParserEvent] = []
        start = 0
        while True:
            start = self._step(buf, start, events)
            if start < 0:
                break
        return events

    def _step(self, buf: bytearray, start: int, events: list[ParserEvent]) -> int:
        """Handle what begins at ``buf[start]``; return the next start, or -1 to wait for data.

        On -1, ``buf`` has been trimmed to the unfinished candidate (or emptied).
        """
        size = len(buf)
        sync = buf.find(_SYNC_BYTE, start)
        if sync < 0:
            self._non_frame(buf, start, size, events)
            buf.clear()
            return -1
        if sync > start:
            self._non_frame(buf, start, sync, events)
        if size - sync < 2:
            del buf[:sync]
            return -1
        version = buf[sync + 1]
        if version != VERSION_V2:
            if version != SYNC:  # a stray 0xFF
                self._non_frame(buf, sync, sync + 1, events)
                return sync + 1
            if size - sync < 3:  # FF FF: v1 header, unless a v2 frame starts at the second FF
                del buf[:sync]
                return -1
            if buf[sync + 2] == VERSION_V2:
                self._non_frame(buf, sync, sync + 1, events)
                return sync + 1
            events.append(OldProtocol())
            self.stats.old_protocol += 1
            return sync + 2
        if size - sync < HEADER_SIZE:
            del buf[:sync]
            return -1
        len_lo = buf[sync + 2]
        len_hi = buf[sync + 3]
        if (len_lo + len_hi + buf[sync + 4]) % 256 != 255:
            self.stats.length_checksum_errors += 1
            return self._reject(buf, sync, HEADER_SIZE, BadFrameReason.LENGTH_CHECKSUM, events)
        length = len_lo | len_hi << 8
        if length > self._max_payload:
            self.stats.oversize += 1
            return self._reject(buf, sync, HEADER_SIZE, BadFrameReason.OVERSIZE, events)
        end = sync + HEADER_SIZE + length + 1
        if size < end:
            del buf[:sync]
            return -1
        covered = memoryview(buf)[sync + 5 : end]
        try:
            valid = sum(covered) % 256 == 255
        finally:
            covered.release()
        if not valid:
            self.stats.checksum_errors += 1
            return self._reject(buf, sync, end - sync, BadFrameReason.CHECKSUM, events)
        events.append(RosFrame(buf[sync + 5] | buf[sync + 6] << 8, bytes(buf[sync + 7 : end - 1])))
        self.stats.frames += 1
        self.stats.frame_bytes += end - sync
        return end

    def _reject(
        self,
        buf: bytearray,
        sync: int,
        extent: int,
        reason: BadFrameReason,
        events: list[ParserEvent],
    ) -> int:
        """Report a failed candidate up to the next 0xFF inside it and resume scanning there."""
        resume = buf.find(_SYNC_BYTE, sync + 1, sync + extent)
        if resume < 0:
            resume = sync + extent
        events.append(BadFrame(reason, bytes(buf[sync:resume])))
        self.stats.bad_frame_bytes += resume - sync
        return resume

    def _non_frame(self, buf: bytearray, start: int, end: int, events: list[ParserEvent]) -> None:
        if end <= start:
            return
        if events and isinstance(events[-1], NonFrameBytes):
            events[-1] = NonFrameBytes(events[-1].data + bytes(buf[start:end]))
        else:
            events.append(NonFrameBytes(bytes(buf[start:end])))
        self.stats.non_frame_bytes += end - start


class RosserialFraming:
    """The framing of rosserial v2 on a stream link (rosserial has no datagram form).

    ``decode`` feeds a :class:`FrameParser` and returns its events (:class:`RosFrame` and the
    notes about what was not a frame); ``encode`` joins the frames into one chunk to write.
    """

    __slots__ = ("parser",)

    datagram = False

    def __init__(self, max_payload: int = DEFAULT_MAX_PAYLOAD) -> None:
        self.parser = FrameParser(max_payload)

    @property
    def max_payload(self) -> int:
        """Largest payload ``decode`` accepts (the host tunes it to the device's buffers)."""
        return self.parser.max_payload

    @max_payload.setter
    def max_payload(self, value: int) -> None:
        self.parser.max_payload = value

    @property
    def stats(self) -> ParserStats:
        """The receive parser's counters."""
        return self.parser.stats

    def decode(self, data: bytes | bytearray | memoryview, /) -> list[ParserEvent]:
        """Consume a chunk of the stream; return the frames and notes it completes."""
        return self.parser.feed(data)

    def encode(self, frames: Sequence[RosFrame], now: float = 0.0, /) -> list[bytes]:
        """The wire bytes of ``frames`` as one chunk (no chunk for no frames)."""
        if not frames:
            return []
        return [b"".join(encode_frame(f.topic_id, f.payload) for f in frames)]


def _check_max(value: int) -> int:
    if not 0 <= value <= MAX_PAYLOAD:
        raise ValueError(f"max_payload must be 0..{MAX_PAYLOAD}, not {value}")
    return value
