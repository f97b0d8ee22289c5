"""HC-SR04 ultrasonic ranger: echo pulse widths to ``sensor_msgs/Range``, and an emulated module.

The board triggers the module (a TTL pulse of at least 10 us), times the echo pulse and sends its
width in microseconds; :class:`UltrasonicRanger` turns that width into a ``sensor_msgs/Range``
with REP-117's special values. :class:`HcSr04Model` produces the width the board would measure for
a true distance, including the board timer's quantization, noise and the fault of clones whose
echo line never drops.

Physics: distance = t x v / 2 with v = 331.3 sqrt(1 + T/273.15) m/s (343.2 m/s at 20 C), so 1 cm of
range is about 58.3 us of echo and 4 m about 23.3 ms; without an echo the module drops the line
after about 38 ms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from hwbridge import msg
from hwbridge.errors import HwBridgeError

__all__ = [
    "FIELD_OF_VIEW",
    "MAX_RANGE",
    "MIN_RANGE",
    "MIN_TRIGGER_PULSE_US",
    "NO_ECHO_TIMEOUT_US",
    "RECOMMENDED_CYCLE_S",
    "SPEED_OF_SOUND_0C",
    "ULTRASOUND",
    "HcSr04Model",
    "UltrasonicError",
    "UltrasonicRanger",
    "distance_for_echo",
    "echo_for_distance",
    "speed_of_sound",
]

SPEED_OF_SOUND_0C: Final = 331.3
"""Speed of sound in dry air at 0 C (m/s)."""
MIN_RANGE: Final = 0.02
MAX_RANGE: Final = 4.0
FIELD_OF_VIEW: Final = 0.2618
"""Beam width, about 15 degrees (rad)."""
ULTRASOUND: Final = 0
"""``sensor_msgs/Range.ULTRASOUND``."""
NO_ECHO_TIMEOUT_US: Final = 38_000.0
"""Echo high time when nothing echoes: the module gives up after about 38 ms."""
MIN_TRIGGER_PULSE_US: Final = 10.0
RECOMMENDED_CYCLE_S: Final = 0.060
"""Recommended time between triggers (s), so that late echoes of one ping fade before the next."""


class UltrasonicError(HwBridgeError, ValueError):
    """An ultrasonic ranger parameter or a model input is out of range."""


def speed_of_sound(temperature_c: float = 20.0) -> float:
    """Speed of sound (m/s) in air at ``temperature_c`` degrees Celsius."""
    if temperature_c <= -273.15:
        raise UltrasonicError(f"temperature {temperature_c} C is below absolute zero")
    return SPEED_OF_SOUND_0C * math.sqrt(1.0 + temperature_c / 273.15)


def echo_for_distance(distance: float, temperature_c: float = 20.0) -> float:
    """Echo high time (s) for an obstacle at ``distance`` metres: the sound goes there and back."""
    return 2.0 * distance / speed_of_sound(temperature_c)


def distance_for_echo(echo: float, temperature_c: float = 20.0) -> float:
    """Distance (m) for an echo high time ``echo`` (s)."""
    return echo * speed_of_sound(temperature_c) / 2.0


@dataclass(frozen=True)
class UltrasonicRanger:
    """Host plugin: echo pulse widths (us, as the board measured them) to ``sensor_msgs/Range``.

    REP-117 values: ``+inf`` when nothing echoed (the module's ~38 ms timeout, or an echo from
    beyond ``max_range``), ``-inf`` for an obstacle closer than ``min_range``, ``nan`` for an
    erroneous reading (a width of 0: the board saw no complete pulse in its own timeout, e.g. a
    clone whose echo line stuck high; or a negative or non-finite width). Readings within
    ``tolerance`` metres outside the limits (one quantization step by default) are clamped to the
    limits rather than reported as out of range.
    """

    frame_id: str = "ultrasonic_link"
    temperature_c: float = 20.0
    """Air temperature assumed for the speed of sound (C)."""
    min_range: float = MIN_RANGE
    max_range: float = MAX_RANGE
    field_of_view: float = FIELD_OF_VIEW
    quantization_us: float = 4.0
    """Resolution of the board's echo timer (us)."""
    no_echo_threshold_us: float = 30_000.0
    """Widths at or above this are the module's no-echo timeout (4 m is 23.3 ms, the timeout 38)."""
    tolerance: float | None = None
    """Margin (m) around the limits that is clamped; ``None``: one quantization step."""

    def __post_init__(self) -> None:
        speed_of_sound(self.temperature_c)
        if not 0.0 <= self.min_range < self.max_range:
            raise UltrasonicError(
                f"need 0 <= min_range < max_range, got {self.min_range} and {self.max_range}"
            )
        if self.quantization_us < 0.0 or self.no_echo_threshold_us <= 0.0:
            raise UltrasonicError("quantization_us and no_echo_threshold_us must be positive")

    @property
    def margin(self) -> float:
        """Clamping margin (m) around the limits."""
        if self.tolerance is not None:
            return self.tolerance
        return distance_for_echo(self.quantization_us * 1e-6, self.temperature_c)

    def range_for_pulse(self, pulse_us: float) -> float:
        """Range (m) for an echo width, or REP-117's ``+inf``, ``-inf`` or ``nan``."""
        if not math.isfinite(pulse_us) or pulse_us <= 0.0:
            return math.nan
        if pulse_us >= self.no_echo_threshold_us:
            return math.inf
        distance = distance_for_echo(pulse_us * 1e-6, self.temperature_c)
        margin = self.margin
        if distance < self.min_range - margin:
            return -math.inf
        if distance > self.max_range + margin:
            return math.inf
        return min(max(distance, self.min_range), self.max_range)

    def to_range_msg(self, pulse_us: float, stamp: float) -> Any:
        """``sensor_msgs/Range`` for an echo width measured at ``stamp`` (s)."""
        return msg.from_dict(
            "sensor_msgs/Range",
            {
                "header": {"stamp": stamp, "frame_id": self.frame_id},
                "radiation_type": ULTRASOUND,
                "field_of_view": self.field_of_view,
                "min_range": self.min_range,
                "max_range": self.max_range,
                "range": self.range_for_pulse(pulse_us),
            },
        )


