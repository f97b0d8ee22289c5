"""Framing of the native protocol: frames, a stream decoder, fragmentation (sans-I/O).

A frame travels as ``COBS(header + payload + crc16) 0x00``; PROTOCOL.md, Part 1, is the
specification and this module its reference implementation. Nothing here does I/O: feed bytes
to :class:`FrameDecoder` and get events back, turn :class:`Frame` objects into bytes with
:func:`encode_frame`, split and join messages with :func:`fragment` and :class:`Reassembler`.

The decoder is the hot path: it splits each chunk on 0x00 in C (``bytes.split``), decodes COBS
with one Python step per group, checks the CRC with ``binascii.crc_hqx`` and reads the header
through a 256-entry table. Anything that is not a valid frame takes a separate, slower path that
classifies it (bad frame, or text printed by the board) and never raises.
"""

from __future__ import annotations

import functools
import re
import struct
from binascii import crc_hqx
from collections.abc import Callable
from dataclasses import dataclass, fields
from enum import Enum, IntEnum
from typing import Any, Final, TypeAlias, TypeVar

from hwbridge.protocols.errors import FramingError
from hwbridge.protocols.native import cobs
from hwbridge.protocols.native.cobs import decode as cobs_decode
from hwbridge.protocols.native.cobs import decode_or_none as _cobs_decode_run
from hwbridge.protocols.native.cobs import encode as cobs_encode
from hwbridge.protocols.native.cobs import encode_short as cobs_encode_short

__all__ = [
    "CRC_INIT",
    "CRC_SIZE",
    "DEFAULT_MAX_PAYLOAD",
    "DELIMITER",
    "HEADER_SIZE",
    "LENGTH_PREFIX_SIZE",
    "MIN_FRAGMENT_PAYLOAD",
    "VERSION",
    "BadFrame",
    "BadFrameReason",
    "Frag",
    "Frame",
    "FrameDecoder",
    "FrameEvent",
    "FrameType",
    "FramingStats",
    "NonFrameBytes",
    "Reassembler",
    "ReassemblyStats",
    "cobs_decode",
    "cobs_encode",
    "crc16",
    "decode_frame",
    "encode_frame",
    "fragment",
    "frame_overhead",
    "make_frame",
    "max_run_size",
    "slot_setter",
    "wire_size",
]

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
_VERSION_BITS: Final = VERSION << 6
_MAX_GROUP: Final = cobs.MAX_GROUP
_ZERO: Final = b"\x00"
_HEAD: Final = struct.Struct("BBB")
"""The header: version, type and frag in one byte, then the channel and the seq."""
_CRC: Final = struct.Struct("<H")
"""The CRC-16 as it ends a frame body (little-endian)."""


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

# Enum members for the per-frame paths: one looked up on its class costs ~0.1 us on Python 3.11.
_ACK: Final = FrameType.ACK
_WHOLE: Final = Frag.WHOLE

_T = TypeVar("_T")


def slot_setter(cls: type[_T], name: str) -> Callable[[_T, Any], None]:
    """The setter of the slot ``name`` of a slotted dataclass ``cls``, frozen or not.

    Hot paths build frozen dataclasses with ``object.__new__(cls)`` and one such setter per
    field (as :func:`make_frame` does): the generated ``__init__`` goes through
    ``object.__setattr__`` once per field, which costs about twice as much. The decoder builds
    frames that way too: ``Frame(...)`` would cost about a third of the decode time.
    """
    setter: Callable[[_T, Any], None] = vars(cls)[name].__set__
    return setter


_new_object: Final[Callable[[type[Frame]], Frame]] = object.__new__
_set_type: Final = slot_setter(Frame, "type")
_set_channel: Final = slot_setter(Frame, "channel")
_set_seq: Final = slot_setter(Frame, "seq")
_set_payload: Final = slot_setter(Frame, "payload")
_set_frag: Final = slot_setter(Frame, "frag")


def make_frame(
    type: FrameType, channel: int, seq: int, payload: bytes, frag: Frag = Frag.WHOLE
) -> Frame:
    """``Frame(type, channel, seq, payload, frag)`` built the fast way (the senders' hot path).

    The arguments are taken as they are (``payload`` must be ``bytes``); like ``Frame(...)``,
    nothing is range-checked until the frame is encoded.
    """
    frame = _new_object(Frame)
    _set_type(frame, type)
    _set_channel(frame, channel)
    _set_seq(frame, seq)
    _set_payload(frame, payload)
    _set_frag(frame, frag)
    return frame


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


