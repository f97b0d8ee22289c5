"""Pin-level device models: the emulator's world on the pins of real firmware in simavr.

:class:`PinWorld` is the pin-level twin of :class:`~hwbridge.emulator.board.VirtualBoard`: the
same :class:`~hwbridge.emulator.world.World` and robot file, but instead of publishing readings
itself it drives the pins of an AVR that runs the firmware a user flashes
(:class:`~hwbridge.firmware.sim.SimAvr`). The world advances on the AVR's own clock: every
report of the simulator (5 ms of simulated time) steps it by the time passed. Each device type
of the robot file with a pin-level model here gets one:

- ``diffdrive``: two quadrature encoders whose A/B edges follow the wheels' angles (one step per
  count of ``counts_per_rev``, which counts every edge: a board decoding x2 sees half), and two
  motors whose PWM duty and direction pin set the wheel targets (full duty is the world's
  ``max_wheel_speed``, the direction pin high is forwards), as ``drivers/motor.h`` drives them;
- ``hcsr04``: a trigger pulse on its pin answered, about 0.5 ms later, by an echo pulse as wide
  as the round trip to the nearest wall in the beam (:class:`~hwbridge.devices.ultrasonic.
  HcSr04Model`; no echo is a 38 ms pulse);
- ``mpu6050`` / ``mpu9250``: the chip's register file on the TWI bus at 0x68 (the register-level
  :class:`~hwbridge.devices.imu.mpu.MpuChip`: asleep at power-on, WHO_AM_I, ranges from its
  configuration registers, a 14-byte burst from 0x3B), sampling the world's motion.

- ``dynamixel``: the servos of the device's ``bus`` (:class:`~hwbridge.devices.dynamixel.
  EmulatedDynamixelBus`) on a second UART (a Mega's Serial2 in DiffDriveBase): each packet the
  firmware sends is answered by the bus model while the AVR waits, so that the firmware's reply
  timeout holds whatever the host's scheduling; an Uno has no second UART and no bus.

Devices without a pin model are left out with one log line.
:class:`PinMap` says where the devices sit; its defaults are the wiring of the DiffDriveBase
example sketch (``firmware/HwBridge/examples/DiffDriveBase``).
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields, replace
from typing import Any, Final

from hwbridge.devices.imu.mpu import Mpu6050, Mpu9250, MpuChip
from hwbridge.devices.ultrasonic import HcSr04Model
from hwbridge.emulator.board import BoardConfig
from hwbridge.emulator.world import World
from hwbridge.errors import HwBridgeError
from hwbridge.firmware.sim import SimAvr, Tick, arduino_pin

__all__ = ["PIN_MODELS", "PinMap", "PinWorld"]

log = logging.getLogger("hwbridge.devices.pins")

Pin = int | str
SONAR_REFRESH: Final = 0.01
"""How often (simulated s) the sonar's next echo width is brought up to date."""
STUCK_ECHO_US: Final = 60_000_000
"""An echo line that never drops (a stuck clone) as a pulse this long."""


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


class _PinModel:
    """One device on the pins: set up before the AVR runs, then stepped at each report."""

    def setup(self, world: PinWorld) -> None:
        raise NotImplementedError

    def tick(self, world: PinWorld, tick: Tick, dt: float) -> None:
        """Before the world steps by ``dt``: read outputs into the world."""

    def after(self, world: PinWorld, now: float) -> None:
        """After the world stepped: put its state on the pins."""

    def i2c_write(self, world: PinWorld, address: int, register: int, data: bytes) -> None:
        """The firmware wrote registers of an I2C device."""

    def packet(self, world: PinWorld, uart: str, data: bytes) -> bytes | None:
        """The firmware sent ``data`` on bus UART ``uart``: the reply, if this device answers."""
        return None


class _DiffDrivePins(_PinModel):
    def __init__(self, settings: Mapping[str, Any]) -> None:
        self.settings = settings
        self.motors: list[tuple[str, str]] = []

    def setup(self, world: PinWorld) -> None:
        pins, mcu = world.pins, world.sim.mcu
        for index, (a, b) in enumerate((pins.left_encoder, pins.right_encoder)):
            world.sim.command(f"enc {index} {arduino_pin(a, mcu)} {arduino_pin(b, mcu)}")
        self.motors = [
            (arduino_pin(pwm, mcu), arduino_pin(direction, mcu))
            for pwm, direction in (pins.left_motor, pins.right_motor)
        ]
        for pwm, direction in self.motors:
            world.sim.command(f"out {pwm}")
            world.sim.command(f"out {direction}")
        self._positions(world)

    def tick(self, world: PinWorld, tick: Tick, dt: float) -> None:
        top = world.world.config.max_wheel_speed
        targets = []
        for pwm, direction in self.motors:
            duty = tick.duty.get(pwm, 0.0)
            forward = tick.duty.get(direction, 0.0) >= 0.5
            targets.append(top * duty * (1.0 if forward else -1.0))
        world.world.base.set_wheel_targets(targets[0], targets[1])

    def after(self, world: PinWorld, now: float) -> None:
        self._positions(world)

    def _positions(self, world: PinWorld) -> None:
        counts_per_rev = world.world.config.counts_per_rev
        for index, angle in enumerate(world.world.base.wheel_angles):
            steps = math.floor(angle / (2.0 * math.pi) * counts_per_rev)
            world.sim.command(f"pos {index} {steps}")


