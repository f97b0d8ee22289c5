"""Virtual boards: the native protocol's device side plus emulated devices in a world.

A :class:`VirtualBoard` behaves like firmware on a real board: it speaks the native protocol
(:class:`~hwbridge.protocols.native.session.DeviceSession`) on a link, reads its emulated
devices (encoder counters, an HC-SR04, an MPU-6050 on I2C) and publishes their raw readings
(``hwbridge_msgs/*``), and drives its motors from ``hwbridge_msgs/WheelTargets``, stopping them
when no target arrived for 0.5 s. Host-side plugins (:mod:`hwbridge.emulator.plugins`) turn the
raw readings into odometry, Range and Imu, as they would for a real board.

A board is described by a small mapping (YAML), see ``boards/diffbot.yaml``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from hwbridge import msg
from hwbridge.devices.encoders import wrap_counter
from hwbridge.devices.imu.mpu import (
    ACCEL_CONFIG,
    ACCEL_RANGES_G,
    ACCEL_XOUT_H,
    AK8963_ADDRESS,
    AK8963_HXL,
    AK8963_ST1,
    GYRO_CONFIG,
    GYRO_RANGES_DPS,
    PWR_MGMT_1,
    I2CBus,
    Mpu6050,
    Mpu9250,
    MpuChip,
)
from hwbridge.devices.imu.plugin import configure_ak8963, decode_burst, decode_magnetometer
from hwbridge.devices.ultrasonic import HcSr04Model
from hwbridge.emulator.faults import FaultySession, LinkFaults
from hwbridge.emulator.world import World, WorldConfig
from hwbridge.errors import HwBridgeError
from hwbridge.links import Link, open_link
from hwbridge.protocols.native import session as ns
from hwbridge.protocols.native.control import EntryKind
from hwbridge.pump import SessionPump

__all__ = ["BOARDS_DIR", "BoardConfig", "VirtualBoard", "load_board"]

log = logging.getLogger("hwbridge.emulator")

BOARDS_DIR = Path(__file__).with_name("boards")
PHYSICS_HZ = 200.0
TARGET_TIMEOUT = 0.5


@dataclass(frozen=True)
class BoardConfig:
    """What a virtual board carries: its name, world and devices."""

    name: str
    world: WorldConfig
    devices: tuple[dict[str, Any], ...]
    host: dict[str, Any]
    """Parameters for the host-side device nodes (e.g. ``diffdrive``)."""
    source: str = ""


def load_board(name_or_path: str) -> BoardConfig:
    """A ready board by name (``diffbot``) or a YAML file describing one."""
    path = Path(name_or_path)
    if not path.suffix:
        path = BOARDS_DIR / f"{name_or_path}.yaml"
    if not path.exists():
        ready = sorted(p.stem for p in BOARDS_DIR.glob("*.yaml"))
        raise HwBridgeError(f"no board {name_or_path!r}: ready boards are {', '.join(ready)}")
    data = yaml.safe_load(path.read_text()) or {}
    try:
        return BoardConfig(
            name=str(data["name"]),
            world=WorldConfig.from_dict(data.get("world", {})),
            devices=tuple(data.get("devices", ())),
            host=dict(data.get("host", {})),
            source=str(path),
        )
    except (KeyError, TypeError) as exc:
        raise HwBridgeError(f"{path}: not a board description ({exc})") from exc


class VirtualBoard:
    """A board with a world, run on a link. ``speed`` > 1 runs faster than real time."""

    def __init__(self, config: BoardConfig, *, seed: int = 0, speed: float = 1.0) -> None:
        self.config = config
        self.seed = seed
        self.speed = speed
        self.world = World(config.world, seed)
        self.registry = msg.registry()
        self._topics: list[ns.TopicEntry] = []
        self._readers: list[tuple[float, Callable[[], tuple[int, bytes] | None]]] = []
        self._targets = (0.0, 0.0)
        self._last_target = -1e9
        self._channel_names: dict[int, str] = {}
        self._inputs: dict[int, Callable[[bytes], None]] = {}
        self.dynamixel_bus: Any = None
        for index, device in enumerate(config.devices):
            try:
                self._add_device(device)
            except HwBridgeError:
                raise
            except (TypeError, ValueError) as exc:  # a setting that is not a number, say
                kind = device.get("type", "?") if isinstance(device, dict) else "?"
                raise HwBridgeError(
                    f"{config.source}: device {index + 1} ({kind}): bad setting: {exc}"
                ) from exc
        self.session = FaultySession(self._new_session(), seed)
        self.resets = 0
        self._count_offset = (0, 0)
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
            ns.BoardInfo(self.config.name, self.seed.to_bytes(4, "little"), "hwbridge-emulator"),
            self._topics,
        )

    # ------------------------------------------------------------------ faults
    def inject(self, faults: LinkFaults) -> None:
        """Lose and corrupt bytes on the board's link from now on (LinkFaults() stops it)."""
        self.session.faults = faults

    def stall(self, seconds: float) -> None:
        """The board's output stops for ``seconds`` (what it sends meanwhile comes later)."""
        self.session.stall(time.monotonic() + seconds)

    def reset(self) -> None:
        """Reboot the board: a new protocol session, counters back to zero, motors stopped."""
        with self._lock:
            left, right = self.world.base.counts()
            self._count_offset = (left, right)
            self._targets = (0.0, 0.0)
            self._last_target = -1e9
            self.resets += 1
        pump = self.pump
        if pump is not None:
            pump.call(lambda _s: setattr(self.session, "inner", self._new_session()))
        log.info("%s: reset", self.config.name)

    # ------------------------------------------------------------------ devices
    def _entry(self, kind: EntryKind, name: str, type_name: str) -> int:
        channel = len(self._topics) + 1
        self._topics.append(
            ns.TopicEntry(channel, kind, name, type_name, self.registry.md5(type_name))
        )
        self._channel_names[channel] = name
        return channel

    def _add_device(self, device: dict[str, Any]) -> None:
        kind = device.get("type")
        rate = float(device.get("rate", 50.0))
        if kind == "diffdrive":
            channel = self._entry(
                EntryKind.PUBLISHER,
                device.get("ticks_topic", "wheel_ticks"),
                "hwbridge_msgs/WheelTicks",
            )
            targets_channel = self._entry(
                EntryKind.SUBSCRIBER,
                device.get("targets_topic", "wheel_targets"),
                "hwbridge_msgs/WheelTargets",
            )
            self._inputs[targets_channel] = self._on_targets
            self._readers.append((rate, lambda: (channel, self._read_ticks())))
        elif kind == "hcsr04":
            sonar = HcSr04Model(
                temperature_c=float(device.get("temperature", 20.0)),
                noise_std=float(device.get("noise_std", 0.002)),
                seed=self.seed + 2,
            )
            channel = self._entry(
                EntryKind.PUBLISHER, device.get("topic", "sonar_echo"), "hwbridge_msgs/SonarEcho"
            )
            self._readers.append((rate, lambda: (channel, self._read_sonar(sonar))))
        elif kind in ("mpu6050", "mpu9250"):
            chip: MpuChip = (Mpu6050 if kind == "mpu6050" else Mpu9250)(seed=self.seed + 3)
            accel_fs = ACCEL_RANGES_G.index(int(device.get("accel_range_g", 2)))
            gyro_fs = GYRO_RANGES_DPS.index(int(device.get("gyro_range_dps", 250)))
            chip.write(PWR_MGMT_1, bytes([0x00]))  # wake (the 6050 starts asleep)
            chip.write(GYRO_CONFIG, bytes([gyro_fs << 3]))
            chip.write(ACCEL_CONFIG, bytes([accel_fs << 3]))
            mag = None
            if isinstance(chip, Mpu9250) and device.get("magnetometer", True):
                mag = _Magnetometer.set_up(chip, self.world.time)
            channel = self._entry(
                EntryKind.PUBLISHER, device.get("topic", "imu_raw"), "hwbridge_msgs/ImuRaw"
            )
            self._readers.append((rate, lambda: (channel, self._read_imu(chip, kind, mag))))
        elif kind == "dynamixel":
            self._add_dynamixel(device, rate)
        else:
            raise HwBridgeError(f"{self.config.source}: unknown device type {kind!r}")

    def _add_dynamixel(self, device: dict[str, Any], rate: float) -> None:
        """A servo on the board's own Dynamixel bus (its second UART), driven by the board."""
        from hwbridge.devices.dynamixel import EmulatedDynamixelBus, find_model, packets

        bus = EmulatedDynamixelBus.from_config(device["bus"])
        servo_id = int(device.get("id", 1))
        joint = str(device.get("joint", "pan"))
        protocol = int(device["bus"].get("protocol", 2))
        model = find_model(bus.servo(servo_id).model.name)
        table = model.table
        self.dynamixel_bus = bus
        bus_time = [0.0]

        def transact(packet: Any) -> Any:
            now = max(bus_time[0], self.world.time)
            reply = bus.feed(packets.encode(packet), now) + bus.advance(now + 0.005)
            bus_time[0] = now + 0.005
            return packets.decode(reply, protocol, "status") if reply else None

        def register(name: str) -> tuple[int, int]:
            found = table[name]
            return found.address, found.size

        address, _ = register("Torque Enable")
        transact(packets.write_packet(protocol, servo_id, address, bytes([1])))

        def read_state() -> bytes:
            with self._lock:
                addr, length = register("Present Position")
                status = transact(packets.read_packet(protocol, servo_id, addr, length))
            ticks = int.from_bytes(status.params, "little", signed=True) if status else 0
            return msg.encode(
                msg.from_dict(
                    "sensor_msgs/JointState",
                    {
                        "header": self._stamp(),
                        "name": [joint],
                        "position": [model.ticks_to_radians(ticks)],
                    },
                )
            )

        def on_goal(payload: bytes) -> None:
            goal = msg.decode(payload, "std_msgs/Float64", self.registry)
            addr, length = register("Goal Position")
            ticks = model.radians_to_ticks(float(goal.data))
            with self._lock:
                transact(
                    packets.write_packet(
                        protocol, servo_id, addr, ticks.to_bytes(length, "little", signed=True)
                    )
                )

        channel = self._entry(
            EntryKind.PUBLISHER, device.get("state_topic", "joint_states"), "sensor_msgs/JointState"
        )
        goal_channel = self._entry(
            EntryKind.SUBSCRIBER, f"{joint}/goal_position", "std_msgs/Float64"
        )
        self._inputs[goal_channel] = on_goal
        self._readers.append((rate, lambda: (channel, read_state())))

    def _stamp(self) -> dict[str, Any]:
        # The session's clock is the pump's (monotonic) clock: stamp readings with the host
        # time of the moment they are taken, as firmware with time sync does. The offset was
        # read under the pump's lock by _publish: the session itself may be resetting.
        return {"stamp": time.monotonic() + self._host_offset}

    def _read_ticks(self) -> bytes:
        left, right = self.world.base.counts()
        bits = self.config.world.counter_bits
        left = wrap_counter(left - self._count_offset[0], bits)
        right = wrap_counter(right - self._count_offset[1], bits)
        return msg.encode(
            msg.from_dict(
                "hwbridge_msgs/WheelTicks",
                {
                    "header": {**self._stamp(), "frame_id": "base_link"},
                    "left": _as_int32(left),
                    "right": _as_int32(right),
                    "counter_bits": bits,
                },
            )
        )

    def _read_sonar(self, sonar: HcSr04Model) -> bytes:
        echo = sonar.measure(self.world.sonar_distance())
        return msg.encode(
            msg.from_dict(
                "hwbridge_msgs/SonarEcho",
                {
                    "header": {**self._stamp(), "frame_id": "sonar_link"},
                    "echo_us": int(echo),
                    "temperature": sonar.temperature_c,
                },
            )
        )

    def _read_imu(self, chip: MpuChip, kind: str, mag: _Magnetometer | None) -> bytes:
        chip.set_truth(self.world.imu_truth())
        chip.sample()
        raw = decode_burst(chip.read(ACCEL_XOUT_H, 14))
        reading = mag.read(self.world.time) if mag is not None else None
        fields = reading or {"mag": [0, 0, 0], "mag_st2": 0, "mag_asa": [0, 0, 0]}
        return msg.encode(
            msg.from_dict(
                "hwbridge_msgs/ImuRaw",
                {
                    "header": {**self._stamp(), "frame_id": "imu_link"},
                    "chip": 0 if kind == "mpu6050" else 1,
                    "accel_config": chip.read(ACCEL_CONFIG, 1)[0],
                    "gyro_config": chip.read(GYRO_CONFIG, 1)[0],
                    "burst": [*raw.accel, raw.temperature, *raw.gyro],
                    **fields,
                    "mag_valid": reading is not None,
                },
            )
        )

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

    def _on_targets(self, payload: bytes) -> None:
        targets = msg.decode(payload, "hwbridge_msgs/WheelTargets", self.registry)
        with self._lock:
            self._targets = (float(targets.left), float(targets.right))
            self._last_target = self.world.time

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
        pump.stop()
        link.close()
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
                if self.world.time - self._last_target > TARGET_TIMEOUT:
                    self._targets = (0.0, 0.0)
                self.world.base.set_wheel_targets(*self._targets)
                self.world.step(dt)
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

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2)
        if self.pump is not None:
            self.pump.stop()
        if self.link is not None:
            self.link.close()


