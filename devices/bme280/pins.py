"""``bme280`` on the pins of firmware in simavr: the chip's register file
(:class:`~hwbridge.devices.bme280.chip.Bme280`) on the TWI bus at its address, measuring the
world's air. The firmware's register writes reach the chip; what the chip shows (trimming
parameters, id, status, ctrl_meas going back to sleep, the data) is put back in the simulator's
register file whenever it changes, status, ctrl_meas and the data in one command so that the
firmware never sees a finished measurement without its data."""

from __future__ import annotations

from typing import Final

from hwbridge.devices.bme280.chip import Bme280
from hwbridge.robot.plugin import PinBoard, PinModel

__all__ = ["Bme280Pins"]

_BLOCKS: Final = ((0x88, 0xA2), (0xD0, 0xD1), (0xE0, 0xE8), (0xF2, 0xFF))
"""The register ranges [first, end) the chip shows: trimming parameters (and dig_H1), id,
reset and the humidity trimming, ctrl_hum..hum_lsb."""


class Bme280Pins(PinModel):
    def __init__(self, chip: Bme280) -> None:
        self.chip = chip
        self.shown: dict[int, bytes] = {}

    def setup(self, board: PinBoard) -> None:
        self.chip.reset()  # power-on
        board.command(f"i2c {self.chip.address:02x}")
        self.shown = {}
        self._show(board)

    def _show(self, board: PinBoard) -> None:
        for first, end in _BLOCKS:
            data = self.chip.read(first, end - first)
            if self.shown.get(first) != data:
                self.shown[first] = data
                board.command(f"reg {self.chip.address:02x} {first:02x} {data.hex()}")

    def i2c_write(self, board: PinBoard, address: int, register: int, data: bytes) -> None:
        if address != self.chip.address:
            return
        self.chip.write(register, data)
        self.shown = {}  # the write went into the simulator's copy too: show all again
        self._show(board)

    def after(self, board: PinBoard, now: float) -> None:
        self.chip.advance(now - board.last_time if now > board.last_time else 0.0)
        self._show(board)
