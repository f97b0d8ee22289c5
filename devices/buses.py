"""Bus models that devices of several kinds share: an emulated I2C bus (register transfers
routed by device address, as a board's I2C master makes them).

A chip on the bus is an :class:`I2CChip`: it says which :class:`I2CTarget` (a register file)
answers at an address, so one chip may answer at several (an MPU-9250 puts its AK8963 on the bus
at 0x0C when its bypass switch is on).
"""

from __future__ import annotations

from typing import Protocol

from hwbridge.errors import HwBridgeError

__all__ = ["I2CBus", "I2CChip", "I2CError", "I2CTarget"]


class I2CError(HwBridgeError):
    """An I2C transfer was not acknowledged (no device at the address, or a bad register)."""


class I2CTarget(Protocol):
    """Something answering register transfers at one I2C address."""

    def write(self, reg: int, data: bytes) -> None:
        """Write ``data`` from register ``reg`` on (auto-increment)."""

    def read(self, reg: int, n: int) -> bytes:
        """Read ``n`` bytes from register ``reg`` on (auto-increment)."""
        ...


class I2CChip(Protocol):
    """A chip on the bus: says which target, if any, answers at an address."""

    def i2c_target(self, address: int) -> I2CTarget | None:
        """The target answering at ``address`` now, or None."""


class I2CBus:
    """Emulated I2C bus: routes register transfers to the chip answering at an address."""

    def __init__(self, *chips: I2CChip) -> None:
        self._chips: list[I2CChip] = list(chips)
        self.transfers = 0

    def attach(self, chip: I2CChip) -> None:
        """Put ``chip`` on the bus."""
        self._chips.append(chip)

    def _target(self, address: int) -> I2CTarget:
        self.transfers += 1
        for chip in self._chips:
            target = chip.i2c_target(address)
            if target is not None:
                return target
        raise I2CError(
            f"no acknowledge from I2C address 0x{address:02X}: check wiring, the address pin "
            "(AD0) and, for an MPU-9250's magnetometer, that bypass mode is enabled"
        )

    def write(self, address: int, reg: int, data: bytes) -> None:
        """Write ``data`` to registers from ``reg`` of the device at ``address``."""
        self._target(address).write(reg, bytes(data))

    def read(self, address: int, reg: int, n: int) -> bytes:
        """Read ``n`` bytes from registers from ``reg`` of the device at ``address``."""
        return self._target(address).read(reg, n)
