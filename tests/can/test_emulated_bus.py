"""The emulated boards' side of a python-can virtual bus: acceptance filters as a board's
controller sets them, and frames copied once for every receiver."""

from __future__ import annotations

import itertools

import can
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge.emulator.virtual_bus import shared_virtual_bus
from hwbridge.protocols.can.transport import (
    MAX_NODE,
    MIN_NODE,
    Kind,
    acceptance_filters,
    encode_id,
)

_channels = itertools.count()


def _wanted(node: int, can_id: int) -> bool:
    return any((can_id ^ value) & mask == 0 for value, mask in acceptance_filters(node))


@settings(max_examples=300, derandomize=True)
@given(
    node=st.integers(MIN_NODE, MAX_NODE),
    priority=st.integers(0, 7),
    kind=st.sampled_from(list(Kind)),
    channel=st.integers(0, 255),
    destination=st.integers(0, MAX_NODE),
    source=st.integers(0, MAX_NODE),
)
def test_a_board_takes_its_own_transfers_and_every_claim(
    node: int, priority: int, kind: Kind, channel: int, destination: int, source: int
) -> None:
    can_id = encode_id(priority, kind, channel, destination, source)
    assert _wanted(node, can_id) == (destination == node or kind is Kind.NODE)


def test_shared_copies_reach_plain_buses_and_filtered_boards() -> None:
    channel = f"emulated{next(_channels)}"
    host = can.Bus(interface="virtual", channel=channel)  # python-can's own, unfiltered
    board3 = shared_virtual_bus(channel)
    board4 = shared_virtual_bus(channel)
    for bus, node in ((board3, 3), (board4, 4)):
        bus.set_filters(
            [{"can_id": i, "can_mask": m, "extended": True} for i, m in acceptance_filters(node)]
        )
    try:
        to_host = encode_id(5, Kind.BEST_EFFORT, 1, 0, 3)
        board3.send(can.Message(arbitration_id=to_host, data=b"\x01\x02", is_extended_id=True))
        received = host.recv(5)
        assert received is not None and received.arbitration_id == to_host
        assert bytes(received.data) == b"\x01\x02" and received.is_rx
        assert board4.recv(0.2) is None  # board 4's controller keeps board 3's data out

        to_board4 = encode_id(4, Kind.RELIABLE, 2, 4, 0)
        host.send(can.Message(arbitration_id=to_board4, data=b"\x07", is_extended_id=True))
        got = board4.recv(5)
        assert got is not None and got.arbitration_id == to_board4
        assert board3.recv(0.2) is None

        claim = encode_id(3, Kind.NODE, 1, 0, 4)
        board4.send(can.Message(arbitration_id=claim, data=bytes(8), is_extended_id=True))
        for bus in (host, board3):
            seen = bus.recv(5)
            assert seen is not None and seen.arbitration_id == claim
    finally:
        for bus in (host, board3, board4):
            bus.shutdown()
