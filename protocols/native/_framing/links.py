"""The two framings of the native protocol: COBS on stream links, bare frames on datagram links.

A native session is built with one of them (PROTOCOL.md 1.3 and 1.13) and never touches link
bytes itself: it hands the framing the frames it sends and gets back what one link write takes,
and feeds it what one link read returned.
"""

from __future__ import annotations

from binascii import crc_hqx
from collections.abc import Sequence
from typing import Final, Protocol

from hwbridge.protocols.native._framing.decoder import FrameDecoder
from hwbridge.protocols.native._framing.encoder import encode_datagram, encode_frame
from hwbridge.protocols.native._framing.frames import (
    _ENVELOPE,
    _HEADER,
    CRC_INIT,
    DEFAULT_MAX_PAYLOAD,
    VERSION,
    BadFrame,
    BadFrameReason,
    Frame,
    FrameEvent,
    FramingStats,
    body_frame,
)

__all__ = ["IDLE_LEAD", "NativeDatagramFraming", "NativeFraming", "NativeStreamFraming"]

IDLE_LEAD: Final = 0.1
"""A chunk written after the line was idle this long (seconds) starts with a 0x00 (1.3)."""

_ZERO: Final = b"\x00"


class NativeFraming(Protocol):
    """What a native session needs of its framing: :class:`hwbridge.protocols.base.Framing`
    plus the decoder's payload limit (the negotiated MTU), its counters and a way to ask for a
    leading delimiter."""

    datagram: bool

    @property
    def stats(self) -> FramingStats:
        """The decoder's counters (frames and bytes received, every rejection by reason)."""
        ...

    @property
    def max_payload(self) -> int:
        """Largest frame payload accepted (the session sets it to the negotiated MTU)."""
        ...

    @max_payload.setter
    def max_payload(self, value: int) -> None: ...

    def decode(self, data: bytes, /) -> list[FrameEvent]: ...

    def encode(self, frames: Sequence[Frame], now: float, /) -> list[bytes]: ...

    def lead_next(self) -> None:
        """Flush the receiver before the next frames (a 0x00 first on a stream link)."""
        ...


class NativeStreamFraming:
    """COBS-framed frames, each ended by 0x00, on a byte stream (serial, TCP, pty).

    ``decode`` feeds a :class:`~hwbridge.protocols.native.framing.FrameDecoder` (any chunking);
    ``encode`` returns one chunk holding all the frames, led by a 0x00 when it is the first
    chunk, when the line was idle for :data:`IDLE_LEAD` seconds, or after :meth:`lead_next`.
    """

    __slots__ = ("_decoder", "_idle_lead", "_last", "_lead")

    datagram = False

    def __init__(
        self, max_payload: int = DEFAULT_MAX_PAYLOAD, *, idle_lead: float = IDLE_LEAD
    ) -> None:
        self._decoder = FrameDecoder(max_payload)
        self._idle_lead = idle_lead
        self._last = 0.0
        self._lead = True
        """The next chunk starts with a delimiter (the first one always does)."""

    @property
    def stats(self) -> FramingStats:
        return self._decoder.stats

    @property
    def max_payload(self) -> int:
        return self._decoder.max_payload

    @max_payload.setter
    def max_payload(self, value: int) -> None:
        self._decoder.max_payload = value

    @property
    def decoder(self) -> FrameDecoder:
        """The stream decoder (its limits and buffer)."""
        return self._decoder

    def decode(self, data: bytes, /) -> list[FrameEvent]:
        return self._decoder.feed(data)

    def encode(self, frames: Sequence[Frame], now: float, /) -> list[bytes]:
        if not frames:
            return []
        lead = self._lead or now - self._last >= self._idle_lead
        self._lead = False
        self._last = now
        if len(frames) == 1:
            return [encode_frame(frames[0], lead=lead)]
        wire = [encode_frame(frame) for frame in frames]
        if lead:
            wire[0] = _ZERO + wire[0]
        return [b"".join(wire)]

    def lead_next(self) -> None:
        self._lead = True


_BAD_COUNTERS: Final = {
    BadFrameReason.CRC: "crc_errors",
    BadFrameReason.TOO_SHORT: "too_short",
    BadFrameReason.VERSION: "version_errors",
    BadFrameReason.RESERVED_TYPE: "reserved_type",
    BadFrameReason.OVERSIZE: "oversize",
}


class NativeDatagramFraming:
    """One whole frame per datagram (CAN, UDP, a tunnel): ``header + payload + CRC-16``, no
    COBS, no delimiter (PROTOCOL.md 1.13). A datagram that fails the CRC, the header or the
    size check is one :class:`~hwbridge.protocols.native.framing.BadFrame`."""

    __slots__ = ("_max_payload", "stats")

    datagram = True

    def __init__(self, max_payload: int = DEFAULT_MAX_PAYLOAD) -> None:
        if max_payload < 0:
            raise ValueError(f"max_payload must be >= 0, not {max_payload}")
        self._max_payload = max_payload
        self.stats = FramingStats()

    @property
    def max_payload(self) -> int:
        return self._max_payload

    @max_payload.setter
    def max_payload(self, value: int) -> None:
        if value < 0:
            raise ValueError(f"max_payload must be >= 0, not {value}")
        self._max_payload = value

    def decode(self, data: bytes, /) -> list[FrameEvent]:
        body = bytes(data)
        if not body:
            return []
        stats = self.stats
        stats.bytes += len(body)
        reason: BadFrameReason
        if len(body) < _ENVELOPE:
            reason = BadFrameReason.TOO_SHORT
        elif crc_hqx(body[:-2], CRC_INIT) != body[-2] | body[-1] << 8:
            reason = BadFrameReason.CRC
        else:
            kind = _HEADER[body[0]]
            if kind is None:
                version = body[0] >> 6 != VERSION
                reason = BadFrameReason.VERSION if version else BadFrameReason.RESERVED_TYPE
            elif len(body) - _ENVELOPE > self._max_payload:
                reason = BadFrameReason.OVERSIZE
            elif kind[2] and len(body) == _ENVELOPE:
                reason = BadFrameReason.TOO_SHORT  # the ACK flag without its byte
            else:
                stats.frames += 1
                return [body_frame(kind, body)]
        name = _BAD_COUNTERS[reason]
        setattr(stats, name, getattr(stats, name) + 1)
        return [BadFrame(reason, body)]

    def encode(self, frames: Sequence[Frame], now: float, /) -> list[bytes]:
        return [encode_datagram(frame) for frame in frames]

    def lead_next(self) -> None:
        """Nothing to flush: every datagram stands alone."""
