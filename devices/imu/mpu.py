"""Emulated InvenSense MPU-6050 and MPU-9250 (with its AK8963 magnetometer) at register level.

Each chip answers on an I2C-like API (``write(reg, data)``, ``read(reg, n)``, register address
auto-incrementing) and is fed a true state (:class:`ImuTruth`: specific force in the chip frame
including gravity, angular velocity, temperature, magnetic field). The shared
:class:`~hwbridge.devices.buses.I2CBus` routes transfers by device address, as the board's I2C
master would.

Modelled: WHO_AM_I, reset values (the 6050 wakes up asleep, data registers zero and frozen until
PWR_MGMT_1's SLEEP bit is cleared; the 9250 wakes up awake), DEVICE_RESET, SMPLRT_DIV and the
DLPF setting (sample rate; noise bandwidth), full-scale selection, the big-endian 14-byte burst at
0x3B with saturation, the temperature sensor, INT_STATUS data-ready, white noise from the
datasheet's spectral densities and per-chip offsets and scale errors drawn within the datasheet's
bounds from a seeded generator; on the 9250 the bypass switch that puts the AK8963 on the bus at
0x0C, its modes, fuse ROM sensitivity adjustment, 14/16-bit output, overflow flag and its axes
(x and y swapped, z reversed relative to the accelerometer).
Not modelled: the DLPF's dynamics (inputs are latched as given), FIFO, self-test, motion
interrupts, the auxiliary I2C master, cross-axis sensitivity, temperature drift.

MPU-6050 figures are from its product specification (see DEVICES.md); MPU-9250 figures (noise
0.01 deg/s/sqrt(Hz) and 300 ug/sqrt(Hz), zero-rate offset +-5 deg/s, zero-g offset +-60 mg X/Y and
+-80 mg Z, temperature 333.87 LSB/C at 21 C) from the MPU-9250 product specification.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Final, SupportsIndex

import numpy as np

from hwbridge.devices.buses import I2CError, I2CTarget
from hwbridge.devices.world import STANDARD_GRAVITY
from hwbridge.errors import HwBridgeError

__all__ = [
    "ACCEL_CONFIG",
    "ACCEL_LSB_PER_G",
    "ACCEL_RANGES_G",
    "ACCEL_XOUT_H",
    "AK8963_ADDRESS",
    "AK8963_ASAX",
    "AK8963_CNTL1",
    "AK8963_CNTL2",
    "AK8963_HXL",
    "AK8963_ST1",
    "AK8963_ST2",
    "AK8963_WIA",
    "AK8963_WIA_VALUE",
    "CONFIG",
    "DLPF_ACCEL_BANDWIDTH_HZ",
    "DLPF_GYRO_BANDWIDTH_HZ",
    "GYRO_CONFIG",
    "GYRO_LSB_PER_DPS",
    "GYRO_RANGES_DPS",
    "INT_ENABLE",
    "INT_PIN_CFG",
    "INT_STATUS",
    "MAG_RANGE_UT",
    "MAG_UT_PER_LSB_14BIT",
    "MAG_UT_PER_LSB_16BIT",
    "MPU6050",
    "MPU9250",
    "MPU_ADDRESS",
    "MPU_ADDRESS_ALT",
    "PWR_MGMT_1",
    "PWR_MGMT_2",
    "SMPLRT_DIV",
    "TEMP_OUT_H",
    "USER_CTRL",
    "WHO_AM_I",
    "Ak8963",
    "ChipErrors",
    "ChipSpec",
    "FullScales",
    "ImuConfigError",
    "ImuError",
    "ImuTruth",
    "Mpu6050",
    "Mpu9250",
    "MpuChip",
    "Vector3",
    "gyro_output_rate",
]

Vector3 = tuple[float, float, float]

MPU_ADDRESS: Final = 0x68
"""I2C address with AD0 low."""
MPU_ADDRESS_ALT: Final = 0x69
"""I2C address with AD0 high."""
AK8963_ADDRESS: Final = 0x0C

# MPU-6050 / MPU-9250 registers
SMPLRT_DIV: Final = 0x19
CONFIG: Final = 0x1A
GYRO_CONFIG: Final = 0x1B
ACCEL_CONFIG: Final = 0x1C
ACCEL_CONFIG2: Final = 0x1D
INT_PIN_CFG: Final = 0x37
INT_ENABLE: Final = 0x38
INT_STATUS: Final = 0x3A
ACCEL_XOUT_H: Final = 0x3B
TEMP_OUT_H: Final = 0x41
GYRO_XOUT_H: Final = 0x43
USER_CTRL: Final = 0x6A
PWR_MGMT_1: Final = 0x6B
PWR_MGMT_2: Final = 0x6C
WHO_AM_I: Final = 0x75

_DEVICE_RESET: Final = 0x80
_SLEEP: Final = 0x40
_BYPASS_EN: Final = 0x02
_I2C_MST_EN: Final = 0x20
_DATA_RDY: Final = 0x01
_READ_ONLY: Final = frozenset({INT_STATUS, WHO_AM_I, *range(ACCEL_XOUT_H, 0x61)})

# AK8963 registers
AK8963_WIA: Final = 0x00
AK8963_WIA_VALUE: Final = 0x48
AK8963_ST1: Final = 0x02
AK8963_HXL: Final = 0x03
AK8963_ST2: Final = 0x09
AK8963_CNTL1: Final = 0x0A
AK8963_CNTL2: Final = 0x0B
AK8963_ASAX: Final = 0x10


class ImuError(HwBridgeError):
    """The IMU did not answer as expected (unknown WHO_AM_I, a setting that did not stick)."""


class ImuConfigError(ImuError, ValueError):
    """An IMU setting is not one the chip offers."""


class FullScales(tuple[int, ...]):
    """The full-scale choices of one setting, in register (FS_SEL) order.

    A tuple of ints, except that :meth:`index`, which turns a full scale into its FS_SEL
    value, raises :class:`ImuConfigError` naming the setting, the value and the choices when
    the chip does not offer that full scale (a plain tuple says only "x not in tuple").
    """

    setting: str
    """The setting's name where users give it (``accel_range_g`` in a board YAML)."""

    def __new__(cls, setting: str, values: tuple[int, ...]) -> FullScales:
        self = super().__new__(cls, values)
        self.setting = setting
        return self

    def index(
        self, value: object, start: SupportsIndex = 0, stop: SupportsIndex = sys.maxsize, /
    ) -> int:
        try:
            return super().index(value, start, stop)
        except ValueError:
            choices = ", ".join(map(str, self))
            raise ImuConfigError(
                f"{self.setting} must be one of {choices}, got {value!r}"
            ) from None


