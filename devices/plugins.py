"""The built-in board devices as plugins (:mod:`hwbridge.robot.plugin`): wheel encoders and
motors (``diffdrive``), an HC-SR04 (``hcsr04``), an MPU-6050/9250 (``mpu6050``, ``mpu9250``) and
a Dynamixel servo on the board's own bus (``dynamixel``).

Each gives its settings, its model on a virtual board (what the firmware would publish, made
from the emulator's world) and its host node (:mod:`hwbridge.devices.nodes`).
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from typing import Any, ClassVar

from hwbridge import msg
from hwbridge.devices.encoders import DiffDriveParams, wrap_counter
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
from hwbridge.devices.nodes import DiffDriveNode, ImuNode, SonarNode
from hwbridge.devices.ultrasonic import MAX_RANGE, MIN_RANGE, HcSr04Model, UltrasonicRanger
from hwbridge.robot.plugin import (
    Closeable,
    DevicePlugin,
    EmulatedBoard,
    Field,
    HostContext,
    TopicUse,
)

__all__ = [
    "BoardServoPlugin",
    "DiffDrivePlugin",
    "HcSr04Plugin",
    "Mpu6050Plugin",
    "Mpu9250Plugin",
]

TARGET_TIMEOUT = 0.5
"""Seconds without wheel targets after which the board stops its motors (as the firmware)."""

_RATE = Field("rate", float, 50.0, "readings per second", minimum=0.1, maximum=1000.0)


def _encode(board: EmulatedBoard, type_name: str, value: Mapping[str, Any]) -> bytes:
    return msg.encode(msg.from_dict(type_name, dict(value), board.registry))


class DiffDrivePlugin(DevicePlugin):
    """Two motors with quadrature encoders: ``wheel_ticks`` out, ``wheel_targets`` in; the host
    node makes ``odom`` and ``/tf`` and takes ``cmd_vel``."""

    type = "diffdrive"
    summary = "wheel encoders and motors: wheel_ticks -> odom and /tf, cmd_vel -> wheel_targets"
    firmware = (
        "hwbridge/drivers/quadrature.h: QuadratureEncoder; "
        "hwbridge/drivers/motor.h: DiffDriveMotors"
    )
    fields: ClassVar[tuple[Field, ...]] = (
        Field("ticks_topic", str, "wheel_ticks", "board topic of the counters"),
        Field("targets_topic", str, "wheel_targets", "board topic of the wheel speed targets"),
        _RATE,
        Field("wheel_radius", float, doc="m", minimum=1e-4),
        Field("wheel_separation", float, doc="m, between the wheels' contact points", minimum=1e-4),
        Field("counts_per_rev", float, doc="counts per wheel turn (4x decoding)", minimum=1.0),
        Field("counter_bits", int, 32, "width of the board's counters", choices=(16, 32)),
        Field("cmd_vel_timeout", float, 0.5, "s without cmd_vel before stopping", minimum=0.05),
        Field("max_wheel_speed", float, 50.0, "rad/s; faster means a counter reset", minimum=0.1),
        Field("odom_frame_id", str, "odom", "frame odometry is given in"),
        Field("base_frame_id", str, "base_link", "the robot's frame (odom's child frame)"),
    )

    def emulate(self, settings: Mapping[str, Any], board: EmulatedBoard) -> None:
        world = board.world
        bits = int(settings["counter_bits"])
        motors = _Motors()

        def read() -> bytes:
            left, right = world.base.counts()
            left0, right0 = motors.offset
            return _encode(
                board,
                "hwbridge_msgs/WheelTicks",
                {
                    "header": board.header(settings["base_frame_id"]),
                    "left": _as_int32(wrap_counter(left - left0, bits)),
                    "right": _as_int32(wrap_counter(right - right0, bits)),
                    "counter_bits": bits,
                },
            )

        def on_targets(payload: bytes) -> None:
            targets = msg.decode(payload, "hwbridge_msgs/WheelTargets", board.registry)
            motors.targets = (float(targets.left), float(targets.right))
            motors.commanded_at = world.time

        def step(now: float) -> None:
            if now - motors.commanded_at > TARGET_TIMEOUT:  # the firmware's own command timeout
                motors.targets = (0.0, 0.0)
            world.base.set_wheel_targets(*motors.targets)

        def reset() -> None:  # counters start again from zero, motors stop
            motors.offset = world.base.counts()
            motors.targets, motors.commanded_at = (0.0, 0.0), -1e9

        board.publisher(settings["ticks_topic"], "hwbridge_msgs/WheelTicks", settings["rate"], read)
        board.subscriber(settings["targets_topic"], "hwbridge_msgs/WheelTargets", on_targets)
        board.on_step(step)
        board.on_reset(reset)

    def topics(self, settings: Mapping[str, Any]) -> tuple[TopicUse, ...]:
        ticks, targets = settings["ticks_topic"], settings["targets_topic"]
        return (
            TopicUse(ticks, "hwbridge_msgs/WheelTicks", "publishes", "board"),
            TopicUse(targets, "hwbridge_msgs/WheelTargets", "subscribes", "board"),
            TopicUse(ticks, "hwbridge_msgs/WheelTicks", "subscribes"),
            TopicUse(targets, "hwbridge_msgs/WheelTargets", "publishes"),
            TopicUse("odom", "nav_msgs/Odometry", "publishes"),
            TopicUse("/tf", "tf2_msgs/TFMessage", "publishes", shared=True),
            TopicUse("cmd_vel", "geometry_msgs/Twist", "subscribes"),
        )

    def host_node(self, settings: Mapping[str, Any], context: HostContext) -> Closeable:
        params = DiffDriveParams.from_dict(
            {
                key: settings[key]
                for key in (
                    "wheel_radius",
                    "wheel_separation",
                    "counts_per_rev",
                    "counter_bits",
                    "cmd_vel_timeout",
                    "odom_frame_id",
                    "base_frame_id",
                )
            }
            | {"publish_rate": settings["rate"]}
        )
        return DiffDriveNode(
            context.node,
            params,
            max_wheel_speed=settings["max_wheel_speed"],
            ticks_topic=settings["ticks_topic"],
            targets_topic=settings["targets_topic"],
        )


class _Motors:
    """The emulated diffdrive firmware's state: wheel targets, when they came, counter zero."""

    def __init__(self) -> None:
        self.targets = (0.0, 0.0)
        self.commanded_at = -1e9
        self.offset: tuple[int, int] = (0, 0)


