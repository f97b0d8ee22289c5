"""The 29-bit ids of the native protocol's CAN transport (CAN.md): their three formats, the
node ids and priorities, and the kind of transfer a native datagram makes. The layouts are in
:mod:`~hwbridge.protocols.can.transport`'s docstring; that module builds transfers on these ids and
re-exports every name here.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Final

__all__ = [
    "CLAIM_CHAINS",
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
    "UID_SIZE",
    "CanId",
    "Kind",
    "acceptance_filters",
    "chain_size_code",
    "decode_id",
    "encode_chain_id",
    "encode_id",
    "encode_id2",
    "kind_of",
    "priority_of",
    "queue_class",
]

HOST_NODE: Final = 0
"""The host's node id (boards use 1..127)."""
MIN_NODE: Final = 1
MAX_NODE: Final = 127

UID_SIZE: Final = 6
"""Bytes of the unique id a node claims its node id with."""
NODE_CLAIM: Final = 1
"""Channel (opcode) of a node-id claim in a NODE-kind transfer."""

PRIORITY_ACK: Final = 1
PRIORITY_CONTROL: Final = 2
PRIORITY_NODE: Final = 3
PRIORITY_RELIABLE: Final = 4
PRIORITY_BEST_EFFORT: Final = 5

_RESERVED_MASK: Final = 0x3 << 14
_FORMAT_2_BIT: Final = 1 << 15
_TO_HOST_BIT: Final = 1 << 14
_CHAIN_BIT: Final = 1 << 7
_CHAIN_RESERVED: Final = 1 << 8
CLAIM_CHAINS: Final = 1 << 11
"""Bit 11 of a format-2 claim's id: the claiming node takes chained transfers (CAN.md §12)."""

_CHAIN_MIN_SIZE: Final = 32


FORMAT_1: Final = 1
"""CAN.md version 1: every transfer carries the whole native datagram (header and CRC-16)."""
FORMAT_2: Final = 2
"""CAN.md version 2: the native header in the id and the tail byte, no native CRC-16."""


class Kind(enum.IntEnum):
    """What a transfer carries: a native frame of one of the three types, or a NODE message."""

    BEST_EFFORT = 0
    RELIABLE = 1
    ACK = 2
    NODE = 3


@dataclass(frozen=True, slots=True)
class CanId:
    """The fields of a 29-bit id (``seq_high`` and ``frag`` only in format 2)."""

    priority: int
    kind: Kind
    channel: int
    destination: int
    source: int
    format: int = FORMAT_1
    seq_high: int = 0
    """Format 2: bits 7..5 of the native sequence number (its bits 4..0 are the transfer id)."""
    frag: int = 0
    """Format 2: the native fragment position (0 WHOLE, 1 FIRST, 2 MIDDLE, 3 LAST)."""
    chain: int = 0
    """Format 2: the fragment size of a chained transfer (0: not chained, CAN.md §12)."""

    def encode(self) -> int:
        if self.format == FORMAT_2 and self.chain:
            return encode_chain_id(
                self.priority,
                self.kind,
                self.channel,
                self.destination,
                self.source,
                self.seq_high << 5,
                self.chain,
            )
        if self.format == FORMAT_2:
            return encode_id2(
                self.priority,
                self.kind,
                self.channel,
                self.destination,
                self.source,
                self.seq_high << 5,
                self.frag,
            )
        return encode_id(self.priority, self.kind, self.channel, self.destination, self.source)


def encode_id(priority: int, kind: int, channel: int, destination: int, source: int) -> int:
    """The 29-bit id of these fields (ValueError for a field out of range)."""
    if not 0 <= priority <= 7:
        raise ValueError(f"priority must be 0..7, not {priority}")
    if not 0 <= kind <= 3:
        raise ValueError(f"kind must be 0..3, not {kind}")
    if not 0 <= channel <= 255:
        raise ValueError(f"channel must be 0..255, not {channel}")
    for what, node in (("destination", destination), ("source", source)):
        if not 0 <= node <= MAX_NODE:
            raise ValueError(f"{what} node id must be 0..{MAX_NODE}, not {node}")
    return priority << 26 | kind << 24 | channel << 16 | destination << 7 | source


def encode_id2(
    priority: int,
    kind: int,
    channel: int,
    destination: int,
    source: int,
    seq: int = 0,
    frag: int = 0,
) -> int:
    """The format-2 id of these fields (``seq``: the whole native sequence number, of which the
    id keeps bits 7..5). One end MUST be the host (node 0): format 2 has no board-to-board
    transfers. ValueError for a field out of range."""
    base = encode_id(priority, kind, channel, destination, source)
    if not 0 <= seq <= 255:
        raise ValueError(f"seq must be 0..255, not {seq}")
    if not 0 <= frag <= 3:
        raise ValueError(f"frag must be 0..3, not {frag}")
    if source == HOST_NODE:
        direction, node = 0, destination
    elif destination == HOST_NODE:
        direction, node = _TO_HOST_BIT, source
    else:
        raise ValueError(f"format 2 goes to or from the host, not from {source} to {destination}")
    return (base & ~0xFFFF) | _FORMAT_2_BIT | direction | (seq >> 5) << 11 | frag << 9 | node


