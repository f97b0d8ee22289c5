"""The CAN transport of the native protocol: ids, tail bytes and transfers (CAN.md).

Sans-I/O: :class:`TransferEncoder` turns one native datagram into the CAN frames of one transfer
(``(can_id, data)`` pairs), :class:`TransferDecoder` turns received frames back into
:class:`Transfer` objects, dropping and counting whatever is malformed, out of sequence,
duplicated, corrupted, too long or never finished (:class:`CanStats`); :class:`ConflictMonitor`
notices two nodes claiming one node id. Nothing here reads a clock or touches a bus.

The 29-bit id (bit 28 first)::

    28..26 priority (0 highest)   25..24 kind   23..16 channel   15..14 reserved (0)
    13..7  destination node id    6..0   source node id

and the last byte of every frame is the tail byte: ``start << 7 | end << 6 | toggle << 5 | tid``.

That is format 1. Format 2 (CAN.md version 2, bit 15 of the id set) carries a native datagram
without its 3-byte header and its CRC-16: type and channel are the id's kind and channel, the
sequence number is split between the id (bits 13..11) and the tail byte's transfer id, the
fragment position is in the id (bits 10..9), and bit 14 says which way the transfer goes between
the host and the board of bits 6..0::

    28..26 priority   25..24 kind   23..16 channel   15 = 1   14 to the host
    13..11 seq bits 7..5   10..9 frag   8..7 reserved (0)   6..0 board node id

A receiver rebuilds the datagram (header and CRC-16) before handing it on, so nothing above the
transfer changes.

Chained transfers (CAN.md version 3, §12): the best-effort fragments of one native message,
FIRST .. LAST at a fragment size of ``32 << code`` bytes, travel as one transfer of the message
bytes alone (no 4-byte length, one transfer CRC, frames filled end to end); bit 7 of the id marks
it and bits 10..8 hold ``code``. The receiver cuts the message into the same fragments again.
A node sends chains only to a peer whose claim has bit 11 set (it takes chains)::

    13..11 seq bits 7..5 of the FIRST fragment   10..8 size code   7 = 1 chained
"""

from __future__ import annotations

from binascii import crc_hqx
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from typing import Final

from hwbridge.protocols.can.ids import (
    CLAIM_CHAINS,
    FORMAT_1,
    FORMAT_2,
    HOST_NODE,
    MAX_NODE,
    MIN_NODE,
    NODE_CLAIM,
    PRIORITY_ACK,
    PRIORITY_BEST_EFFORT,
    PRIORITY_CONTROL,
    PRIORITY_NODE,
    PRIORITY_RELIABLE,
    UID_SIZE,
    CanId,
    Kind,
    acceptance_filters,
    chain_size_code,
    decode_id,
    encode_chain_id,
    encode_id,
    encode_id2,
    kind_of,
    priority_of,
    queue_class,
)

__all__ = [
    "CHAIN_MAX",
    "CLAIM_CHAINS",
    "CLASSIC_MTU",
    "CRC_INIT",
    "FD_LENGTHS",
    "FD_MTU",
    "FORMAT_1",
    "FORMAT_2",
    "HOST_NODE",
    "MAX_NODE",
    "MIN_NODE",
    "NODE_CLAIM",
    "PRIORITY_ACK",
    "PRIORITY_BEST_EFFORT",
    "PRIORITY_CONTROL",
    "PRIORITY_NODE",
    "PRIORITY_RELIABLE",
    "TID_MODULO",
    "UID_SIZE",
    "CanId",
    "CanStats",
    "ConflictMonitor",
    "Kind",
    "Transfer",
    "TransferDecoder",
    "TransferEncoder",
    "acceptance_filters",
    "chain_datagrams",
    "chain_size_code",
    "crc16",
    "decode_id",
    "encode_id",
    "encode_id2",
    "frame_lengths",
    "kind_of",
    "priority_of",
    "queue_class",
    "rebuild_datagram",
    "split_transfer",
]

CLASSIC_MTU: Final = 8
"""Data bytes of a classic CAN frame (7 of payload and the tail byte)."""
FD_MTU: Final = 64
"""Data bytes of the largest CAN FD frame."""
FD_LENGTHS: Final = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
"""The data lengths a CAN FD frame can have (DLC 0..15)."""
_VALID_LENGTH: Final = frozenset(FD_LENGTHS)
TID_MODULO: Final = 32
"""Transfer ids count 0..31 and wrap."""
CRC_INIT: Final = 0xFFFF

