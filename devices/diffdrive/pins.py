"""``diffdrive`` on the pins of firmware in simavr: two quadrature encoders whose A/B edges
follow the wheels' angles (one step per count of ``counts_per_rev``, which counts every edge: a
board decoding x2 sees half), and two motors whose PWM duty and direction pin set the wheel
targets (full duty is the world's ``max_wheel_speed``, the direction pin high is forwards), as
``drivers/motor.h`` drives them."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING

from hwbridge.firmware.sim import arduino_pin
from hwbridge.robot.plugin import PinBoard, PinModel

if TYPE_CHECKING:
    from hwbridge.firmware.boards import PinName
    from hwbridge.firmware.sim import Tick

__all__ = ["DiffDrivePins"]


class DiffDrivePins(PinModel):
    def __init__(self, pins: Mapping[str, tuple[PinName, PinName]]) -> None:
        self.pins = pins
        """The device's pins (its ``pins`` setting over its defaults for the board)."""
        self.motors: list[tuple[str, str]] = []

    def setup(self, board: PinBoard) -> None:
        pins, mcu = self.pins, board.mcu
        for index, key in enumerate(("left_encoder", "right_encoder")):
            a, b = (board.pins.number(pin) for pin in pins[key])
            board.command(f"enc {index} {arduino_pin(a, mcu)} {arduino_pin(b, mcu)}")
        self.motors = []
        for key in ("left_motor", "right_motor"):
            pwm, direction = (arduino_pin(board.pins.number(pin), mcu) for pin in pins[key])
            self.motors.append((pwm, direction))
        for pwm, direction in self.motors:
            board.command(f"out {pwm}")
            board.command(f"out {direction}")
        self._positions(board)

    def tick(self, board: PinBoard, tick: Tick, dt: float) -> None:
        top = board.world.config.max_wheel_speed
        targets = []
        for pwm, direction in self.motors:
            duty = tick.duty.get(pwm, 0.0)
            forward = tick.duty.get(direction, 0.0) >= 0.5
            targets.append(top * duty * (1.0 if forward else -1.0))
        board.world.base.set_wheel_targets(targets[0], targets[1])

    def after(self, board: PinBoard, now: float) -> None:
        self._positions(board)

    def _positions(self, board: PinBoard) -> None:
        counts_per_rev = board.world.config.counts_per_rev
        for index, angle in enumerate(board.world.base.wheel_angles):
            steps = math.floor(angle / (2.0 * math.pi) * counts_per_rev)
            board.command(f"pos {index} {steps}")
