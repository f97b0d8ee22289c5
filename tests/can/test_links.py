"""can:// links on python-can's virtual bus and the emulated SLCAN adapter: URLs, datagrams both
ways (classic and FD), one shared bus per process, and bad traffic, error frames, bus-off and a
failed adapter dropped or reported and counted without hurting the other boards."""

from __future__ import annotations

import itertools
import os
import select
import time
from collections.abc import Callable, Iterator

import can
import pytest

from hwbridge.emulator.can_bus import FaultyBus
from hwbridge.emulator.slcan import SlcanAdapter
from hwbridge.errors import LinkError
from hwbridge.links import LinkClosedError, create_link
from hwbridge.links.can import CanLink, frame_bits
from hwbridge.protocols.can.transport import Kind, crc16, encode_id

_names = itertools.count()


def wait_for(condition: Callable[[], object], timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return bool(condition())


def _ask(port: int, line: str, answered: Callable[[bytes], bool] | None = None) -> bytes:
    """Send one SLCAN command line to an adapter's serial port; what it answers, read until
    ``answered`` says it is all there (by default: up to a CR, or a BEL for a refusal)."""
    os.write(port, line.encode("ascii") + b"\r")
    answer = b""
    while not (answered or _ends_a_line)(answer):
        ready, _, _ = select.select([port], [], [], 5.0)
        assert ready, f"no answer to {line!r} (so far {answer!r})"
        answer += os.read(port, 256)
    return answer


def _ends_a_line(answer: bytes) -> bool:
    return answer.endswith((b"\r", b"\a"))


@pytest.fixture
def channel() -> str:
    return f"links{next(_names)}"


@pytest.fixture
def opened() -> Iterator[list[CanLink]]:
    links: list[CanLink] = []
    yield links
    for link in links:
        link.close()


def _open(links: list[CanLink], url: str, **kwargs: object) -> CanLink:
    link = CanLink(url, **kwargs)
    link.open()
    links.append(link)
    return link


def _datagram(channel: int, size: int, reliable: bool = False, seq: int = 0) -> bytes:
    """A native datagram (header, payload, CRC-16): format 2 sends only valid ones."""
    flags = 0x50 if reliable else 0x40
    body = bytes([flags, channel, seq]) + bytes((i * 7) & 0xFF for i in range(size))
    return body + crc16(body).to_bytes(2, "little")


def test_urls() -> None:
    link = create_link("can://virtual/bench/node3")
    assert isinstance(link, CanLink)
    assert (link.interface, link.channel, link.node, link.local) == ("virtual", "bench", 3, 0)
    slcan = CanLink("can://slcan/dev/ttyACM0/node12?bitrate=1000000&sleep_after_open=0")
    assert (slcan.channel, slcan.node) == ("/dev/ttyACM0", 12)
    assert CanLink("can://slcan/COM3?node=2").channel == "COM3"
    fd = CanLink("can://socketcan/can0?node=127&fd=1")
    assert (fd.channel, fd.node, fd.fd) == ("can0", 127, True)
    board_side = CanLink("can://virtual/bench?node=0&local=9")
    assert (board_side.node, board_side.local) == (0, 9)
    group = CanLink("can://udp_multicast/239.74.163.2/node1?port=43200")
    assert group.channel == "239.74.163.2"


@pytest.mark.parametrize(
    ("url", "words"),
    [
        ("can://virtual/bench", "node id"),
        ("can://virtual/bench/node0", "1..127"),
        ("can://virtual/bench/node128", "1..127"),
        ("can://virtual/bench/node1?nod=2", "did you mean 'node'"),
        ("can://virtual/node1", "channel"),
        ("can:///bench/node1", "interface"),
        ("can://virtual/bench/node1?fd=maybe", "fd"),
        ("can://virtual/bench?node=4&local=4", "own"),
        ("can://virtual/bench/node1?pace=-5", "pace"),
        ("can://virtual/bench/node1?transfer_timeout=0", "transfer_timeout"),
    ],
)
def test_bad_urls(url: str, words: str) -> None:
    with pytest.raises(LinkError, match=words):
        create_link(url)


@pytest.mark.parametrize("fd", [False, True])
def test_datagrams_both_ways_on_one_shared_bus(
    channel: str, opened: list[CanLink], fd: bool
) -> None:
    query = f"?fd={int(fd)}"
    hosts = [_open(opened, f"can://virtual/{channel}/node{n}{query}") for n in (1, 2)]
    boards = [_open(opened, f"can://virtual/{channel}{query}&node=0&local={n}") for n in (1, 2)]
    assert hosts[0].hub is hosts[1].hub  # one python-can bus for the host's links
    for size in (0, 4, 5, 60, 61, 300, 1024):
        for host, board in zip(hosts, boards, strict=True):
            data = _datagram(board.local, size, reliable=size % 2 == 0)
            host.write(data)
            assert board.read(4096, 5.0) == data
            back = _datagram(board.local, size, reliable=size % 2 == 1, seq=size & 0xFF)
            board.write(back)
            assert host.read(4096, 5.0) == back
    stats = hosts[0].can_stats()
    assert stats["rx_crc_errors"] == stats["rx_malformed"] == stats["rx_unexpected"] == 0
    assert set(stats["claims"]) >= {1, 2}
    with pytest.raises(LinkError, match="already open"):
        _open(opened, f"can://virtual/{channel}/node1{query}")


def test_bad_frames_are_counted_and_other_traffic_flows(
    channel: str, opened: list[CanLink]
) -> None:
    host = _open(opened, f"can://virtual/{channel}/node5")
    board = _open(opened, f"can://virtual/{channel}?node=0&local=5")
    raw = can.Bus(interface="virtual", channel=channel)
    try:
        to_host = encode_id(5, Kind.BEST_EFFORT, 1, 0, 6)
        bad = [
            can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\xe0"),  # 11-bit id
            can.Message(arbitration_id=to_host | 1 << 14, data=b"\xe0"),  # reserved bits
            can.Message(arbitration_id=to_host, data=b""),  # no tail byte
            can.Message(arbitration_id=to_host, data=b"\x01\x02\x00"),  # middle, never started
            can.Message(arbitration_id=to_host, data=bytes(7) + b"\xa1"),  # never ends
            can.Message(arbitration_id=to_host, data=b"\x00\x42"),  # wrong transfer id
            can.Message(is_error_frame=True, arbitration_id=0),
            can.Message(arbitration_id=to_host, is_remote_frame=True, dlc=1),
        ]
        for message in bad:
            message.is_extended_id = message.arbitration_id > 0x7FF
            raw.send(message)
        data = _datagram(1, 100)
        board.write(data)
        assert host.read(4096, 5.0) == data
        assert wait_for(lambda: host.can_stats()["rx_timeouts"] >= 1, 5)
        stats = host.can_stats()
        assert stats["rx_malformed"] >= 4
        assert stats["rx_unexpected"] >= 2
        assert stats["error_frames"] == 1
        assert stats["rx_transfers"] >= 1
    finally:
        raw.shutdown()


def test_bus_off_and_recovery(channel: str, opened: list[CanLink]) -> None:
    faulty = FaultyBus(can.Bus(interface="virtual", channel=channel))
    try:
        host = _open(opened, "can://faulty/bus/node3", bus=faulty)
        board = _open(opened, f"can://virtual/{channel}?node=0&local=3")
        faulty.bus_off(0.5)
        for _ in range(5):
            host.write(_datagram(1, 10))  # queued; the controller refuses them
        assert wait_for(lambda: host.can_stats()["bus_off"] == 1, 5)
        assert host.can_stats()["sending"] is False
        time.sleep(0.6)
        data = _datagram(2, 30)
        deadline = time.monotonic() + 5
        received = b""
        while received != data and time.monotonic() < deadline:
            host.write(data)
            received = board.read(4096, 0.2)
        assert received == data
        stats = host.can_stats()
        assert stats["send_errors"] >= 1
        assert stats["recoveries"] == 1
        assert stats["sending"] is True
    finally:
        faulty.shutdown()


def test_priority_queue_sheds_best_effort_and_keeps_control(
    channel: str, opened: list[CanLink]
) -> None:
    # 20 kbit/s: about 150 classic frames a second; the flood asks for far more.
    host = _open(opened, f"can://virtual/{channel}/node2?pace=20000&tx_queue=64")
    flood = _open(opened, f"can://virtual/{channel}/node9?pace=20000&tx_queue=64")
    board = _open(opened, f"can://virtual/{channel}?node=0&local=2")
    for _ in range(40):
        flood.write(_datagram(1, 60))  # best-effort data, 9 frames each
    control = _datagram(0, 1, reliable=True)  # a reliable control message: overtakes the flood
    host.write(control)
    started = time.monotonic()
    assert board.read(4096, 5.0) == control
    waited = time.monotonic() - started
    assert host.can_stats()["tx_dropped"] > 0
    # Behind the queued flood it would have waited for 64 frames (over 0.4 s at 20 kbit/s).
    assert waited < 64 * frame_bits(8) / 20000


def test_frame_bits() -> None:
    # Worst-case stuffed classic frame with 8 data bytes and a 29-bit id: 160 bits.
    assert frame_bits(8) == 160
    assert frame_bits(8, worst_case=False) == 131
    assert frame_bits(0, worst_case=False) == 67
    assert frame_bits(64, fd=True) > frame_bits(8)


@pytest.mark.parametrize("fd", [False, True], ids=["classic", "fd"])
def test_slcan_adapter_through_python_can(opened: list[CanLink], fd: bool) -> None:
    name = f"slcan{next(_names)}"
    with SlcanAdapter(name) as adapter:
        host = _open(
            opened,
            f"can://slcan{adapter.path}/node7?sleep_after_open=0&bitrate=500000&fd={int(fd)}",
        )
        board = _open(opened, f"can://virtual/{name}?node=0&local=7&fd={int(fd)}")
        assert wait_for(lambda: adapter.is_open, 5)
        assert adapter.bitrate == 500000
        for size in (1, 50, 400):
            data = _datagram(3, size)
            host.write(data)
            assert board.read(4096, 5.0) == data
            back = _datagram(board.local, size, reliable=size % 2 == 1, seq=size & 0xFF)
            board.write(back)
            assert host.read(4096, 5.0) == back
        assert adapter.frames_to_bus > 0
        assert adapter.frames_to_host > 0
        assert (adapter.fd_frames > 0) == fd
        host.close()
        opened.remove(host)
        assert wait_for(lambda: not adapter.is_open, 5)
        # The adapter refuses what it cannot parse and goes on, as a serial terminal sees it.
        port = os.open(adapter.path, os.O_RDWR | os.O_NOCTTY)
        try:
            # answers still on their way to the closed host's port (its 'C' was answered)
            # come first; the adapter answers in order, so they come before this one
            _ask(port, "N", lambda answer: answer.endswith(b"NHWB1\r"))
            refused = adapter.refused
            assert _ask(port, "Txyz") == b"\a"
            assert _ask(port, "T0000000191122") == b"\a"  # length 9 in a classic frame
            assert _ask(port, "V").startswith(b"V")
            assert adapter.refused == refused + 2
        finally:
            os.close(port)


def test_failed_adapter_loses_every_link(opened: list[CanLink]) -> None:
    name = f"slcan{next(_names)}"
    adapter = SlcanAdapter(name).start()
    try:
        links = [
            _open(opened, f"can://slcan{adapter.path}/node{n}?sleep_after_open=0") for n in (1, 2)
        ]
    finally:
        adapter.stop()  # the adapter is unplugged
    for link in links:
        with pytest.raises(LinkClosedError) as info:
            while True:
                link.read(4096, 0.5)
        assert not info.value.local