_START: Final = 0x80
_END: Final = 0x40
_TOGGLE: Final = 0x20
_TID_MASK: Final = 0x1F
CHAIN_MAX: Final = 4096
"""The longest message a sender chains (a receiver's transfer limit, CAN.md §4)."""
_LENGTH_PREFIX: Final = 4
_NATIVE_VERSION: Final = 0x40
_ACK_FLAG: Final = 0x01
"""Header byte 0, bit 0 of a data frame: an ACK byte before the CRC (PROTOCOL.md 1.4)."""
_ACK_FLAGS: Final = 0x60
"""Header byte 0 of an ACK frame (WHOLE)."""
_NATIVE_ENVELOPE: Final = 5


def crc16(data: bytes | bytearray | memoryview, value: int = CRC_INIT) -> int:
    """CRC-16/CCITT-FALSE (``crc16(b"123456789") == 0x29B1``); over a transfer followed by its
    big-endian CRC it is 0."""
    return crc_hqx(data, value)


def frame_lengths(size: int, mtu: int) -> list[int]:
    """Data lengths (tail byte included) of the frames a transfer of ``size`` payload bytes takes
    with frames of at most ``mtu`` bytes: one frame when ``size + 1`` fits and is a valid length,
    otherwise payload and CRC in frames of the largest valid length that fits (never padding)."""
    if size + 1 <= mtu and size + 1 in _VALID_LENGTH:
        return [size + 1]
    left = size + 2
    lengths: list[int] = []
    while left:
        # The first frame leaves at least one byte for a second: a transfer with a CRC is
        # never a single frame.
        room = min(left if not lengths else left + 1, mtu)
        while room not in _VALID_LENGTH:
            room -= 1
        lengths.append(room)
        left -= room - 1
    return lengths


def split_transfer(payload: bytes | bytearray | memoryview, tid: int, mtu: int) -> list[bytes]:
    """The frames' data (tail bytes included) of one transfer of ``payload``."""
    data = bytes(payload)
    lengths = frame_lengths(len(data), mtu)
    if len(lengths) == 1:
        return [data + bytes([_START | _END | _TOGGLE | tid])]
    data += crc16(data).to_bytes(2, "big")
    frames: list[bytes] = []
    offset = 0
    toggle = _TOGGLE
    for index, length in enumerate(lengths):
        tail = toggle | tid
        if index == 0:
            tail |= _START
        if index == len(lengths) - 1:
            tail |= _END
        frames.append(data[offset : offset + length - 1] + bytes([tail]))
        offset += length - 1
        toggle ^= _TOGGLE
    return frames


class _ChainTx:
    """A chain being sent (CAN.md §12): the fragments taken so far, streamed into frames."""

    __slots__ = (
        "can_id",
        "channel",
        "crc",
        "index",
        "left",
        "lengths",
        "next_seq",
        "pending",
        "size",
        "tid",
        "toggle",
    )

    def __init__(
        self, can_id: int, seq: int, channel: int, size: int, total: int, mtu: int
    ) -> None:
        self.can_id = can_id
        self.tid = seq & _TID_MASK
        self.next_seq = (seq + 1) & 0xFF
        self.channel = channel
        self.size = size
        self.left = total
        self.lengths = frame_lengths(total, mtu)
        self.index = 0
        self.toggle = _TOGGLE
        self.crc = CRC_INIT
        self.pending = bytearray()

    def take(self, chunk: bytes) -> list[bytes]:
        """Frames completed by the next ``chunk`` of the message (the end frames with the
        last chunk)."""
        self.crc = crc16(chunk, self.crc)
        self.left -= len(chunk)
        self.pending += chunk
        if self.left == 0 and len(self.lengths) > 1:
            self.pending += self.crc.to_bytes(2, "big")
        frames: list[bytes] = []
        last = len(self.lengths) - 1
        while self.index <= last and len(self.pending) >= self.lengths[self.index] - 1:
            body = self.lengths[self.index] - 1
            tail = self.toggle | self.tid
            if self.index == 0:
                tail |= _START
            if self.index == last:
                tail |= _END
            frames.append(bytes(self.pending[:body]) + bytes([tail]))
            del self.pending[:body]
            self.toggle ^= _TOGGLE
            self.index += 1
        return frames


