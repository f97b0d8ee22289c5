"""A native board on a datagram link (UDP): one frame per datagram, no COBS, no detection probe.

The board is a real device session with the native datagram framing on a real UDP socket; the
bridge listens on ``udp-listen://`` and learns the board's address from its first datagram.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import Any

import pytest

from hwbridge import msg
from hwbridge.bridge import BoardSpec, Bridge
from hwbridge.graph import Graph
from hwbridge.links import Link, open_link
from hwbridge.protocols import base
from hwbridge.protocols.native import session as ns
from hwbridge.protocols.native.framing import BadFrame, Frame, NativeDatagramFraming
from hwbridge.pump import SessionPump
from tests.boards import native_chatter, native_sketch
from tests.netutil import free_port, wait_until


class SpyLink:
    """Forwards to a link and keeps every datagram the board wrote."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self.written: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.written.append(bytes(data))
        self.link.write(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.link, name)


@pytest.fixture
def udp_board() -> Iterator[tuple[Bridge, Graph, SessionPump, SpyLink, list[Any]]]:
    port = free_port()
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="datagram")
    bridge = Bridge(graph)
    sketch = native_sketch("esp")
    device = ns.DeviceSession(
        sketch.board, list(sketch.topics.values()), framing=NativeDatagramFraming()
    )
    link = SpyLink(open_link(f"udp://127.0.0.1:{port}"))
    events: list[Any] = []
    pump = SessionPump(link, device, events.append, name="udp-board")  # type: ignore[arg-type]
    stop = threading.Event()
    chatter = native_chatter([0])

    def publish() -> None:
        while not stop.wait(0.02):
            if device.connected:
                pump.call(chatter)

    publisher = threading.Thread(target=publish, daemon=True)
    try:
        bridge.add_board(BoardSpec(f"udp-listen://127.0.0.1:{port}", namespace="/udp", name="esp"))
        pump.start()
        publisher.start()
        yield bridge, graph, pump, link, events
    finally:
        stop.set()
        bridge.stop()
        graph.close()
        pump.stop()
        link.close()


def test_a_native_board_over_udp_reaches_the_graph_both_ways(
    udp_board: tuple[Bridge, Graph, SessionPump, SpyLink, list[Any]],
) -> None:
    bridge, graph, pump, link, events = udp_board
    heard: list[str] = []
    node = graph.node("listener")
    node.subscriber("/udp/chatter", "std_msgs/String", lambda m: heard.append(m.data))
    board = bridge.boards["esp"]
    assert wait_until(lambda: len(heard) >= 3), board.info()
    assert heard[-1].startswith("hello ")

    led = node.publisher("/udp/led", "std_msgs/Bool")
    delivered = lambda: [e for e in events if isinstance(e, base.Message) and e.channel == 2]  # noqa: E731
    assert wait_until(lambda: led.publish({"data": True}) or bool(delivered()))
    assert msg.decode(delivered()[0].payload, "std_msgs/Bool").data is True

    info = board.info()
    assert info["protocol"] == "native"  # auto on a datagram link
    assert info["stats"]["bad_frames"] == 0
    assert info["stats"]["non_frame_bytes"] == 0
    # Nothing but frames reached the board: no detection probe was written to it.
    device = pump.session
    assert isinstance(device, ns.DeviceSession)
    assert device.counters().bad_frames == 0
    # Every datagram is one bare frame: it parses whole, with no COBS and no 0x00 delimiter.
    framing = NativeDatagramFraming()
    assert len(link.written) > 5
    for datagram in link.written:
        (frame,) = framing.decode(datagram)
        assert isinstance(frame, Frame) and not isinstance(frame, BadFrame), frame


def test_a_listening_udp_link_keeps_to_one_board_until_it_falls_silent(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Two senders on one ``udp-listen://`` port: the first heard is the board; the other's
    datagrams are dropped and counted while the board is heard, and it is taken once the board
    has been silent for PEER_HOLD (a board that rebooted onto a new port)."""
    import socket

    from hwbridge.links import udp

    monkeypatch.setattr(udp, "PEER_HOLD", 0.3)
    port = free_port()
    link = open_link(f"udp-listen://127.0.0.1:{port}")
    first = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    second = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        first.bind(("127.0.0.1", 0))
        second.bind(("127.0.0.1", 0))
        first.sendto(b"one", ("127.0.0.1", port))
        assert link.read(100, 5.0) == b"one"
        second.sendto(b"two", ("127.0.0.1", port))
        first.sendto(b"three", ("127.0.0.1", port))
        assert link.read(100, 5.0) == b"three"  # "two" was dropped
        assert link.transport_stats()["udp"] == {
            "board": f"127.0.0.1:{first.getsockname()[1]}",
            "foreign_datagrams": 1,
        }
        link.write(b"to the board")
        assert first.recv(100) == b"to the board"

        # the board falls silent: after PEER_HOLD the other sender is the board
        def taken() -> bool:
            second.sendto(b"four", ("127.0.0.1", port))
            return link.read(100, 0.05) == b"four"

        assert wait_until(taken, 10.0, 0.05)
        link.write(b"to the new board")
        second.settimeout(5.0)
        assert second.recv(100) == b"to the new board"
    finally:
        first.close()
        second.close()
        link.close()