class _SonarPins(_PinModel):
    def __init__(self, settings: Mapping[str, Any], seed: int) -> None:
        self.model = HcSr04Model(
            temperature_c=settings["temperature"],
            noise_std=settings.get("noise_std", 0.0),
            seed=seed + 2,
        )
        self.next_refresh = 0.0
        self.echo_us = -1

    def setup(self, world: PinWorld) -> None:
        mcu = world.sim.mcu
        trigger, echo = world.pins.sonar
        world.sim.command(f"sonar 0 {arduino_pin(trigger, mcu)} {arduino_pin(echo, mcu)}")
        self.next_refresh, self.echo_us = 0.0, -1
        self.after(world, 0.0)

    def after(self, world: PinWorld, now: float) -> None:
        if now < self.next_refresh:
            return
        self.next_refresh = now + SONAR_REFRESH
        high = self.model.echo_high_us(world.world.sonar_distance())
        echo_us = STUCK_ECHO_US if not math.isfinite(high) else max(1, round(high))
        if echo_us != self.echo_us:
            self.echo_us = echo_us
            world.sim.command(f"echo 0 {echo_us}")


class _MpuPins(_PinModel):
    def __init__(self, chip: MpuChip) -> None:
        self.chip = chip
        self.data = b""

    def setup(self, world: PinWorld) -> None:
        address = world.pins.imu_address
        self.chip.address = address
        self.chip.reset()  # power-on: asleep, registers at their reset values
        world.sim.command(f"i2c {address:02x}")
        self._registers(world)

    def _registers(self, world: PinWorld) -> None:
        world.sim.command(f"reg {self.chip.address:02x} 00 {self.chip.read(0, 0x3A).hex()}")
        world.sim.command(
            f"reg {self.chip.address:02x} 49 {self.chip.read(0x49, 128 - 0x49).hex()}"
        )
        self.data = b""
        self._data(world)

    def _data(self, world: PinWorld) -> None:
        data = self.chip.read(0x3B, 14)
        if data != self.data:
            self.data = data
            world.sim.command(f"reg {self.chip.address:02x} 3b {data.hex()}")

    def i2c_write(self, world: PinWorld, address: int, register: int, data: bytes) -> None:
        if address != self.chip.address or register + len(data) > 128:
            return
        self.chip.write(register, data)
        self._registers(world)

    def after(self, world: PinWorld, now: float) -> None:
        self.chip.set_truth(world.world.imu_truth())
        self.chip.advance(now - world.last_time if now > world.last_time else 0.0)
        self._data(world)


class _DynamixelPins(_PinModel):
    """Servos on a bus UART: the firmware's packets answered by the emulated bus."""

    def __init__(self, settings: Mapping[str, Any]) -> None:
        from hwbridge.devices.dynamixel import EmulatedDynamixelBus

        self.bus = EmulatedDynamixelBus.from_config(settings["bus"])
        self.uart: str | None = None

    def setup(self, world: PinWorld) -> None:
        self.uart = world.pins.dynamixel_uart
        if self.uart is not None:
            world.sim.command(f"bus {self.uart}")

    def packet(self, world: PinWorld, uart: str, data: bytes) -> bytes | None:
        if uart != self.uart:
            return None
        now = world.last_time
        reply = self.bus.feed(data, now) + self.bus.advance(now + 0.002)
        return reply


def _diffdrive(settings: Mapping[str, Any], seed: int) -> _PinModel:
    return _DiffDrivePins(settings)


def _hcsr04(settings: Mapping[str, Any], seed: int) -> _PinModel:
    return _SonarPins(settings, seed)


def _mpu6050(settings: Mapping[str, Any], seed: int) -> _PinModel:
    return _MpuPins(Mpu6050(seed=seed + 3))


def _mpu9250(settings: Mapping[str, Any], seed: int) -> _PinModel:
    return _MpuPins(Mpu9250(seed=seed + 3))


def _dynamixel(settings: Mapping[str, Any], seed: int) -> _PinModel:
    return _DynamixelPins(settings)


PIN_MODELS: Final[dict[str, Callable[[Mapping[str, Any], int], _PinModel]]] = {
    "dynamixel": _dynamixel,
    "diffdrive": _diffdrive,
    "hcsr04": _hcsr04,
    "mpu6050": _mpu6050,
    "mpu9250": _mpu9250,
}
"""Device types with a pin-level model, by robot-file type."""


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
        self.models: list[_PinModel] = []
        self.skipped: list[str] = []
        for device in config.devices:
            make = PIN_MODELS.get(device.type)
            if make is _dynamixel and self.pins.dynamixel_uart is None:
                make = None  # no second UART for the bus
            if make is None:
                self.skipped.append(device.type)
                log.info("%s: no pin-level model for %s; left out", config.name, device.type)
                continue
            self.models.append(make(device.settings, seed))

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