class TransferEncoder:
    """Frames for what one node sends: a transfer id per CAN id, counting 0..31; the chains in
    progress (CAN.md §12), one per destination."""

    def __init__(self, source: int, mtu: int = CLASSIC_MTU) -> None:
        if not 0 <= source <= MAX_NODE:
            raise ValueError(f"node id must be 0..{MAX_NODE}, not {source}")
        if mtu not in (CLASSIC_MTU, *FD_LENGTHS[9:]):
            raise ValueError(f"mtu must be 8 (classic CAN) or a CAN FD length 12..64, not {mtu}")
        self.source = source
        self.mtu = mtu
        self._tids: dict[int, int] = {}
        self._chains: dict[int, _ChainTx] = {}
        self.chains = 0
        """Chained transfers begun."""
        self.chain_breaks = 0
        """Chains left unfinished: a datagram to their destination that did not continue them
        (the receiver drops the part it got)."""

    def transfer(
        self, can_id: int, payload: bytes | bytearray | memoryview
    ) -> list[tuple[int, bytes]]:
        """The frames of one transfer of ``payload`` on ``can_id`` (its next transfer id)."""
        tid = self._tids.get(can_id, 0)
        self._tids[can_id] = (tid + 1) % TID_MODULO
        return [(can_id, data) for data in split_transfer(payload, tid, self.mtu)]

    def datagram(
        self,
        datagram: bytes | bytearray | memoryview,
        destination: int,
        priority: int | None = None,
        *,
        format: int = FORMAT_2,
        chain: bool = False,
    ) -> list[tuple[int, bytes]]:
        """The frames carrying one native datagram to ``destination`` in ``format`` (2: without
        its header and CRC-16, which must be right: ValueError otherwise).

        ``chain`` (format 2, CAN.md §12): a best-effort FIRST fragment of a power-of-two size
        begins a chained transfer, and its MIDDLE and LAST fragments, given next, continue it:
        each returns the frames it completes (possibly none). A best-effort datagram that does
        not continue the chain in progress to its destination breaks it off (``chain_breaks``)
        and is sent as usual; reliable and ACK datagrams go beside it."""
        if format == FORMAT_1:
            kind, channel = kind_of(datagram)
            if priority is None:
                priority = priority_of(kind, channel)
            can_id = encode_id(priority, kind, channel, destination, self.source)
            return self.transfer(can_id, datagram)
        data = bytes(datagram)
        if len(data) < _NATIVE_ENVELOPE:
            raise ValueError(f"a native datagram has at least 5 bytes, not {len(data)}")
        flags, channel, seq = data[0], data[1], data[2]
        frame_type = (flags >> 4) & 3
        if flags & 0xC0 != _NATIVE_VERSION or frame_type == 3:
            raise ValueError(
                f"not a version-1 native datagram of a known type (flags {flags:#04x})"
            )
        if crc16(data[:-2]) != int.from_bytes(data[-2:], "little"):
            raise ValueError("the native datagram's CRC-16 is wrong")
        kind = Kind(frame_type)
        if flags & _ACK_FLAG and kind is not Kind.ACK and len(data) > _NATIVE_ENVELOPE:
            # A data frame that carries an ACK (ACK_IN_DATA, PROTOCOL.md 1.4): the id has no room
            # for its flag bit, so it goes as the frame without it and an ACK datagram after it.
            return self.datagram(
                _rebuilt(flags & ~_ACK_FLAG, channel, seq, data[3:-3]),
                destination,
                priority,
                format=format,
                chain=chain,
            ) + self.datagram(_rebuilt(_ACK_FLAGS, 0, data[-3], b""), destination, format=format)
        frag = (flags >> 2) & 3
        payload = data[3:-2]
        going = self._chains.get(destination)
        if going is not None and kind is Kind.BEST_EFFORT:  # other streams go on beside it
            if (
                frag in (2, 3)
                and channel == going.channel
                and seq == going.next_seq
                and len(payload) == (going.size if frag == 2 else going.left)
                and (going.left > going.size) == (frag == 2)
            ):
                going.next_seq = (seq + 1) & 0xFF
                frames = going.take(payload)
                if frag == 3:
                    del self._chains[destination]
                return [(going.can_id, frame) for frame in frames]
            del self._chains[destination]
            self.chain_breaks += 1
        if priority is None:
            priority = priority_of(kind, channel)
        if (
            chain
            and kind is Kind.BEST_EFFORT
            and frag == 1
            and chain_size_code(len(payload)) is not None
        ):
            total = int.from_bytes(payload[:_LENGTH_PREFIX], "little")
            if len(payload) - _LENGTH_PREFIX < total <= CHAIN_MAX:
                can_id = encode_chain_id(
                    priority, kind, channel, destination, self.source, seq, len(payload)
                )
                going = _ChainTx(can_id, seq, channel, len(payload), total, self.mtu)
                self._chains[destination] = going
                self.chains += 1
                return [(can_id, frame) for frame in going.take(payload[_LENGTH_PREFIX:])]
        can_id = encode_id2(priority, kind, channel, destination, self.source, seq, frag)
        frames = split_transfer(payload, seq & _TID_MASK, self.mtu)
        return [(can_id, frame) for frame in frames]

    def claim(
        self, uid: bytes, *, format: int = FORMAT_2, chains: bool = False
    ) -> list[tuple[int, bytes]]:
        """A node-id claim: this node's unique id, to every node (destination 0), in
        ``format`` (the format this node speaks: receivers learn it from the claim); ``chains``
        (format 2): this node takes chained transfers (bit 11 of the id, CAN.md §12)."""
        if len(uid) != UID_SIZE:
            raise ValueError(f"a unique id has {UID_SIZE} bytes, not {len(uid)}")
        if format == FORMAT_1:
            can_id = encode_id(PRIORITY_NODE, Kind.NODE, NODE_CLAIM, HOST_NODE, self.source)
        else:
            can_id = encode_id2(PRIORITY_NODE, Kind.NODE, NODE_CLAIM, HOST_NODE, self.source)
            if chains:
                can_id |= CLAIM_CHAINS
        return self.transfer(can_id, uid)


