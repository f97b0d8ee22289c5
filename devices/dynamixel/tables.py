"""Control tables of the supported Dynamixel models, and their units.

Addresses, sizes, access, initial values and ranges are the maker's (ROBOTIS e-manual), for the
models in DEVICES.md: XL430-W250 (model 1060), XM430-W350 (1020), XM430-W210 (1030, the
e-manual's packet examples use it) and AX-12A (12). Indirect addresses are left out.

Units (DEVICES.md, "What ROS users expect"): X series position tick 2048 is 0 rad, 2 pi / 4096
rad per tick; velocity in 0.229 rev/min units (signed). AX-12A tick 512 is 0 rad, 300 deg / 1024
per tick; speed in 0.111 rev/min units, bit 10 the direction (set: clockwise, negative).
"""

from __future__ import annotations

import difflib
import functools
import math
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Final, Literal

from hwbridge.errors import HwBridgeError

__all__ = [
    "MODELS",
    "ControlTable",
    "Register",
    "ServoModel",
    "UnknownModelError",
    "UnknownRegisterError",
    "find_model",
    "normalize_name",
]

Access = Literal["R", "RW"]


class UnknownRegisterError(HwBridgeError, KeyError):
    """A register name or address that the model's control table does not have."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


class UnknownModelError(HwBridgeError, KeyError):
    """A model name or number that hwbridge has no control table for."""

    def __str__(self) -> str:
        return str(self.args[0])


@functools.lru_cache(maxsize=1024)
def normalize_name(name: str) -> str:
    """``Present Position``, ``present_position`` and ``PRESENT-POSITION`` all give one key."""
    return re.sub(r"[^a-z0-9]", "", name.lower())


@dataclass(frozen=True)
class Register:
    """One control-table item."""

    name: str
    address: int
    size: int
    access: Access = "RW"
    default: int = 0
    low: int | None = None
    """Smallest value accepted (None: any that fits)."""
    high: int | None = None
    unit: str = ""
    eeprom: bool = False
    signed: bool = False
    limit: tuple[str, str] | None = None
    """Names of the registers holding this one's (min, max) limits (a "Data Limit" check);
    the same name twice means ``-value .. value`` of that register."""
    allowed: frozenset[int] | None = None
    """The only values accepted, when they are not a range (Operating Mode)."""

    @property
    def end(self) -> int:
        return self.address + self.size

    @property
    def writable(self) -> bool:
        return self.access == "RW"

    def in_range(self, value: int) -> bool:
        """``low <= value <= high`` (a missing bound does not limit)."""
        return (self.low is None or value >= self.low) and (self.high is None or value <= self.high)

    def decode(self, data: bytes) -> int:
        """The register's value from its little-endian bytes."""
        return int.from_bytes(data, "little", signed=self.signed)

    def encode(self, value: int) -> bytes:
        """The little-endian bytes of ``value``; ValueError when it does not fit."""
        try:
            return int(value).to_bytes(self.size, "little", signed=self.signed)
        except OverflowError:
            kind = "signed" if self.signed else "unsigned"
            raise ValueError(
                f"{value} does not fit {self.name} ({self.size}-byte {kind})"
            ) from None


@dataclass(frozen=True)
class ControlTable:
    """The registers of one model, looked up by name (any spelling) or address."""

    registers: tuple[Register, ...]
    model: str = ""
    """The model's name (for messages)."""
    _by_name: dict[str, Register] = field(init=False, repr=False, compare=False)
    _by_address: dict[int, Register] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_by_name", {normalize_name(r.name): r for r in self.registers})
        object.__setattr__(self, "_by_address", {r.address: r for r in self.registers})

    def __iter__(self) -> Iterator[Register]:
        return iter(self.registers)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and normalize_name(name) in self._by_name

    @property
    def size(self) -> int:
        """Bytes from address 0 to the end of the last register."""
        return max(r.end for r in self.registers)

    def get(self, name: str) -> Register | None:
        return self._by_name.get(normalize_name(name))

    def __getitem__(self, name: str) -> Register:
        register = self.get(name)
        if register is None:
            names = [r.name for r in self.registers]
            close = difflib.get_close_matches(name, names, n=3, cutoff=0.5)
            close += [
                n for n in names if normalize_name(name) in normalize_name(n) and n not in close
            ][:3]
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            owner = f"the {self.model} control table" if self.model else "this control table"
            raise UnknownRegisterError(f"no register {name!r} in {owner}{hint}")
        return register

    def at(self, address: int) -> Register | None:
        """The register that starts at ``address``."""
        return self._by_address.get(address)

    def covering(self, address: int) -> Register | None:
        """The register that holds the byte at ``address``."""
        for register in self.registers:
            if register.address <= address < register.end:
                return register
        return None


