"""The emulator's world on the pins of real firmware in simavr.

:class:`PinWorld` is the pin-level twin of :class:`~hwbridge.emulator.board.VirtualBoard`: the
same :class:`~hwbridge.emulator.world.World` and robot file, but instead of publishing readings
itself it drives the pins of an AVR that runs the firmware a user flashes
(:class:`~hwbridge.firmware.sim.SimAvr`). The world advances on the AVR's own clock: every
report of the simulator (5 ms of simulated time) steps it by the time passed. Each device of the
robot file's board is put on the pins by its plugin's pin-level model
(:meth:`hwbridge.robot.plugin.DevicePlugin.pin_model`, in ``devices/<device>/pins.py``);
devices without one (or without what they need on this board) are left out with one log line.
:class:`PinMap` says where the devices sit; its defaults are the wiring of the DiffDriveBase
example sketch (``firmware/HwBridge/examples/DiffDriveBase``).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

from hwbridge.emulator.board import BoardConfig
from hwbridge.emulator.world import World
from hwbridge.errors import HwBridgeError
from hwbridge.firmware.sim import SimAvr, Tick
from hwbridge.robot.plugin import PinModel
from hwbridge.robot.registry import get_device

__all__ = ["PinMap", "PinWorld"]

log = logging.getLogger("hwbridge.devices.pins")

Pin = int | str


@dataclass(frozen=True)
class PinMap:
    """Arduino pins (numbers, ``"A4"``, or port bits like ``"PD2"``) of the robot's devices.

    The defaults are DiffDriveBase's Uno wiring; :meth:`for_board` gives the Mega's."""

    left_encoder: tuple[Pin, Pin] = (2, 4)
    """A, B."""
    right_encoder: tuple[Pin, Pin] = (3, 5)
    left_motor: tuple[Pin, Pin] = (6, 7)
    """PWM, direction."""
    right_motor: tuple[Pin, Pin] = (10, 11)
    sonar: tuple[Pin, Pin] = (8, 12)
    """Trigger, echo."""
    imu_address: int = 0x68
    dynamixel_uart: str | None = None
    """The UART of the Dynamixel bus ("1".."3"; an Uno has none)."""

    @classmethod
    def for_board(cls, board: str) -> PinMap:
        """DiffDriveBase's wiring on ``uno`` or ``mega``."""
        if board == "uno":
            return cls()
        if board == "mega":
            return cls(left_encoder=(2, 3), right_encoder=(18, 19), dynamixel_uart="2")
        raise HwBridgeError(f"no DiffDriveBase wiring for board {board!r} (uno or mega)")

    def with_settings(self, settings: Mapping[str, Any]) -> PinMap:
        """This map with some pins replaced (``{"sonar": [9, 10]}``); unknown names refused."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(settings) - known)
        if unknown:
            raise HwBridgeError(
                f"unknown pins {', '.join(unknown)}: use {', '.join(sorted(known))}"
            )
        values: dict[str, Any] = {
            key: (
                int(value)
                if key == "imu_address"
                else str(value)
                if key == "dynamixel_uart"
                else tuple(value)
            )
            for key, value in settings.items()
        }
        return replace(self, **values)


class PinWorld:
    """A robot-file board's world on the pins of ``sim``. Call :meth:`attach` while the AVR is
    held (``sim.start(hold=True)``, then ``attach()``, then ``sim.go()``); a restart of the
    simulation sets the devices up again (the world goes on: the robot stays where it is)."""

    def __init__(
        self,
        sim: SimAvr,
        config: BoardConfig,
        *,
        pins: PinMap | None = None,
        seed: int = 0,
    ) -> None:
        self.sim = sim
        self.config = config
        self.pins = pins or PinMap.for_board("mega" if sim.mcu == "atmega2560" else "uno")
        self.world = World(config.world, seed)
        self.lock = threading.Lock()
        """Held while the world steps (read the ground truth under it)."""
        self.last_time = 0.0
        self.seed = seed
        self.models: list[PinModel] = []
        self.skipped: list[str] = []
        for device in config.devices:
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
