"""MPU-6050 / MPU-9250 IMU: the emulated chip (:mod:`.mpu`), the host-side driver and
conversions (:mod:`.host`), the device plugins ``mpu6050`` and ``mpu9250`` (:mod:`.plugin`), their
host node (:mod:`.node`) and their pin-level model for simavr (:mod:`.pins`).

The host side turns the chip's registers into ``sensor_msgs/Imu`` (and
``sensor_msgs/MagneticField`` on an MPU-9250); the emulated chip answers the same register
transfers on the shared emulated I2C bus (:mod:`hwbridge.devices.buses`).
"""

from hwbridge.devices.buses import I2CBus, I2CError
from hwbridge.devices.imu.host import (
    I2CPort,
    ImuConfigError,
    ImuError,
    ImuReading,
    MpuImu,
    RawSample,
    decode_burst,
)
from hwbridge.devices.imu.mpu import (
    Ak8963,
    ChipErrors,
    ChipSpec,
    ImuTruth,
    Mpu6050,
    Mpu9250,
    MpuChip,
)

__all__ = [
    "Ak8963",
    "ChipErrors",
    "ChipSpec",
    "I2CBus",
    "I2CError",
    "I2CPort",
    "ImuConfigError",
    "ImuError",
    "ImuReading",
    "ImuTruth",
    "Mpu6050",
    "Mpu9250",
    "MpuChip",
    "MpuImu",
    "RawSample",
    "decode_burst",
]
