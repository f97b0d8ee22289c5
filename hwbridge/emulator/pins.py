"""The emulator's world on the pins of real firmware in simavr.

:class:`PinWorld` is the pin-level twin of :class:`~hwbridge.emulator.board.VirtualBoard`: the
same :class:`~hwbridge.emulator.world.World` and robot file, but instead of publishing readings
itself it drives the pins of an AVR that runs the firmware a user flashes
(:class:`~hwbridge.firmware.sim.SimAvr`). The world advances on the AVR's own clock: every
report of the simulator (5 ms of simulated time) steps it by the time passed. Each device of the
robot file's board is put on the pins by its plugin's pin-level model
(:meth:`hwbridge.robot.plugin.DevicePlugin.pin_model`, in ``devices/<device>/pins.py``), which
reads the device's pins from its own settings in the robot file (its defaults for the board
where the file gives none) against the board's pin table (:mod:`hwbridge.firmware.boards`);
devices without a pin model (or without what they need on this board, or whose ``only_on``
leaves this board out) are left out with one log line.
"""

from __future__ import annotations

import logging
import threading

from hwbridge.emulator.board import BoardConfig
from hwbridge.emulator.world import World
from hwbridge.errors import HwBridgeError
from hwbridge.firmware.boards import McuBoard, board_of_mcu, mcu_board
from hwbridge.firmware.sim import SimAvr, Tick
from hwbridge.robot.plugin import PinModel
from hwbridge.robot.registry import get_device

__all__ = ["PinWorld"]

log = logging.getLogger("hwbridge.devices.pins")


class PinWorld:
    """A robot-file board's world on the pins of ``sim``. Call :meth:`attach` while the AVR is
    held (``sim.start(hold=True)``, then ``attach()``, then ``sim.go()``); a restart of the
    simulation sets the devices up again (the world goes on: the robot stays where it is)."""

    def __init__(
        self,
        sim: SimAvr,
        config: BoardConfig,
        *,
        board: str | None = None,
        seed: int = 0,
    ) -> None:
        self.sim = sim
        self.config = config
        self.pins: McuBoard = mcu_board(board) if board is not None else board_of_mcu(sim.mcu)
        """The MCU board's pin table (``board``, default the Uno or the Mega of the AVR)."""
        if self.pins.mcu != sim.mcu:
            raise HwBridgeError(f"a {self.pins.name} has an {self.pins.mcu}, not an {sim.mcu}")
        self.world = World(config.world, seed)
        self.lock = threading.Lock()
        """Held while the world steps (read the ground truth under it)."""
        self.last_time = 0.0
        self.seed = seed
        self.models: list[PinModel] = []
        self.skipped: list[str] = []
        for device in config.devices:
            if device.only_on and self.pins.name not in device.only_on:
                self.skipped.append(device.type)
                log.info(
                    "%s: %s is only on %s", config.name, device.name, ", ".join(device.only_on)
                )
                continue
            model = get_device(device.type).pin_model(device.settings, self)
            if model is None:
                self.skipped.append(device.type)
                log.info("%s: no pin-level model for %s; left out", config.name, device.type)
                continue
            self.models.append(model)

    @property
    def mcu(self) -> str:
        """The simulated AVR."""
        return self.sim.mcu

    def command(self, line: str) -> None:
        """Send one command line to the simulator."""
        self.sim.command(line)

    def attach(self) -> PinWorld:
        """Put the devices on the pins (now, and again at each restart of the simulation)."""
        self._setup()
        self.sim.on_start.append(self._setup)
        self.sim.on_tick.append(self._on_tick)
        self.sim.on_i2c_write.append(self._on_i2c_write)
        self.sim.on_uart.append(self._on_uart)
        return self

    def _setup(self) -> None:
        with self.lock:
            self.last_time = 0.0  # a restarted simulation's clock starts again from zero
            for model in self.models:
                model.setup(self)

    def _on_tick(self, tick: Tick) -> None:
        with self.lock:
            dt = tick.time - self.last_time
            if dt <= 0:
                return
            for model in self.models:
                model.tick(self, tick, dt)
            self.world.step(dt)
            for model in self.models:
                model.after(self, tick.time)
            self.last_time = tick.time

    def _on_uart(self, uart: str, data: bytes) -> bytes | None:
        with self.lock:
            for model in self.models:
                reply = model.packet(self, uart, data)
                if reply is not None:
                    return reply
        return None

    def _on_i2c_write(self, address: int, register: int, data: bytes) -> None:
        with self.lock:
            for model in self.models:
                model.i2c_write(self, address, register, data)