def encode_frame(frame: Frame, *, lead: bool = False) -> bytes:
    """Encode ``frame`` for the wire: ``COBS(body) 0x00``, optionally preceded by ``0x00``.

    ``lead=True`` adds a delimiter before the frame, which flushes whatever the receiver holds
    (half a frame, text printed by a board) so that this frame is not glued to it. Send it on the
    first frame after opening a link or after the line has been idle; receivers ignore the empty
    run it creates.

    Raises:
        FramingError: the type, frag, channel or seq is out of range.
    """
    ftype = frame.type
    frag = frame.frag
    if not (0 <= ftype <= 2 and 0 <= frag <= 3):
        raise FramingError(
            f"cannot encode frame type {ftype!r} frag {frag!r}: type must be 0..2, frag 0..3"
        )
    byte0 = _VERSION_BITS | ftype << 4 | frag << 2
    try:
        body = _HEAD.pack(byte0, frame.channel, frame.seq)
    except struct.error:  # channel or seq is not a byte
        body = _checked_header(byte0, frame.channel, frame.seq)
    payload = frame.payload
    if ftype is _ACK and payload == b"":
        return _encode_bare_ack(body, lead)
    return _encode_body(body + payload, lead)


def _encode_body(body: bytes, lead: bool) -> bytes:
    """The wire bytes of a frame whose header and payload are ``body`` (led by 0x00 if ``lead``)."""
    body += _CRC.pack(crc_hqx(body, CRC_INIT))
    # cobs.encode would take the same branch, but its extra call and bytes() cost ~15% of
    # framing_encode at 16 bytes (measured): the frame encoder goes to the short path itself.
    wire = (cobs_encode_short(body) if len(body) < _MAX_GROUP else cobs_encode(body)) + _ZERO
    return _ZERO + wire if lead else wire


@functools.lru_cache(maxsize=1024)
def _encode_bare_ack(header: bytes, lead: bool) -> bytes:
    """:func:`_encode_body` of an ACK without a bitmap, computed once per header and lead.

    An in-order receiver acknowledges every reliable frame with one: the most frequent frame,
    of which a session sends at most 512 different encodings (seq and lead).
    """
    return _encode_body(header, lead)


def _checked_header(byte0: int, channel: int, seq: int) -> bytes:
    """The header built by ``bytes()``, for its errors when ``struct`` refused a field.

    A number out of 0..255 is a FramingError; anything else raises bytes()'s TypeError.
    """
    try:
        return bytes((byte0, channel, seq))
    except ValueError:
        raise FramingError(
            f"cannot encode frame with channel {channel} seq {seq}: both are 0..255"
        ) from None


def _header_table() -> tuple[tuple[FrameType, Frag] | None, ...]:
    table: list[tuple[FrameType, Frag] | None] = []
    for byte0 in range(256):
        type_bits = (byte0 >> 4) & 3
        if byte0 >> 6 != VERSION or type_bits == 3:
            table.append(None)
        else:
            table.append((FrameType(type_bits), Frag((byte0 >> 2) & 3)))
    return tuple(table)


_HEADER: Final = _header_table()
"""Header byte 0 -> (type, frag), or None for another version or the reserved type."""

_BARE_RUN: Final = _ENVELOPE + 1
"""Length of every run that encodes a frame without payload (and of no other valid frame)."""
_DECODED_ACKS: Final[dict[bytes, Frame]] = {}
"""ACK frames without a bitmap by their run, decoded once: an in-order receiver sends one per
reliable frame, the most frequent frame. Frames are immutable, and one without payload passes
every limit of any decoder, so all decoders share them."""
_DECODED_ACKS_LIMIT: Final = 1024


def _parse_run(run: bytes, max_payload: int) -> Frame | BadFrameReason:
    """Decode one run between delimiters into a frame, or say why it is not one."""
    body = _cobs_decode_run(run)
    if body is None:
        return BadFrameReason.COBS
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
    return Frame(kind[0], body[1], body[2], body[3:-2], kind[1])


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


_CHECKED_BEFORE_CRC: Final = frozenset(
    {BadFrameReason.COBS, BadFrameReason.TOO_SHORT, BadFrameReason.CRC}
)
"""Failures that say 'not a frame' (so the run may be text), unlike those of a CRC-valid run."""

