"""The pins of the MCU boards a robot file can name (``mcu: uno | nano | mega``): one table,
read by ``hwbridge robot check`` (:mod:`hwbridge.robot.wiring`), the sketch generator
(:mod:`hwbridge.sketchgen`) and the devices' pin models in simavr.

The facts are those of the Arduino AVR core's variants (``variants/standard``,
``variants/eightanaloginputs`` and ``variants/mega``, ``pins_arduino.h``): which numbers are
pins, where ``A0`` starts, which pins have PWM (``digitalPinHasPWM``) and an external interrupt
(``digitalPinToInterrupt``), the hardware UARTs and the TWI (I2C) pins. ``Serial`` (UART0, pins
0 and 1) always carries the board's link to the host, so its pins are never free.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from hwbridge.errors import HwBridgeError

__all__ = ["MCU_BOARDS", "McuBoard", "PinName", "UartPins", "board_of_mcu", "mcu_board"]

PinName = int | str
"""A pin as a robot file writes it: an Arduino number (``2``) or an analog name (``"A0"``)."""


@dataclass(frozen=True)
class UartPins:
    """A hardware serial port: its Arduino object name and its pins."""

    name: str
    rx: int
    tx: int


@dataclass(frozen=True)
class McuBoard:
    """One MCU board's pins, by Arduino number."""

    name: str
    mcu: str
    """The AVR (``atmega328p``), as avr-gcc and simavr name it."""
    digital: int
    """Pins 0 .. digital-1 are digital pins (the analog ones among them)."""
    first_analog: int
    """The number of ``A0``."""
    analog: int
    """``A0`` .. ``A{analog-1}``."""
    analog_only: frozenset[int]
    """Analog inputs that are no digital pins (the Nano's A6 and A7)."""
    pwm: frozenset[int]
    interrupts: frozenset[int]
    """Pins with an external interrupt (``attachInterrupt``)."""
    uarts: tuple[UartPins, ...]
    """Hardware serial ports; the first is ``Serial``, the host link."""
    sda: int
    scl: int

    @property
    def link(self) -> UartPins:
        """The UART of the board's link to the host (``Serial``)."""
        return self.uarts[0]

    @property
    def spare_uarts(self) -> tuple[UartPins, ...]:
        """The UARTs a device may have (all but the link's)."""
        return self.uarts[1:]

    def uart(self, name: str) -> UartPins | None:
        for uart in self.uarts:
            if uart.name == name:
                return uart
        return None

    def number(self, pin: PinName) -> int:
        """The Arduino number of ``pin`` (``"A4"`` -> 18 on an Uno); HwBridgeError, saying which
        pins there are, if the board has no such pin."""
        last_digital = self.digital - 1
        known = f"the {self.name} has pins 0-{last_digital} and A0-A{self.analog - 1}" + (
            f" (A{self.analog - 2}, A{self.analog - 1} analog only)" if self.analog_only else ""
        )
        if isinstance(pin, bool):
            raise HwBridgeError(f"{pin!r} is not a pin; {known}")
        if isinstance(pin, str):
            text = pin.strip().upper()
            if text.startswith("A") and text[1:].isdigit():
                index = int(text[1:])
                if index >= self.analog:
                    raise HwBridgeError(f"no pin {pin}: {known}")
                return self.first_analog + index
            if text.isdigit():
                pin = int(text)
            else:
                raise HwBridgeError(f"{pin!r} is not a pin (a number or A0, A1, ...); {known}")
        if not isinstance(pin, int):
            raise HwBridgeError(f"{pin!r} is not a pin (a number or A0, A1, ...); {known}")
        if 0 <= pin < self.digital or pin in self.analog_only:
            return pin
        raise HwBridgeError(f"no pin {pin}: {known}")

    def label(self, number: int) -> str:
        """``18`` -> ``18 (A4)`` on an Uno: a pin's number with its analog name, if it has one."""
        if self.first_analog <= number < self.first_analog + self.analog:
            return f"{number} (A{number - self.first_analog})"
        return str(number)


def _range(first: int, last: int) -> frozenset[int]:
    return frozenset(range(first, last + 1))


_ATMEGA328P_PWM: Final = frozenset({3, 5, 6, 9, 10, 11})

MCU_BOARDS: Final[dict[str, McuBoard]] = {
    "uno": McuBoard(
        name="uno",
        mcu="atmega328p",
        digital=20,
        first_analog=14,
        analog=6,
        analog_only=frozenset(),
        pwm=_ATMEGA328P_PWM,
        interrupts=frozenset({2, 3}),
        uarts=(UartPins("Serial", 0, 1),),
        sda=18,
        scl=19,
    ),
    "nano": McuBoard(
        name="nano",
        mcu="atmega328p",
        digital=20,
        first_analog=14,
        analog=8,
        analog_only=frozenset({20, 21}),
        pwm=_ATMEGA328P_PWM,
        interrupts=frozenset({2, 3}),
        uarts=(UartPins("Serial", 0, 1),),
        sda=18,
        scl=19,
    ),
    "mega": McuBoard(
        name="mega",
        mcu="atmega2560",
        digital=70,
        first_analog=54,
        analog=16,
        analog_only=frozenset(),
        pwm=_range(2, 13) | _range(44, 46),
        interrupts=frozenset({2, 3, 18, 19, 20, 21}),
        uarts=(
            UartPins("Serial", 0, 1),
            UartPins("Serial1", 19, 18),
            UartPins("Serial2", 17, 16),
            UartPins("Serial3", 15, 14),
        ),
        sda=20,
        scl=21,
    ),
}
"""The MCU boards a robot file's ``mcu:`` can name."""


def mcu_board(name: str) -> McuBoard:
    """The pin table of ``name``; HwBridgeError naming the known boards otherwise."""
    board = MCU_BOARDS.get(name)
    if board is None:
        raise HwBridgeError(f"unknown MCU board {name!r}; use one of {', '.join(MCU_BOARDS)}")
    return board


def board_of_mcu(mcu: str) -> McuBoard:
    """The table of a simulated AVR (``atmega2560`` -> the Mega; ``atmega328p`` -> the Uno)."""
    for board in MCU_BOARDS.values():
        if board.mcu == mcu:
            return board
    raise HwBridgeError(f"no MCU board with an {mcu}")