ACCEL_RANGES_G: Final = FullScales("accel_range_g", (2, 4, 8, 16))
"""Accelerometer full scale (+-g) for AFS_SEL 0..3 (ACCEL_CONFIG bits 4:3)."""
ACCEL_LSB_PER_G: Final = (16384.0, 8192.0, 4096.0, 2048.0)
GYRO_RANGES_DPS: Final = FullScales("gyro_range_dps", (250, 500, 1000, 2000))
"""Gyroscope full scale (+-deg/s) for FS_SEL 0..3 (GYRO_CONFIG bits 4:3)."""
GYRO_LSB_PER_DPS: Final = (131.0, 65.5, 32.8, 16.4)
DLPF_ACCEL_BANDWIDTH_HZ: Final = (260.0, 184.0, 94.0, 44.0, 21.0, 10.0, 5.0, 260.0)
"""Accelerometer bandwidth for DLPF_CFG 0..7 (7 is reserved; taken as 0)."""
DLPF_GYRO_BANDWIDTH_HZ: Final = (256.0, 188.0, 98.0, 42.0, 20.0, 10.0, 5.0, 256.0)
"""Gyroscope bandwidth for DLPF_CFG 0..7 (7 is reserved; taken as 0)."""
MAG_UT_PER_LSB_16BIT: Final = 0.15
MAG_UT_PER_LSB_14BIT: Final = 0.6
MAG_RANGE_UT: Final = 4912.0
"""AK8963 measurement range (+-uT); beyond it ST2's HOFL bit is set."""


def gyro_output_rate(dlpf_cfg: int) -> float:
    """Gyroscope output rate (Hz) that SMPLRT_DIV divides: 8 kHz with the DLPF off (DLPF_CFG 0
    or 7), 1 kHz otherwise."""
    return 8000.0 if dlpf_cfg in (0, 7) else 1000.0


