"""The emulated BME280 at register level, on the emulated I2C bus.

Register map (BME280 datasheet, section 5): trimming parameters at 0x88..0xA1 and 0xE1..0xE7
(:mod:`.compensation`), ``id`` 0xD0 (0x60), ``reset`` 0xE0 (0xB6 resets; reads 0), ``ctrl_hum``
0xF2 (osrs_h in bits 2:0, taking effect at the next write of ctrl_meas), ``status`` 0xF3 (bit 3
``measuring``), ``ctrl_meas`` 0xF4 (osrs_t 7:5, osrs_p 4:2, mode 1:0: 00 sleep, 01/10 forced, 11
normal), ``config`` 0xF5 (t_sb 7:5, filter 4:2), and the data: pressure 0xF7..0xF9 and
temperature 0xFA..0xFC (20 bits, msb first, the last byte's high nibble), humidity 0xFD..0xFE.

A forced measurement takes the datasheet's typical measurement time (section 9.1), with
``measuring`` set, then the chip goes back to sleep (mode bits 00) with the new data; in normal
mode it measures again after each standby time ``t_sb``. A measurement reads the air
(:class:`~hwbridge.devices.world.Air`, clamped to the operating range) and gives the raw ADC
values that the datasheet's compensation formulas turn back into it: each is found by bisection
(the formulas are monotonic over the chip's range) at the ADC's resolution, 16 bits plus one per
doubling of the oversampling for temperature and pressure (the IIR filter, not modelled, would
give 20), 16 bits for humidity. A skipped quantity (oversampling 0) reads 0x80000 (0x8000).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

from hwbridge.devices.bme280.compensation import (
    CALIB_H1,
    CALIB_H2,
    CALIB_TP,
    TYPICAL,
    Calibration,
    compensate_h,
    compensate_p,
    t_fine,
)
from hwbridge.devices.buses import I2CTarget
from hwbridge.devices.world import Air

__all__ = [
    "ADDRESSES",
    "CHIP_ID",
    "CONFIG",
    "CTRL_HUM",
    "CTRL_MEAS",
    "DATA",
    "ID",
    "MEASURING",
    "MODE_FORCED",
    "MODE_NORMAL",
    "MODE_SLEEP",
    "OVERSAMPLING",
    "PRESSURE_RANGE",
    "RESET",
    "RESET_VALUE",
    "STANDBY_MS",
    "STATUS",
    "TEMPERATURE_RANGE",
    "Bme280",
    "adc_values",
    "decode_data",
    "measurement_time",
]

ADDRESSES: Final = (0x76, 0x77)
"""SDO to GND, SDO to VDDIO."""
ID: Final = 0xD0
CHIP_ID: Final = 0x60
RESET: Final = 0xE0
RESET_VALUE: Final = 0xB6
CTRL_HUM: Final = 0xF2
STATUS: Final = 0xF3
CTRL_MEAS: Final = 0xF4
CONFIG: Final = 0xF5
DATA: Final = 0xF7
"""press_msb..hum_lsb, 8 bytes."""
MEASURING: Final = 0x08
"""status bit 3."""
MODE_SLEEP: Final = 0
MODE_FORCED: Final = 1
MODE_NORMAL: Final = 3
OVERSAMPLING: Final = (0, 1, 2, 4, 8, 16)
"""Oversampling by osrs_x code 0..5 (0: skipped; codes 6 and 7 also mean 16)."""
STANDBY_MS: Final = (0.5, 62.5, 125.0, 250.0, 500.0, 1000.0, 10.0, 20.0)
"""Normal mode's t_sb by config bits 7:5."""
TEMPERATURE_RANGE: Final = (-40.0, 85.0)
PRESSURE_RANGE: Final = (30000.0, 110000.0)
"""Operating range, Pa."""
_SKIPPED_20: Final = 0x80000
_SKIPPED_16: Final = 0x8000


def _oversampling(code: int) -> int:
    return OVERSAMPLING[min(code & 7, 5)]


