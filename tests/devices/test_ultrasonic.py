"""hwbridge.devices.ultrasonic.hcsr04: HC-SR04 physics, the emulated module and
sensor_msgs/Range."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge import msg
from hwbridge.devices.ultrasonic.hcsr04 import (
    FIELD_OF_VIEW,
    MAX_RANGE,
    MIN_RANGE,
    NO_ECHO_TIMEOUT_US,
    HcSr04Model,
    UltrasonicError,
    UltrasonicRanger,
    distance_for_echo,
    echo_for_distance,
    speed_of_sound,
)

SETTINGS = settings(max_examples=200, deadline=None, derandomize=True)
QUANTUM_US = 4.0


def test_speed_of_sound_and_echo_times() -> None:
    assert speed_of_sound(0.0) == 331.3
    assert speed_of_sound(20.0) == pytest.approx(343.2, abs=0.05)
    # 1 cm of range = 58.3 us of echo at 343 m/s; 4 m = 23.3 ms.
    centimetre_us = 2 * 0.01 / 343.0 * 1e6
    assert centimetre_us == pytest.approx(58.3, abs=0.05)
    assert echo_for_distance(0.01, 20.0) * 1e6 == pytest.approx(58.3, abs=0.1)
    assert echo_for_distance(4.0, 20.0) * 1e3 == pytest.approx(23.3, abs=0.05)
    assert echo_for_distance(1.0, 0.0) > echo_for_distance(1.0, 30.0)  # slower sound when cold
    with pytest.raises(UltrasonicError):
        speed_of_sound(-300.0)


@SETTINGS
@given(
    distance=st.floats(min_value=0.0, max_value=10.0),
    temperature=st.floats(min_value=-40.0, max_value=60.0),
)
def test_distance_echo_round_trip(distance: float, temperature: float) -> None:
    echo = echo_for_distance(distance, temperature)
    assert distance_for_echo(echo, temperature) == pytest.approx(distance, rel=1e-12, abs=1e-15)


def _step_m(temperature: float) -> float:
    return distance_for_echo(QUANTUM_US * 1e-6, temperature)


@pytest.mark.parametrize("temperature", [-10.0, 20.0, 35.0])
def test_acceptance_range_within_one_quantization_step(temperature: float) -> None:
    model = HcSr04Model(temperature_c=temperature, seed=11)
    ranger = UltrasonicRanger(temperature_c=temperature)
    rng = np.random.default_rng(5)
    for distance in rng.uniform(MIN_RANGE, MAX_RANGE, size=300):
        pulse = model.measure(float(distance))
        assert pulse % 4 == 0
        assert abs(ranger.range_for_pulse(pulse) - distance) <= _step_m(temperature)


def test_acceptance_with_modelled_noise() -> None:
    noise = 0.003
    model = HcSr04Model(noise_std=noise, seed=3)
    ranger = UltrasonicRanger()
    rng = np.random.default_rng(9)
    errors = []
    for distance in rng.uniform(0.1, 3.9, size=500):
        error = ranger.range_for_pulse(model.measure(float(distance))) - distance
        assert abs(error) <= _step_m(20.0) + 5 * noise
        errors.append(error)
    assert np.std(errors) == pytest.approx(noise, rel=0.15)  # the noise is really there


def test_quantization_is_seeded() -> None:
    distances = [0.5, 1.234, 2.0, 3.3]
    first = [HcSr04Model(seed=1, noise_std=0.01).measure(d) for d in distances]
    again = [HcSr04Model(seed=1, noise_std=0.01).measure(d) for d in distances]
    other = [HcSr04Model(seed=2, noise_std=0.01).measure(d) for d in distances]
    assert first == again != other


def test_edge_cases_2cm_4m_beyond_and_no_echo() -> None:
    model = HcSr04Model(seed=4)
    ranger = UltrasonicRanger()
    at_min = ranger.range_for_pulse(model.measure(0.02))
    assert at_min == pytest.approx(0.02, abs=_step_m(20.0))
    assert at_min >= MIN_RANGE  # never -inf at the rated minimum
    at_max = ranger.range_for_pulse(model.measure(4.0))
    assert at_max == pytest.approx(4.0, abs=_step_m(20.0))
    assert at_max <= MAX_RANGE  # never +inf at the rated maximum
    assert model.measure(4.5) == NO_ECHO_TIMEOUT_US  # beyond: the module gives up at 38 ms
    assert ranger.range_for_pulse(model.measure(4.5)) == math.inf
    assert ranger.range_for_pulse(model.measure(None)) == math.inf  # nothing in the beam
    assert ranger.range_for_pulse(model.measure(0.01)) == -math.inf  # too close
    assert ranger.range_for_pulse(model.measure(0.0)) == -math.inf


def test_clone_fault_echo_never_drops() -> None:
    model = HcSr04Model(clone_fault=True, seed=4)
    ranger = UltrasonicRanger()
    assert ranger.range_for_pulse(model.measure(1.0)) == pytest.approx(1.0, abs=0.001)
    assert model.measure(None) == 0  # the board's pulse timing timed out
    assert model.stuck
    assert math.isnan(ranger.range_for_pulse(model.measure(1.0)))  # stuck until power cycled
    model.power_cycle()
    assert ranger.range_for_pulse(model.measure(1.0)) == pytest.approx(1.0, abs=0.001)


@pytest.mark.parametrize(
    ("pulse", "expected"),
    [
        (0, math.nan),
        (-58, math.nan),
        (math.nan, math.nan),
        (math.inf, math.nan),
        (58, -math.inf),
        (116, 0.02),
        (5_829, 1.0003),
        (23_312, 4.0),
        (23_400, math.inf),
        (30_000, math.inf),
        (38_000, math.inf),
    ],
)
def test_rep117_values(pulse: float, expected: float) -> None:
    value = UltrasonicRanger().range_for_pulse(pulse)
    if math.isnan(expected):
        assert math.isnan(value)
    elif math.isinf(expected):
        assert value == expected
    else:
        assert value == pytest.approx(expected, abs=0.001)


def test_range_message_serializes() -> None:
    ranger = UltrasonicRanger(frame_id="sonar_front")
    for pulse, expected in [(5_829, 1.0003), (38_000, math.inf), (20, -math.inf)]:
        message = ranger.to_range_msg(pulse, stamp=12.25)
        back = msg.to_dict(msg.decode(msg.encode(message), "sensor_msgs/Range"))
        assert back["header"]["frame_id"] == "sonar_front"
        assert back["header"]["stamp"] == {"secs": 12, "nsecs": 250_000_000}
        assert back["radiation_type"] == 0
        assert back["field_of_view"] == pytest.approx(FIELD_OF_VIEW)
        assert back["min_range"] == pytest.approx(0.02)
        assert back["max_range"] == 4.0
        assert back["range"] == pytest.approx(expected, abs=1e-4)
    nan = msg.decode(msg.encode(ranger.to_range_msg(0, 1.0)), "sensor_msgs/Range")
    assert math.isnan(nan.range)


def test_bad_configuration() -> None:
    with pytest.raises(UltrasonicError):
        UltrasonicRanger(min_range=5.0, max_range=4.0)
    with pytest.raises(UltrasonicError):
        HcSr04Model(timer_resolution_us=0.0)
    with pytest.raises(UltrasonicError, match="distance"):
        HcSr04Model().measure(-1.0)
