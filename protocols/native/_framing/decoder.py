"""The native stream decoder: a byte stream in, frames, bad frames and text out (sans-I/O).

The decoder is the hot path: it splits each chunk on 0x00 in C (``bytes.split``), decodes COBS
with one Python step per group, checks the CRC with ``binascii.crc_hqx`` and reads the header
through a 256-entry table (see :mod:`hwbridge.protocols.native._hotpath` for how it builds
frames). Anything that is not a valid frame takes a separate, slower path that classifies it
(bad frame, or text printed by the board) and never raises. PROTOCOL.md 1.6.
"""

from __future__ import annotations

import re
from binascii import crc_hqx
from typing import Final

from hwbridge.protocols.native._framing.frames import (
    _ENVELOPE,
    _HEADER,
    _ZERO,
    CRC_INIT,
    DEFAULT_MAX_PAYLOAD,
    BadFrame,
    BadFrameReason,
    Frame,
    FrameEvent,
    FramingStats,
    NonFrameBytes,
    _parse_run,
    body_frame,
    max_run_size,
)
from hwbridge.protocols.native._hotpath import (
    ACK,
    NEW_FRAME,
    SET_ACK,
    SET_CHANNEL,
    SET_FRAG,
    SET_PAYLOAD,
    SET_SEQ,
    SET_TYPE,
)
from hwbridge.protocols.native.cobs import decode_or_none as _cobs_decode_run

_BARE_RUN: Final = _ENVELOPE + 1
"""Length of every run that encodes a frame without payload (and of no other valid frame)."""
_DECODED_ACKS: Final[dict[bytes, Frame]] = {}
"""ACK frames without a bitmap by their run, decoded once: an in-order receiver sends one per
reliable frame, the most frequent frame. Frames are immutable, and one without payload passes
every limit of any decoder, so all decoders share them."""
_DECODED_ACKS_LIMIT: Final = 1024


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
                if isinstance(second, Frame) and (not kind[2] or length > _ENVELOPE):
                    return body_frame(kind, decoded), second
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
        new, set_type, set_channel, set_seq, set_payload, set_frag, set_ack = (
            NEW_FRAME,
            SET_TYPE,
            SET_CHANNEL,
            SET_SEQ,
            SET_PAYLOAD,
            SET_FRAG,
            SET_ACK,
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
                        set_frag(frame, kind[1])
                        if not kind[2]:
                            set_payload(frame, body[o + 3 : -2])
                            set_ack(frame, None)
                        elif len(body) - o > _ENVELOPE:  # the ACK byte before the CRC
                            set_payload(frame, body[o + 3 : -3])
                            set_ack(frame, body[-3])
                        else:
                            self._slow(run, events)  # the ACK flag without its byte
                            continue
                        append(frame)
                        count += 1
                        if (
                            size == _BARE_RUN
                            and kind[0] is ACK
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