class HcSr04Model:
    """Emulated HC-SR04 as the board sees it: echo widths (us) for true distances.

    :meth:`measure` takes the true distance to the nearest obstacle in the beam (``None`` when
    there is none) and gives the echo width the board's timer reads: the true round-trip time
    plus ``N(0, noise_std)`` metres of range noise, measured by a timer of ``timer_resolution_us``
    (4 us: ``micros()`` on a 16 MHz AVR, Timer0 with prescaler 64) started at a random phase, so
    the error is under one tick. Obstacles beyond ``max_detect`` give no echo: the line drops
    after :data:`NO_ECHO_TIMEOUT_US`. With ``clone_fault`` the first missing echo leaves the line
    high for good (until :meth:`power_cycle`), and the board, timing out after
    ``board_timeout_us``, reads 0. Closer than 2 cm the module still reports the round trip; the
    host maps it to ``-inf``. A completed pulse reads at least one timer tick, so that 0 keeps
    meaning "timed out" (as Arduino's ``pulseIn`` returns). Randomness comes from a generator
    seeded with ``seed``.
    """

    def __init__(
        self,
        *,
        temperature_c: float = 20.0,
        timer_resolution_us: float = 4.0,
        noise_std: float = 0.0,
        max_detect: float = MAX_RANGE,
        clone_fault: bool = False,
        board_timeout_us: float = 50_000.0,
        seed: int = 0,
    ) -> None:
        speed_of_sound(temperature_c)
        if timer_resolution_us <= 0.0 or noise_std < 0.0 or max_detect <= 0.0:
            raise UltrasonicError(
                "timer_resolution_us and max_detect must be positive, noise_std not negative"
            )
        self.temperature_c = temperature_c
        self.timer_resolution_us = timer_resolution_us
        self.noise_std = noise_std
        self.max_detect = max_detect
        self.clone_fault = clone_fault
        self.board_timeout_us = board_timeout_us
        self.stuck = False
        """True once a clone's echo line has stuck high."""
        self.pings = 0
        self._rng = np.random.default_rng(seed)

    def power_cycle(self) -> None:
        """Switch the module off and on: a stuck echo line is released."""
        self.stuck = False

    def echo_high_us(self, distance: float | None) -> float:
        """True echo high time (us) before the board's timer: round trip or the no-echo timeout.

        ``inf`` when the line never drops (a stuck clone).
        """
        if distance is not None and not distance >= 0.0:
            raise UltrasonicError(f"a distance must be 0 or more metres, got {distance!r}")
        if self.stuck:
            return math.inf
        if distance is None or distance > self.max_detect:
            if self.clone_fault:
                self.stuck = True
                return math.inf
            return NO_ECHO_TIMEOUT_US
        noisy = distance
        if self.noise_std > 0.0:
            noisy = max(0.0, distance + float(self._rng.normal(0.0, self.noise_std)))
        return echo_for_distance(noisy, self.temperature_c) * 1e6

    def measure(self, distance: float | None) -> int:
        """Trigger once; the echo width (us) the board measures, 0 if it timed out."""
        self.pings += 1
        phase = float(self._rng.uniform(0.0, 1.0))  # timer phase at the rising edge, in ticks
        high = self.echo_high_us(distance)
        if high >= self.board_timeout_us:
            return 0
        q = self.timer_resolution_us
        ticks = math.floor(phase + high / q) - math.floor(phase)
        return int(max(ticks, 1) * q)  # a completed pulse reads at least one tick; 0 = timeout