_PRINTABLE: Final = bytes(range(0x20, 0x7F)) + b"\t\n\r"
_TEXT_PREFIX: Final = re.compile(rb"[\x20-\x7e\t\n\r]*")
_TEXT_SPLIT_TRIES: Final = 8
"""Most newlines tried when looking for a frame glued after a line of text."""


def _is_text(data: bytes) -> bool:
    """At least 90 % printable ASCII (0x20-0x7E, TAB, LF, CR)."""
    non_printable = len(data.translate(None, _PRINTABLE))
    return non_printable * 10 <= len(data)


def _split_glued_frames(run: bytes, max_payload: int) -> tuple[Frame, Frame] | None:
    """Two valid frames glued by a corrupted delimiter (``A X B``), or None.

    Walks the COBS groups of ``run``; wherever a group ends before the end of the run, the bytes
    decoded so far could be frame A and the next byte its damaged delimiter. A split counts only
    if both A and the rest (B) pass every check, so a damaged frame is not mistaken for a shorter
    one (two CRCs must match by chance, not one).
    """
    size = len(run)
    decoded = bytearray()
    crc = CRC_INIT  # CRC of decoded[:covered], extended as the prefix grows
    covered = 0
    pos = 0
    while pos < size:
        code = run[pos]
        end = pos + code
        if end >= size:
            return None
        decoded += run[pos + 1 : end]
        kind = _HEADER[decoded[0]] if decoded else None
        if kind is None:
            return None  # byte 0 is not a version-1 header: no prefix can be a frame
        length = len(decoded)
        if length >= _ENVELOPE:
            crc = crc_hqx(decoded[covered : length - 2], crc)
            covered = length - 2
            if crc == decoded[-2] | decoded[-1] << 8 and length - _ENVELOPE <= max_payload:
                rest = run[end + 1 :]
                second = _parse_run(rest, max_payload) if rest else None
                if isinstance(second, Frame):
                    payload = bytes(decoded[3:-2])
                    return Frame(kind[0], decoded[1], decoded[2], payload, kind[1]), second
        if code != 0xFF:
            decoded.append(0)
        pos = end
    return None