@dataclass(frozen=True)
class ServoModel:
    """A servo model: number, control table and unit conversions."""

    name: str
    number: int
    table: ControlTable
    firmware: int
    series: Literal["X", "AX"]
    ticks_per_turn: float
    """Position ticks per radian times 2 pi: 4096 (X), 1024 * 360 / 300 (AX)."""
    zero_tick: int
    velocity_unit_rpm: float
    max_speed_rpm: float
    """No-load speed (emulated motion never goes faster)."""
    baud_rates: Mapping[int, int]
    """Baud Rate register value -> bits per second (the common ones for AX)."""
    eeprom_end: int
    """First RAM address: registers below it are EEPROM."""

    @property
    def radians_per_tick(self) -> float:
        return 2 * math.pi / self.ticks_per_turn

    def ticks_to_radians(self, ticks: float) -> float:
        return (ticks - self.zero_tick) * self.radians_per_tick

    def radians_to_ticks(self, radians: float) -> int:
        return round(radians / self.radians_per_tick + self.zero_tick)

    def velocity_to_rad_s(self, raw: int) -> float:
        """Present/Goal Velocity (X, signed) or Speed (AX, bit 10 = clockwise) to rad/s."""
        if self.series == "AX":
            magnitude = raw & 0x3FF
            value = -magnitude if raw & 0x400 else magnitude
        else:
            value = raw
        return value * self.velocity_unit_rpm * 2 * math.pi / 60

    def rad_s_to_velocity(self, rad_s: float) -> int:
        """rad/s to the register value (AX: magnitude 0-1023 and bit 10 for clockwise)."""
        units = round(rad_s * 60 / (2 * math.pi) / self.velocity_unit_rpm)
        if self.series == "AX":
            magnitude = min(abs(units), 0x3FF)
            return magnitude | (0x400 if units < 0 else 0)
        return units

    def baud_of(self, value: int) -> int:
        if self.series == "AX":
            return round(2_000_000 / (value + 1))
        return self.baud_rates[value]


