"""Eight emulated boards on one CAN bus, each in a native session with the host through a
can:// link (the host's half is the runtime's own: HostSession in a SessionPump): multi-frame
Imu and Odometry intact, reliable traffic exactly once and in order under 5 % frame loss (and
duplication), services, a board that stops talking, two boards with one node id."""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import can
import pytest

from hwbridge import msg
from hwbridge.emulator.can_bus import CanBusEmulator, shared_virtual_bus
from hwbridge.links.can import CanLink
from hwbridge.protocols import base
from hwbridge.protocols.can.transport import Kind, encode_id
from hwbridge.protocols.native.spec import new_session
from hwbridge.protocols.registry import SessionContext
from hwbridge.pump import SessionPump

_names = itertools.count()


def wait_for(condition: Callable[[], object], timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.05)
    return bool(condition())


class HostSide:
    """The host's sessions with boards ``nodes`` over can:// links, recording events."""

    def __init__(self, url: str, nodes: list[int], query: str = "") -> None:
        self.events: dict[int, list[Any]] = {n: [] for n in nodes}
        self.channels: dict[int, dict[str, int]] = {n: {} for n in nodes}
        self.links: dict[int, CanLink] = {}
        self.pumps: dict[int, SessionPump] = {}
        self._lock = threading.Lock()
        for node in nodes:
            link = CanLink(f"{url}/node{node}{query}")
            link.open()
            session = new_session(
                SessionContext(
                    registry=msg.registry(), datagram=True, now=time.monotonic(), wall_offset=0.0
                )
            )
            self.links[node] = link
            self.pumps[node] = SessionPump(
                link, session, lambda e, n=node: self._on(n, e), name=f"host-{node}"
            ).start()

    def _on(self, node: int, event: Any) -> None:
        if isinstance(event, base.Connected):
            self.channels[node] = {e.name: e.channel for e in event.endpoints}
        with self._lock:
            self.events[node].append(event)

    def of(self, node: int, kind: type) -> list[Any]:
        with self._lock:
            return [e for e in self.events[node] if isinstance(e, kind)]

    def messages(self, node: int, topic: str) -> list[bytes]:
        channel = self.channels[node].get(topic)
        return [e.payload for e in self.of(node, base.Message) if e.channel == channel]

    def connected(self, node: int) -> bool:
        return self.pumps[node].call(lambda s: bool(s.connected))

    def counts(self, node: int) -> list[int]:
        return [int.from_bytes(p, "little") for p in self.messages(node, "~count")]

    def close(self) -> None:
        for node, pump in self.pumps.items():
            pump.stop()
            self.links[node].close()


@pytest.fixture
def bus() -> Iterator[tuple[str, Callable[..., CanBusEmulator]]]:
    channel = f"boards{next(_names)}"
    made: list[CanBusEmulator] = []

    def emulate(count: int = 8, **kwargs: Any) -> CanBusEmulator:
        emulator = CanBusEmulator(lambda: shared_virtual_bus(channel), count, **kwargs)
        made.append(emulator)
        return emulator.start()

    yield channel, emulate
    for emulator in made:
        emulator.stop()


@pytest.fixture
def hosts() -> Iterator[list[HostSide]]:
    made: list[HostSide] = []
    yield made
    for host in made:
        host.close()


def _call_whoami(host: HostSide, node: int) -> bytes:
    channel = host.channels[node]["~whoami"]
    request_id = host.pumps[node].call(
        lambda s: s.call_service(channel, b"", timeout=10.0, now=time.monotonic())
    )
    assert wait_for(
        lambda: any(e.request_id == request_id for e in host.of(node, base.ServiceResponse)), 15
    )
    (response,) = [e for e in host.of(node, base.ServiceResponse) if e.request_id == request_id]
    assert response.error is None, response.error
    return bytes(response.payload)


