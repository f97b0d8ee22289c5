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
from hwbridge.protocols.can.transport import Kind, TransferEncoder, crc16, decode_id, encode_id

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


def _formats_on_bus(raw: can.BusABC, seconds: float = 0.3) -> dict[int, set[int]]:
    """The formats (1 or 2, from id bit 15) of the datagrams each source node id sent while
    ``seconds`` pass (claims left out: an end claims in its own format)."""
    seen: dict[int, set[int]] = {}
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        message = raw.recv(left)
        if message is None:
            break
        ident = decode_id(message.arbitration_id)
        if ident is not None and ident.kind is not Kind.NODE:
            seen.setdefault(ident.source, set()).add(ident.format)
    return seen


@pytest.mark.parametrize("old", ["board", "host"])
def test_version_1_and_version_2_ends_interoperate(
    channel: str, opened: list[CanLink], old: str, caplog: pytest.LogCaptureFixture
) -> None:
    """A CAN.md version-1 end (``can_format=1``: format 1 only, format 2 malformed) and a
    version-2 end: the version-2 end hears the other's claims and speaks format 1 to it, so
    datagrams flow both ways, and nothing but format 1 is on the bus once it has."""
    host_q, board_q = ("?can_format=1", "") if old == "host" else ("", "&can_format=1")
    host = _open(opened, f"can://virtual/{channel}/node4{host_q}")
    board = _open(opened, f"can://virtual/{channel}?node=0&local=4{board_q}")
    new = board if old == "host" else host
    peer = 0 if old == "host" else 4
    hub = new.hub
    assert hub is not None
    assert wait_for(lambda: hub.peer_formats.get(peer) == 1, 10), hub.peer_formats
    raw = can.Bus(interface="virtual", channel=channel)
    try:
        for size in (0, 4, 9, 200):
            data = _datagram(4, size, reliable=True, seq=size)
            host.write(data)
            assert board.read(4096, 5.0) == data
            board.write(data)
            assert host.read(4096, 5.0) == data
        seen = _formats_on_bus(raw)
    finally:
        raw.shutdown()
    assert seen.get(peer) == {1} and seen.get(4 - peer) == {1}, seen
    stats = new.can_stats()
    assert stats["format_changes"] == 1 and stats["peer_formats"] == {peer: 1}
    if old == "board":
        assert "node 4 claims in CAN.md format 1 (older firmware)" in caplog.text


def test_a_version_1_end_drops_format_2_as_malformed(channel: str, opened: list[CanLink]) -> None:
    """What a node that predates format 2 does with it (and why the format-2 end must hear its
    claims first): format-2 frames are malformed, nothing is delivered."""
    old = _open(opened, f"can://virtual/{channel}/node4?can_format=1")
    raw = can.Bus(interface="virtual", channel=channel)
    try:
        body = bytes([0x40, 1, 7, 0xAA])
        for can_id, data in TransferEncoder(4).datagram(
            body + crc16(body).to_bytes(2, "little"), 0
        ):
            raw.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=True))
        assert wait_for(lambda: old.can_stats()["rx_malformed"] >= 1, 5)
        assert old.read(4096, 0.3) == b""
    finally:
        raw.shutdown()