@dataclass(frozen=True)
class ChipSpec:
    """Datasheet figures of one chip model."""

    name: str
    who_am_i: int
    pwr_mgmt_1_reset: int
    temp_lsb_per_c: float
    temp_offset_c: float
    """Temperature at raw 0: C = raw / temp_lsb_per_c + temp_offset_c."""
    gyro_noise_density: float
    """deg/s/sqrt(Hz)."""
    accel_noise_density: float
    """g/sqrt(Hz)."""
    gyro_offset_max: float
    """Initial zero-rate offset bound (+-deg/s)."""
    accel_offset_max: Vector3
    """Initial zero-g offset bound per axis (+-g)."""
    scale_tolerance: float
    """Sensitivity tolerance (fraction)."""

    def gyro_noise_std(self, dlpf_cfg: int) -> float:
        """Per-sample gyro noise (deg/s) at a DLPF setting."""
        return self.gyro_noise_density * math.sqrt(DLPF_GYRO_BANDWIDTH_HZ[dlpf_cfg & 7])

    def accel_noise_std(self, dlpf_cfg: int) -> float:
        """Per-sample accelerometer noise (g) at a DLPF setting."""
        return self.accel_noise_density * math.sqrt(DLPF_ACCEL_BANDWIDTH_HZ[dlpf_cfg & 7])


MPU6050: Final = ChipSpec(
    name="MPU-6050",
    who_am_i=0x68,
    pwr_mgmt_1_reset=0x40,
    temp_lsb_per_c=340.0,
    temp_offset_c=36.53,
    gyro_noise_density=0.005,
    accel_noise_density=400e-6,
    gyro_offset_max=20.0,
    accel_offset_max=(0.050, 0.050, 0.080),
    scale_tolerance=0.03,
)
MPU9250: Final = ChipSpec(
    name="MPU-9250",
    who_am_i=0x71,
    pwr_mgmt_1_reset=0x01,
    temp_lsb_per_c=333.87,
    temp_offset_c=21.0,
    gyro_noise_density=0.01,
    accel_noise_density=300e-6,
    gyro_offset_max=5.0,
    accel_offset_max=(0.060, 0.060, 0.080),
    scale_tolerance=0.03,
)


@dataclass(frozen=True)
class ImuTruth:
    """The true state a chip senses, in the chip's (accelerometer) frame, SI units."""

    specific_force: Vector3 = (0.0, 0.0, STANDARD_GRAVITY)
    """Acceleration minus gravity (m/s^2): at rest with z up, +g on z."""
    angular_velocity: Vector3 = (0.0, 0.0, 0.0)
    """rad/s."""
    temperature_c: float = 25.0
    magnetic_field: Vector3 = (0.0, 0.0, 0.0)
    """Tesla (used by the MPU-9250's magnetometer)."""


@dataclass(frozen=True)
class ChipErrors:
    """One chip's fixed errors: a reading is ``true x (1 + scale) + offset`` before noise."""

    accel_offset: Vector3 = (0.0, 0.0, 0.0)
    """m/s^2."""
    accel_scale: Vector3 = (0.0, 0.0, 0.0)
    gyro_offset: Vector3 = (0.0, 0.0, 0.0)
    """rad/s."""
    gyro_scale: Vector3 = (0.0, 0.0, 0.0)

    @classmethod
    def draw(cls, spec: ChipSpec, rng: np.random.Generator) -> ChipErrors:
        """Errors drawn uniformly within the datasheet's bounds."""

        def uniform(bounds: Vector3) -> Vector3:
            x, y, z = (float(rng.uniform(-b, b)) for b in bounds)
            return (x, y, z)

        tol = spec.scale_tolerance
        gyro_max = math.radians(spec.gyro_offset_max)
        accel_max = spec.accel_offset_max
        return cls(
            accel_offset=uniform(
                (
                    accel_max[0] * STANDARD_GRAVITY,
                    accel_max[1] * STANDARD_GRAVITY,
                    accel_max[2] * STANDARD_GRAVITY,
                )
            ),
            accel_scale=uniform((tol, tol, tol)),
            gyro_offset=uniform((gyro_max, gyro_max, gyro_max)),
            gyro_scale=uniform((tol, tol, tol)),
        )


def _int16(value: float) -> int:
    return max(-32768, min(32767, round(value)))


def _check_register_span(reg: int, n: int, size: int) -> None:
    if not 0 <= reg < size or n < 0 or reg + n > size:
        raise I2CError(f"register span 0x{reg:02X}+{n} is outside the map (0x00-0x{size - 1:02X})")


