"""The host node of ``mpu6050`` and ``mpu9250``: ``imu_raw`` (hwbridge_msgs/ImuRaw) -> ``imu``
(sensor_msgs/Imu), and on an MPU-9250 with its magnetometer read, ``mag``
(sensor_msgs/MagneticField), next to the board on the graph (same namespace)."""

from __future__ import annotations

import logging
from typing import Any, Final

from hwbridge.devices.common import stamp_seconds
from hwbridge.devices.imu.host import MpuImu, RawSample, sensitivity_adjustment
from hwbridge.devices.imu.mpu import ACCEL_RANGES_G, GYRO_RANGES_DPS, MPU6050, MPU9250, ChipSpec
from hwbridge.graph import Node

__all__ = ["ImuNode"]

log = logging.getLogger("hwbridge.devices")


_RAW_CHIPS: Final[dict[int, ChipSpec]] = {0: MPU6050, 1: MPU9250}
"""hwbridge_msgs/ImuRaw ``chip`` values (its MPU6050 and MPU9250 constants) -> the chip."""


class ImuNode:
    """Raw MPU-6050/9250 registers -> sensor_msgs/Imu in SI units (REP-145); the MPU-9250's
    magnetometer readings -> sensor_msgs/MagneticField (tesla, NaN on overflow) on ``mag``,
    advertised with the first of them. Each reading is converted with the figures (temperature,
    noise) of the chip the board names; readings naming an unknown chip are dropped (counted in
    :attr:`dropped`, logged once)."""

    def __init__(
        self,
        node: Node,
        *,
        raw_topic: str = "imu_raw",
        imu_topic: str = "imu",
        mag_topic: str = "mag",
        frame_id: str = "imu_link",
    ) -> None:
        self.latest: Any = None
        self.latest_field: Any = None
        self.temperature_c: float | None = None
        """The die temperature (C) of the latest reading."""
        self.dropped = 0
        """Readings dropped because they name a chip this node does not know."""
        self.frame_id = frame_id
        """The frame of the Imu and MagneticField messages."""
        self._node = node
        self._converters: dict[tuple[str, int, int], MpuImu] = {}
        self._imu = node.publisher(imu_topic, "sensor_msgs/Imu")
        self._mag: Any = None
        self._mag_topic = mag_topic
        self._closed = False
        self._raw = node.subscriber(raw_topic, "hwbridge_msgs/ImuRaw", self._on_raw)

    def close(self) -> None:
        self._closed = True  # a reading still in _on_raw publishes nothing more (or a no-op)
        self._raw.close()
        self._imu.close()
        if self._mag is not None:
            self._mag.close()

    def _converter(self, chip: ChipSpec, accel_config: int, gyro_config: int) -> MpuImu:
        accel_fs, gyro_fs = (accel_config >> 3) & 3, (gyro_config >> 3) & 3
        key = (chip.name, accel_fs, gyro_fs)
        found = self._converters.get(key)
        if found is None:
            found = MpuImu(
                _NoPort(),
                accel_range_g=ACCEL_RANGES_G[accel_fs],
                gyro_range_dps=GYRO_RANGES_DPS[gyro_fs],
                chip=chip,
                frame_id=self.frame_id,
            )
            self._converters[key] = found
        return found

    def _on_raw(self, raw: Any) -> None:
        chip = _RAW_CHIPS.get(int(raw.chip))
        if chip is None:
            self.dropped += 1
            if self.dropped == 1:
                log.warning(
                    "%s: imu_raw names chip %d, which is neither MPU6050 (0) nor MPU9250 (1); "
                    "dropping such readings",
                    self._node.name,
                    int(raw.chip),
                )
            return
        words = [int(v) for v in raw.burst]
        converter = self._converter(chip, int(raw.accel_config), int(raw.gyro_config))
        accel, gyro, temperature = converter.convert(
            RawSample((words[0], words[1], words[2]), words[3], (words[4], words[5], words[6]))
        )
        stamp = stamp_seconds(raw.header.stamp)
        self.temperature_c = temperature
        self.latest = converter.imu_msg(accel, gyro, stamp)
        self._imu.publish(self.latest)
        if raw.mag_valid:
            converter.magnetometer_adjustment = sensitivity_adjustment(
                [int(v) for v in raw.mag_asa]
            )
            mx, my, mz = (int(v) for v in raw.mag)
            field = converter.magnetometer_field((mx, my, mz), int(raw.mag_st2))
            self.latest_field = converter.magnetic_field_msg(field, stamp)
            if self._closed:
                return
            if self._mag is None:
                self._mag = self._node.publisher(self._mag_topic, "sensor_msgs/MagneticField")
            self._mag.publish(self.latest_field)


class _NoPort:
    """The board reads the chip; the host only converts, so there is no I2C port here."""

    def write(self, address: int, reg: int, data: bytes) -> None:
        raise NotImplementedError("the board owns the I2C bus")

    def read(self, address: int, reg: int, n: int) -> bytes:
        raise NotImplementedError("the board owns the I2C bus")
