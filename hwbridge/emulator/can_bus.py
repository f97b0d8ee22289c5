"""Virtual boards on a CAN bus, and the faults a real bus has.

:class:`CanBoard` is a :class:`~hwbridge.emulator.board.VirtualBoard` (its robot-file devices,
its world) with a node id, the native protocol's datagram framing, and the endpoints every CAN
test board carries: ``imu`` (``sensor_msgs/Imu``) and ``odom`` (``nav_msgs/Odometry``), both
multi-frame, best effort; ``count`` (``std_msgs/UInt32``, reliable, counting up); the subscriber
``command`` (``std_msgs/UInt32``, reliable: every value it gets is kept in ``commands``) and the
service ``whoami`` (``std_srvs/Trigger``: answers ``node N``). All names are private (``~``):
on the graph they sit under the board's name (``/node3/imu``).

Each board talks through its own python-can bus object wrapped in a :class:`FaultyBus`, which
loses or duplicates frames, sends error frames, goes bus-off for a while or stops talking, on
demand. :class:`CanBusEmulator` puts ``count`` boards (node ids 1..count) on one bus::

    python -m hwbridge.emulator.can_bus --boards 8 --bus udp_multicast/239.74.163.9
    python -m hwbridge.emulator.can_bus --boards 8 --slcan   # prints the adapter's pty

and prints the links to give ``hwbridge connect`` (``can://.../node1`` ...), then a line
``nodeN command V`` for each value a board's ``command`` subscriber gets.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import random
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from hwbridge import msg
from hwbridge.emulator.board import BoardConfig, VirtualBoard, emulator_firmware, load_board
from hwbridge.emulator.faults import FaultySession
from hwbridge.emulator.virtual_bus import shared_virtual_bus
from hwbridge.emulator.world import WorldConfig
from hwbridge.errors import HwBridgeError
from hwbridge.links.can import CanLink
from hwbridge.protocols.can.transport import acceptance_filters
from hwbridge.protocols.native import session as ns
from hwbridge.protocols.native.control import EntryKind
from hwbridge.protocols.native.framing import NativeDatagramFraming

__all__ = ["CanBoard", "CanBusEmulator", "FaultyBus", "main"]

log = logging.getLogger("hwbridge.emulator.can")


class FaultyBus:
    """A python-can bus with faults: ``loss`` and ``duplicate`` (probabilities per frame, both
    ways), :meth:`bus_off` (sends fail and nothing is received for a while), :meth:`silence`
    (the node stops talking: what it sends is lost), :meth:`error_frame`. Seeded."""

    def __init__(self, inner: Any, *, seed: int = 0) -> None:
        self.inner = inner
        self.loss = 0.0
        self.duplicate = 0.0
        self.lost = 0
        self.duplicated = 0
        self.silenced = 0
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self._off_until = 0.0
        self._silent_until = 0.0
        self._again: Any = None

    def bus_off(self, seconds: float) -> None:
        """The controller goes bus-off for ``seconds``: sends raise, receives get nothing."""
        self._off_until = time.monotonic() + seconds

    def silence(self, seconds: float) -> None:
        """The node stops talking for ``seconds`` (its frames vanish; it still listens)."""
        self._silent_until = time.monotonic() + seconds

    def error_frame(self) -> None:
        """Put an error frame on the bus (what a node seeing a bit error signals)."""
        import can

        self.inner.send(can.Message(is_error_frame=True, is_extended_id=True, arbitration_id=0))

    def _roll(self) -> float:
        with self._lock:
            return self._rng.random()

    def send(self, message: Any, timeout: float | None = None) -> None:
        import can

        now = time.monotonic()
        if now < self._off_until:
            raise can.CanOperationError("bus-off (emulated)")
        if now < self._silent_until:
            self.silenced += 1
            return
        roll = self._roll()
        if roll < self.loss:
            self.lost += 1
            return
        self.inner.send(message, timeout)
        if roll < self.loss + self.duplicate:
            self.duplicated += 1
            self.inner.send(message, timeout)

    def recv(self, timeout: float | None = None) -> Any:
        again, self._again = self._again, None
        if again is not None:
            return again
        message = self.inner.recv(timeout)
        if message is None:
            return None
        if time.monotonic() < self._off_until:
            return None
        roll = self._roll()
        if roll < self.loss:
            self.lost += 1
            return None
        if roll < self.loss + self.duplicate:
            self.duplicated += 1
            self._again = message
        return message

    def shutdown(self) -> None:
        self.inner.shutdown()


_ENTRY_REPLACE = dataclasses.replace


class _DatagramSession(FaultySession):
    """The board's session as :class:`VirtualBoard` holds it (``inner`` is swapped on a reset),
    passing each datagram through as its own chunk: faults on a CAN bus are frames lost or
    doubled (:class:`FaultyBus`), not bytes."""

    def chunks_to_send(self) -> list[bytes]:
        chunks: list[bytes] = self.inner.chunks_to_send()
        return chunks


class CanBoard(VirtualBoard):
    """A virtual board with node id ``node`` on a CAN bus (see the module docstring).

    ``rate`` is how often ``count`` publishes (per simulated second), ``sensor_rate`` how often
    ``imu`` and ``odom`` do (default: ``rate``);
    ``mtu`` the largest native frame payload it negotiates (smaller frames make shorter CAN
    transfers, which survive frame loss better)."""

    def __init__(
        self,
        config: BoardConfig,
        node: int,
        *,
        seed: int = 0,
        rate: float = 2.0,
        mtu: int = 64,
        speed: float = 1.0,
        sensor_rate: float | None = None,
    ) -> None:
        super().__init__(config, seed=seed, speed=speed)
        self.node = node
        self.mtu = mtu
        self.count = 0
        self.commands: list[int] = []
        """Every value the ``command`` subscriber got, in order."""
        self.calls = 0
        self.on_command: Callable[[int, int], None] | None = None
        """Called with (node, value) for each value the ``command`` subscriber gets."""
        sensors = rate if sensor_rate is None else sensor_rate
        self.publisher("~imu", "sensor_msgs/Imu", sensors, self._imu)
        self.publisher("~odom", "nav_msgs/Odometry", sensors, self._odom)
        self.publisher("~count", "std_msgs/UInt32", rate, self._count)
        self._make_reliable()
        self.subscriber("~command", "std_msgs/UInt32", self._command)
        self._make_reliable()
        self._whoami = self._entry(EntryKind.SERVICE_SERVER, "~whoami", "std_srvs/Trigger")
        self.session = _DatagramSession(self._new_session(), seed)
        self.bus: FaultyBus | None = None

    def _make_reliable(self) -> None:
        self._topics[-1] = _ENTRY_REPLACE(self._topics[-1], reliable=True)

    def _new_session(self) -> ns.DeviceSession:
        return ns.DeviceSession(
            ns.BoardInfo(self.config.name, self.seed.to_bytes(4, "little"), emulator_firmware()),
            self._topics,
            ns.DeviceConfig(mtu=getattr(self, "mtu", 64)),
            framing=NativeDatagramFraming(),
        )

    # ------------------------------------------------------------------ readings
    def _imu(self) -> bytes:
        t = self.world.time
        return msg.encode(
            msg.from_dict(
                "sensor_msgs/Imu",
                {
                    "header": self.header(f"node{self.node}_imu"),
                    "orientation": {"z": math.sin(t / 2), "w": math.cos(t / 2)},
                    "angular_velocity": {"z": 0.5},
                    "linear_acceleration": {"x": math.cos(t), "z": 9.81},
                    "orientation_covariance": [0.01 * i for i in range(9)],
                },
            )
        )

    def _odom(self) -> bytes:
        t = self.world.time
        return msg.encode(
            msg.from_dict(
                "nav_msgs/Odometry",
                {
                    "header": self.header("odom"),
                    "child_frame_id": f"node{self.node}_base",
                    "pose": {"pose": {"position": {"x": t, "y": float(self.node)}}},
                    "twist": {"twist": {"linear": {"x": 1.0}}},
                },
            )
        )

    def _count(self) -> bytes:
        value = self.count
        self.count += 1
        return value.to_bytes(4, "little")

    def _command(self, payload: bytes) -> None:
        if len(payload) == 4:
            value = int.from_bytes(payload, "little")
            self.commands.append(value)
            if self.on_command is not None:
                self.on_command(self.node, value)

    def _on_event(self, event: Any) -> None:
        if isinstance(event, ns.ServiceRequest) and event.channel == self._whoami:
            self.calls += 1
            text = f"node {self.node}".encode()
            response = b"\x01" + len(text).to_bytes(4, "little") + text
            channel, request_id, pump = event.channel, event.request_id, self.pump
            if pump is not None:
                pump.call(lambda s: s.respond_service(channel, request_id, response))
            return
        super()._on_event(event)

    # ------------------------------------------------------------------ running
    def start_on(
        self, bus: Any, *, fd: bool = False, url: str = "can://emulated/bus", pace: int = 0
    ) -> CanBoard:
        """Run on a python-can bus object (wrapped in a :class:`FaultyBus`); ``pace`` (bits/s)
        spaces its frames as a bus of that rate would (0: as fast as they come)."""
        # What the board's controller lets through (as the MCP2515 driver's filters do): its
        # own transfers and NODE claims, not the other boards' traffic to the host.
        bus.set_filters(
            [
                {"can_id": can_id, "can_mask": mask, "extended": True}
                for can_id, mask in acceptance_filters(self.node)
            ]
        )
        self.bus = FaultyBus(bus, seed=self.seed)
        query = f"node=0&local={self.node}&fd={int(fd)}&pace={pace}"
        link = CanLink(f"{url}?{query}", bus=self.bus)
        link.open()
        self.start(link)
        return self


def _default_config(name: str) -> BoardConfig:
    return BoardConfig(name, WorldConfig(), ())


class CanBusEmulator:
    """``count`` :class:`CanBoard` s (node ids ``first``..) on one python-can bus: each opens
    ``new_bus()`` (a python-can bus object of its own on the shared channel)."""

    def __init__(
        self,
        new_bus: Any,
        count: int = 8,
        *,
        first: int = 1,
        fd: bool = False,
        rate: float = 2.0,
        mtu: int = 64,
        seed: int = 0,
        config: BoardConfig | None = None,
        sensor_rate: float | None = None,
        pace: int = 0,
    ) -> None:
        self.pace = pace
        self.boards: list[CanBoard] = []
        for index in range(count):
            node = first + index
            base = config if config is not None else _default_config("")
            board_config = dataclasses.replace(base, name=f"node{node}")
            board = CanBoard(
                board_config, node, seed=seed + node, rate=rate, mtu=mtu, sensor_rate=sensor_rate
            )
            self.boards.append(board)
        self._new_bus = new_bus
        self.fd = fd

    def start(self) -> CanBusEmulator:
        for board in self.boards:
            board.start_on(
                self._new_bus(), fd=self.fd, url=f"can://emulated/board{board.node}", pace=self.pace
            )
        return self

    def board(self, node: int) -> CanBoard:
        for board in self.boards:
            if board.node == node:
                return board
        raise HwBridgeError(f"no emulated board has node id {node}")

    def set_faults(self, *, loss: float = 0.0, duplicate: float = 0.0) -> None:
        """Lose and duplicate frames on every board's bus from now on."""
        for board in self.boards:
            if board.bus is not None:
                board.bus.loss, board.bus.duplicate = loss, duplicate

    def stop(self) -> None:
        for board in self.boards:
            board.stop()
            if board.bus is not None:
                board.bus.shutdown()