class _Magnetometer:
    """The MPU-9250's AK8963 as firmware drives it: reached through the bypass switch, its
    sensitivity adjustment read once from fuse ROM, then measuring continuously at 100 Hz with
    16-bit output; each reading takes the newest measurement, if there is one."""

    def __init__(self, chip: Mpu9250, bus: I2CBus, asa: bytes, now: float) -> None:
        self.chip, self.bus, self.asa, self.last = chip, bus, list(asa), now

    @classmethod
    def set_up(cls, chip: Mpu9250, now: float) -> _Magnetometer:
        bus = I2CBus(chip)
        return cls(chip, bus, configure_ak8963(bus, chip.address), now)

    def read(self, now: float) -> dict[str, Any] | None:
        """The ImuRaw magnetometer fields of a new measurement, None if none is ready."""
        self.chip.magnetometer.advance(max(0.0, now - self.last))
        self.last = now
        if not self.bus.read(AK8963_ADDRESS, AK8963_ST1, 1)[0] & 0x01:  # DRDY
            return None
        counts, st2 = decode_magnetometer(self.bus.read(AK8963_ADDRESS, AK8963_HXL, 7))
        return {"mag": list(counts), "mag_st2": st2, "mag_asa": self.asa}


def _as_int32(value: int) -> int:
    """A counter register value as the int32 field carries it (two's complement)."""
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value >= 1 << 31 else value