def chain_size_code(size: int) -> int | None:
    """The id's code of a chain's fragment size (``size == 32 << code``), None when ``size`` is
    not a power of two from 32 to 4096 (such fragments are not chained)."""
    if size < _CHAIN_MIN_SIZE or size & (size - 1) or size > _CHAIN_MIN_SIZE << 7:
        return None
    return size.bit_length() - _CHAIN_MIN_SIZE.bit_length()


def encode_chain_id(
    priority: int,
    kind: int,
    channel: int,
    destination: int,
    source: int,
    seq: int,
    size: int,
) -> int:
    """The id of a chained transfer (CAN.md §12): format 2 with bit 7 set, bits 10..8 the code
    of the fragment size ``size``, ``seq`` the FIRST fragment's sequence number."""
    code = chain_size_code(size)
    if code is None:
        raise ValueError(f"a chain's fragment size is a power of two 32..4096, not {size}")
    base = encode_id2(priority, kind, channel, destination, source, seq, 0)
    return base | code << 8 | _CHAIN_BIT


def acceptance_filters(node: int) -> list[tuple[int, int]]:
    """What node ``node`` needs to receive, as (id, mask) pairs of 29-bit ids (a frame is
    wanted when ``frame_id & mask == id & mask`` for one pair): transfers addressed to it in
    either format, and NODE messages (claims) from anyone. A controller's acceptance filters, or
    python-can's ``can_filters``, set from these keep other nodes' traffic out (the MCP2515
    driver sets its own, CAN.md §11)."""
    if not 0 <= node <= MAX_NODE:
        raise ValueError(f"node id must be 0..{MAX_NODE}, not {node}")
    if node == HOST_NODE:
        format_2 = (_FORMAT_2_BIT | _TO_HOST_BIT, _FORMAT_2_BIT | _TO_HOST_BIT)
    else:
        format_2 = (_FORMAT_2_BIT | node, _FORMAT_2_BIT | _TO_HOST_BIT | MAX_NODE)
    return [
        (node << 7, MAX_NODE << 7 | _RESERVED_MASK),
        format_2,
        (int(Kind.NODE) << 24, 3 << 24),
    ]


def decode_id(can_id: int) -> CanId | None:
    """The fields of a 29-bit id of either format, or None when it is not one of ours (reserved
    bits set, or a format-2 id from the host to the host or from board 0). A chained id (bit 7)
    decodes with ``frag`` FIRST and ``chain`` its fragment size."""
    if not 0 <= can_id < 1 << 29:
        return None
    if can_id & _FORMAT_2_BIT:
        node = can_id & 0x7F
        to_host = bool(can_id & _TO_HOST_BIT)
        if to_host and node == HOST_NODE:
            return None
        chained = bool(can_id & _CHAIN_BIT)
        if not chained and can_id & _CHAIN_RESERVED:
            return None
        return CanId(
            can_id >> 26,
            Kind((can_id >> 24) & 3),
            (can_id >> 16) & 0xFF,
            HOST_NODE if to_host else node,
            node if to_host else HOST_NODE,
            FORMAT_2,
            (can_id >> 11) & 7,
            1 if chained else (can_id >> 9) & 3,
            _CHAIN_MIN_SIZE << ((can_id >> 8) & 7) if chained else 0,
        )
    if can_id & _RESERVED_MASK:
        return None
    return CanId(
        can_id >> 26,
        Kind((can_id >> 24) & 3),
        (can_id >> 16) & 0xFF,
        (can_id >> 7) & 0x7F,
        can_id & 0x7F,
    )


def kind_of(datagram: bytes | bytearray | memoryview) -> tuple[Kind, int]:
    """The kind and channel of a native datagram (from its flags and channel bytes)."""
    if len(datagram) < 2:
        return Kind.BEST_EFFORT, 0
    frame_type = (datagram[0] >> 4) & 3
    kind = Kind(frame_type) if frame_type < 3 else Kind.BEST_EFFORT
    return kind, datagram[1]


def priority_of(kind: Kind, channel: int) -> int:
    """The priority a native datagram of this kind on this channel is sent with."""
    if kind is Kind.ACK:
        return PRIORITY_ACK
    if kind is Kind.NODE:
        return PRIORITY_NODE
    if channel == 0:
        return PRIORITY_CONTROL
    return PRIORITY_RELIABLE if kind is Kind.RELIABLE else PRIORITY_BEST_EFFORT


def queue_class(kind: Kind) -> int:
    """A sender's queue order for a transfer of ``kind`` (CAN.md §3): ACKs, NODE messages, then
    the reliable and the best-effort streams, each kept in its own order whatever the priorities
    of its ids (a control datagram must not overtake the data queued before it on its stream)."""
    if kind is Kind.ACK:
        return PRIORITY_ACK
    if kind is Kind.NODE:
        return PRIORITY_NODE
    return PRIORITY_RELIABLE if kind is Kind.RELIABLE else PRIORITY_BEST_EFFORT
