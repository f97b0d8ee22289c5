"""``dynamixel`` on the pins of firmware in simavr: the servos of the device's ``bus``
(:class:`~hwbridge.devices.dynamixel.emulator.EmulatedDynamixelBus`) on a second UART (a Mega's
Serial2 in DiffDriveBase): each packet the firmware sends is answered by the bus model while the
AVR waits, so that the firmware's reply timeout holds whatever the host's scheduling."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hwbridge.devices.dynamixel.emulator import EmulatedDynamixelBus
from hwbridge.robot.plugin import PinBoard, PinModel

__all__ = ["DynamixelPins"]


class DynamixelPins(PinModel):
    """Servos on a bus UART: the firmware's packets answered by the emulated bus."""

    def __init__(self, settings: Mapping[str, Any], uart: str) -> None:
        self.bus = EmulatedDynamixelBus.from_config(settings["bus"])
        self.uart = uart
        """The simulator's number of the bus's UART (``2`` for Serial2)."""

    def setup(self, board: PinBoard) -> None:
        board.command(f"bus {self.uart}")

    def packet(self, board: PinBoard, uart: str, data: bytes) -> bytes | None:
        if uart != self.uart:
            return None
        now = board.last_time
        reply = self.bus.feed(data, now) + self.bus.advance(now + 0.002)
        return reply
