"""Virtual boards: the native protocol's device side plus emulated devices in a world.

A :class:`VirtualBoard` behaves like firmware on a real board: it speaks the native protocol
(:class:`~hwbridge.protocols.native.session.DeviceSession`) on a link and publishes what its
devices read from the simulated world. It knows no device: each device of its robot-file board
is built by its plugin (:meth:`hwbridge.robot.plugin.DevicePlugin.emulate`) through the
:class:`~hwbridge.robot.plugin.EmulatedBoard` methods the board offers (publishers read at a
rate, subscribers, host-time headers, per-step and reset hooks). The host side of the same
plugins turns the raw readings into odometry, Range and Imu, as for a real board.

Boards come from robot files (:mod:`hwbridge.robot.config`); ``diffbot`` names the robot file
packaged in ``robots/`` (``examples/robots/diffbot.yaml``).
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hwbridge import msg
from hwbridge.emulator.faults import FaultySession, LinkFaults
from hwbridge.emulator.world import World, WorldConfig
from hwbridge.errors import HwBridgeError
from hwbridge.links import Link, open_link
from hwbridge.protocols.native import session as ns
from hwbridge.protocols.native.control import EntryKind
from hwbridge.pump import SessionPump
from hwbridge.robot.model import DeviceConfig

__all__ = ["ROBOTS_DIR", "BoardConfig", "VirtualBoard", "emulator_firmware", "load_board"]

log = logging.getLogger("hwbridge.emulator")


@functools.cache
def emulator_firmware() -> str:
    """The ``firmware_version`` text of a virtual board: "hwbridge-emulator" and the identity of
    firmware built with this hwbridge (PROTOCOL.md 2.6.1), so that the bridge finds nothing to
    warn about."""
    from hwbridge.bridge.identity import host_identity
    from hwbridge.protocols.native.identity import format_identity

    return format_identity(host_identity(msg.registry(), "hwbridge-emulator"))


ROBOTS_DIR = Path(__file__).with_name("robots")
PHYSICS_HZ = 200.0


@dataclass(frozen=True)
class BoardConfig:
    """What a virtual board carries: its name, its world and its devices (checked settings)."""

    name: str
    world: WorldConfig
    devices: tuple[DeviceConfig, ...]
    source: str = ""


def ready_robots() -> list[str]:
    """Names of the robot files packaged with hwbridge (``hwbridge emulate NAME``)."""
    return sorted(p.stem for p in ROBOTS_DIR.glob("*.yaml"))


def load_board(name_or_path: str, board: str | None = None) -> BoardConfig:
    """A board of a robot file (``board``: by name; default the first), the file given by its
    path or as the name of a packaged one (``diffbot``)."""
    from hwbridge.robot.config import load_robot

    path = Path(name_or_path)
    if not path.suffix and not path.exists():
        path = ROBOTS_DIR / f"{name_or_path}.yaml"
        if not path.exists():
            raise HwBridgeError(
                f"no robot {name_or_path!r}: ready robots are {', '.join(ready_robots())} "
                "(or give a robot file's path)"
            )
    robot = load_robot(path)
    if not robot.boards:
        raise HwBridgeError(f"{path}: the robot has no boards to emulate")
    chosen = robot.board(board) if board is not None else robot.boards[0]
    try:
        world = WorldConfig.from_dict(dict(robot.world))
    except (KeyError, TypeError, ValueError) as exc:
        raise HwBridgeError(f"{path}: world: {exc}") from exc
    from hwbridge.robot.wiring import on_board

    devices = tuple(  # a device that only_on keeps off the board's MCU board is not on it
        d for d in chosen.devices if chosen.mcu is None or on_board(d, chosen.mcu)
    )
    return BoardConfig(robot.name, world, devices, str(path))


class VirtualBoard:
    """A board with a world, run on a link. ``speed`` > 1 runs faster than real time."""

    def __init__(self, config: BoardConfig, *, seed: int = 0, speed: float = 1.0) -> None:
        from hwbridge.robot.registry import get_device

        self.config = config
        self.seed = seed
        self.speed = speed
        self.world = World(config.world, seed)
        self.registry = msg.registry()
        self._topics: list[ns.TopicEntry] = []
        self._readers: list[tuple[float, Callable[[], tuple[int, bytes] | None]]] = []
        self._steps: list[Callable[[float], None]] = []
        self._resets: list[Callable[[], None]] = []
        self._reads: dict[str, Callable[[], bytes | None]] = {}
        self._inputs: dict[int, Callable[[bytes], None]] = {}
        for device in config.devices:
            try:
                get_device(device.type).emulate(device.settings, self)
            except HwBridgeError:
                raise
            except (TypeError, ValueError, KeyError) as exc:  # a setting the model refuses
                raise HwBridgeError(
                    f"{device.source or config.source}: {device.type} {device.name}: "
                    f"bad setting: {exc}"
                ) from exc
        self.session = FaultySession(self._new_session(), seed)
        self.resets = 0
        self._host_offset = 0.0  # host minus board time, as of the reading being taken
        self.read_errors = 0
        """Device readings that raised (the first is logged with its traceback)."""
        self.pump: SessionPump | None = None
        self.link: Link | None = None
        self.published = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    def _new_session(self) -> ns.DeviceSession:
        return ns.DeviceSession(
            ns.BoardInfo(self.config.name, self.seed.to_bytes(4, "little"), emulator_firmware()),
            self._topics,
        )

    # ------------------------------------------------------------------ devices (EmulatedBoard)
    def _entry(self, kind: EntryKind, name: str, type_name: str) -> int:
        channel = len(self._topics) + 1
        self._topics.append(
            ns.TopicEntry(channel, kind, name, type_name, self.registry.md5(type_name))
        )
        return channel

    def publisher(
        self, topic: str, type_name: str, rate: float, read: Callable[[], bytes | None]
    ) -> int:
        """A board publisher whose ``read()`` runs ``rate`` times a simulated second."""
        channel = self._entry(EntryKind.PUBLISHER, topic, type_name)

        def reading() -> tuple[int, bytes] | None:
            payload = read()
            return None if payload is None else (channel, payload)

        self._readers.append((float(rate), reading))
        self._reads[topic] = read
        return channel

    @property
    def topics(self) -> tuple[ns.TopicEntry, ...]:
        """The board's topic table (its publishers and subscribers, by channel), as it
        announces it to the host."""
        return tuple(self._topics)

    def read(self, topic: str) -> bytes | None:
        """One reading of the board publisher ``topic``, taken now from the world as it stands
        and returned instead of sent (None: the device has nothing to report). For checking a
        device model without a link: step ``world`` between readings, as the physics thread
        does. An error for a topic the board does not publish."""
        read = self._reads.get(topic)
        if read is None:
            published = ", ".join(self._reads) or "none"
            raise HwBridgeError(
                f"{self.config.name} publishes no topic {topic!r} (its publishers: {published})"
            )
        return read()

    def subscriber(self, topic: str, type_name: str, handle: Callable[[bytes], None]) -> int:
        """A board subscriber; ``handle(payload)`` runs on the protocol's thread."""
        channel = self._entry(EntryKind.SUBSCRIBER, topic, type_name)
        self._inputs[channel] = handle
        return channel

    def header(self, frame_id: str) -> dict[str, Any]:
        """A header stamped with the host time of now (as firmware with time sync stamps)."""
        # The session's clock is the pump's (monotonic) clock; the offset was read under the
        # pump's lock by _publish: the session itself may be resetting.
        return {"stamp": time.monotonic() + self._host_offset, "frame_id": frame_id}

    def on_step(self, step: Callable[[float], None]) -> None:
        self._steps.append(step)

    def on_reset(self, reset: Callable[[], None]) -> None:
        self._resets.append(reset)

    # ------------------------------------------------------------------ faults
    def inject(self, faults: LinkFaults) -> None:
        """Lose and corrupt bytes on the board's link from now on (LinkFaults() stops it)."""
        self.session.faults = faults

    def stall(self, seconds: float) -> None:
        """The board's output stops for ``seconds`` (what it sends meanwhile comes later)."""
        self.session.stall(time.monotonic() + seconds)

    def reset(self) -> None:
        """Reboot the board: a new protocol session, its devices back to power-on."""
        with self._lock:
            for reset in self._resets:
                reset()
            self.resets += 1
        pump = self.pump
        if pump is not None:
            pump.call(lambda _s: setattr(self.session, "inner", self._new_session()))
        log.info("%s: reset", self.config.name)

    # ------------------------------------------------------------------ running
    def _on_event(self, event: Any) -> None:
        if isinstance(event, ns.Message):
            handler = self._inputs.get(event.channel)
            if handler is not None:
                handler(event.payload)
        elif isinstance(event, ns.Connected):
            log.info("%s: connected to the host", self.config.name)
        elif isinstance(event, ns.Disconnected):
            log.info("%s: host session ended (%s)", self.config.name, event.reason)

    def start(self, link: Link) -> VirtualBoard:
        """Run on ``link`` (opened): the protocol pump and the physics thread."""
        self._attach(link)
        self._thread = threading.Thread(target=self._simulate, name="physics", daemon=True)
        self._thread.start()
        return self

    def _attach(self, link: Link) -> None:
        self.link = link
        self.pump = SessionPump(
            link, self.session, self._on_event, name=f"board-{self.config.name}"
        )
        self.pump.start()

    def unplug(self, seconds: float) -> None:
        """Pull the cable for ``seconds``: the link goes away (a pty's path disappears) and
        comes back at the same URL. The board itself keeps running."""
        link, pump = self.link, self.pump
        if link is None or pump is None:
            raise HwBridgeError("the board is not running on a link")
        url = link.url
        self.pump = None
        _halt(pump, link)
        log.info("%s: unplugged for %.1f s", self.config.name, seconds)
        self._stop.wait(seconds)
        if not self._stop.is_set():
            self._attach(open_link(url))

    def _simulate(self) -> None:
        dt = 1.0 / PHYSICS_HZ
        next_read = [0.0 for _ in self._readers]
        started = time.monotonic()
        steps = 0
        while not self._stop.is_set():
            with self._lock:
                self.world.step(dt)
                for step in self._steps:
                    step(self.world.time)
            steps += 1
            for index, (rate, read) in enumerate(self._readers):
                if self.world.time + 1e-9 >= next_read[index]:
                    next_read[index] = self.world.time + 1.0 / rate
                    try:
                        self._publish(read)
                    except Exception:
                        # One bad reading must not stop the board (and its other devices).
                        self.read_errors += 1
                        if self.read_errors == 1:
                            log.exception("%s: a device reading failed", self.config.name)
            wake = started + steps * dt / self.speed
            delay = wake - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)

    def _publish(self, read: Callable[[], tuple[int, bytes] | None]) -> None:
        pump = self.pump
        if pump is None:
            return
        # The pump thread resets the session when the link drops, so connection state and
        # time offset are read under its lock, in one go.
        try:
            offset = pump.call(lambda s: s.time_offset if s.connected else None)
            if offset is None:
                return  # like firmware that waits for time sync, so stamps are in host time
            self._host_offset = offset
            result = read()
            if result is None:
                return
            channel, payload = result
            if pump.call(lambda s: s.publish(channel, payload)):
                self.published += 1
        except HwBridgeError as exc:  # the link went away under us, a full queue: try later
            log.debug("%s: publishing a reading failed: %s", self.config.name, exc)

    @property
    def running(self) -> bool:
        """The board's simulation runs (started, not stopped, and not ended by an error)."""
        return self._thread is not None and self._thread.is_alive()

    def stop(self) -> None:
        """Stop the physics thread and the pump, and close the link. The link is closed before
        the threads are waited for: a write blocked on it (a host that does not read, a full
        pty or socket), in the pump thread or in a reading the physics thread publishes, then
        returns at once instead of holding the stop until the threads' join timeouts."""
        self._stop.set()
        pump, link = self.pump, self.link
        if link is not None:
            _halt(pump, link, wait=False)
        if self._thread is not None:
            self._thread.join(2)
        if pump is not None:
            pump.stop()


def _halt(pump: SessionPump | None, link: Link, *, wait: bool = True) -> None:
    """End ``pump`` and close its ``link``: the pump is told to stop first (so that the link's
    closing is no error to it), then the link is closed, which wakes a read or write blocked
    on it; then (``wait``) the pump's thread is waited for."""
    if pump is not None:
        pump.request_stop()  # no waiting: its thread may be blocked on the link
    link.close()
    if pump is not None and wait:
        pump.stop()