def measurement_time(osrs_t: int, osrs_p: int, osrs_h: int) -> float:
    """Typical measurement time (s) for the oversampling factors (datasheet 9.1)."""
    ms = 1.0 + 2.0 * osrs_t
    ms += 2.0 * osrs_p + 0.5 if osrs_p else 0.0
    ms += 2.0 * osrs_h + 0.5 if osrs_h else 0.0
    return ms / 1000.0


def _bisect(
    value: Callable[[int], int], target: float, bits: int, width: int, *, rising: bool = True
) -> int:
    """The raw reading of ``bits`` resolution (as a ``width``-bit ADC value) whose compensated
    ``value`` is nearest ``target``; ``value`` increases with the reading (decreases if not
    ``rising``)."""
    shift = width - bits
    lo, hi = 0, (1 << bits) - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        found = value(mid << shift)
        if found < target if rising else found > target:
            lo = mid
        else:
            hi = mid
    best = min((lo, hi), key=lambda code: abs(value(code << shift) - target))
    return best << shift


def _clamp(value: float, low: float, high: float) -> float:
    return min(max(value, low), high)


def adc_values(
    air: Air, cal: Calibration = TYPICAL, osrs: tuple[int, int, int] = (1, 1, 1)
) -> tuple[int, int, int]:
    """Raw (adc_T, adc_P, adc_H) that compensate to ``air`` with ``cal``, at the resolution of
    the oversampling factors (osrs_t, osrs_p, osrs_h; 0 skips one)."""
    osrs_t, osrs_p, osrs_h = osrs
    temperature = _clamp(air.temperature, *TEMPERATURE_RANGE)
    fine_target = temperature * 5120.0
    adc_t = _bisect(lambda a: t_fine(a, cal), fine_target, _bits(osrs_t), 20)
    fine = t_fine(adc_t, cal)
    if not osrs_t:
        adc_t = _SKIPPED_20
    adc_p = _SKIPPED_20
    if osrs_p:
        pressure = _clamp(air.pressure, *PRESSURE_RANGE) * 256.0
        adc_p = _bisect(
            lambda a: _signed32(compensate_p(a, fine, cal)),
            pressure,
            _bits(osrs_p),
            20,
            rising=False,  # the more pressure, the lower the reading
        )
    adc_h = _SKIPPED_16
    if osrs_h:
        humidity = _clamp(air.humidity, 0.0, 100.0) * 1024.0
        adc_h = _bisect(lambda a: compensate_h(a, fine, cal), humidity, 16, 16)
    return adc_t, adc_p, adc_h


def _signed32(value: int) -> int:
    """A C uint32_t read as int32_t (the formula's result for readings beyond vacuum)."""
    return value - (1 << 32) if value & 0x80000000 else value


def _bits(osrs: int) -> int:
    """ADC resolution of temperature or pressure at oversampling ``osrs`` (filter off)."""
    return 16 + {1: 0, 2: 1, 4: 2, 8: 3, 16: 4}.get(osrs, 0)