@dataclass(frozen=True, slots=True)
class Transfer:
    """One received transfer. ``payload`` is the native datagram (rebuilt with its header and
    CRC-16 from a format-2 transfer) or, for a NODE message, its payload."""

    priority: int
    kind: Kind
    channel: int
    destination: int
    source: int
    payload: bytes
    format: int = FORMAT_1
    chained: tuple[bytes, ...] = ()
    """A chained transfer (CAN.md §12): the native datagrams (FIRST .. LAST) it carried, rebuilt;
    ``payload`` is then the message."""
    takes_chains: bool = False
    """A format-2 claim: the claiming node takes chained transfers (bit 11 of its id)."""

    @property
    def datagrams(self) -> tuple[bytes, ...]:
        """The native datagrams to hand on: the chain's, or the payload."""
        return self.chained or (self.payload,)


@dataclass
class CanStats:
    """Counters of a :class:`TransferDecoder` (they only grow)."""

    frames: int = 0
    """Frames fed."""
    transfers: int = 0
    """Transfers returned."""
    foreign: int = 0
    """Well-formed frames for another node (skipped, not an error)."""
    malformed: int = 0
    """Frames dropped as not ours: standard ids, reserved id bits set, no data, a length CAN FD
    cannot have, a start frame whose toggle is 0; chained frames at a receiver that does not
    take chains, and chains too short to be a fragmented message."""
    unexpected: int = 0
    """Frames out of sequence: a middle or end frame with no transfer started, or of another
    transfer id than the one in progress."""
    duplicate_frames: int = 0
    """A frame with the toggle of the frame before it: repeated, or the one between was lost
    (then the transfer's CRC fails at its end)."""
    duplicate_transfers: int = 0
    """A whole format-1 transfer received again: the transfer id and content of the last one on
    its CAN id, within ``tid_timeout`` (two nodes that share a node id are told apart by
    content). Format 2 leaves repeats to the native session, which knows them by sequence
    number (and must see a reliable datagram resent to acknowledge it again)."""
    crc_errors: int = 0
    """Multi-frame transfers whose CRC was wrong (a frame lost, reordered or corrupted)."""
    abandoned: int = 0
    """Transfers left unfinished by a new start on the same id, or evicted for room."""
    timeouts: int = 0
    """Transfers that never ended: nothing came for ``timeout`` seconds."""
    oversize: int = 0
    """Transfers that grew past ``max_transfer`` bytes."""

    @property
    def dropped(self) -> int:
        """Frames or transfers dropped for any reason (foreign frames not included)."""
        return (
            self.malformed
            + self.unexpected
            + self.duplicate_frames
            + self.duplicate_transfers
            + self.crc_errors
            + self.abandoned
            + self.timeouts
            + self.oversize
        )

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class _Rx:
    __slots__ = ("buf", "frames", "started", "tid", "toggle")

    def __init__(self, tid: int, body: bytes, now: float) -> None:
        self.tid = tid
        self.toggle = _TOGGLE
        self.buf = bytearray(body)
        self.frames = 1
        self.started = now


