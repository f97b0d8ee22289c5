"""Host side of the MPU-6050 / MPU-9250: configure the chip, read bursts, publish SI messages.

:class:`MpuImu` talks to the chip through any :class:`I2CPort` (the emulated
:class:`~hwbridge.devices.buses.I2CBus`, or a board relaying I2C transfers), identifies it by
WHO_AM_I, wakes it, sets ranges, DLPF and sample rate, and turns 14-byte bursts into
``sensor_msgs/Imu`` (m/s^2, rad/s, REP-145; frame ``imu_link``; no orientation, so
``orientation_covariance[0] = -1`` and the orientation left as the identity quaternion) and, on
an MPU-9250, ``sensor_msgs/MagneticField`` in tesla rotated into the accelerometer's axes.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Final, Protocol, SupportsInt

from hwbridge import msg
from hwbridge.devices.imu.mpu import (
    ACCEL_CONFIG,
    ACCEL_LSB_PER_G,
    ACCEL_RANGES_G,
    ACCEL_XOUT_H,
    AK8963_ADDRESS,
    AK8963_ASAX,
    AK8963_CNTL1,
    AK8963_HXL,
    AK8963_WIA,
    AK8963_WIA_VALUE,
    CONFIG,
    GYRO_CONFIG,
    GYRO_LSB_PER_DPS,
    GYRO_RANGES_DPS,
    INT_ENABLE,
    INT_PIN_CFG,
    INT_STATUS,
    MAG_UT_PER_LSB_14BIT,
    MAG_UT_PER_LSB_16BIT,
    MPU6050,
    MPU9250,
    MPU_ADDRESS,
    PWR_MGMT_1,
    SMPLRT_DIV,
    USER_CTRL,
    WHO_AM_I,
    ChipSpec,
    ImuConfigError,
    ImuError,
    Vector3,
    gyro_output_rate,
)
from hwbridge.devices.world import STANDARD_GRAVITY

__all__ = [
    "CHIPS",
    "I2CPort",
    "ImuConfigError",
    "ImuError",
    "ImuReading",
    "MpuImu",
    "RawSample",
    "accel_scale",
    "configure_ak8963",
    "decode_burst",
    "decode_magnetometer",
    "gyro_scale",
    "sample_rate_divider",
    "sensitivity_adjustment",
]

CHIPS: Final[dict[int, ChipSpec]] = {MPU6050.who_am_i: MPU6050, MPU9250.who_am_i: MPU9250}
"""Chip models by WHO_AM_I value."""
_BURST: Final = struct.Struct(">7h")
_MAG: Final = struct.Struct("<3hB")
_RAW_IMU_ORIENTATION_COVARIANCE: Final = (-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


class I2CPort(Protocol):
    """Register transfers to devices on an I2C bus."""

    def write(self, address: int, reg: int, data: bytes) -> None:
        """Write ``data`` to registers from ``reg`` of the device at ``address``."""

    def read(self, address: int, reg: int, n: int) -> bytes:
        """Read ``n`` bytes from registers from ``reg`` of the device at ``address``."""
        ...


@dataclass(frozen=True)
class RawSample:
    """One 14-byte burst from ACCEL_XOUT_H, as signed counts."""

    accel: tuple[int, int, int]
    temperature: int
    gyro: tuple[int, int, int]


def decode_burst(data: bytes) -> RawSample:
    """The big-endian signed words of a 14-byte burst read from 0x3B."""
    if len(data) != _BURST.size:
        raise ImuError(f"an MPU data burst is {_BURST.size} bytes, got {len(data)}")
    ax, ay, az, temp, gx, gy, gz = _BURST.unpack(data)
    return RawSample((ax, ay, az), temp, (gx, gy, gz))


def decode_magnetometer(data: bytes) -> tuple[tuple[int, int, int], int]:
    """The HX, HY, HZ counts (little-endian signed) and the ST2 byte of the AK8963's 7 bytes
    read from 0x03 (HXL..ST2; reading ST2 ends the measurement's read)."""
    if len(data) != _MAG.size:
        raise ImuError(f"an AK8963 data read is {_MAG.size} bytes, got {len(data)}")
    mx, my, mz, st2 = _MAG.unpack(data)
    return (mx, my, mz), st2


def accel_scale(range_g: int) -> float:
    """m/s^2 per LSB at a full scale of +-``range_g`` g."""
    return STANDARD_GRAVITY / ACCEL_LSB_PER_G[ACCEL_RANGES_G.index(range_g)]


def gyro_scale(range_dps: int) -> float:
    """rad/s per LSB at a full scale of +-``range_dps`` deg/s."""
    return math.radians(1.0) / GYRO_LSB_PER_DPS[GYRO_RANGES_DPS.index(range_dps)]


def sensitivity_adjustment(asa: Iterable[SupportsInt]) -> Vector3:
    """The AK8963's per-axis factors from its fuse ROM bytes ASAX..ASAZ (datasheet 8.3.11):
    ``(ASA - 128) / 256 + 1``."""
    values = [int(value) for value in asa]
    if len(values) != 3 or not all(0 <= value <= 255 for value in values):
        raise ImuError(f"AK8963 sensitivity adjustment is 3 bytes, got {values!r}")
    ax, ay, az = ((value - 128) / 256.0 + 1.0 for value in values)
    return (ax, ay, az)


def sample_rate_divider(rate_hz: float, dlpf_cfg: int) -> int:
    """SMPLRT_DIV giving the rate closest to ``rate_hz``: gyro rate / (1 + div)."""
    gyro_rate = gyro_output_rate(dlpf_cfg)
    if not rate_hz > 0.0:
        raise ImuConfigError(f"sample rate must be positive, got {rate_hz!r}")
    return max(0, min(255, round(gyro_rate / rate_hz) - 1))


def configure_ak8963(port: I2CPort, mpu_address: int = MPU_ADDRESS) -> bytes:
    """Put an MPU-9250's AK8963 on the bus (bypass), read its fuse ROM and start it measuring
    continuously at 100 Hz with 16-bit output; its sensitivity adjustment bytes ASAX..ASAZ."""
    port.write(mpu_address, USER_CTRL, b"\x00")  # I2C master off ...
    port.write(mpu_address, INT_PIN_CFG, b"\x02")  # ... and bypass on: the AK8963 appears at 0x0C
    wia = port.read(AK8963_ADDRESS, AK8963_WIA, 1)[0]
    if wia != AK8963_WIA_VALUE:
        raise ImuError(f"AK8963 at 0x0C says WIA 0x{wia:02X}, expected 0x48")
    port.write(AK8963_ADDRESS, AK8963_CNTL1, b"\x00")  # power-down between modes
    port.write(AK8963_ADDRESS, AK8963_CNTL1, b"\x0f")  # fuse ROM access
    asa = port.read(AK8963_ADDRESS, AK8963_ASAX, 3)
    port.write(AK8963_ADDRESS, AK8963_CNTL1, b"\x00")
    port.write(AK8963_ADDRESS, AK8963_CNTL1, b"\x16")  # 16-bit, continuous 100 Hz
    return asa


def _xyz(vector: Vector3) -> dict[str, float]:
    return {"x": vector[0], "y": vector[1], "z": vector[2]}


@dataclass(frozen=True)
class ImuReading:
    """One reading, converted: the messages and the values they hold."""

    imu: Any
    """sensor_msgs/Imu."""
    magnetic_field: Any | None
    """sensor_msgs/MagneticField, on an MPU-9250 with its magnetometer enabled."""
    linear_acceleration: Vector3
    """m/s^2."""
    angular_velocity: Vector3
    """rad/s."""
    temperature_c: float
    field: Vector3 | None
    """Magnetic field (T) in the IMU frame; NaN on overflow."""


class MpuImu:
    """Host plugin for an MPU-6050 or MPU-9250 on an I2C port.

    ``accel_range_g`` (2, 4, 8, 16) and ``gyro_range_dps`` (250, 500, 1000, 2000) pick the full
    scales, ``dlpf_cfg`` (0-6) the bandwidth, ``sample_rate_hz`` the divider. ``accel_bias`` (m/s^2)
    and ``gyro_bias`` (rad/s) are subtracted after conversion (a calibration). Covariances default
    to the datasheet's white noise over the DLPF bandwidth; override with ``*_variance``.

    Temperature and covariances use the figures of the chip: the one :meth:`configure` finds,
    or ``chip`` when the chip is known otherwise (a board that reads it and says which it is).
    """

    def __init__(
        self,
        port: I2CPort,
        address: int = MPU_ADDRESS,
        *,
        accel_range_g: int = 2,
        gyro_range_dps: int = 250,
        dlpf_cfg: int = 3,
        sample_rate_hz: float = 100.0,
        frame_id: str = "imu_link",
        use_magnetometer: bool = True,
        accel_bias: Vector3 = (0.0, 0.0, 0.0),
        gyro_bias: Vector3 = (0.0, 0.0, 0.0),
        accel_variance: float | None = None,
        gyro_variance: float | None = None,
        chip: ChipSpec | None = None,
    ) -> None:
        self.port = port
        self.address = address
        self.accel_range_g = accel_range_g
        self.gyro_range_dps = gyro_range_dps
        self.accel_scale = accel_scale(accel_range_g)
        self.gyro_scale = gyro_scale(gyro_range_dps)
        if not 0 <= dlpf_cfg <= 6:
            raise ImuConfigError(f"dlpf_cfg must be 0-6, got {dlpf_cfg!r}")
        self.dlpf_cfg = dlpf_cfg
        self.divider = sample_rate_divider(sample_rate_hz, dlpf_cfg)
        self.frame_id = frame_id
        self.use_magnetometer = use_magnetometer
        self.accel_bias = accel_bias
        self.gyro_bias = gyro_bias
        self._accel_variance = accel_variance
        self._gyro_variance = gyro_variance
        self.chip: ChipSpec | None = chip
        """The chip whose figures convert readings: ``chip``, or the one :meth:`configure`
        found."""
        self.magnetometer_adjustment: Vector3 | None = None
        """AK8963 sensitivity adjustment per axis once configured (None without one)."""

    # ------------------------------------------------------------------ setup
    def configure(self, reset: bool = True) -> ChipSpec:
        """Identify, (reset,) wake and set up the chip; on an MPU-9250 also its magnetometer.

        A real chip needs about 100 ms after a reset before it takes writes; the caller waits
        (time is not read here).
        """
        who = self._read(WHO_AM_I, 1)[0]
        chip = CHIPS.get(who)
        if chip is None:
            raise ImuError(
                f"device at 0x{self.address:02X} says WHO_AM_I 0x{who:02X}; expected 0x68 "
                "(MPU-6050) or 0x71 (MPU-9250): check the address and the part"
            )
        settings = {
            PWR_MGMT_1: 0x01,  # awake, clock from the X gyro's PLL
            SMPLRT_DIV: self.divider,
            CONFIG: self.dlpf_cfg,
            GYRO_CONFIG: GYRO_RANGES_DPS.index(self.gyro_range_dps) << 3,
            ACCEL_CONFIG: ACCEL_RANGES_G.index(self.accel_range_g) << 3,
        }
        if reset:
            self._write(PWR_MGMT_1, 0x80)
        for reg, value in settings.items():
            self._write(reg, value)
        self._write(INT_ENABLE, 0x01)  # data ready
        for reg, value in settings.items():
            got = self._read(reg, 1)[0]
            if got != value:
                raise ImuError(
                    f"{chip.name} register 0x{reg:02X} reads 0x{got:02X} after writing "
                    f"0x{value:02X}: the chip did not take its configuration"
                )
        self.chip = chip
        self.magnetometer_adjustment = None
        if chip is MPU9250 and self.use_magnetometer:
            asa = configure_ak8963(self.port, self.address)
            self.magnetometer_adjustment = sensitivity_adjustment(asa)
        return chip

    # ------------------------------------------------------------------ reading
    def data_ready(self) -> bool:
        """True when a new sample was latched since the last check (reads INT_STATUS)."""
        return bool(self._read(INT_STATUS, 1)[0] & 0x01)

    def convert(self, raw: RawSample) -> tuple[Vector3, Vector3, float]:
        """SI values of a raw sample: acceleration (m/s^2), angular velocity (rad/s), temp (C)."""
        chip = self._spec
        ab, gb = self.accel_bias, self.gyro_bias
        a = tuple(
            count * self.accel_scale - bias for count, bias in zip(raw.accel, ab, strict=True)
        )
        g = tuple(count * self.gyro_scale - bias for count, bias in zip(raw.gyro, gb, strict=True))
        temperature = raw.temperature / chip.temp_lsb_per_c + chip.temp_offset_c
        return (a[0], a[1], a[2]), (g[0], g[1], g[2]), temperature

    def convert_magnetometer(self, data: bytes) -> Vector3:
        """Field (T) in the IMU's axes from the AK8963's 7 bytes at 0x03 (data and ST2)."""
        return self.magnetometer_field(*decode_magnetometer(data))

    def magnetometer_field(self, counts: tuple[int, int, int], st2: int) -> Vector3:
        """Field (T) in the IMU's axes from the AK8963's HX, HY, HZ counts and its ST2 byte
        (bit 4: 16-bit output; bit 3: overflow, giving NaN)."""
        mx, my, mz = counts
        if st2 & 0x08:  # HOFL: magnetic sensor overflow
            return (math.nan, math.nan, math.nan)
        per_lsb = MAG_UT_PER_LSB_16BIT if st2 & 0x10 else MAG_UT_PER_LSB_14BIT
        adj = self.magnetometer_adjustment or (1.0, 1.0, 1.0)
        bx, by, bz = (v * per_lsb * a * 1e-6 for v, a in zip((mx, my, mz), adj, strict=True))
        return (by, bx, -bz)  # AK8963 axes: x = IMU y, y = IMU x, z = -IMU z

    def read(self, stamp: float) -> ImuReading:
        """Read the latest sample (and field) and build the messages stamped ``stamp`` (s)."""
        accel, gyro, temperature = self.convert(decode_burst(self._read(ACCEL_XOUT_H, 14)))
        field: Vector3 | None = None
        mag_msg: Any | None = None
        if self.magnetometer_adjustment is not None:
            field = self.convert_magnetometer(self.port.read(AK8963_ADDRESS, AK8963_HXL, 7))
            mag_msg = self.magnetic_field_msg(field, stamp)
        return ImuReading(
            self.imu_msg(accel, gyro, stamp), mag_msg, accel, gyro, temperature, field
        )

    # ------------------------------------------------------------------ messages
    @property
    def _spec(self) -> ChipSpec:
        """The chip's figures; an error while the chip is unknown (never another chip's)."""
        if self.chip is None:
            raise ImuError(
                "the IMU's chip is not known yet: call configure() first, or give chip= "
                "(MPU6050 or MPU9250)"
            )
        return self.chip

    @property
    def accel_variance(self) -> float:
        """Variance (m/s^2)^2 put on the diagonal of linear_acceleration_covariance."""
        if self._accel_variance is not None:
            return self._accel_variance
        return (self._spec.accel_noise_std(self.dlpf_cfg) * STANDARD_GRAVITY) ** 2

    @property
    def gyro_variance(self) -> float:
        """Variance (rad/s)^2 put on the diagonal of angular_velocity_covariance."""
        if self._gyro_variance is not None:
            return self._gyro_variance
        return math.radians(self._spec.gyro_noise_std(self.dlpf_cfg)) ** 2

    def imu_msg(self, accel: Vector3, gyro: Vector3, stamp: float) -> Any:
        """``sensor_msgs/Imu`` without orientation (its covariance[0] is -1)."""
        av, gv = self.accel_variance, self.gyro_variance
        return msg.from_dict(
            "sensor_msgs/Imu",
            {
                "header": {"stamp": stamp, "frame_id": self.frame_id},
                "orientation": {"w": 1.0},
                "orientation_covariance": list(_RAW_IMU_ORIENTATION_COVARIANCE),
                "angular_velocity": _xyz(gyro),
                "angular_velocity_covariance": [gv, 0, 0, 0, gv, 0, 0, 0, gv],
                "linear_acceleration": _xyz(accel),
                "linear_acceleration_covariance": [av, 0, 0, 0, av, 0, 0, 0, av],
            },
        )

    def magnetic_field_msg(self, field: Vector3, stamp: float) -> Any:
        """``sensor_msgs/MagneticField`` in tesla; covariance all zero (unknown)."""
        return msg.from_dict(
            "sensor_msgs/MagneticField",
            {
                "header": {"stamp": stamp, "frame_id": self.frame_id},
                "magnetic_field": _xyz(field),
            },
        )

    # ------------------------------------------------------------------ I/O
    def _write(self, reg: int, value: int) -> None:
        self.port.write(self.address, reg, bytes([value]))

    def _read(self, reg: int, n: int) -> bytes:
        return self.port.read(self.address, reg, n)