@pytest.mark.parametrize("fd", [False, True], ids=["classic", "fd"])
def test_eight_boards_topics_services_and_multi_frame_messages(
    bus: tuple[str, Callable[..., CanBusEmulator]], hosts: list[HostSide], fd: bool
) -> None:
    channel, emulate = bus
    # 4 Imu and Odometry a second per board (over 1,000 classic frames a second in all): the
    # boards' buses copy each frame once for all receivers (shared_virtual_bus says why)
    emulator = emulate(8, rate=4.0, fd=fd, mtu=200 if fd else 64)
    nodes = [b.node for b in emulator.boards]
    host = HostSide(f"can://virtual/{channel}", nodes, f"?fd={int(fd)}")
    hosts.append(host)
    assert wait_for(lambda: all(host.connected(n) for n in nodes))
    for node in nodes:
        board = emulator.board(node)
        assert wait_for(lambda n=node: host.messages(n, "~odom") and host.messages(n, "~imu"))
        odom = msg.decode(host.messages(node, "~odom")[-1], "nav_msgs/Odometry")
        assert odom.child_frame_id == f"node{node}_base"
        assert odom.pose.pose.position.y == float(node)
        imu = msg.decode(host.messages(node, "~imu")[-1], "sensor_msgs/Imu")
        assert imu.header.frame_id == f"node{node}_imu"
        assert list(imu.orientation_covariance) == [0.01 * i for i in range(9)]
        assert _call_whoami(host, node)[5:] == f"node {node}".encode()
        assert board.calls == 1
        command = host.channels[node]["~command"]
        assert host.pumps[node].call(
            lambda s, c=command, n=node: s.publish(c, n.to_bytes(4, "little"))
        )
        assert wait_for(lambda b=board, n=node: b.commands == [n])
    stats = host.links[1].can_stats()
    assert stats["rx_crc_errors"] == 0
    assert stats["rx_malformed"] == 0
    # claims are the nodes heard claiming in the last 3 s (three claim intervals): a board
    # whose claim waits for a CPU drops out for a moment (seen with both cores loaded)
    link = host.links[1]
    assert wait_for(lambda: set(link.can_stats()["claims"]) == set(nodes)), link.can_stats()


@pytest.mark.parametrize(
    ("loss", "duplicate"), [(0.05, 0.0), (0.05, 0.05)], ids=["loss", "loss+duplicates"]
)
def test_reliable_exactly_once_in_order_under_frame_loss(
    bus: tuple[str, Callable[..., CanBusEmulator]],
    hosts: list[HostSide],
    loss: float,
    duplicate: float,
) -> None:
    channel, emulate = bus
    emulator = emulate(8, rate=10.0, sensor_rate=0.5, mtu=32)
    nodes = [b.node for b in emulator.boards]
    host = HostSide(f"can://virtual/{channel}", nodes)
    hosts.append(host)
    assert wait_for(lambda: all(host.connected(n) for n in nodes))
    emulator.set_faults(loss=loss, duplicate=duplicate)
    sent = 30
    for value in range(sent):
        for node in nodes:
            command = host.channels[node]["~command"]
            assert host.pumps[node].call(
                lambda s, c=command, v=value: s.publish(c, v.to_bytes(4, "little"))
            )
        time.sleep(0.02)
    for node in nodes:
        board = emulator.board(node)
        assert wait_for(lambda b=board: len(b.commands) >= sent, 60), (node, board.commands)
        assert board.commands == list(range(sent))  # host -> board: each once, in order
        # board -> host: the reliable counter, consecutive from the first one received
        assert wait_for(lambda n=node: len(host.counts(n)) >= 40, 60)
        counts = host.counts(node)
        assert counts == list(range(counts[0], counts[0] + len(counts))), (node, counts)
    lost = sum(b.bus.lost for b in emulator.boards if b.bus is not None)
    assert lost > 100  # the faults really were there
    stats = host.links[1].can_stats()
    assert stats["rx_crc_errors"] + stats["rx_unexpected"] + stats["rx_timeouts"] > 0
    if duplicate:
        assert stats["rx_duplicate_frames"] + stats["rx_duplicate_transfers"] > 0


def test_board_that_stops_talking_and_comes_back(
    bus: tuple[str, Callable[..., CanBusEmulator]], hosts: list[HostSide]
) -> None:
    channel, emulate = bus
    emulator = emulate(3, rate=10.0, sensor_rate=1.0)
    host = HostSide(f"can://virtual/{channel}", [1, 2, 3])
    hosts.append(host)
    assert wait_for(lambda: all(host.connected(n) for n in (1, 2, 3)))
    silent = emulator.board(2)
    assert silent.bus is not None
    silent.bus.silence(2.0)
    assert wait_for(lambda: host.of(2, base.Disconnected), 10)  # the link timeout noticed
    before = {n: len(host.counts(n)) for n in (1, 3)}
    assert wait_for(lambda: all(len(host.counts(n)) > before[n] for n in (1, 3)), 10)
    assert wait_for(lambda: host.connected(2), 20)  # and it came back
    assert len(host.of(2, base.Connected)) >= 2


def test_two_boards_with_one_node_id(
    bus: tuple[str, Callable[..., CanBusEmulator]], hosts: list[HostSide]
) -> None:
    channel, emulate = bus
    emulate(2, first=4)
    emulate(1, first=4, seed=100)  # a second board configured as node 4
    host = HostSide(f"can://virtual/{channel}", [4, 5])
    hosts.append(host)
    assert wait_for(lambda: host.links[5].can_stats()["node_conflicts"] > 0, 10)
    stats = host.links[5].can_stats()
    assert wait_for(lambda: host.connected(5), 10)  # the other board is unaffected
    assert stats["node_conflicts"] >= 1


