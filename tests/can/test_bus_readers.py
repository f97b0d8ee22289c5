"""The two ways frames reach many boards cheaply: the emulator's multicast gateway (one socket
for all its boards, its own echoes dropped) and the bridge's bulk SLCAN reader (replies split
or joined any way across reads come out as python-can's byte-at-a-time reader gives them)."""

from __future__ import annotations

import random
import time
from typing import Any

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge.emulator.multicast import MulticastGateway
from hwbridge.emulator.virtual_bus import shared_virtual_bus
from hwbridge.links.slcan import _take_line
from tests.netutil import free_port


def _frames(bus: Any, seconds: float, until: int | None = None) -> list[can.Message]:
    got: list[can.Message] = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and (until is None or len(got) < until):
        message = bus.recv(0.05)
        if message is not None:
            got.append(message)
    return got


def test_the_multicast_gateway_carries_frames_both_ways_once() -> None:
    group = f"239.74.{random.randrange(1, 250)}.{random.randrange(1, 250)}"
    port = free_port()
    local = f"gw-{random.getrandbits(32):x}"
    host = can.Bus(interface="udp_multicast", channel=group, port=port)
    with MulticastGateway(local, group, port, fd=False) as gateway:
        board_a = shared_virtual_bus(local)
        board_b = shared_virtual_bus(local)
        try:
            # a frame from the group reaches each board once
            host.send(can.Message(arbitration_id=0x1400007F, data=b"\x01\x02"))
            for board in (board_a, board_b):
                (got,) = _frames(board, 10, until=1)
                assert (got.arbitration_id, bytes(got.data)) == (0x1400007F, b"\x01\x02")
            # a board's frame reaches the group once (the host's socket gets its own frame back
            # too: the group echoes to every member) and the other board once; its echo from
            # the group is not handed back to the boards
            for n in range(20):
                board_a.send(can.Message(arbitration_id=0x10000003, data=bytes([n])))
            from_group = [m for m in _frames(host, 10, until=21) if m.arbitration_id == 0x10000003]
            assert [bytes(m.data) for m in from_group] == [bytes([n]) for n in range(20)]
            assert [bytes(m.data) for m in _frames(board_b, 10, until=20)] == [
                bytes([n]) for n in range(20)
            ]
            deadline = time.monotonic() + 10
            while gateway.echoes < 20 and time.monotonic() < deadline:
                time.sleep(0.02)
            assert gateway.echoes == 20 and gateway.frames_out == 20
            assert _frames(board_a, 0.5) == []  # nothing echoed, nothing from itself
            assert [m.arbitration_id for m in _frames(board_b, 0.5)] == []
            assert gateway.frames_in == 1
        finally:
            board_a.shutdown()
            board_b.shutdown()
            host.shutdown()


_reply = st.one_of(
    st.builds(lambda body: f"T{body}\r", st.text("0123456789ABCDEF", max_size=24)),
    st.just("\r"),
    st.just("\a"),
    st.builds(lambda v: f"V{v}\r", st.text("0123456789", min_size=4, max_size=4)),
)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.lists(_reply, max_size=20), st.lists(st.integers(1, 40), max_size=40))
def test_replies_split_or_joined_across_reads_come_out_whole(
    replies: list[str], cuts: list[int]
) -> None:
    stream = "".join(replies).encode()
    buffer = bytearray()
    out: list[str] = []
    position = 0
    for size in [*cuts, len(stream)]:
        buffer.extend(stream[position : position + size])
        position += size
        while (line := _take_line(buffer)) is not None:
            out.append(line)
    assert out == replies and not buffer


@pytest.mark.parametrize("tail", ["", "T123"])
def test_an_unfinished_reply_waits_for_its_end(tail: str) -> None:
    buffer = bytearray(f"T1\r{tail}".encode())
    assert _take_line(buffer) == "T1\r"
    assert _take_line(buffer) is None and buffer == tail.encode()
