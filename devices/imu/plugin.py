"""``mpu6050`` and ``mpu9250``: an MPU on a board's I2C bus, as device plugins
(:mod:`hwbridge.robot.plugin`): their settings, their model on a virtual board, their pin-level
model (:mod:`.pins`) and their host node (:mod:`.node`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, ClassVar

from hwbridge.devices.buses import I2CBus
from hwbridge.devices.common import RATE, encode
from hwbridge.devices.imu import firmware as onboard
from hwbridge.devices.imu.host import configure_ak8963, decode_burst, decode_magnetometer
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
    Mpu6050,
    Mpu9250,
    MpuChip,
)
from hwbridge.devices.imu.node import ImuNode
from hwbridge.devices.imu.pins import MpuPins
from hwbridge.robot.plugin import (
    Closeable,
    DevicePlugin,
    EmulatedBoard,
    Field,
    HostContext,
    PinBoard,
    PinModel,
    SketchContext,
    SketchPart,
    TopicUse,
    Wiring,
)

if TYPE_CHECKING:
    from hwbridge.firmware.boards import McuBoard

__all__ = ["Mpu6050Plugin", "Mpu9250Plugin"]


class _MpuPlugin(DevicePlugin):
    """An MPU on the board's I2C bus: raw registers on ``imu_raw``; the host node makes ``imu``
    (and ``mag`` for an MPU-9250 with its magnetometer)."""

    chip_value: ClassVar[int]
    firmware = "hwbridge/drivers/mpu.h: Mpu"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("topic", str, "imu_raw", "board topic of the raw registers"),
        Field("imu_topic", str, "imu", "host topic of sensor_msgs/Imu"),
        RATE,
        Field("accel_range_g", int, 2, "accelerometer full scale, g", ACCEL_RANGES_G),
        Field("gyro_range_dps", int, 250, "gyroscope full scale, deg/s", GYRO_RANGES_DPS),
        Field("frame_id", str, "imu_link"),
        Field(
            "address", int, onboard.ADDRESSES[0], "I2C address (0x69: AD0 high)", onboard.ADDRESSES
        ),
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
            return encode(
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

    def pin_model(self, settings: Mapping[str, Any], board: PinBoard) -> PinModel:
        return MpuPins(self._chip(board.seed + 3), int(settings.get("address", 0x68)))

    def wiring(self, settings: Mapping[str, Any], board: McuBoard) -> Wiring:
        return onboard.wiring(settings, board, self._magnetometer(settings))

    def sketch(self, settings: Mapping[str, Any], context: SketchContext) -> SketchPart:
        return onboard.sketch(settings, context, self.chip_value, self._magnetometer(settings))

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