def test_saturated_bus_keeps_control_traffic_flowing(
    bus: tuple[str, Callable[..., CanBusEmulator]], hosts: list[HostSide]
) -> None:
    # Each board's frames are spaced as on a 50 kbit/s bus (about 330 a second) while its Imu
    # and Odometry ask for ten times that: best-effort data queues and is shed, while ACKs,
    # control (heartbeats, the table), services and the reliable counter go first.
    channel, emulate = bus
    emulator = emulate(2, rate=5.0, sensor_rate=20.0, pace=50_000)
    host = HostSide(f"can://virtual/{channel}", [1, 2])
    hosts.append(host)
    assert wait_for(lambda: all(host.connected(n) for n in (1, 2)), 30)
    started = time.monotonic()
    calls = 0
    while time.monotonic() - started < 3.0:
        for node in (1, 2):
            assert _call_whoami(host, node)[5:] == f"node {node}".encode()
            calls += 1
    assert calls >= 6
    for node in (1, 2):
        assert not host.of(node, base.Disconnected)  # heartbeats kept the sessions alive
        counts = host.counts(node)
        assert len(counts) >= 10
        assert counts == list(range(counts[0], counts[0] + len(counts)))
        link = emulator.board(node).link
        assert isinstance(link, CanLink)
        assert link.can_stats()["tx_dropped"] > 0  # the bus really was saturated


def test_bad_traffic_error_frames_and_bus_off_leave_other_boards_alone(
    bus: tuple[str, Callable[..., CanBusEmulator]], hosts: list[HostSide]
) -> None:
    channel, emulate = bus
    emulator = emulate(3, rate=10.0, sensor_rate=1.0)
    host = HostSide(f"can://virtual/{channel}", [1, 2, 3])
    hosts.append(host)
    assert wait_for(lambda: all(host.connected(n) for n in (1, 2, 3)))
    before = {n: len(host.counts(n)) for n in (1, 2, 3)}
    noisy = emulator.board(2).bus
    off = emulator.board(3).bus
    assert noisy is not None and off is not None
    raw = can.Bus(interface="virtual", channel=channel)
    try:
        as_board_2 = encode_id(4, Kind.RELIABLE, 200, 0, 2)  # as if from board 2
        for _ in range(20):
            noisy.error_frame()
            for data in (b"", bytes(9), b"\x01\x02\x00", bytes(7) + b"\xa5", b"\x00\x46"):
                raw.send(can.Message(arbitration_id=as_board_2, data=data, is_extended_id=True))
            raw.send(can.Message(arbitration_id=0x7FF, data=b"\xe0", is_extended_id=False))
            time.sleep(0.02)
        off.bus_off(3.0)  # longer than the link timeout: board 3's session ends
        time.sleep(1.5)
    finally:
        raw.shutdown()
    assert wait_for(lambda: host.of(3, base.Disconnected), 10)
    assert wait_for(lambda: host.connected(3), 20)  # recovered, negotiated again
    for node in (1, 2):
        assert not host.of(node, base.Disconnected)
        counts = host.counts(node)
        assert len(counts) > before[node] + 10
        assert counts == list(range(counts[0], counts[0] + len(counts)))
    stats = host.links[1].can_stats()
    assert stats["error_frames"] >= 20
    assert stats["rx_malformed"] >= 40
    assert stats["rx_unexpected"] >= 20
    assert wait_for(lambda: host.links[1].can_stats()["rx_timeouts"] >= 1, 5)
    board_3 = emulator.board(3).link
    assert isinstance(board_3, CanLink)
    board_stats = board_3.can_stats()
    assert board_stats["bus_off"] >= 1
    assert board_stats["recoveries"] >= 1


def test_robot_file_devices_ride_along(
    bus: tuple[str, Callable[..., CanBusEmulator]], hosts: list[HostSide]
) -> None:
    from hwbridge.emulator.board import load_board

    channel, emulate = bus
    emulate(1, config=load_board("diffbot"), rate=2.0)
    host = HostSide(f"can://virtual/{channel}", [1])
    hosts.append(host)
    assert wait_for(lambda: host.connected(1))
    names = set(host.channels[1])
    assert {"~imu", "~odom", "~count", "~command", "~whoami"} <= names
    assert len(names) > 5  # and the diffbot board's own devices
    device_channels = {c for n, c in host.channels[1].items() if not n.startswith("~")}
    assert wait_for(lambda: any(e.channel in device_channels for e in host.of(1, base.Message)), 10)
