"""hwbridge.devices.diffdrive.encoders: counters, quadrature, odometry, cmd_vel and the
emulated base."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge import msg
from hwbridge.devices.diffdrive.encoders import (
    ARC_THRESHOLD,
    CommandWatchdog,
    DiffDriveBase,
    DiffDriveOdometry,
    DiffDriveParams,
    EncoderConfigError,
    QuadratureDecoder,
    QuadratureEncoder,
    QuadratureMode,
    counts_per_revolution,
    ticks_per_metre,
    wheel_targets,
    wrap_counter,
    wrap_delta,
)
from hwbridge.devices.world import Pose2D
from hwbridge.errors import HwBridgeError

SETTINGS = settings(max_examples=200, deadline=None, derandomize=True)


# ---------------------------------------------------------------------- counters
@SETTINGS
@given(
    bits=st.sampled_from([16, 32]),
    start=st.integers(min_value=-(2**40), max_value=2**40),
    data=st.data(),
)
def test_wrap_delta_recovers_any_step_under_half_range(
    bits: int, start: int, data: st.DataObject
) -> None:
    half = 1 << (bits - 1)
    step = data.draw(st.integers(min_value=-half, max_value=half - 1))
    old, new = wrap_counter(start, bits), wrap_counter(start + step, bits)
    assert 0 <= old < 2**bits and 0 <= new < 2**bits
    assert wrap_delta(new, old, bits) == step

    def signed(v: int) -> int:  # the same counter sent as a signed intN
        return v - (1 << bits) if v >= half else v

    assert wrap_delta(signed(new), signed(old), bits) == step


def test_wrap_delta_16_bit_both_directions() -> None:
    assert wrap_delta(5, 65530, 16) == 11  # forwards through 65535 -> 0
    assert wrap_delta(65530, 5, 16) == -11  # backwards through 0 -> 65535
    assert wrap_delta(-32768, 32767, 16) == 1  # int16 overflow
    assert wrap_delta(32767, -32768, 16) == -1
    assert wrap_delta(0, 2**32 - 1, 32) == 1
    assert wrap_delta(2**32 - 1, 0, 32) == -1


@pytest.mark.parametrize("direction", [1, -1])
def test_odometry_through_16_bit_wrap(direction: int) -> None:
    odom = DiffDriveOdometry(0.05, 0.3, 1000, counter_bits=16)
    count = 65000 if direction > 0 else 500
    state = odom.update(count, count, 0.0)
    for i in range(1, 21):  # 20 steps of 100 counts: crosses the wrap
        count = wrap_counter(count + direction * 100, 16)
        state = odom.update(count, count, i * 0.02)
    expected = direction * 2000 * 2 * math.pi * 0.05 / 1000
    assert state.x == pytest.approx(expected, abs=1e-12)
    assert state.y == 0.0 and state.theta == 0.0
    assert state.linear == pytest.approx(direction * 100 * odom.metres_per_count / 0.02)


# ---------------------------------------------------------------------- quadrature
def test_counts_per_revolution_and_ticks_per_metre() -> None:
    assert counts_per_revolution(500, QuadratureMode.X4) == 2000
    assert counts_per_revolution(11, 2, gear_ratio=30) == 660
    assert counts_per_revolution(11, QuadratureMode.X1, gear_ratio=30) == 330
    assert ticks_per_metre(2000, 0.05) == pytest.approx(2000 / (math.pi * 0.1))
    with pytest.raises(EncoderConfigError):
        counts_per_revolution(500, 3)
    with pytest.raises(HwBridgeError):
        ticks_per_metre(2000, 0.0)


@pytest.mark.parametrize("mode", list(QuadratureMode))
def test_quadrature_counts_per_revolution(mode: QuadratureMode) -> None:
    ppr, gear = 11, 30
    encoder = QuadratureEncoder(ppr, gear)
    decoder = QuadratureDecoder(mode, encoder.levels)
    eps = 1e-9  # stay clear of an edge exactly at one turn
    for k in range(1, 101):  # one turn forwards in 100 moves
        decoder.feed_many(encoder.move_to(2 * math.pi * k / 100 + eps))
    assert decoder.count == counts_per_revolution(ppr, mode, gear) == ppr * int(mode) * gear
    decoder.feed_many(encoder.move_to(eps))  # and back in one move
    assert decoder.count == 0
    assert decoder.errors == 0


@settings(max_examples=60, deadline=None, derandomize=True)
@given(
    mode=st.sampled_from(list(QuadratureMode)),
    angles=st.lists(st.floats(min_value=-20.0, max_value=20.0), min_size=1, max_size=30),
)
def test_quadrature_decoder_tracks_position_in_every_mode(
    mode: QuadratureMode, angles: list[float]
) -> None:
    """Back-and-forth motion (jitter on an edge included) never makes the count drift."""
    encoder = QuadratureEncoder(ppr=3, gear_ratio=2.0)
    decoder = QuadratureDecoder(mode, encoder.levels)
    for angle in angles:
        decoder.feed_many(encoder.move_to(angle))
    edges = math.floor(angles[-1] / (2 * math.pi) * 2.0 * 3 * 4)  # x4 steps from zero
    assert decoder.count == math.ceil(edges * int(mode) / 4)
    assert decoder.errors == 0


def test_quadrature_decoder_counts_missed_edges_as_errors() -> None:
    decoder = QuadratureDecoder(QuadratureMode.X4)
    decoder.feed(True, False)
    decoder.feed(False, True)  # both channels changed: an edge was missed
    assert (decoder.count, decoder.errors) == (1, 1)
    decoder.feed(False, True)  # no change
    assert (decoder.count, decoder.errors) == (1, 1)


# ---------------------------------------------------------------------- odometry
def _drive(
    odom: DiffDriveOdometry, per_step: tuple[int, int], steps: int, dt: float = 0.02
) -> None:
    left = right = 0
    odom.update(left, right, 0.0)
    for i in range(1, steps + 1):
        left, right = left + per_step[0], right + per_step[1]
        odom.update(wrap_counter(left, 32), wrap_counter(right, 32), i * dt)


def _hobby_integration(per_step: tuple[int, int], steps: int, m: float, w: float) -> Pose2D:
    """The widely copied diff_tf.py update with its lateral step y = -sin(dth) d (wrong)."""
    x = y = th = 0.0
    for _ in range(steps):
        d_left, d_right = per_step[0] * m, per_step[1] * m
        d, dth = (d_right + d_left) / 2, (d_right - d_left) / w
        step_x, step_y = math.cos(dth) * d, -math.sin(dth) * d
        x += math.cos(th) * step_x - math.sin(th) * step_y
        y += math.sin(th) * step_x + math.cos(th) * step_y
        th += dth
    return Pose2D(x, y, th)


def test_arc_integration_matches_a_closed_form_circle() -> None:
    odom = DiffDriveOdometry(0.05, 0.4, 4096)
    per_step, steps = (300, 500), 80  # half a circle
    _drive(odom, per_step, steps)
    m = odom.metres_per_count
    d_left, d_right = per_step[0] * m * steps, per_step[1] * m * steps
    theta = (d_right - d_left) / 0.4
    radius = (d_right + d_left) / 2 / theta
    state = odom.state
    # Centre of the circle at (0, R): x = R sin(theta), y = R (1 - cos(theta)).
    assert state.x == pytest.approx(radius * math.sin(theta), abs=1e-9)
    assert state.y == pytest.approx(radius * (1 - math.cos(theta)), abs=1e-9)
    assert state.theta == pytest.approx(math.remainder(theta, 2 * math.pi), abs=1e-9)
    # The same drive with the widely copied lateral step lands far away: the test can tell.
    wrong = _hobby_integration(per_step, steps, m, 0.4)
    truth = Pose2D(radius * math.sin(theta), radius * (1 - math.cos(theta)))
    assert wrong.distance_to(truth) > 0.05


def test_straight_line_uses_the_midpoint_heading() -> None:
    odom = DiffDriveOdometry(0.05, 0.3, 1000)
    odom.reset(Pose2D(1.0, 2.0, math.pi / 6))
    _drive(odom, (40, 40), 50)
    travel = 50 * 40 * odom.metres_per_count
    assert odom.state.x == pytest.approx(1.0 + travel * math.cos(math.pi / 6), abs=1e-12)
    assert odom.state.y == pytest.approx(2.0 + travel * math.sin(math.pi / 6), abs=1e-12)
    assert odom.state.theta == pytest.approx(math.pi / 6, abs=1e-15)


def test_rereference_keeps_pose_and_distance_and_reset_starts_over() -> None:
    """A board that restarted (its counters begin again) is taken from where the base is: the
    pose and the distance travelled go on; reset() starts over from the pose it is given."""
    odom = DiffDriveOdometry(0.05, 0.3, 1000)
    step = 2 * math.pi * 0.05  # metres a wheel revolution (1000 counts)
    odom.update(0, 0, 0.0)
    odom.update(1000, 1000, 1.0)
    assert (odom.state.x, odom.state.distance) == pytest.approx((step, step))
    odom.rereference()
    assert (odom.state.linear, odom.state.angular) == (0.0, 0.0)
    odom.update(5, 5, 2.0)  # the new reference: no step from 1000 down to 5
    assert (odom.state.x, odom.state.distance) == pytest.approx((step, step))
    odom.update(1005, 1005, 3.0)
    assert (odom.state.x, odom.state.distance) == pytest.approx((2 * step, 2 * step))
    odom.reset(Pose2D(1.0, 0.0, 0.0))
    assert (odom.state.x, odom.state.distance) == (1.0, 0.0)
    odom.update(7, 7, 4.0)
    odom.update(1007, 1007, 5.0)
    assert (odom.state.x, odom.state.distance) == pytest.approx((1.0 + step, step))


def test_turn_below_threshold_is_continuous_with_the_arc() -> None:
    # Separation so wide that one count of difference turns by less than ARC_THRESHOLD.
    counts, separation = 1_000_000, 1000.0
    odom = DiffDriveOdometry(0.05, separation, counts)
    turn = odom.metres_per_count / separation
    assert turn < ARC_THRESHOLD
    odom.update(0, 0, 0.0)
    state = odom.update(100_000, 100_001, 0.02)
    travel = 100_000.5 * odom.metres_per_count
    assert state.x == pytest.approx(travel * math.cos(turn / 2), rel=1e-15)
    assert state.y == pytest.approx(travel * math.sin(turn / 2), rel=1e-12)
    assert state.theta == pytest.approx(turn, rel=1e-12)


def test_velocity_rolling_mean_and_short_steps() -> None:
    odom = DiffDriveOdometry(0.05, 0.3, 1000, velocity_window=10)
    state = odom.update(0, 0, 0.0)
    for i in range(1, 20):  # accelerate: 10, 20, ... counts per 20 ms step
        state = odom.update(sum(10 * k for k in range(1, i + 1)), 0, i * 0.02)
    m = odom.metres_per_count
    mean_counts = sum(10 * k for k in range(10, 20)) / 10  # the last ten steps
    assert state.linear == pytest.approx(mean_counts * m / 2 / 0.02)
    assert state.angular == pytest.approx(-mean_counts * m / 0.3 / 0.02)

    steady = DiffDriveOdometry(0.05, 0.3, 1000, velocity_window=3)
    steady.update(0, 0, 1.0)
    steady.update(100, 100, 1.02)
    short = steady.update(101, 101, 1.02005)  # 50 us: no new estimate, travel kept
    assert short.linear == pytest.approx(100 * m / 0.02)
    later = steady.update(200, 200, 1.04)
    assert later.linear == pytest.approx(100 * m / 0.02, rel=1e-9)
    assert later.x == pytest.approx(200 * m)


def test_time_going_backwards_restarts_the_velocity_estimate() -> None:
    odom = DiffDriveOdometry(0.05, 0.3, 1000)
    odom.update(0, 0, 5.0)
    odom.update(100, 100, 5.02)
    state = odom.update(200, 200, 0.0)
    assert state.linear == 0.0
    assert state.x == pytest.approx(200 * odom.metres_per_count)  # the pose never jumps
    state = odom.update(300, 300, 0.02)
    assert state.linear == pytest.approx(100 * odom.metres_per_count / 0.02)


def test_odometry_messages_serialize() -> None:
    odom = DiffDriveOdometry(0.05, 0.3, 1000)
    _drive(odom, (100, 140), 25)
    state = odom.state
    data = msg.encode(odom.to_odometry_msg())
    back = msg.to_dict(msg.decode(data, "nav_msgs/Odometry"))
    assert back["header"]["frame_id"] == "odom"
    assert back["child_frame_id"] == "base_link"
    assert back["header"]["stamp"] == {"secs": 0, "nsecs": 500_000_000}
    pose = back["pose"]["pose"]
    assert (pose["position"]["x"], pose["position"]["y"]) == (state.x, state.y)
    assert 2 * math.atan2(pose["orientation"]["z"], pose["orientation"]["w"]) == pytest.approx(
        state.theta
    )
    cov = back["pose"]["covariance"]
    assert len(cov) == 36
    assert [cov[i * 7] for i in range(6)] == [1e-3, 1e-3, 1e6, 1e6, 1e6, 1e-2]
    assert sum(cov) == sum(cov[i * 7] for i in range(6))  # off-diagonal zero
    assert back["twist"]["twist"]["linear"]["x"] == state.linear > 0
    assert back["twist"]["twist"]["angular"]["z"] == state.angular > 0

    tf = msg.to_dict(msg.decode(msg.encode(odom.to_tf_msg()), "tf2_msgs/TFMessage"))
    (transform,) = tf["transforms"]
    assert transform["header"]["frame_id"] == "odom"
    assert transform["child_frame_id"] == "base_link"
    assert transform["transform"]["translation"] == {"x": state.x, "y": state.y, "z": 0.0}
    assert transform["transform"]["rotation"] == pose["orientation"]


# ---------------------------------------------------------------------- cmd_vel
def test_wheel_targets_inverse_kinematics() -> None:
    assert wheel_targets(0.5, 0.0, 0.05, 0.3) == pytest.approx((10.0, 10.0))
    assert wheel_targets(0.0, 2.0, 0.05, 0.3) == pytest.approx((-6.0, 6.0))
    left, right = DiffDriveOdometry(0.05, 0.3, 1000).wheel_targets(0.2, -1.0)
    assert (left * 0.05, right * 0.05) == pytest.approx((0.2 + 0.15, 0.2 - 0.15))


def test_command_watchdog_zeroes_targets_after_timeout() -> None:
    dog = CommandWatchdog(timeout=0.5)
    assert dog.targets(0.0) == (0.0, 0.0)  # nothing commanded yet
    dog.command((3.0, 4.0), now=10.0)
    assert dog.targets(10.0) == (3.0, 4.0)
    assert dog.targets(10.499) == (3.0, 4.0)
    assert not dog.expired(10.499)
    assert dog.targets(10.5) == (0.0, 0.0)
    assert dog.targets(11.0) == (0.0, 0.0)
    assert dog.timeouts == 1
    dog.command((1.0, -1.0), now=12.0)
    assert dog.targets(12.1) == (1.0, -1.0)


# ---------------------------------------------------------------------- parameters
def test_params_from_dict() -> None:
    params = DiffDriveParams.from_dict(
        {"wheel_radius": 0.033, "wheel_separation": 0.16, "encoder_ppr": 11, "gear_ratio": 30}
    )
    assert params.counts_per_rev == 1320
    assert params.counter_bits == 32 and params.velocity_window == 10
    assert params.cmd_vel_timeout == 0.5
    odom = DiffDriveOdometry.from_params(params)
    assert odom.wheel_radius == 0.033 and odom.counts_per_rev == 1320
    custom = DiffDriveParams.from_dict(
        {
            "wheel_radius": 0.1,
            "wheel_separation": 0.5,
            "encoder_ppr": 100,
            "decoding": "x2",
            "counter_bits": 16,
            "odom_frame_id": "wheel_odom",
            "pose_covariance_diagonal": [1, 1, 1, 1, 1, 1],
        }
    )
    assert custom.counts_per_rev == 200 and custom.counter_bits == 16
    assert DiffDriveOdometry.from_params(custom).to_odometry_msg().header.frame_id == "wheel_odom"


@pytest.mark.parametrize(
    ("data", "words"),
    [
        ({"wheel_radius": 0.1, "wheel_separation": 0.5}, "counts_per_rev is required"),
        ({"wheel_radius": 0.1, "wheel_separation": 0.5, "counts_per_rev": 10, "x": 1}, "'x'"),
        ({"wheel_radius": -0.1, "wheel_separation": 0.5, "counts_per_rev": 10}, "wheel_radius"),
        ({"wheel_radius": "big", "wheel_separation": 0.5, "counts_per_rev": 10}, "number"),
        (
            {"wheel_radius": 0.1, "wheel_separation": 0.5, "encoder_ppr": 10, "decoding": 3},
            "decoding",
        ),
        (
            {"wheel_radius": 0.1, "wheel_separation": 0.5, "counts_per_rev": 9, "counter_bits": 1},
            "counter_bits",
        ),
    ],
)
def test_params_errors_name_the_problem(data: dict[str, object], words: str) -> None:
    with pytest.raises(EncoderConfigError, match=words):
        DiffDriveParams.from_dict(data)


# ---------------------------------------------------------------------- emulated base
def test_base_first_order_motor_response() -> None:
    base = DiffDriveBase(0.05, 0.3, 1000, motor_time_constant=0.1)
    base.set_wheel_targets(10.0, -10.0)
    base.step(0.1)
    assert base.wheel_speeds == pytest.approx((10 * (1 - math.exp(-1)), -10 * (1 - math.exp(-1))))
    # Angle = integral of the exponential approach, exactly.
    expected = 10 * (0.1 - 0.1 * (1 - math.exp(-1)))
    assert base.wheel_angles == pytest.approx((expected, -expected))
    assert base.pose.x == pytest.approx(0.0, abs=1e-12)  # spinning on the spot
    assert base.pose.theta == pytest.approx(-2 * expected * 0.05 / 0.3)  # clockwise


def test_base_slip_and_noise_are_seeded() -> None:
    def run(seed: int) -> tuple[tuple[int, int], Pose2D, float]:
        base = DiffDriveBase(0.05, 0.3, 1000, slip_std=0.05, count_noise_std=2.0, seed=seed)
        base.set_wheel_targets(5.0, 5.0)
        for _ in range(50):
            base.step(0.02)
        return base.counts(), base.pose, base.distance

    assert run(7) == run(7)
    assert run(7) != run(8)
    counts, _, distance = run(7)
    ideal = DiffDriveBase(0.05, 0.3, 1000)
    ideal.set_wheel_targets(5.0, 5.0)
    for _ in range(50):
        ideal.step(0.02)
    assert distance < ideal.distance  # slip: the wheels turned further than the base moved
    assert all(abs(c - i) <= 10 for c, i in zip(counts, ideal.counts(), strict=True))


@pytest.mark.parametrize(
    ("bits", "counts_per_rev", "initial"),
    [(32, 4 * 1024 * 20, (2**32 - 5000, 1000)), (16, 4 * 11 * 30, (65000, 100))],
    ids=["32-bit", "16-bit"],
)
def test_acceptance_odometry_error_over_100m_random_drive(
    bits: int, counts_per_rev: int, initial: tuple[int, int]
) -> None:
    """Odometry within 0.5 % of the distance of the true pose after 100 m of seeded cmd_vel."""
    radius, separation, dt = 0.033, 0.16, 0.02  # 50 Hz
    base = DiffDriveBase(
        radius,
        separation,
        counts_per_rev,
        counter_bits=bits,
        initial_counts=initial,
        motor_time_constant=0.08,
    )
    odom = DiffDriveOdometry(radius, separation, counts_per_rev, counter_bits=bits)
    dog = CommandWatchdog(0.5)
    rng = random.Random(20240521)
    t, next_command, command = 0.0, 0.0, (0.0, 0.0)
    previous = base.counts()
    state = odom.update(*previous, t)
    wraps, worst = 0, 0.0
    while base.distance < 100.0:
        if t >= next_command:  # a new random command every 0.5-3 s, some straight
            command = (rng.uniform(-0.3, 1.0), rng.uniform(-2.0, 2.0))
            if rng.random() < 0.2:
                command = (command[0], 0.0)
            next_command = t + rng.uniform(0.5, 3.0)
        dog.command(odom.wheel_targets(*command), t)
        base.set_wheel_targets(*dog.targets(t))
        base.step(dt)
        t += dt
        counts = base.counts()
        wraps += sum(abs(a - b) > 2 ** (bits - 1) for a, b in zip(counts, previous, strict=True))
        previous = counts
        state = odom.update(*counts, t)
        allowed = 0.005 * base.distance + odom.metres_per_count  # + one count of quantization
        worst = max(worst, state.pose.distance_to(base.pose) - allowed)
    assert wraps >= 1  # the counters wrapped during the drive
    assert worst <= 0.0  # within 0.5 % of the distance so far, all along the drive
    error = state.pose.distance_to(base.pose)
    assert error <= 0.005 * base.distance
    # Measured: about 5e-6 of the distance. The widely copied lateral step y = -sin(dth) d
    # stays under 0.5 % here (about 1.8e-3), so also hold the exact arc to a tighter bound.
    assert error <= 1e-4 * base.distance
    assert abs(math.remainder(state.theta - base.pose.theta, 2 * math.pi)) < 1e-3
