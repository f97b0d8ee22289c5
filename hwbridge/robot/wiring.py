"""A board's wiring checked against its MCU board's pins (``mcu:`` in a robot file).

Each device says what it takes of the board (:meth:`~hwbridge.robot.plugin.DevicePlugin.wiring`:
pins with what each needs, I2C addresses, UARTs); :func:`board_problems` checks them all against
the board's pin table (:mod:`hwbridge.firmware.boards`) and reports, each at the line of the
offending value:

- a pin the board does not have;
- a pin used twice (naming both uses; the link's UART pins 0 and 1, a UART's RX and TX and the
  I2C bus's SDA and SCL count as used);
- a pin without an external interrupt where the driver counts edges in one (an encoder's A);
- a pin without PWM where the driver writes a duty (a motor's PWM pin);
- a UART the board does not have, or ``Serial`` (the link to the host): an Uno or a Nano has no
  second UART;
- two I2C devices at one address.

Devices with ``only_on`` that leaves this board out are not checked (the generator leaves them
out of this board's sketch).
"""

from __future__ import annotations

from dataclasses import dataclass

from hwbridge.errors import HwBridgeError
from hwbridge.firmware.boards import McuBoard, mcu_board
from hwbridge.robot.model import DeviceConfig, Robot, RobotBoardConfig, RobotFileError
from hwbridge.robot.plugin import Wiring, WiringError

__all__ = ["board_problems", "check_wiring", "device_wiring", "on_board"]


@dataclass
class _Taken:
    role: str
    device: str
    line: int


def on_board(device: DeviceConfig, mcu: str) -> bool:
    """Whether ``device`` is on a board of MCU board ``mcu`` (``only_on``)."""
    return not device.only_on or mcu in device.only_on


def _entry_line(device: DeviceConfig) -> int:
    _path, _sep, line = device.source.rpartition(":")
    return int(line) if line.isdigit() else 1


def device_wiring(device: DeviceConfig, board: McuBoard) -> Wiring | None:
    """The device's wiring on ``board`` from its plugin (WiringError for bad pin settings)."""
    from hwbridge.robot.registry import get_device

    return get_device(device.type).wiring(device.settings, board)


def board_problems(board: RobotBoardConfig, mcu: str) -> list[tuple[int, str]]:
    """Every wiring problem of ``board``'s devices on MCU board ``mcu``, as (line, text)."""
    table = mcu_board(mcu)
    problems: list[tuple[int, str]] = []
    taken: dict[int, _Taken] = {}
    link = table.link
    for number, end in ((link.rx, "RX"), (link.tx, "TX")):
        taken[number] = _Taken(f"Serial {end} (the link to the host)", "the board", 0)
    addresses: dict[int, _Taken] = {}
    bus_taken = False

    def take(number: int, role: str, device: DeviceConfig, line: int) -> None:
        other = taken.get(number)
        if other is None:
            taken[number] = _Taken(role, device.name, line)
            return
        where = f" at line {other.line}" if other.line else ""
        owner = f"{other.device}'s " if other.device != "the board" else ""
        problems.append(
            (
                line,
                f"{device.name}: pin {table.label(number)} ({role}) is used twice: also "
                f"{owner}{other.role}{where}",
            )
        )

    for device in board.devices:
        if not on_board(device, table.name):
            continue
        entry = _entry_line(device)

        def line_of(setting: str, device: DeviceConfig = device, entry: int = entry) -> int:
            return (device.line_of(setting) if setting else None) or entry

        try:
            wiring = device_wiring(device, table)
        except WiringError as exc:
            problems.append((line_of(exc.setting), f"{device.name}: {exc}"))
            continue
        if wiring is None:
            continue
        for use in wiring.pins:
            line = line_of(use.setting)
            try:
                number = table.number(use.pin)
            except HwBridgeError as exc:
                problems.append((line, f"{device.name}: {use.role}: {exc}"))
                continue
            if "interrupt" in use.needs and number not in table.interrupts:
                pins = ", ".join(map(str, sorted(table.interrupts)))
                problems.append(
                    (
                        line,
                        f"{device.name}: {use.role} on pin {table.label(number)}, which has no "
                        f"external interrupt (the {table.name} has them on pins {pins}): the "
                        "driver counts its edges in that interrupt",
                    )
                )
            if "pwm" in use.needs and number not in table.pwm:
                pins = ", ".join(map(str, sorted(table.pwm)))
                problems.append(
                    (
                        line,
                        f"{device.name}: {use.role} on pin {table.label(number)}, which has no "
                        f"PWM (the {table.name} has it on pins {pins})",
                    )
                )
            take(number, use.role, device, line)
        for name, setting in wiring.uarts:
            line = line_of(setting)
            uart = table.uart(name)
            spare = ", ".join(u.name for u in table.spare_uarts)
            if uart is None or uart is table.link:
                why = (
                    f"the {table.name} has no UART besides Serial, which carries the link to "
                    "the host (put the device on a mega, or mark it only_on: [mega])"
                    if not spare
                    else f"use one of {spare}"
                    + (" (Serial carries the link to the host)" if uart is table.link else "")
                )
                problems.append((line, f"{device.name}: {name} cannot be the device's UART: {why}"))
                continue
            take(uart.rx, f"{name} RX", device, line)
            take(uart.tx, f"{name} TX", device, line)
        for address, setting in wiring.i2c:
            line = line_of(setting)
            other = addresses.get(address)
            if other is not None:
                problems.append(
                    (
                        line,
                        f"{device.name}: I2C address 0x{address:02x} is used twice: also "
                        f"{other.device} at line {other.line}",
                    )
                )
            else:
                addresses[address] = _Taken("I2C", device.name, line)
            if not bus_taken:
                bus_taken = True
                take(table.sda, "I2C SDA", device, line)
                take(table.scl, "I2C SCL", device, line)
    return sorted(problems, key=lambda found: found[0])


def check_wiring(robot: Robot, board_name: str, mcu: str) -> None:
    """RobotFileError (``FILE:LINE: board NAME (MCU): ...`` each) if the wiring of board
    ``board_name`` does not fit MCU board ``mcu``."""
    board = robot.board(board_name)
    found = board_problems(board, mcu)
    if found:
        raise RobotFileError(
            [f"{robot.path}:{line}: board {board.name} ({mcu}): {text}" for line, text in found]
        )
