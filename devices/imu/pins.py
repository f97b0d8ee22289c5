"""``mpu6050`` / ``mpu9250`` on the pins of firmware in simavr: the chip's register file on the
TWI bus at its ``address`` setting (the register-level
:class:`~hwbridge.devices.imu.mpu.MpuChip`: asleep at power-on, WHO_AM_I, ranges from its
configuration registers, a 14-byte burst from 0x3B), sampling the world's motion."""

from __future__ import annotations

from hwbridge.devices.imu.mpu import MpuChip
from hwbridge.robot.plugin import PinBoard, PinModel

__all__ = ["MpuPins"]


class MpuPins(PinModel):
    def __init__(self, chip: MpuChip, address: int = 0x68) -> None:
        self.chip = chip
        self.address = address
        self.data = b""

    def setup(self, board: PinBoard) -> None:
        address = self.address
        self.chip.address = address
        self.chip.reset()  # power-on: asleep, registers at their reset values
        board.command(f"i2c {address:02x}")
        self._registers(board)

    def _registers(self, board: PinBoard) -> None:
        board.command(f"reg {self.chip.address:02x} 00 {self.chip.read(0, 0x3A).hex()}")
        board.command(f"reg {self.chip.address:02x} 49 {self.chip.read(0x49, 128 - 0x49).hex()}")
        self.data = b""
        self._data(board)

    def _data(self, board: PinBoard) -> None:
        data = self.chip.read(0x3B, 14)
        if data != self.data:
            self.data = data
            board.command(f"reg {self.chip.address:02x} 3b {data.hex()}")

    def i2c_write(self, board: PinBoard, address: int, register: int, data: bytes) -> None:
        if address != self.chip.address or register + len(data) > 128:
            return
        self.chip.write(register, data)
        self._registers(board)

    def after(self, board: PinBoard, now: float) -> None:
        self.chip.set_truth(board.world.imu_truth())
        self.chip.advance(now - board.last_time if now > board.last_time else 0.0)
        self._data(board)