class MpuChip:
    """Register-level model of an MPU-6050 family chip (use :class:`Mpu6050` or :class:`Mpu9250`).

    ``errors`` are the chip's offsets and scale errors; ``None`` draws them from ``seed`` within
    the datasheet's bounds (``ChipErrors()`` gives an ideal chip). ``noise=False`` removes the
    white noise. Time only moves through :meth:`advance`; samples are latched at the configured
    sample rate while the chip is awake.
    """

    spec: ChipSpec = MPU6050

    def __init__(
        self,
        address: int = MPU_ADDRESS,
        *,
        seed: int = 0,
        errors: ChipErrors | None = None,
        noise: bool = True,
        truth: ImuTruth | None = None,
    ) -> None:
        if address not in (MPU_ADDRESS, MPU_ADDRESS_ALT):
            raise I2CError(f"an {self.spec.name} answers at 0x68 or 0x69, not 0x{address:02X}")
        self.address = address
        error_seed, noise_seed = np.random.SeedSequence(seed).spawn(2)
        self.errors = (
            errors
            if errors is not None
            else ChipErrors.draw(self.spec, np.random.default_rng(error_seed))
        )
        self.noise = noise
        self._rng = np.random.default_rng(noise_seed)
        self.truth = truth if truth is not None else ImuTruth()
        self.samples = 0
        """Sample instants passed while awake (the registers hold the latest)."""
        self._regs = bytearray(128)
        self._since_sample = 0.0
        self.reset()

    # ------------------------------------------------------------------ I2C
    def i2c_target(self, address: int) -> I2CTarget | None:
        """Self at its own address."""
        return self if address == self.address else None

    def reset(self) -> None:
        """Power-on / DEVICE_RESET state: every register to its reset value, data zero."""
        self._regs[:] = bytes(128)
        self._regs[PWR_MGMT_1] = self.spec.pwr_mgmt_1_reset
        self._regs[WHO_AM_I] = self.spec.who_am_i
        self._since_sample = 0.0

    def write(self, reg: int, data: bytes) -> None:
        """Write registers from ``reg`` on; read-only registers ignore writes."""
        _check_register_span(reg, len(data), len(self._regs))
        for offset, value in enumerate(data):
            address = reg + offset
            if address == PWR_MGMT_1 and value & _DEVICE_RESET:
                self.reset()
            elif address not in _READ_ONLY:
                self._regs[address] = value

    def read(self, reg: int, n: int) -> bytes:
        """Read ``n`` registers from ``reg`` on; reading INT_STATUS clears it."""
        _check_register_span(reg, n, len(self._regs))
        data = bytes(self._regs[reg : reg + n])
        if reg <= INT_STATUS < reg + n:
            self._regs[INT_STATUS] = 0
        return data

    # ------------------------------------------------------------------ configuration
    @property
    def asleep(self) -> bool:
        """True while PWR_MGMT_1's SLEEP bit is set."""
        return bool(self._regs[PWR_MGMT_1] & _SLEEP)

    @property
    def dlpf_cfg(self) -> int:
        """CONFIG bits 2:0."""
        return self._regs[CONFIG] & 0x07

    @property
    def accel_fs_sel(self) -> int:
        """ACCEL_CONFIG bits 4:3."""
        return (self._regs[ACCEL_CONFIG] >> 3) & 0x03

    @property
    def gyro_fs_sel(self) -> int:
        """GYRO_CONFIG bits 4:3."""
        return (self._regs[GYRO_CONFIG] >> 3) & 0x03

    @property
    def sample_rate(self) -> float:
        """Sample rate (Hz): gyro output rate / (1 + SMPLRT_DIV)."""
        return gyro_output_rate(self.dlpf_cfg) / (1 + self._regs[SMPLRT_DIV])

    # ------------------------------------------------------------------ time
    def set_truth(self, truth: ImuTruth) -> None:
        """The state the chip senses from now on."""
        self.truth = truth

    def advance(self, dt: float) -> None:
        """Let ``dt`` seconds pass; latch a sample if a sample instant passed while awake."""
        if dt < 0.0:
            raise ValueError(f"cannot go back in time (dt={dt!r})")
        if self.asleep:
            return
        period = 1.0 / self.sample_rate
        self._since_sample += dt
        instants = int(self._since_sample // period)
        if instants:
            self._since_sample -= instants * period
            self._latch()  # only the latest of several samples stays in the registers
            self.samples += instants

    def sample(self) -> None:
        """Latch one sample of the true state into the data registers now (if awake)."""
        if not self.asleep:
            self._latch()
            self.samples += 1

    def _latch(self) -> None:
        spec, truth, errors = self.spec, self.truth, self.errors
        accel_lsb = ACCEL_LSB_PER_G[self.accel_fs_sel]
        gyro_lsb = GYRO_LSB_PER_DPS[self.gyro_fs_sel]
        accel_noise = spec.accel_noise_std(self.dlpf_cfg) if self.noise else 0.0
        gyro_noise = spec.gyro_noise_std(self.dlpf_cfg) if self.noise else 0.0
        noise = self._rng.normal(0.0, 1.0, size=6)
        words: list[int] = []
        for axis in range(3):
            force = truth.specific_force[axis] * (1.0 + errors.accel_scale[axis])
            g = (force + errors.accel_offset[axis]) / STANDARD_GRAVITY
            words.append(_int16((g + accel_noise * float(noise[axis])) * accel_lsb))
        words.append(_int16((truth.temperature_c - spec.temp_offset_c) * spec.temp_lsb_per_c))
        for axis in range(3):
            rate = truth.angular_velocity[axis] * (1.0 + errors.gyro_scale[axis])
            dps = math.degrees(rate + errors.gyro_offset[axis])
            words.append(_int16((dps + gyro_noise * float(noise[3 + axis])) * gyro_lsb))
        for index, word in enumerate(words):
            self._regs[ACCEL_XOUT_H + 2 * index : ACCEL_XOUT_H + 2 * index + 2] = word.to_bytes(
                2, "big", signed=True
            )
        if self._regs[INT_ENABLE] & _DATA_RDY:
            self._regs[INT_STATUS] |= _DATA_RDY


class Mpu6050(MpuChip):
    """MPU-6050: WHO_AM_I 0x68, wakes up asleep (PWR_MGMT_1 = 0x40)."""

    spec = MPU6050


class Ak8963:
    """Register-level model of the AK8963 magnetometer inside the MPU-9250.

    Reset state is power-down (data zero). CNTL1 bits 3:0 pick the mode (0 power-down, 1 single,
    2 continuous 8 Hz, 6 continuous 100 Hz, 15 fuse ROM access), bit 4 the output width (0: 14-bit,
    0.6 uT/LSB; 1: 16-bit, 0.15 uT/LSB). Data are little-endian at 0x03-0x08 in the chip's own
    axes; ST1 bit 0 is data ready (cleared by reading ST2), ST2 bit 3 overflow, bit 4 the width.
    The sensitivity adjustment bytes ASAX..ASAZ (0x10-0x12) read only in fuse ROM mode; readings
    are scaled by ``1 / ((ASA - 128) / 256 + 1)`` so that the datasheet's correction restores them.
    """

    address: Final = AK8963_ADDRESS
    _MODE_RATES: Final = {0x2: 8.0, 0x6: 100.0}

    def __init__(self, asa: tuple[int, int, int] = (176, 176, 176)) -> None:
        self.asa = asa
        self.magnetic_field: Vector3 = (0.0, 0.0, 0.0)
        """True field (T) in the chip's axes."""
        self._regs = bytearray(0x13)
        self._since_sample = 0.0
        self._single_pending = False
        self.reset()

    def reset(self) -> None:
        """Power-on / soft reset: power-down mode, data zero."""
        self._regs[:] = bytes(len(self._regs))
        self._regs[AK8963_WIA] = AK8963_WIA_VALUE
        self._regs[0x01] = 0x9A  # INFO: a device information byte
        self._since_sample = 0.0
        self._single_pending = False

    def i2c_target(self, address: int) -> I2CTarget | None:
        """Self at 0x0C (for an AK8963 wired to the bus on its own)."""
        return self if address == self.address else None

    @property
    def mode(self) -> int:
        """CNTL1 bits 3:0."""
        return self._regs[AK8963_CNTL1] & 0x0F

    @property
    def sixteen_bit(self) -> bool:
        """CNTL1 bit 4 (BIT): 16-bit output."""
        return bool(self._regs[AK8963_CNTL1] & 0x10)

    def write(self, reg: int, data: bytes) -> None:
        """Write registers from ``reg`` on (CNTL1, CNTL2, ASTC are writable)."""
        _check_register_span(reg, len(data), len(self._regs))
        for offset, value in enumerate(data):
            address = reg + offset
            if address == AK8963_CNTL2 and value & 0x01:
                self.reset()
            elif address == AK8963_CNTL1:
                self._regs[address] = value & 0x1F
                self._single_pending = value & 0x0F == 0x1
                self._since_sample = 0.0
            elif address == 0x0C:
                self._regs[address] = value & 0x40

    def read(self, reg: int, n: int) -> bytes:
        """Read registers from ``reg`` on; reading ST2 ends a data read (clears DRDY and DOR)."""
        _check_register_span(reg, n, len(self._regs))
        data = bytearray(self._regs[reg : reg + n])
        for offset in range(n):
            if reg + offset >= AK8963_ASAX:
                asa_index = reg + offset - AK8963_ASAX
                data[offset] = self.asa[asa_index] if self.mode == 0xF else 0
        if reg <= AK8963_ST2 < reg + n:
            self._regs[AK8963_ST1] = 0
        return bytes(data)

    def advance(self, dt: float) -> None:
        """Let ``dt`` seconds pass; measure when the mode calls for it."""
        if self._single_pending and dt > 0.0:
            self._single_pending = False
            self.measure()
            self._regs[AK8963_CNTL1] &= 0x10  # back to power-down
            return
        rate = self._MODE_RATES.get(self.mode)
        if rate is None:
            return
        self._since_sample += dt
        if self._since_sample >= 1.0 / rate:
            self._since_sample %= 1.0 / rate
            self.measure()

    def measure(self) -> None:
        """Latch one measurement of :attr:`magnetic_field` into the data registers."""
        per_lsb = MAG_UT_PER_LSB_16BIT if self.sixteen_bit else MAG_UT_PER_LSB_14BIT
        limit = 32760 if self.sixteen_bit else 8190
        overflow = False
        for axis in range(3):
            microtesla = self.magnetic_field[axis] * 1e6
            overflow = overflow or abs(microtesla) > MAG_RANGE_UT
            adjust = (self.asa[axis] - 128) / 256.0 + 1.0
            raw = max(-limit, min(limit, round(microtesla / per_lsb / adjust)))
            start = AK8963_HXL + 2 * axis
            self._regs[start : start + 2] = raw.to_bytes(2, "little", signed=True)
        status = self._regs[AK8963_ST1]
        self._regs[AK8963_ST1] = 0x01 | (0x02 if status & 0x01 else 0x00)
        self._regs[AK8963_ST2] = (0x10 if self.sixteen_bit else 0x00) | (0x08 if overflow else 0)


class Mpu9250(MpuChip):
    """MPU-9250: WHO_AM_I 0x71, wakes up awake (PWR_MGMT_1 = 0x01), AK8963 behind a bypass.

    The magnetometer answers at 0x0C only while INT_PIN_CFG's BYPASS_EN is set and USER_CTRL's
    I2C_MST_EN is clear. Its axes relative to the accelerometer: x_mag = y, y_mag = x, z_mag = -z.
    """

    spec = MPU9250

    def __init__(
        self,
        address: int = MPU_ADDRESS,
        *,
        seed: int = 0,
        errors: ChipErrors | None = None,
        noise: bool = True,
        truth: ImuTruth | None = None,
        asa: tuple[int, int, int] | None = None,
    ) -> None:
        super().__init__(address, seed=seed, errors=errors, noise=noise, truth=truth)
        if asa is None:
            rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(3)[2])
            drawn = rng.integers(150, 200, size=3)
            asa = (int(drawn[0]), int(drawn[1]), int(drawn[2]))
        self.magnetometer = Ak8963(asa)
        self._feed_magnetometer()

    @property
    def bypass(self) -> bool:
        """True when the AK8963 is reachable on the main bus."""
        return bool(self._regs[INT_PIN_CFG] & _BYPASS_EN) and not (
            self._regs[USER_CTRL] & _I2C_MST_EN
        )

    def i2c_target(self, address: int) -> I2CTarget | None:
        """Self at its own address; the magnetometer at 0x0C in bypass mode."""
        if address == AK8963_ADDRESS and self.bypass:
            return self.magnetometer
        return super().i2c_target(address)

    def set_truth(self, truth: ImuTruth) -> None:
        """The state the chip (and its magnetometer) senses from now on."""
        super().set_truth(truth)
        self._feed_magnetometer()

    def _feed_magnetometer(self) -> None:
        bx, by, bz = self.truth.magnetic_field
        self.magnetometer.magnetic_field = (by, bx, -bz)

    def advance(self, dt: float) -> None:
        """Let ``dt`` seconds pass for the chip and its magnetometer."""
        super().advance(dt)
        self.magnetometer.advance(dt)