class FrameDecoder:
    """Turns a byte stream into :data:`FrameEvent` objects; never raises on any input.

    Every 0x00 ends a run; each non-empty run is a frame, a bad frame or text
    (:class:`NonFrameBytes`), or is split into what it holds when it is damaged: two frames glued
    by a corrupted delimiter, or a line of text glued before a frame. Memory is bounded: at most
    :attr:`max_buffer` bytes of an unfinished run are held; beyond that the run's head is
    reported (text up to its last LF, or one ``BadFrame(OVERSIZE)`` after which the rest of the
    run is dropped). Splitting a stream into chunks differently never changes the events.
    See PROTOCOL.md, Part 1, section 1.6.
    """

    __slots__ = ("_discard", "_max_buffer", "_max_frame", "_max_payload", "_pending", "stats")

    def __init__(self, max_payload: int = DEFAULT_MAX_PAYLOAD) -> None:
        self._set_limits(max_payload)
        self._pending = b""
        self._discard = False
        self.stats = FramingStats()

    def _set_limits(self, max_payload: int) -> None:
        if max_payload < 0:
            raise ValueError(f"max_payload must be >= 0, not {max_payload}")
        self._max_payload = max_payload
        self._max_frame = max_run_size(max_payload)
        self._max_buffer = 2 * self._max_frame + 1

    @property
    def max_payload(self) -> int:
        """Largest payload accepted in one frame (the local per-frame MTU)."""
        return self._max_payload

    @max_payload.setter
    def max_payload(self, value: int) -> None:
        self._set_limits(value)  # a longer pending run is cut on the next feed

    @property
    def max_frame(self) -> int:
        """Longest run between delimiters that can be one frame."""
        return self._max_frame

    @property
    def max_buffer(self) -> int:
        """Most bytes of an unfinished run held: two frames and a damaged delimiter."""
        return self._max_buffer

    @property
    def buffered(self) -> int:
        """Bytes held of an unfinished run (never more than :attr:`max_buffer`)."""
        return len(self._pending)

    def reset(self) -> None:
        """Forget any unfinished run (e.g. after reopening the link). Counters are kept."""
        self._pending = b""
        self._discard = False

    def feed(self, data: bytes | bytearray | memoryview) -> list[FrameEvent]:
        """Consume ``data`` and return the events of every run it completes, in order."""
        chunk = bytes(data)
        if not chunk:
            return []
        self.stats.bytes += len(chunk)
        events: list[FrameEvent] = []
        runs = chunk.split(_ZERO)
        tail = runs.pop()
        if runs:
            if self._discard:
                runs[0] = b""
                self._discard = False
            elif self._pending:
                runs[0] = self._pending + runs[0]
            self._pending = b""
            self._decode_runs(runs, events)
        self._extend_pending(tail, events)
        return events

    def _decode_runs(self, runs: list[bytes], events: list[FrameEvent]) -> None:
        """Hot path: valid frames are decoded inline, everything else goes to ``_slow``."""
        max_frame = self._max_frame
        max_payload = self._max_payload
        header = _HEADER
        append = events.append
        new, set_type, set_channel, set_seq, set_payload, set_frag = (
            _new_object,
            _set_type,
            _set_channel,
            _set_seq,
            _set_payload,
            _set_frag,
        )
        bare_acks = _DECODED_ACKS
        count = 0
        for run in runs:
            if not run:
                continue
            size = len(run)
            if size == _BARE_RUN:  # maybe an ACK without a bitmap seen before
                frame = bare_acks.get(run)
                if frame is not None:
                    append(frame)
                    count += 1
                    continue
            if size <= max_frame:
                # ``body`` is the decoded body starting at offset ``o``: a run that is one COBS
                # group is its own body after the code byte, so it needs no copy.
                if run[0] == size:
                    body: bytes | None = run
                    o = 1
                else:
                    body = _cobs_decode_run(run)
                    o = 0
                if (
                    body is not None
                    and len(body) - o >= _ENVELOPE
                    and crc_hqx(body[o:-2], CRC_INIT) == body[-2] | body[-1] << 8
                ):
                    kind = header[body[o]]
                    if kind is not None and len(body) - o - _ENVELOPE <= max_payload:
                        frame = new(Frame)
                        set_type(frame, kind[0])
                        set_channel(frame, body[o + 1])
                        set_seq(frame, body[o + 2])
                        set_payload(frame, body[o + 3 : -2])
                        set_frag(frame, kind[1])
                        append(frame)
                        count += 1
                        if (
                            size == _BARE_RUN
                            and kind[0] is _ACK
                            and len(bare_acks) < _DECODED_ACKS_LIMIT
                        ):
                            bare_acks[run] = frame
                        continue
            self._slow(run, events)
        self.stats.frames += count

    def _slow(self, run: bytes, events: list[FrameEvent]) -> None:
        """Classify a complete run the hot path did not accept."""
        if len(run) > self._max_buffer:
            start = self._cut_overlong(run, events)
            if start < 0:
                return  # the rest of this run is dropped
            run = run[start:]
        if len(run) <= self._max_frame:
            result = _parse_run(run, self._max_payload)
            if isinstance(result, Frame):
                events.append(result)
                self.stats.frames += 1
                return
            if result not in _CHECKED_BEFORE_CRC:
                self._bad(result, run, events)
                return
            reason = result
        else:
            reason = BadFrameReason.OVERSIZE  # too long for one frame
        glued = _split_glued_frames(run, self._max_payload)
        if glued is not None:
            events += glued
            self.stats.frames += 2
            return
        self._reject(run, reason, events)

    def _cut_overlong(self, data: bytes, events: list[FrameEvent]) -> int:
        """Report the head of a run while more than ``max_buffer`` bytes of it remain.

        Text is reported up to the last LF of the first ``max_buffer`` bytes (all of them if
        there is none), so a frame sent right after a line stays whole; anything else is
        reported once as oversize. Returns the offset of the rest of the run, or -1 when the
        run must be dropped up to its delimiter.
        """
        limit = self._max_buffer
        start = 0
        while len(data) - start > limit:
            piece = data[start : start + limit]
            if not _is_text(piece):
                self._bad(BadFrameReason.OVERSIZE, piece, events)
                return -1
            cut = piece.rfind(b"\n") + 1 or limit
            events.append(NonFrameBytes(piece[:cut]))
            self.stats.non_frame_bytes += cut
            start += cut
        return start

    def _extend_pending(self, tail: bytes, events: list[FrameEvent]) -> None:
        """Keep the unfinished run; report its head once it gets longer than ``max_buffer``."""
        if self._discard or not tail:
            return
        pending = self._pending + tail if self._pending else tail
        if len(pending) > self._max_buffer:
            start = self._cut_overlong(pending, events)
            if start < 0:
                self._pending = b""
                self._discard = True
                return
            pending = pending[start:]
        self._pending = pending

    def _reject(self, run: bytes, reason: BadFrameReason, events: list[FrameEvent]) -> None:
        """A run failed COBS, length or CRC: text, text glued to a frame, or a bad frame."""
        if b"\n" in run:
            # A board that prints a line and then sends a frame without a leading delimiter
            # produces ``text \n frame``: try the frame after each newline of the text prefix.
            match = _TEXT_PREFIX.match(run)
            limit = match.end() if match else 0
            for _ in range(_TEXT_SPLIT_TRIES):
                newline = run.rfind(b"\n", 0, limit)
                if newline < 0:
                    break
                rest = run[newline + 1 :]
                result = _parse_run(rest, self._max_payload) if rest else None
                if isinstance(result, Frame):
                    text = run[: newline + 1]
                    events.append(NonFrameBytes(text))
                    self.stats.non_frame_bytes += len(text)
                    events.append(result)
                    self.stats.frames += 1
                    return
                limit = newline
        if _is_text(run):
            events.append(NonFrameBytes(run))
            self.stats.non_frame_bytes += len(run)
        else:
            self._bad(reason, run, events)

    def _bad(self, reason: BadFrameReason, data: bytes, events: list[FrameEvent]) -> None:
        events.append(BadFrame(reason, data))
        stats = self.stats
        if reason is BadFrameReason.CRC:
            stats.crc_errors += 1
        elif reason is BadFrameReason.COBS:
            stats.cobs_errors += 1
        elif reason is BadFrameReason.TOO_SHORT:
            stats.too_short += 1
        elif reason is BadFrameReason.VERSION:
            stats.version_errors += 1
        elif reason is BadFrameReason.RESERVED_TYPE:
            stats.reserved_type += 1
        else:
            stats.oversize += 1