def _x_table(
    name: str,
    *,
    number: int,
    temperature_limit: int,
    max_voltage: int,
    min_voltage: int,
    voltage_range: tuple[int, int],
    velocity_limit: int,
    velocity_i: int,
    position_d: int,
    position_p: int,
    current: bool,
) -> ControlTable:
    """The X series table (Protocol 2.0); ``current`` adds the XM current registers."""
    modes = {0, 1, 3, 4, 5, 16} if current else {1, 3, 4, 16}
    v_low, v_high = voltage_range
    eeprom = [
        Register("Model Number", 0, 2, "R", number, eeprom=True),
        Register("Model Information", 2, 4, "R", 0, eeprom=True),
        Register("Firmware Version", 6, 1, "R", 0, eeprom=True),
        Register("ID", 7, 1, "RW", 1, 0, 252, eeprom=True),
        Register("Baud Rate", 8, 1, "RW", 1, 0, 7, eeprom=True),
        Register("Return Delay Time", 9, 1, "RW", 250, 0, 254, "2 us", eeprom=True),
        Register("Drive Mode", 10, 1, "RW", 0, 0, 13, eeprom=True),
        Register("Operating Mode", 11, 1, "RW", 3, 0, 16, eeprom=True, allowed=frozenset(modes)),
        Register("Secondary ID", 12, 1, "RW", 255, 0, 255, eeprom=True),
        Register("Protocol Type", 13, 1, "RW", 2, 1, 2, eeprom=True),
        Register(
            "Homing Offset", 20, 4, "RW", 0, -1044479, 1044479, "tick", eeprom=True, signed=True
        ),
        Register("Moving Threshold", 24, 4, "RW", 10, 0, 1023, "0.229 rpm", eeprom=True),
        Register("Temperature Limit", 31, 1, "RW", temperature_limit, 0, 100, "C", eeprom=True),
        Register(
            "Max Voltage Limit", 32, 2, "RW", max_voltage, v_low, v_high, "0.1 V", eeprom=True
        ),
        Register(
            "Min Voltage Limit", 34, 2, "RW", min_voltage, v_low, v_high, "0.1 V", eeprom=True
        ),
        Register("PWM Limit", 36, 2, "RW", 885, 0, 885, "0.113 %", eeprom=True),
    ]
    if current:
        eeprom.append(Register("Current Limit", 38, 2, "RW", 1193, 0, 1193, "2.69 mA", eeprom=True))
    eeprom += [
        Register("Velocity Limit", 44, 4, "RW", velocity_limit, 0, 1023, "0.229 rpm", eeprom=True),
        Register("Max Position Limit", 48, 4, "RW", 4095, 0, 4095, "tick", eeprom=True),
        Register("Min Position Limit", 52, 4, "RW", 0, 0, 4095, "tick", eeprom=True),
        Register("Shutdown", 63, 1, "RW", 52, 0, 255, eeprom=True),
    ]
    ram = [
        Register("Torque Enable", 64, 1, "RW", 0, 0, 1),
        Register("LED", 65, 1, "RW", 0, 0, 1),
        Register("Status Return Level", 68, 1, "RW", 2, 0, 2),
        Register("Registered Instruction", 69, 1, "R", 0),
        Register("Hardware Error Status", 70, 1, "R", 0),
        Register("Velocity I Gain", 76, 2, "RW", velocity_i, 0, 16383),
        Register("Velocity P Gain", 78, 2, "RW", 100, 0, 16383),
        Register("Position D Gain", 80, 2, "RW", position_d, 0, 16383),
        Register("Position I Gain", 82, 2, "RW", 0, 0, 16383),
        Register("Position P Gain", 84, 2, "RW", position_p, 0, 16383),
        Register("Feedforward 2nd Gain", 88, 2, "RW", 0, 0, 16383),
        Register("Feedforward 1st Gain", 90, 2, "RW", 0, 0, 16383),
        Register("Bus Watchdog", 98, 1, "RW", 0, 0, 127, "20 ms"),
        Register(
            "Goal PWM",
            100,
            2,
            "RW",
            0,
            unit="0.113 %",
            signed=True,
            limit=("PWM Limit", "PWM Limit"),
        ),
    ]
    if current:
        ram.append(
            Register(
                "Goal Current",
                102,
                2,
                "RW",
                0,
                unit="2.69 mA",
                signed=True,
                limit=("Current Limit", "Current Limit"),
            )
        )
    ram += [
        Register(
            "Goal Velocity",
            104,
            4,
            "RW",
            0,
            unit="0.229 rpm",
            signed=True,
            limit=("Velocity Limit", "Velocity Limit"),
        ),
        Register("Profile Acceleration", 108, 4, "RW", 0, 0, 32767, "214.577 rev/min^2"),
        Register("Profile Velocity", 112, 4, "RW", 0, 0, 32767, "0.229 rpm"),
        Register(
            "Goal Position",
            116,
            4,
            "RW",
            0,
            unit="tick",
            signed=True,
            limit=("Min Position Limit", "Max Position Limit"),
        ),
        Register("Realtime Tick", 120, 2, "R", 0, unit="ms"),
        Register("Moving", 122, 1, "R", 0),
        Register("Moving Status", 123, 1, "R", 0),
        Register("Present PWM", 124, 2, "R", 0, unit="0.113 %", signed=True),
        Register(
            "Present Current" if current else "Present Load",
            126,
            2,
            "R",
            0,
            unit="2.69 mA" if current else "0.1 %",
            signed=True,
        ),
        Register("Present Velocity", 128, 4, "R", 0, unit="0.229 rpm", signed=True),
        Register("Present Position", 132, 4, "R", 0, unit="tick", signed=True),
        Register("Velocity Trajectory", 136, 4, "R", 0, unit="0.229 rpm", signed=True),
        Register("Position Trajectory", 140, 4, "R", 0, unit="tick", signed=True),
        Register("Present Input Voltage", 144, 2, "R", 0, unit="0.1 V"),
        Register("Present Temperature", 146, 1, "R", 0, unit="C"),
    ]
    return ControlTable(tuple(eeprom + ram), name)