class HcSr04Plugin(DevicePlugin):
    """An HC-SR04: echo widths on ``sonar_echo``; the host node makes ``range``."""

    type = "hcsr04"
    summary = "ultrasonic ranger: sonar_echo -> range (sensor_msgs/Range)"
    firmware = "hwbridge/drivers/hcsr04.h: HcSr04"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("topic", str, "sonar_echo", "board topic of the echo widths"),
        Field("range_topic", str, "range", "host topic of sensor_msgs/Range"),
        Field("rate", float, 15.0, "readings per second", minimum=0.1, maximum=40.0),
        Field("temperature", float, 20.0, "air temperature, C", minimum=-40.0, maximum=85.0),
        Field("noise_std", float, 0.002, "emulator: echo noise, m", minimum=0.0),
        Field("frame_id", str, "sonar_link"),
        Field("min_range", float, MIN_RANGE, "m", minimum=0.0),
        Field("max_range", float, MAX_RANGE, "m", minimum=0.01),
    )

    def emulate(self, settings: Mapping[str, Any], board: EmulatedBoard) -> None:
        sonar = HcSr04Model(
            temperature_c=settings["temperature"],
            noise_std=settings["noise_std"],
            seed=board.seed + 2,
        )

        def read() -> bytes:
            echo = sonar.measure(board.world.sonar_distance())
            return _encode(
                board,
                "hwbridge_msgs/SonarEcho",
                {
                    "header": board.header(settings["frame_id"]),
                    "echo_us": int(echo),
                    "temperature": sonar.temperature_c,
                },
            )

        board.publisher(settings["topic"], "hwbridge_msgs/SonarEcho", settings["rate"], read)

    def topics(self, settings: Mapping[str, Any]) -> tuple[TopicUse, ...]:
        return (
            TopicUse(settings["topic"], "hwbridge_msgs/SonarEcho", "publishes", "board"),
            TopicUse(settings["topic"], "hwbridge_msgs/SonarEcho", "subscribes"),
            TopicUse(settings["range_topic"], "sensor_msgs/Range", "publishes"),
        )

    def host_node(self, settings: Mapping[str, Any], context: HostContext) -> Closeable:
        ranger = UltrasonicRanger(
            frame_id=settings["frame_id"],
            temperature_c=settings["temperature"],
            min_range=settings["min_range"],
            max_range=settings["max_range"],
        )
        return SonarNode(
            context.node,
            echo_topic=settings["topic"],
            range_topic=settings["range_topic"],
            ranger=ranger,
        )


