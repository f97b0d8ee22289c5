"""Finding Dynamixel packets in a byte stream cut anywhere (sans-I/O), and decoding one packet."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from hwbridge.devices.dynamixel.framing import (
    HEADER_1,
    STATUS_INSTRUCTION,
    STUFF_PATTERN,
    CorruptPacket,
    InstructionPacket,
    Packet,
    StatusPacket,
    check_protocol,
    checksum,
    crc16,
    unstuff,
)
from hwbridge.errors import FramingError


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
        check_protocol(self.protocol)

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
        index = buf.find(STUFF_PATTERN)
        if index < 0:
            self._keep_header_prefix(STUFF_PATTERN)
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
