"""Fragmentation of the native protocol: one message into frames, and frames back into it.

PROTOCOL.md 1.9. :func:`fragment` splits a message for the peer's MTU; a :class:`Reassembler`
joins the fragments of one sequence space, never holding more than ``max_message`` bytes.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from hwbridge.protocols.errors import FramingError
from hwbridge.protocols.native._framing.frames import (
    LENGTH_PREFIX_SIZE,
    MIN_FRAGMENT_PAYLOAD,
    Frag,
    Frame,
    FrameType,
)
from hwbridge.protocols.native._hotpath import ACK, WHOLE, make_frame


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
    if type is ACK:
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
        self._last = (frame.seq, frame.channel, WHOLE, frame.payload)
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