class Bme280:
    """The chip's registers; time moves on with :meth:`advance`, the air it measures comes from
    ``air()`` at the start of each measurement."""

    def __init__(
        self,
        air: Callable[[], Air] = Air,
        *,
        address: int = ADDRESSES[0],
        calibration: Calibration = TYPICAL,
    ) -> None:
        self.air = air
        self.address = address
        self.calibration = calibration
        self.measurements = 0
        """Measurements completed since power-on (for tests)."""
        self.reset()

    def reset(self) -> None:
        """Power-on reset: sleep, nothing configured, data registers at their reset values."""
        self.regs = bytearray(256)
        self.regs[CALIB_TP : CALIB_TP + 24] = self.calibration.tp_bytes()
        self.regs[CALIB_H1] = self.calibration.h1
        self.regs[CALIB_H2 : CALIB_H2 + 7] = self.calibration.h_bytes()
        self.regs[ID] = CHIP_ID
        self._put_data(_SKIPPED_20, _SKIPPED_20, _SKIPPED_16)
        self._osrs_h = 0
        self._busy = 0.0
        """Time (s) left of the measurement under way (0: none)."""
        self._standby = 0.0
        """Normal mode: time (s) left before the next measurement."""

    def i2c_target(self, address: int) -> I2CTarget | None:
        return self if address == self.address else None

    @property
    def mode(self) -> int:
        mode = self.regs[CTRL_MEAS] & 3
        return MODE_FORCED if mode == 2 else mode

    @property
    def measuring(self) -> bool:
        return bool(self.regs[STATUS] & MEASURING)

    def oversampling(self) -> tuple[int, int, int]:
        """(osrs_t, osrs_p, osrs_h) factors in effect."""
        meas = self.regs[CTRL_MEAS]
        return _oversampling(meas >> 5), _oversampling(meas >> 2), _oversampling(self._osrs_h)

    def write(self, reg: int, data: bytes) -> None:
        for offset, value in enumerate(data):
            self._write_one((reg + offset) & 0xFF, value)

    def _write_one(self, reg: int, value: int) -> None:
        if reg == RESET:
            if value == RESET_VALUE:
                self.reset()
            return
        if reg == CTRL_HUM:
            self.regs[CTRL_HUM] = value & 0x07
        elif reg == CONFIG:
            self.regs[CONFIG] = value & 0xFD  # bit 1 reserved
        elif reg == CTRL_MEAS:
            self.regs[CTRL_MEAS] = value
            self._osrs_h = self.regs[CTRL_HUM]  # ctrl_hum takes effect now
            if self.mode == MODE_SLEEP:
                self._busy = 0.0
                self.regs[STATUS] &= ~MEASURING
            else:
                self._start()
        # other registers are read-only

    def _start(self) -> None:
        self._busy = measurement_time(*self.oversampling())
        self.regs[STATUS] |= MEASURING

    def read(self, reg: int, n: int) -> bytes:
        return bytes(self.regs[(reg + i) & 0xFF] for i in range(n))

    def advance(self, dt: float) -> None:
        """Let ``dt`` seconds pass: a measurement under way may end (forced: back to sleep;
        normal: the next starts after the standby time)."""
        while dt > 0.0:
            if self._busy > 0.0:
                step = min(dt, self._busy)
                self._busy -= step
                dt -= step
                if self._busy <= 1e-12:
                    self._finish()
            elif self.mode == MODE_NORMAL:
                step = min(dt, self._standby)
                self._standby -= step
                dt -= step
                if self._standby <= 1e-12:
                    self._start()
            else:
                return

    def _finish(self) -> None:
        self._busy = 0.0
        self.measurements += 1
        self._put_data(*adc_values(self.air(), self.calibration, self.oversampling()))
        self.regs[STATUS] &= ~MEASURING
        if self.mode == MODE_FORCED:
            self.regs[CTRL_MEAS] &= 0xFC  # back to sleep
        else:
            self._standby = STANDBY_MS[self.regs[CONFIG] >> 5] / 1000.0

    def _put_data(self, adc_t: int, adc_p: int, adc_h: int) -> None:
        self.regs[DATA : DATA + 8] = bytes(
            [
                (adc_p >> 12) & 0xFF,
                (adc_p >> 4) & 0xFF,
                (adc_p << 4) & 0xF0,
                (adc_t >> 12) & 0xFF,
                (adc_t >> 4) & 0xFF,
                (adc_t << 4) & 0xF0,
                (adc_h >> 8) & 0xFF,
                adc_h & 0xFF,
            ]
        )


def decode_data(data: bytes) -> tuple[int, int, int]:
    """(adc_T, adc_P, adc_H) from the 8 bytes at 0xF7."""
    adc_p = (data[0] << 12) | (data[1] << 4) | (data[2] >> 4)
    adc_t = (data[3] << 12) | (data[4] << 4) | (data[5] >> 4)
    return adc_t, adc_p, (data[6] << 8) | data[7]