class _MpuPlugin(DevicePlugin):
    """An MPU on the board's I2C bus: raw registers on ``imu_raw``; the host node makes ``imu``
    (and ``mag`` for an MPU-9250 with its magnetometer)."""

    chip_value: ClassVar[int]
    firmware = "hwbridge/drivers/mpu.h: Mpu"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("topic", str, "imu_raw", "board topic of the raw registers"),
        Field("imu_topic", str, "imu", "host topic of sensor_msgs/Imu"),
        _RATE,
        Field("accel_range_g", int, 2, "accelerometer full scale, g", ACCEL_RANGES_G),
        Field("gyro_range_dps", int, 250, "gyroscope full scale, deg/s", GYRO_RANGES_DPS),
        Field("frame_id", str, "imu_link"),
    )

    def _chip(self, seed: int) -> MpuChip:
        raise NotImplementedError

    def _magnetometer(self, settings: Mapping[str, Any]) -> bool:
        return False

    def emulate(self, settings: Mapping[str, Any], board: EmulatedBoard) -> None:
        chip = self._chip(board.seed + 3)
        accel_fs = ACCEL_RANGES_G.index(settings["accel_range_g"])
        gyro_fs = GYRO_RANGES_DPS.index(settings["gyro_range_dps"])
        chip.write(PWR_MGMT_1, bytes([0x00]))  # wake (the 6050 starts asleep)
        chip.write(GYRO_CONFIG, bytes([gyro_fs << 3]))
        chip.write(ACCEL_CONFIG, bytes([accel_fs << 3]))
        world = board.world
        mag = (
            _Magnetometer.set_up(chip, world.time)
            if isinstance(chip, Mpu9250) and self._magnetometer(settings)
            else None
        )
        chip_value = self.chip_value

        def read() -> bytes:
            chip.set_truth(world.imu_truth())
            chip.sample()
            raw = decode_burst(chip.read(ACCEL_XOUT_H, 14))
            reading = mag.read(world.time) if mag is not None else None
            fields = reading or {"mag": [0, 0, 0], "mag_st2": 0, "mag_asa": [0, 0, 0]}
            return _encode(
                board,
                "hwbridge_msgs/ImuRaw",
                {
                    "header": board.header(settings["frame_id"]),
                    "chip": chip_value,
                    "accel_config": chip.read(ACCEL_CONFIG, 1)[0],
                    "gyro_config": chip.read(GYRO_CONFIG, 1)[0],
                    "burst": [*raw.accel, raw.temperature, *raw.gyro],
                    **fields,
                    "mag_valid": reading is not None,
                },
            )

        board.publisher(settings["topic"], "hwbridge_msgs/ImuRaw", settings["rate"], read)

    def topics(self, settings: Mapping[str, Any]) -> tuple[TopicUse, ...]:
        uses: tuple[TopicUse, ...] = (
            TopicUse(settings["topic"], "hwbridge_msgs/ImuRaw", "publishes", "board"),
            TopicUse(settings["topic"], "hwbridge_msgs/ImuRaw", "subscribes"),
            TopicUse(settings["imu_topic"], "sensor_msgs/Imu", "publishes"),
        )
        if self._magnetometer(settings):
            uses += (TopicUse(settings["mag_topic"], "sensor_msgs/MagneticField", "publishes"),)
        return uses

    def host_node(self, settings: Mapping[str, Any], context: HostContext) -> Closeable:
        return ImuNode(
            context.node,
            raw_topic=settings["topic"],
            imu_topic=settings["imu_topic"],
            frame_id=settings["frame_id"],
        )


class Mpu6050Plugin(_MpuPlugin):
    type = "mpu6050"
    summary = "MPU-6050 IMU on I2C: imu_raw -> imu (sensor_msgs/Imu)"
    chip_value = 0  # hwbridge_msgs/ImuRaw MPU6050

    def _chip(self, seed: int) -> MpuChip:
        return Mpu6050(seed=seed)