class TransferDecoder:
    """Reassembles transfers addressed to ``local`` (None: to any node) from CAN frames.

    One transfer is in progress per CAN id. ``timeout`` bounds how long a transfer may take,
    ``tid_timeout`` how long a finished transfer's id is remembered to drop a repeat of it,
    ``max_transfer`` the bytes of one transfer, ``max_pending`` the transfers in progress at once
    (the oldest is abandoned for a new one), so garbage costs bounded memory. ``format_2=False``
    makes a CAN.md version-1 receiver: format-2 frames are ``malformed`` (their id bit 15 was
    reserved), as a node that predates format 2 counts them; ``chains=False`` a version-2 one:
    chained frames (CAN.md §12) are ``malformed`` (their id bit 7 was reserved).
    """

    def __init__(
        self,
        local: int | None,
        *,
        max_transfer: int = 4096,
        timeout: float = 1.0,
        tid_timeout: float = 1.0,
        max_pending: int = 256,
        format_2: bool = True,
        chains: bool = True,
    ) -> None:
        self.local = local
        self.format_2 = format_2
        self.chains = chains and format_2
        self.max_transfer = max_transfer
        self.timeout = timeout
        self.tid_timeout = tid_timeout
        self.max_pending = max_pending
        self.stats = CanStats()
        self._rx: dict[int, _Rx] = {}
        self._done: dict[int, tuple[int, float, int]] = {}

    @property
    def pending(self) -> int:
        """Transfers in progress."""
        return len(self._rx)

    def feed(
        self, can_id: int, data: bytes | bytearray, now: float, *, extended: bool = True
    ) -> Transfer | None:
        """Take one received frame; the transfer it completes, if any."""
        stats = self.stats
        stats.frames += 1
        size = len(data)
        ident = decode_id(can_id) if extended else None
        if ident is not None and ident.format == FORMAT_2 and not self.format_2:
            ident = None
        if ident is not None and ident.chain and not self.chains:
            ident = None
        if ident is None or not size or size > FD_MTU or size not in _VALID_LENGTH:
            stats.malformed += 1
            return None
        local = self.local
        if local is not None and ident.destination != local and ident.kind is not Kind.NODE:
            stats.foreign += 1
            return None
        tail = data[-1]
        tid = tail & _TID_MASK
        body = bytes(data[:-1])
        rx = self._rx.get(can_id)
        if tail & _START:
            if not tail & _TOGGLE:
                stats.malformed += 1
                return None
            if rx is not None:
                if rx.frames == 1 and rx.tid == tid and rx.buf == body:
                    stats.duplicate_frames += 1
                    return None
                del self._rx[can_id]
                stats.abandoned += 1
            if tail & _END:
                return self._finish(can_id, ident, tid, body, now)
            if len(self._rx) >= self.max_pending:
                self._evict()
            self._rx[can_id] = _Rx(tid, body, now)
            return None
        if rx is None:
            done = self._done.get(can_id)
            if done is not None and done[0] == tid and tail & _END:
                stats.duplicate_frames += 1  # the end frame of the transfer just finished, again
            else:
                stats.unexpected += 1
            return None
        if tid != rx.tid:
            stats.unexpected += 1
            return None
        toggle = tail & _TOGGLE
        if toggle == rx.toggle:
            stats.duplicate_frames += 1
            return None
        rx.toggle = toggle
        rx.buf += body
        rx.frames += 1
        if len(rx.buf) > self.max_transfer + 2:
            del self._rx[can_id]
            stats.oversize += 1
            return None
        if not tail & _END:
            return None
        del self._rx[can_id]
        if len(rx.buf) < 2 or crc16(rx.buf):
            stats.crc_errors += 1
            return None
        return self._finish(can_id, ident, tid, bytes(rx.buf[:-2]), now)

    def _finish(
        self, can_id: int, ident: CanId, tid: int, payload: bytes, now: float
    ) -> Transfer | None:
        done = self._done.get(can_id)
        check = crc16(payload)
        if (
            ident.format == FORMAT_1
            and done is not None
            and done[0] == tid
            and done[2] == check
            and now - done[1] < self.tid_timeout
        ):
            self.stats.duplicate_transfers += 1
            return None
        if len(payload) > self.max_transfer:
            self.stats.oversize += 1
            return None
        chained: tuple[bytes, ...] = ()
        if ident.chain:
            chained = chain_datagrams(ident, tid, payload)
            if not chained:
                self.stats.malformed += 1
                return None
        if can_id not in self._done and len(self._done) >= 4 * self.max_pending:
            self._done.pop(next(iter(self._done)))
        self._done[can_id] = (tid, now, check)
        self.stats.transfers += 1
        if ident.format == FORMAT_2 and ident.kind is not Kind.NODE and not ident.chain:
            payload = rebuild_datagram(ident, tid, payload)
        return Transfer(
            ident.priority,
            ident.kind,
            ident.channel,
            ident.destination,
            ident.source,
            payload,
            ident.format,
            chained,
            ident.format == FORMAT_2
            and ident.kind is Kind.NODE
            and bool(ident.seq_high << 11 & CLAIM_CHAINS),
        )

    def _evict(self) -> None:
        oldest = min(self._rx, key=lambda key: self._rx[key].started)
        del self._rx[oldest]
        self.stats.abandoned += 1

    def expire(self, now: float) -> int:
        """Drop (and count) the transfers that started ``timeout`` seconds ago or more."""
        stale = [key for key, rx in self._rx.items() if now - rx.started >= self.timeout]
        for key in stale:
            del self._rx[key]
        self.stats.timeouts += len(stale)
        return len(stale)