def fragment(
    type: FrameType,
    channel: int,
    first_seq: int,
    payload: bytes | bytearray | memoryview,
    max_payload: int,
) -> list[Frame]:
    """Split one message into frames whose payloads fit ``max_payload`` (the peer's MTU).

    A message that fits is one WHOLE frame. A larger one becomes FIRST, MIDDLE..., LAST with
    consecutive sequence numbers from ``first_seq`` (mod 256); the FIRST payload starts with
    the message length as uint32 little-endian. ACK frames are never fragmented.

    Raises:
        FramingError: ACK type, ``max_payload`` below :data:`MIN_FRAGMENT_PAYLOAD` for a message
            that needs fragments, or a message of 2**32 bytes or more.
    """
    if type is _ACK:
        raise FramingError("ACK frames are never fragmented: send the acknowledgement whole")
    data = payload if isinstance(payload, bytes) else bytes(payload)
    size = len(data)
    if size <= max_payload:
        return [make_frame(type, channel, first_seq, data)]
    if max_payload < MIN_FRAGMENT_PAYLOAD:
        raise FramingError(
            f"cannot fragment {size} bytes with a per-frame payload limit of {max_payload}: "
            f"fragmenting needs at least {MIN_FRAGMENT_PAYLOAD}"
        )
    if size >= 1 << 32:
        raise FramingError(f"message of {size} bytes is too large: the limit is 2**32 - 1")
    first_chunk = max_payload - LENGTH_PREFIX_SIZE
    frames = [
        Frame(
            type,
            channel,
            first_seq & 0xFF,
            size.to_bytes(LENGTH_PREFIX_SIZE, "little") + data[:first_chunk],
            Frag.FIRST,
        )
    ]
    seq = first_seq + 1
    for start in range(first_chunk, size, max_payload):
        end = start + max_payload
        frag = Frag.LAST if end >= size else Frag.MIDDLE
        frames.append(Frame(type, channel, seq & 0xFF, data[start:end], frag))
        seq += 1
    return frames


