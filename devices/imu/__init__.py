"""MPU-6050 / MPU-9250 IMU: the emulated chip (:mod:`.mpu`) and the host plugin (:mod:`.plugin`).

The plugin turns the chip's registers into ``sensor_msgs/Imu`` (and ``sensor_msgs/MagneticField``
on an MPU-9250); the emulated chip answers the same register transfers on an emulated I2C bus.
"""

from hwbridge.devices.imu.mpu import (
    Ak8963,
    ChipErrors,
    ChipSpec,
    I2CBus,
    I2CError,
    ImuTruth,
    Mpu6050,
    Mpu9250,
    MpuChip,
)
from hwbridge.devices.imu.plugin import (
    I2CPort,
    ImuConfigError,
    ImuError,
    ImuReading,
    MpuImu,
    RawSample,
    decode_burst,
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