def rebuild_datagram(ident: CanId, tid: int, payload: bytes) -> bytes:
    """The native datagram a format-2 transfer carried: header from the id and the transfer id,
    the payload, its CRC-16 (little-endian, as PROTOCOL.md §1.4)."""
    seq = ident.seq_high << 5 | tid
    body = bytes((_NATIVE_VERSION | int(ident.kind) << 4 | ident.frag << 2, ident.channel, seq))
    body += payload
    return body + crc16(body).to_bytes(2, "little")


def chain_datagrams(ident: CanId, tid: int, message: bytes) -> tuple[bytes, ...]:
    """The native datagrams a chained transfer of ``message`` carried (CAN.md §12): FIRST (the
    4-byte length and ``size - 4`` bytes), MIDDLE (``size`` bytes each) and LAST fragments,
    numbered from the id's and the tail byte's sequence number on; empty when the message is
    too short to have been fragmented at that size."""
    size = ident.chain
    total = len(message)
    if total <= size - _LENGTH_PREFIX:
        return ()
    seq = ident.seq_high << 5 | tid
    head = total.to_bytes(_LENGTH_PREFIX, "little") + message[: size - _LENGTH_PREFIX]
    chunks = [(1, head)]
    offset = size - _LENGTH_PREFIX
    while offset < total:
        chunks.append((3 if total - offset <= size else 2, message[offset : offset + size]))
        offset += size
    out = []
    for index, (frag, chunk) in enumerate(chunks):
        number = (seq + index) & 0xFF
        fragment = CanId(
            ident.priority, ident.kind, ident.channel, 0, 0, FORMAT_2, number >> 5, frag
        )
        out.append(rebuild_datagram(fragment, number & _TID_MASK, chunk))
    return tuple(out)


class ConflictMonitor:
    """Notices one node id claimed by two unique ids within ``window`` seconds."""

    def __init__(self, window: float = 3.0) -> None:
        self.window = window
        self.conflicts = 0
        """Claims that contradicted the one before them."""
        self._claims: dict[int, tuple[bytes, float]] = {}
        self._conflicted: dict[int, float] = {}

    def claim(self, node: int, uid: bytes, now: float) -> bool:
        """Record a claim; True if it conflicts with another unique id's recent claim."""
        before = self._claims.get(node)
        self._claims[node] = (uid, now)
        if before is not None and before[0] != uid and now - before[1] < self.window:
            self.conflicts += 1
            self._conflicted[node] = now
            return True
        return False

    def in_conflict(self, node: int, now: float) -> bool:
        """True while a conflict on ``node`` was seen in the last ``window`` seconds."""
        seen = self._conflicted.get(node)
        return seen is not None and now - seen < self.window

    def claimed(self, now: float) -> Iterator[tuple[int, bytes]]:
        """Nodes with a claim in the last ``window`` seconds, and their unique ids."""
        for node, (uid, seen) in sorted(self._claims.items()):
            if now - seen < self.window:
                yield node, uid


def _rebuilt(flags: int, channel: int, seq: int, payload: bytes) -> bytes:
    """A native datagram: header, payload and its CRC-16."""
    body = bytes((flags, channel, seq)) + payload
    return body + crc16(body).to_bytes(2, "little")