def _ax_table() -> ControlTable:
    """AX-12A (Protocol 1.0)."""
    return ControlTable(
        (
            Register("Model Number", 0, 2, "R", 12, eeprom=True),
            Register("Firmware Version", 2, 1, "R", 0, eeprom=True),
            Register("ID", 3, 1, "RW", 1, 0, 253, eeprom=True),
            Register("Baud Rate", 4, 1, "RW", 1, 0, 254, eeprom=True),
            Register("Return Delay Time", 5, 1, "RW", 250, 0, 254, "2 us", eeprom=True),
            Register("CW Angle Limit", 6, 2, "RW", 0, 0, 1023, "tick", eeprom=True),
            Register("CCW Angle Limit", 8, 2, "RW", 1023, 0, 1023, "tick", eeprom=True),
            Register("Temperature Limit", 11, 1, "RW", 70, 0, 150, "C", eeprom=True),
            Register("Min Voltage Limit", 12, 1, "RW", 60, 50, 250, "0.1 V", eeprom=True),
            Register("Max Voltage Limit", 13, 1, "RW", 140, 50, 250, "0.1 V", eeprom=True),
            Register("Max Torque", 14, 2, "RW", 1023, 0, 1023, "0.1 %", eeprom=True),
            Register("Status Return Level", 16, 1, "RW", 2, 0, 2, eeprom=True),
            Register("Alarm LED", 17, 1, "RW", 36, 0, 127, eeprom=True),
            Register("Shutdown", 18, 1, "RW", 36, 0, 127, eeprom=True),
            Register("Torque Enable", 24, 1, "RW", 0, 0, 1),
            Register("LED", 25, 1, "RW", 0, 0, 1),
            Register("CW Compliance Margin", 26, 1, "RW", 1, 0, 255),
            Register("CCW Compliance Margin", 27, 1, "RW", 1, 0, 255),
            Register("CW Compliance Slope", 28, 1, "RW", 32, 0, 254),
            Register("CCW Compliance Slope", 29, 1, "RW", 32, 0, 254),
            Register(
                "Goal Position",
                30,
                2,
                "RW",
                512,
                0,
                1023,
                "tick",
                limit=("CW Angle Limit", "CCW Angle Limit"),
            ),
            Register("Moving Speed", 32, 2, "RW", 0, 0, 2047, "0.111 rpm"),
            Register("Torque Limit", 34, 2, "RW", 1023, 0, 1023, "0.1 %"),
            Register("Present Position", 36, 2, "R", 0, unit="tick"),
            Register("Present Speed", 38, 2, "R", 0, unit="0.111 rpm"),
            Register("Present Load", 40, 2, "R", 0, unit="0.1 %"),
            Register("Present Voltage", 42, 1, "R", 0, unit="0.1 V"),
            Register("Present Temperature", 43, 1, "R", 0, unit="C"),
            Register("Registered", 44, 1, "R", 0),
            Register("Moving", 46, 1, "R", 0),
            Register("Lock", 47, 1, "RW", 0, 0, 1),
            Register("Punch", 48, 2, "RW", 32, 32, 1023),
        ),
        "AX-12A",
    )


_X_BAUDS: Final = {
    0: 9600,
    1: 57600,
    2: 115200,
    3: 1_000_000,
    4: 2_000_000,
    5: 3_000_000,
    6: 4_000_000,
    7: 4_500_000,
}
_AX_BAUDS: Final = {
    1: 1_000_000,
    3: 500_000,
    4: 400_000,
    7: 250_000,
    9: 200_000,
    16: 117647,
    34: 57143,
    103: 19231,
    207: 9615,
}


def _x_model(name: str, number: int, *, xm: bool, velocity_limit: int, speed: float) -> ServoModel:
    table = _x_table(
        name,
        number=number,
        temperature_limit=80 if xm else 72,
        max_voltage=160 if xm else 140,
        min_voltage=95 if xm else 60,
        voltage_range=(95, 160) if xm else (60, 140),
        velocity_limit=velocity_limit,
        velocity_i=1920 if xm else 1000,
        position_d=0 if xm else 4000,
        position_p=800 if xm else 640,
        current=xm,
    )
    return ServoModel(
        name=name,
        number=number,
        table=table,
        firmware=38 if xm else 45,
        series="X",
        ticks_per_turn=4096,
        zero_tick=2048,
        velocity_unit_rpm=0.229,
        max_speed_rpm=speed,
        baud_rates=_X_BAUDS,
        eeprom_end=64,
    )


MODELS: Final[Mapping[str, ServoModel]] = {
    m.name: m
    for m in (
        _x_model("XL430-W250", 1060, xm=False, velocity_limit=265, speed=61.0),
        _x_model("XM430-W350", 1020, xm=True, velocity_limit=200, speed=46.0),
        _x_model("XM430-W210", 1030, xm=True, velocity_limit=330, speed=77.0),
        ServoModel(
            name="AX-12A",
            number=12,
            table=_ax_table(),
            firmware=24,
            series="AX",
            ticks_per_turn=1024 * 360 / 300,
            zero_tick=512,
            velocity_unit_rpm=0.111,
            max_speed_rpm=59.0,
            baud_rates=_AX_BAUDS,
            eeprom_end=24,
        ),
    )
}
"""Supported models by name."""


def find_model(key: str | int) -> ServoModel:
    """A model by name (any case, with or without dashes) or model number.

    Raises :class:`UnknownModelError`, naming ``key`` and the known models, for anything else.
    """
    if isinstance(key, int):
        number: int | None = key
    elif isinstance(key, str) and key.strip().isdigit():
        number = int(key)
    else:
        number = None
    if number is not None:
        for model in MODELS.values():
            if model.number == number:
                return model
        known = ", ".join(f"{m.name} ({m.number})" for m in MODELS.values())
        raise UnknownModelError(f"unknown Dynamixel model number {number}; known: {known}")
    if isinstance(key, str):
        wanted = normalize_name(key)
        for model in MODELS.values():
            if normalize_name(model.name) == wanted:
                return model
    raise UnknownModelError(f"unknown Dynamixel model {key!r}; known: {', '.join(MODELS)}")
