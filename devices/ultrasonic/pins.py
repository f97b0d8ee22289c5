"""``hcsr04`` on the pins of firmware in simavr: a trigger pulse on its pin answered, about
0.5 ms later, by an echo pulse as wide as the round trip to the nearest wall in the beam
(:class:`~hwbridge.devices.ultrasonic.hcsr04.HcSr04Model`; no echo is a 38 ms pulse)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Final

from hwbridge.devices.ultrasonic.hcsr04 import HcSr04Model
from hwbridge.firmware.sim import arduino_pin
from hwbridge.robot.plugin import PinBoard, PinModel

if TYPE_CHECKING:
    from hwbridge.firmware.boards import PinName

__all__ = ["SONAR_REFRESH", "STUCK_ECHO_US", "SonarPins"]

SONAR_REFRESH: Final = 0.01
"""How often (simulated s) the sonar's next echo width is brought up to date."""
STUCK_ECHO_US: Final = 60_000_000
"""An echo line that never drops (a stuck clone) as a pulse this long."""


class SonarPins(PinModel):
    def __init__(self, settings: Mapping[str, Any], pins: Mapping[str, PinName], seed: int) -> None:
        self.pins = pins
        self.model = HcSr04Model(
            temperature_c=settings["temperature"],
            noise_std=settings.get("noise_std", 0.0),
            seed=seed + 2,
        )
        self.next_refresh = 0.0
        self.echo_us = -1

    def setup(self, board: PinBoard) -> None:
        mcu = board.mcu
        trigger, echo = (board.pins.number(self.pins[key]) for key in ("trigger", "echo"))
        board.command(f"sonar 0 {arduino_pin(trigger, mcu)} {arduino_pin(echo, mcu)}")
        self.next_refresh, self.echo_us = 0.0, -1
        self.after(board, 0.0)

    def after(self, board: PinBoard, now: float) -> None:
        if now < self.next_refresh:
            return
        self.next_refresh = now + SONAR_REFRESH
        high = self.model.echo_high_us(board.world.sonar_distance())
        echo_us = STUCK_ECHO_US if not math.isfinite(high) else max(1, round(high))
        if echo_us != self.echo_us:
            self.echo_us = echo_us
            board.command(f"echo 0 {echo_us}")