def _bus_factory(interface: str, channel: str, fd: bool, port: int | None) -> Any:
    import can

    if interface == "virtual":
        return lambda: shared_virtual_bus(channel)

    def new_bus() -> Any:
        kwargs: dict[str, Any] = {"interface": interface, "channel": channel}
        if fd:
            kwargs["fd"] = True
        if port is not None:
            kwargs["port"] = port
        return can.Bus(**kwargs)

    return new_bus


def _print_command(node: int, value: int) -> None:
    sys.stdout.write(f"node{node} command {value}\n")
    sys.stdout.flush()


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m hwbridge.emulator.can_bus``: boards on a bus until Ctrl-C (or SIGTERM)."""
    parser = argparse.ArgumentParser(prog="python -m hwbridge.emulator.can_bus")
    parser.add_argument("--boards", type=int, default=8, help="how many boards (node ids 1..N)")
    parser.add_argument(
        "--bus", default="virtual/hwbridge", help="python-can INTERFACE/CHANNEL the boards use"
    )
    parser.add_argument("--port", type=int, default=None, help="udp_multicast port")
    parser.add_argument("--slcan", action="store_true", help="serve the bus as an SLCAN pty")
    parser.add_argument("--fd", action="store_true", help="CAN FD frames (up to 64 bytes)")
    parser.add_argument("--rate", type=float, default=2.0, help="counts published per second")
    parser.add_argument(
        "--sensor-rate", type=float, default=None, help="Imu and Odometry per second (--rate)"
    )
    parser.add_argument("--mtu", type=int, default=64, help="native frame payload MTU")
    parser.add_argument("--loss", type=float, default=0.0, help="frame loss, 0..1")
    parser.add_argument(
        "--robot",
        default=None,
        help="a robot file whose first board's devices every board also carries",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--pace",
        type=int,
        default=0,
        help="bits/s: each board sends no faster than a bus of this rate carries its frames "
        "(0: as fast as they come; a shared 1 Mbit/s bus of N boards is about 1000000/N)",
    )
    args = parser.parse_args(argv)
    if args.pace < 0:
        parser.error("--pace must be 0 or more bits/s")
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    interface, _, channel = args.bus.partition("/")
    where = f"{interface}/{channel}"
    adapter = gateway = None
    if interface == "udp_multicast":
        # one socket for all the boards (see hwbridge.emulator.multicast)
        from hwbridge.emulator.multicast import MulticastGateway

        local = f"mcast-{id(parser):x}"
        gateway = MulticastGateway(local, channel, args.port, fd=args.fd).start()
        interface, channel = "virtual", local
    if args.slcan:
        from hwbridge.emulator.slcan import SlcanAdapter

        interface, channel = "virtual", f"slcan-{id(parser):x}"
        adapter = SlcanAdapter(channel).start()
    config = load_board(args.robot) if args.robot else None
    emulator = CanBusEmulator(
        _bus_factory(interface, channel, args.fd, args.port),
        args.boards,
        fd=args.fd,
        rate=args.rate,
        mtu=args.mtu,
        seed=args.seed,
        config=config,
        sensor_rate=args.sensor_rate,
        pace=args.pace,
    )
    for board in emulator.boards:
        board.on_command = _print_command
    emulator.start()
    emulator.set_faults(loss=args.loss)
    if adapter is not None:
        where = f"slcan{adapter.path}"
        query = "?sleep_after_open=0&bitrate=1000000"
    else:
        port = f"&port={args.port}" if args.port is not None else ""
        query = f"?fd={int(args.fd)}{port}"
    urls = " ".join(f"can://{where}/node{b.node}{query}" for b in emulator.boards)
    sys.stdout.write(f"links: {urls}\n")
    sys.stdout.flush()
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    try:
        done.wait()
    except KeyboardInterrupt:
        pass
    finally:
        emulator.stop()
        if adapter is not None:
            adapter.stop()
        if gateway is not None:
            gateway.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
