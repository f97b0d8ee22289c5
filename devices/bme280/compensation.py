"""The BME280's trimming parameters and the datasheet's integer compensation formulas.

Each chip carries its own trimming parameters in non-volatile memory: ``dig_T1..T3`` and
``dig_P1..P9`` as little-endian words at 0x88..0x9F, ``dig_H1`` at 0xA1 and ``dig_H2..H6`` at
0xE1..0xE7, where H4 and H5 are 12-bit values sharing the nibbles of 0xE5 (BME280 datasheet,
section 4.2.2). :func:`compensate_t`, :func:`compensate_p` and :func:`compensate_h` are the
datasheet's ``BME280_compensate_T_int32``, ``BME280_compensate_P_int64`` and
``BME280_compensate_H_int32`` (section 4.2.3): raw ADC values in, 0.01 degC, Pa in Q24.8 and %RH
in Q22.10 out, in exact integer arithmetic (C's arithmetic shifts; its division truncates toward
zero, as :func:`_div` does). The board's driver (``hwbridge/drivers/bme280.h``) runs the same
formulas.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Final

__all__ = [
    "CALIB_H1",
    "CALIB_H2",
    "CALIB_TP",
    "TYPICAL",
    "Calibration",
    "compensate_h",
    "compensate_p",
    "compensate_t",
    "t_fine",
]

CALIB_TP: Final = 0x88
"""dig_T1..dig_P9: 12 little-endian words, 0x88..0x9F."""
CALIB_H1: Final = 0xA1
"""dig_H1 (unsigned byte)."""
CALIB_H2: Final = 0xE1
"""dig_H2..dig_H6: 7 bytes, 0xE1..0xE7."""

_TP: Final = struct.Struct("<HhhHhhhhhhhh")


@dataclass(frozen=True)
class Calibration:
    """One chip's trimming parameters (their C types in the datasheet's table 16)."""

    t1: int  # unsigned short
    t2: int  # signed short
    t3: int  # signed short
    p1: int  # unsigned short
    p2: int
    p3: int
    p4: int
    p5: int
    p6: int
    p7: int
    p8: int
    p9: int
    h1: int  # unsigned char
    h2: int  # signed short
    h3: int  # unsigned char
    h4: int  # signed 12 bits
    h5: int  # signed 12 bits
    h6: int  # signed char

    def tp_bytes(self) -> bytes:
        """Registers 0x88..0x9F."""
        return _TP.pack(
            self.t1, self.t2, self.t3, self.p1, self.p2, self.p3, self.p4, self.p5, self.p6,
            self.p7, self.p8, self.p9,
        )  # fmt: skip

    def h_bytes(self) -> bytes:
        """Registers 0xE1..0xE7: H2 (LE word), H3, then H4 and H5 packed into 0xE4..0xE6
        (0xE4 = H4[11:4], 0xE5 = H5[3:0] << 4 | H4[3:0], 0xE6 = H5[11:4]), H6."""
        h4, h5 = self.h4 & 0xFFF, self.h5 & 0xFFF
        return struct.pack(
            "<hBBBBb", self.h2, self.h3, h4 >> 4, ((h5 & 0x0F) << 4) | (h4 & 0x0F), h5 >> 4, self.h6
        )

    @classmethod
    def from_registers(cls, tp: bytes, h1: int, h: bytes) -> Calibration:
        """Parse what a driver reads: 24 bytes from 0x88, the byte at 0xA1, 7 bytes from 0xE1."""
        t1, t2, t3, p1, p2, p3, p4, p5, p6, p7, p8, p9 = _TP.unpack(bytes(tp[:24]))
        h2, h3, e4, e5, e6, h6 = struct.unpack("<hBbBbb", bytes(h[:7]))
        return cls(
            t1,
            t2,
            t3,
            p1,
            p2,
            p3,
            p4,
            p5,
            p6,
            p7,
            p8,
            p9,
            h1=h1 & 0xFF,
            h2=h2,
            h3=h3,
            h4=(e4 << 4) | (e5 & 0x0F),  # e4 is signed: the sign of H4
            h5=(e6 << 4) | (e5 >> 4),  # e6 is signed: the sign of H5
            h6=h6,
        )


TYPICAL: Final = Calibration(
    t1=27504, t2=26435, t3=-1000,
    p1=36477, p2=-10685, p3=3024, p4=2855, p5=140, p6=-7, p7=15500, p8=-14600, p9=6000,
    h1=75, h2=362, h3=0, h4=313, h5=50, h6=30,
)  # fmt: skip
"""Trimming parameters of a typical chip (the datasheet's worked example for T and P;
humidity values as chips commonly carry)."""


def _div(a: int, b: int) -> int:
    """C's integer division: the quotient truncated toward zero."""
    q = abs(a) // abs(b)
    return q if (a < 0) == (b < 0) else -q


def t_fine(adc_t: int, cal: Calibration) -> int:
    """The fine temperature the pressure and humidity formulas take (t_fine / 5120 is degC)."""
    var1 = (((adc_t >> 3) - (cal.t1 << 1)) * cal.t2) >> 11
    d = (adc_t >> 4) - cal.t1
    var2 = (((d * d) >> 12) * cal.t3) >> 14
    return var1 + var2


def compensate_t(fine: int) -> int:
    """Temperature in 0.01 degC from :func:`t_fine` (5123 is 51.23 degC)."""
    return (fine * 5 + 128) >> 8


def compensate_p(adc_p: int, fine: int, cal: Calibration) -> int:
    """Pressure in Pa as Q24.8 (24674867 is 96386.2 Pa); 0 where the formula would divide by
    zero."""
    var1 = fine - 128000
    var2 = var1 * var1 * cal.p6
    var2 += (var1 * cal.p5) << 17
    var2 += cal.p4 << 35
    var1 = ((var1 * var1 * cal.p3) >> 8) + ((var1 * cal.p2) << 12)
    var1 = (((1 << 47) + var1) * cal.p1) >> 33
    if var1 == 0:
        return 0
    p = 1048576 - adc_p
    p = _div(((p << 31) - var2) * 3125, var1)
    var1 = (cal.p9 * (p >> 13) * (p >> 13)) >> 25
    var2 = (cal.p8 * p) >> 19
    return (((p + var1 + var2) >> 8) + (cal.p7 << 4)) & 0xFFFFFFFF


def compensate_h(adc_h: int, fine: int, cal: Calibration) -> int:
    """Relative humidity in %RH as Q22.10 (47445 is 46.333 %RH), 0..100 %RH."""
    x = fine - 76800
    x = ((((adc_h << 14) - (cal.h4 << 20) - (cal.h5 * x)) + 16384) >> 15) * (
        (
            (((((x * cal.h6) >> 10) * (((x * cal.h3) >> 11) + 32768)) >> 10) + 2097152) * cal.h2
            + 8192
        )
        >> 14
    )
    x -= ((((x >> 15) * (x >> 15)) >> 7) * cal.h1) >> 4
    x = min(max(x, 0), 419430400)
    return x >> 12