@dataclass(slots=True)
class ReassemblyStats:
    """Counters of a :class:`Reassembler`."""

    messages: int = 0
    """Complete messages returned (WHOLE frames included)."""
    dropped_partial: int = 0
    """Partial messages abandoned: a gap in seq, another channel, or a new FIRST or WHOLE."""
    oversize: int = 0
    """Messages refused because their announced length is above ``max_message``."""
    orphans: int = 0
    """MIDDLE or LAST fragments that continue no message in progress (dropped)."""
    malformed: int = 0
    """FIRST too short for its length prefix, or fragments that disagree with that length."""
    duplicates: int = 0
    """Repeats of the last frame accepted (same seq, channel, frag and payload), ignored."""

    def as_dict(self) -> dict[str, int]:
        """Counters by name, for logs and JSON."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


class Reassembler:
    """Joins fragments of one sequence space (one type, one direction) into messages.

    Frames must be fed in arrival order (for RELIABLE traffic: in the order the reliability
    layer delivers them). One message is in progress at a time, because a sender never
    interleaves the fragments of two messages in one sequence space; anything that breaks the
    run of consecutive sequence numbers abandons the partial message. Memory held never exceeds
    ``max_message`` bytes, and a message whose FIRST announces more is refused before any of it
    is buffered. A message is returned only when exactly its announced length arrived in
    consecutive fragments, so loss, duplication or reordering can lose a message, never
    corrupt one.
    """

    __slots__ = (
        "_buf",
        "_channel",
        "_last",
        "_next_seq",
        "_skipping",
        "_total",
        "max_message",
        "stats",
    )

    def __init__(self, max_message: int) -> None:
        if max_message < 0:
            raise ValueError(f"max_message must be >= 0, not {max_message}")
        self.max_message = max_message
        """Largest message accepted, in bytes."""
        self.stats = ReassemblyStats()
        self._buf: bytearray | None = None
        self._skipping = False
        self._total = 0
        self._channel = 0
        self._next_seq = 0
        self._last: tuple[int, int, Frag, bytes] | None = None

    @property
    def in_progress(self) -> bool:
        """True while a partial message is buffered."""
        return self._buf is not None

    @property
    def buffered(self) -> int:
        """Bytes of the partial message held."""
        return 0 if self._buf is None else len(self._buf)

    def reset(self) -> None:
        """Abandon any partial message (counted in ``dropped_partial``)."""
        self._abandon()
        self._last = None

    def _abandon(self) -> None:
        if self._buf is not None:
            self.stats.dropped_partial += 1
        self._buf = None
        self._skipping = False

    def feed(self, frame: Frame) -> bytes | None:
        """Consume one frame; return a complete message (of ``frame.channel``) or None."""
        frag = frame.frag
        seq = frame.seq
        last = self._last
        if (
            last is not None
            and last[0] == seq
            and last[1] == frame.channel
            and last[2] == frag
            and last[3] == frame.payload
        ):
            self.stats.duplicates += 1
            return None
        if frag == Frag.WHOLE:
            self._abandon()
            self._last = (seq, frame.channel, frag, frame.payload)
            self.stats.messages += 1
            return frame.payload
        if frag == Frag.FIRST:
            self._first(frame)
            return None
        return self._next(frame)

    def whole(self, frame: Frame) -> bytes:
        """:meth:`feed` for a WHOLE frame while no message is in progress, without the
        duplicate check (for receivers that already drop repeated sequence numbers)."""
        self._last = (frame.seq, frame.channel, _WHOLE, frame.payload)
        self.stats.messages += 1
        return frame.payload

    def _remember(self, frame: Frame) -> None:
        self._last = (frame.seq, frame.channel, frame.frag, frame.payload)
        self._next_seq = (frame.seq + 1) & 0xFF

    def _first(self, frame: Frame) -> None:
        self._abandon()
        self._last = None
        payload = frame.payload
        if len(payload) < LENGTH_PREFIX_SIZE:
            self.stats.malformed += 1
            return
        total = int.from_bytes(payload[:LENGTH_PREFIX_SIZE], "little")
        chunk = payload[LENGTH_PREFIX_SIZE:]
        self._channel = frame.channel
        self._remember(frame)
        if total > self.max_message:
            self.stats.oversize += 1
            self._skipping = True  # swallow this message's other fragments quietly
            return
        if len(chunk) > total:
            self.stats.malformed += 1
            return
        self._total = total
        self._buf = bytearray(chunk)

    def _next(self, frame: Frame) -> bytes | None:
        buf = self._buf
        if buf is None and not self._skipping:
            self.stats.orphans += 1
            return None
        if frame.seq != self._next_seq or frame.channel != self._channel:
            self._abandon()
            self._last = None
            self.stats.orphans += 1
            return None
        self._remember(frame)
        is_last = frame.frag == Frag.LAST
        if buf is None:  # skipping an oversize message
            if is_last:
                self._skipping = False
            return None
        payload = frame.payload
        if len(buf) + len(payload) > self._total or (
            is_last and len(buf) + len(payload) != self._total
        ):
            self._buf = None
            self.stats.malformed += 1
            return None
        buf += payload
        if not is_last:
            return None
        self._buf = None
        self.stats.messages += 1
        return bytes(buf)