class Mpu9250Plugin(_MpuPlugin):
    type = "mpu9250"
    summary = "MPU-9250 IMU on I2C with its AK8963: imu_raw -> imu and mag"
    chip_value = 1  # hwbridge_msgs/ImuRaw MPU9250
    fields = (
        *_MpuPlugin.fields,
        Field("magnetometer", bool, True, "read the AK8963 (publishes mag)"),
        Field("mag_topic", str, "mag", "host topic of sensor_msgs/MagneticField"),
    )

    def _chip(self, seed: int) -> MpuChip:
        return Mpu9250(seed=seed)

    def _magnetometer(self, settings: Mapping[str, Any]) -> bool:
        return bool(settings["magnetometer"])

    def host_node(self, settings: Mapping[str, Any], context: HostContext) -> Closeable:
        return ImuNode(
            context.node,
            raw_topic=settings["topic"],
            imu_topic=settings["imu_topic"],
            mag_topic=settings["mag_topic"],
            frame_id=settings["frame_id"],
        )


class BoardServoPlugin(DevicePlugin):
    """A Dynamixel servo on the board's own bus (its second UART), driven by the board: it
    publishes the joint's state and takes goal positions itself, so the host needs no node."""

    type = "dynamixel"
    summary = "a Dynamixel servo the board drives: joint_states, <joint>/goal_position"
    firmware = "hwbridge/drivers/dynamixel.h: DynamixelBus"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("joint", str, "pan", "joint name"),
        Field("id", int, 1, "servo id", minimum=0, maximum=252),
        Field("rate", float, 20.0, "joint state readings per second", minimum=0.1),
        Field("state_topic", str, "joint_states", "board topic of sensor_msgs/JointState"),
        Field("bus", dict, doc="the board's bus: {protocol, baud, servos: [{id, model}]}"),
    )

    def emulate(self, settings: Mapping[str, Any], board: EmulatedBoard) -> None:
        from hwbridge.devices.dynamixel import EmulatedDynamixelBus, find_model, packets

        bus = EmulatedDynamixelBus.from_config(settings["bus"])
        servo_id, joint = int(settings["id"]), str(settings["joint"])
        protocol = int(settings["bus"].get("protocol", 2))
        model = find_model(bus.servo(servo_id).model.name)
        table = model.table
        world = board.world
        lock = threading.Lock()
        bus_time = [0.0]

        def transact(packet: Any) -> Any:
            now = max(bus_time[0], world.time)
            reply = bus.feed(packets.encode(packet), now) + bus.advance(now + 0.005)
            bus_time[0] = now + 0.005
            return packets.decode(reply, protocol, "status") if reply else None

        address = table["Torque Enable"].address
        transact(packets.write_packet(protocol, servo_id, address, bytes([1])))

        def read() -> bytes:
            found = table["Present Position"]
            with lock:
                status = transact(
                    packets.read_packet(protocol, servo_id, found.address, found.size)
                )
            ticks = int.from_bytes(status.params, "little", signed=True) if status else 0
            return _encode(
                board,
                "sensor_msgs/JointState",
                {
                    "header": board.header(""),
                    "name": [joint],
                    "position": [model.ticks_to_radians(ticks)],
                },
            )

        def on_goal(payload: bytes) -> None:
            goal = msg.decode(payload, "std_msgs/Float64", board.registry)
            found = table["Goal Position"]
            ticks = model.radians_to_ticks(float(goal.data))
            with lock:
                transact(
                    packets.write_packet(
                        protocol,
                        servo_id,
                        found.address,
                        ticks.to_bytes(found.size, "little", signed=True),
                    )
                )

        board.publisher(settings["state_topic"], "sensor_msgs/JointState", settings["rate"], read)
        board.subscriber(f"{joint}/goal_position", "std_msgs/Float64", on_goal)

    def topics(self, settings: Mapping[str, Any]) -> tuple[TopicUse, ...]:
        return (
            TopicUse(settings["state_topic"], "sensor_msgs/JointState", "publishes", "board"),
            TopicUse(
                f"{settings['joint']}/goal_position", "std_msgs/Float64", "subscribes", "board"
            ),
        )


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
