"""Wheel encoders and differential-drive odometry: host logic and an emulated base.

Host side (what runs next to the bridge):

- :func:`wrap_delta` turns two readings of a 16- or 32-bit board counter into a signed step;
- :class:`QuadratureDecoder` counts A/B edges in x1, x2 or x4 mode (for boards that stream edges,
  and to check :class:`QuadratureEncoder`, the emulated disc);
- :class:`DiffDriveOdometry` integrates counter readings into a pose on exact arcs, estimates the
  velocity with a rolling mean and builds ``nav_msgs/Odometry`` and the ``odom -> base_link``
  transform on ``/tf`` (REP-105);
- :func:`wheel_targets` and :class:`CommandWatchdog` turn ``cmd_vel`` into wheel speeds and stop
  the wheels when commands stop arriving;
- :class:`DiffDriveParams` holds the named parameters, loadable from a dict (YAML, the parameter
  server).

Emulated side: :class:`DiffDriveBase`, a differential-drive base with first-order motors, wheel
encoders (optional slip and count noise from a seeded RNG) and its ground-truth pose.

Everything here is pure and deterministic: time is always passed in, never read from a clock.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields, replace
from enum import IntEnum
from typing import Any, Final

import numpy as np

from hwbridge import msg
from hwbridge.devices.world import ORIGIN, Pose2D, normalize_angle, yaw_to_quaternion
from hwbridge.errors import HwBridgeError

__all__ = [
    "ARC_THRESHOLD",
    "DEFAULT_POSE_COVARIANCE_DIAGONAL",
    "DEFAULT_TWIST_COVARIANCE_DIAGONAL",
    "MIN_VELOCITY_DT",
    "CommandWatchdog",
    "DiffDriveBase",
    "DiffDriveOdometry",
    "DiffDriveParams",
    "EncoderConfigError",
    "OdomState",
    "QuadratureDecoder",
    "QuadratureEncoder",
    "QuadratureMode",
    "counts_per_revolution",
    "covariance_from_diagonal",
    "ticks_per_metre",
    "wheel_targets",
    "wrap_counter",
    "wrap_delta",
]

ARC_THRESHOLD: Final = 1e-6
"""Below this heading change per step (rad) the pose is integrated with the midpoint heading."""
MIN_VELOCITY_DT: Final = 1e-4
"""Steps shorter than this (s) are not used for a velocity estimate (0.1 ms)."""

# Planar base: z, roll and pitch are not observed, so their variances are large and a filter
# (robot_localization, an EKF) ignores them; x, y and yaw get modest values.
DEFAULT_POSE_COVARIANCE_DIAGONAL: Final = (1e-3, 1e-3, 1e6, 1e6, 1e6, 1e-2)
DEFAULT_TWIST_COVARIANCE_DIAGONAL: Final = (1e-3, 1e-3, 1e6, 1e6, 1e6, 1e-2)


class EncoderConfigError(HwBridgeError, ValueError):
    """An encoder or odometry parameter is missing, of the wrong type or out of range."""


def _positive(name: str, value: float) -> float:
    if not math.isfinite(value) or value <= 0.0:
        raise EncoderConfigError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def _counter_bits(bits: int) -> int:
    if not 2 <= bits <= 64:
        raise EncoderConfigError(f"counter_bits must be between 2 and 64, got {bits!r}")
    return bits


def _velocity_window(window: int) -> int:
    if window < 1:
        raise EncoderConfigError(f"velocity_window must be at least 1, got {window!r}")
    return window


# ---------------------------------------------------------------------- counters
def wrap_counter(value: int, bits: int) -> int:
    """``value`` as the board's unsigned ``bits``-bit counter holds it (modulo 2**bits)."""
    return value % (1 << bits)


def wrap_delta(new: int, old: int, bits: int) -> int:
    """Signed change from ``old`` to ``new`` of a ``bits``-bit counter that may have wrapped.

    Readings may be given signed or unsigned; the result is in [-2**(bits-1), 2**(bits-1)) and is
    right while the counter moved less than half its range between the two readings.
    """
    half = 1 << (bits - 1)
    return (new - old + half) % (1 << bits) - half


# ---------------------------------------------------------------------- quadrature
class QuadratureMode(IntEnum):
    """Quadrature decoding: the value is the number of counts per encoder line (pulse)."""

    X1 = 1
    """One edge of A per cycle (the rising edge, counted down when crossed backwards)."""
    X2 = 2
    """Both edges of A."""
    X4 = 4
    """Every edge of A and B."""


def counts_per_revolution(ppr: float, mode: QuadratureMode | int, gear_ratio: float = 1.0) -> float:
    """Counts per wheel revolution: encoder PPR x decoding factor x gear ratio."""
    try:
        factor = int(QuadratureMode(mode))
    except ValueError:
        raise EncoderConfigError(f"decoding must be 1, 2 or 4 (x1, x2, x4), got {mode!r}") from None
    return _positive("ppr", ppr) * factor * _positive("gear_ratio", gear_ratio)


def ticks_per_metre(counts_per_rev: float, wheel_radius: float) -> float:
    """Counts per metre of wheel travel: counts per revolution / (pi x wheel diameter)."""
    return _positive("counts_per_rev", counts_per_rev) / (
        math.pi * 2.0 * _positive("wheel_radius", wheel_radius)
    )


# Channel levels (A, B) through one quadrature cycle, turning forwards: A leads B.
_PHASES: Final[tuple[tuple[bool, bool], ...]] = (
    (False, False),
    (True, False),
    (True, True),
    (False, True),
)
_PHASE_OF: Final[dict[tuple[bool, bool], int]] = {
    levels: index for index, levels in enumerate(_PHASES)
}


class QuadratureEncoder:
    """Emulated incremental encoder: A/B levels from the wheel angle.

    The disc sits on the motor shaft, ``gear_ratio`` turns per wheel turn, with ``ppr`` lines;
    each line gives one full A/B cycle, i.e. four edges.
    """

    def __init__(self, ppr: int, gear_ratio: float = 1.0, wheel_angle: float = 0.0) -> None:
        if ppr <= 0:
            raise EncoderConfigError(f"ppr must be a positive integer, got {ppr!r}")
        self.ppr = ppr
        self.gear_ratio = _positive("gear_ratio", gear_ratio)
        self._step = self._step_at(wheel_angle)

    def _step_at(self, wheel_angle: float) -> int:
        return math.floor(wheel_angle / (2.0 * math.pi) * self.gear_ratio * self.ppr * 4.0)

    @property
    def levels(self) -> tuple[bool, bool]:
        """Current (A, B) levels."""
        return _PHASES[self._step % 4]

    def move_to(self, wheel_angle: float) -> list[tuple[bool, bool]]:
        """Turn the wheel to ``wheel_angle`` (rad); the (A, B) levels after each edge, in order."""
        target = self._step_at(wheel_angle)
        direction = 1 if target >= self._step else -1
        steps = range(self._step + direction, target + direction, direction)
        states: list[tuple[bool, bool]] = [_PHASES[s % 4] for s in steps]
        self._step = target
        return states


class QuadratureDecoder:
    """Counts A/B level changes in x1, x2 or x4 mode, as a board's counter or ISR does.

    A change of both channels at once (an edge was missed) cannot be given a direction: it is
    counted in :attr:`errors` and ignored.
    """

    def __init__(
        self,
        mode: QuadratureMode | int = QuadratureMode.X4,
        levels: tuple[bool, bool] = (False, False),
    ) -> None:
        self.mode = QuadratureMode(mode)
        self.count = 0
        self.errors = 0
        self._phase = _PHASE_OF[levels]

    def feed(self, a: bool, b: bool) -> None:
        """Take the channels' new levels."""
        phase = _PHASE_OF[(bool(a), bool(b))]
        step = (phase - self._phase) % 4
        old, self._phase = self._phase, phase
        if step == 0:
            return
        if step == 2:
            self.errors += 1
            return
        direction = 1 if step == 1 else -1
        # The edge crossed lies between phases lo and lo + 1 (mod 4).
        lo = old if direction == 1 else phase
        if self.mode is QuadratureMode.X4:
            self.count += direction
        elif self.mode is QuadratureMode.X2:
            if lo in (0, 2):  # 0<->1 and 2<->3 are the edges of A
                self.count += direction
        elif lo == 0:  # X1: the rising edge of A (falling when crossed backwards)
            self.count += direction

    def feed_many(self, states: Iterable[tuple[bool, bool]]) -> None:
        """Take a sequence of (A, B) levels."""
        for a, b in states:
            self.feed(a, b)


# ---------------------------------------------------------------------- kinematics
def wheel_targets(
    linear_x: float, angular_z: float, wheel_radius: float, wheel_separation: float
) -> tuple[float, float]:
    """Wheel speeds (left, right) in rad/s for a body twist (m/s, rad/s)."""
    half = 0.5 * wheel_separation * angular_z
    return (linear_x - half) / wheel_radius, (linear_x + half) / wheel_radius


def covariance_from_diagonal(diagonal: Iterable[float]) -> list[float]:
    """A 6x6 row-major covariance (36 values) with ``diagonal`` on its diagonal."""
    values = [float(v) for v in diagonal]
    if len(values) != 6:
        raise EncoderConfigError(f"a covariance diagonal needs 6 values, got {len(values)}")
    matrix = [0.0] * 36
    for index, value in enumerate(values):
        matrix[index * 7] = value
    return matrix


@dataclass(frozen=True)
class OdomState:
    """Odometry at one instant: pose in ``odom``, velocity in ``base_link``."""

    stamp: float
    """Time of the counter readings (s)."""
    x: float
    y: float
    theta: float
    """Heading (rad) in [-pi, pi)."""
    linear: float = 0.0
    """Forward velocity (m/s), rolling mean."""
    angular: float = 0.0
    """Yaw rate (rad/s), rolling mean."""
    distance: float = 0.0
    """Path length travelled since the start (m)."""

    @property
    def pose(self) -> Pose2D:
        """The pose as a :class:`~hwbridge.devices.world.Pose2D`."""
        return Pose2D(self.x, self.y, self.theta)


class DiffDriveOdometry:
    """Odometry of a differential-drive base from its two wheel counters.

    ``counts_per_rev`` counts per wheel revolution (see :func:`counts_per_revolution`); readings
    come from ``counter_bits``-bit counters that may wrap between readings.
    """

    def __init__(
        self,
        wheel_radius: float,
        wheel_separation: float,
        counts_per_rev: float,
        counter_bits: int = 32,
        velocity_window: int = 10,
        *,
        frame_id: str = "odom",
        child_frame_id: str = "base_link",
        pose_covariance_diagonal: Iterable[float] = DEFAULT_POSE_COVARIANCE_DIAGONAL,
        twist_covariance_diagonal: Iterable[float] = DEFAULT_TWIST_COVARIANCE_DIAGONAL,
    ) -> None:
        self.wheel_radius = _positive("wheel_radius", wheel_radius)
        self.wheel_separation = _positive("wheel_separation", wheel_separation)
        self.counts_per_rev = _positive("counts_per_rev", counts_per_rev)
        self.counter_bits = _counter_bits(counter_bits)
        _velocity_window(velocity_window)
        self.frame_id = frame_id
        self.child_frame_id = child_frame_id
        self.pose_covariance = covariance_from_diagonal(pose_covariance_diagonal)
        self.twist_covariance = covariance_from_diagonal(twist_covariance_diagonal)
        self.metres_per_count = 2.0 * math.pi * self.wheel_radius / self.counts_per_rev
        self._window: deque[tuple[float, float]] = deque(maxlen=velocity_window)
        self._last_counts: tuple[int, int] | None = None
        self._velocity_stamp = 0.0
        self._pending = (0.0, 0.0)  # travel and turn not yet used for a velocity estimate
        self._state = OdomState(0.0, 0.0, 0.0, 0.0)

    @classmethod
    def from_params(cls, params: DiffDriveParams) -> DiffDriveOdometry:
        """Odometry configured from named parameters."""
        return cls(
            params.wheel_radius,
            params.wheel_separation,
            params.counts_per_rev,
            params.counter_bits,
            params.velocity_window,
            frame_id=params.odom_frame_id,
            child_frame_id=params.base_frame_id,
            pose_covariance_diagonal=params.pose_covariance_diagonal,
            twist_covariance_diagonal=params.twist_covariance_diagonal,
        )

    @property
    def state(self) -> OdomState:
        """The latest state."""
        return self._state

    def reset(self, pose: Pose2D = ORIGIN) -> None:
        """Restart from ``pose`` with zero velocity and no distance travelled; the next reading
        becomes the reference."""
        self._state = OdomState(self._state.stamp, pose.x, pose.y, normalize_angle(pose.theta))
        self._forget_counts()

    def rereference(self) -> None:
        """The counters began again (the board restarted): the next reading becomes the
        reference, from the pose and distance travelled so far (odometry stays continuous),
        with zero velocity."""
        self._state = replace(self._state, linear=0.0, angular=0.0)
        self._forget_counts()

    def _forget_counts(self) -> None:
        self._last_counts = None
        self._window.clear()
        self._pending = (0.0, 0.0)

    def update(self, left_count: int, right_count: int, stamp: float) -> OdomState:
        """Take one reading of both counters taken at ``stamp`` (s); the new state.

        The first reading (and the first after :meth:`reset`) only sets the reference.
        """
        previous = self._last_counts
        self._last_counts = (left_count, right_count)
        state = self._state
        if previous is None:
            self._velocity_stamp = stamp
            self._state = replace(state, stamp=stamp, linear=0.0, angular=0.0)
            return self._state
        bits = self.counter_bits
        d_left = wrap_delta(left_count, previous[0], bits) * self.metres_per_count
        d_right = wrap_delta(right_count, previous[1], bits) * self.metres_per_count
        travel = 0.5 * (d_right + d_left)
        turn = (d_right - d_left) / self.wheel_separation
        x, y, theta = _arc_step(state.x, state.y, state.theta, travel, turn)
        linear, angular = self._estimate_velocity(travel, turn, stamp, state)
        self._state = OdomState(stamp, x, y, theta, linear, angular, state.distance + abs(travel))
        return self._state

    def _estimate_velocity(
        self, travel: float, turn: float, stamp: float, state: OdomState
    ) -> tuple[float, float]:
        pending_travel = self._pending[0] + travel
        pending_turn = self._pending[1] + turn
        dt = stamp - self._velocity_stamp
        if dt < 0.0:  # time went backwards (a clock reset): restart the estimate
            self._window.clear()
            self._velocity_stamp = stamp
            self._pending = (0.0, 0.0)
            return 0.0, 0.0
        if dt < MIN_VELOCITY_DT:
            self._pending = (pending_travel, pending_turn)
            return state.linear, state.angular
        self._pending = (0.0, 0.0)
        self._velocity_stamp = stamp
        self._window.append((pending_travel / dt, pending_turn / dt))
        count = len(self._window)
        return (
            math.fsum(v for v, _ in self._window) / count,
            math.fsum(w for _, w in self._window) / count,
        )

    def wheel_targets(self, linear_x: float, angular_z: float) -> tuple[float, float]:
        """Wheel speeds (left, right) in rad/s for a ``cmd_vel`` twist of this base."""
        return wheel_targets(linear_x, angular_z, self.wheel_radius, self.wheel_separation)

    def to_odometry_msg(self, state: OdomState | None = None) -> Any:
        """``nav_msgs/Odometry`` of ``state`` (default: the latest)."""
        s = state if state is not None else self._state
        qx, qy, qz, qw = yaw_to_quaternion(s.theta)
        return msg.from_dict(
            "nav_msgs/Odometry",
            {
                "header": {"stamp": s.stamp, "frame_id": self.frame_id},
                "child_frame_id": self.child_frame_id,
                "pose": {
                    "pose": {
                        "position": {"x": s.x, "y": s.y},
                        "orientation": {"x": qx, "y": qy, "z": qz, "w": qw},
                    },
                    "covariance": self.pose_covariance,
                },
                "twist": {
                    "twist": {"linear": {"x": s.linear}, "angular": {"z": s.angular}},
                    "covariance": self.twist_covariance,
                },
            },
        )

    def to_tf_msg(self, state: OdomState | None = None) -> Any:
        """``tf2_msgs/TFMessage`` holding the ``odom -> base_link`` transform of ``state``."""
        s = state if state is not None else self._state
        qx, qy, qz, qw = yaw_to_quaternion(s.theta)
        transform = {
            "header": {"stamp": s.stamp, "frame_id": self.frame_id},
            "child_frame_id": self.child_frame_id,
            "transform": {
                "translation": {"x": s.x, "y": s.y},
                "rotation": {"x": qx, "y": qy, "z": qz, "w": qw},
            },
        }
        return msg.from_dict("tf2_msgs/TFMessage", {"transforms": [transform]})


def _arc_step(
    x: float, y: float, theta: float, travel: float, turn: float
) -> tuple[float, float, float]:
    """Move along an arc of length ``travel`` turning by ``turn`` (DEVICES.md's exact update)."""
    if abs(turn) < ARC_THRESHOLD:
        heading = theta + 0.5 * turn  # midpoint (second-order Runge-Kutta) heading
        x += travel * math.cos(heading)
        y += travel * math.sin(heading)
        return x, y, normalize_angle(theta + turn)
    radius = travel / turn
    new_theta = theta + turn
    x += radius * (math.sin(new_theta) - math.sin(theta))
    y -= radius * (math.cos(new_theta) - math.cos(theta))
    return x, y, normalize_angle(new_theta)


class CommandWatchdog:
    """Holds the latest wheel targets and zeroes them when commands stop arriving.

    Call :meth:`command` when a ``cmd_vel`` arrives and :meth:`targets` on every control cycle;
    both take the current time (s) from the caller.
    """

    def __init__(self, timeout: float = 0.5) -> None:
        self.timeout = _positive("timeout", timeout)
        self.timeouts = 0
        """How many times the targets were zeroed because commands stopped."""
        self.commands = 0
        """How many commands arrived."""
        self._targets = (0.0, 0.0)
        self._last: float | None = None
        self._expired = True

    def command(self, targets: tuple[float, float], now: float) -> None:
        """A new command arrived at ``now``."""
        self.commands += 1
        self._targets = (float(targets[0]), float(targets[1]))
        self._last = now
        self._expired = False

    def expired(self, now: float) -> bool:
        """True when no command arrived in the last ``timeout`` seconds (or none ever did)."""
        return self._last is None or now - self._last >= self.timeout

    def targets(self, now: float) -> tuple[float, float]:
        """The targets to apply at ``now``: the latest command, or zeros once it is too old."""
        if self.expired(now):
            if not self._expired:
                self._expired = True
                self.timeouts += 1
            return (0.0, 0.0)
        return self._targets


# ---------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class DiffDriveParams:
    """Named parameters of a differential-drive base (SI units)."""

    wheel_radius: float
    """Wheel radius (m)."""
    wheel_separation: float
    """Distance between the wheels' contact points (m)."""
    counts_per_rev: float
    """Encoder counts per wheel revolution, after decoding and gearing."""
    counter_bits: int = 32
    """Width of the board's counters (16 or 32)."""
    velocity_window: int = 10
    """Steps in the velocity rolling mean."""
    publish_rate: float = 50.0
    """Odometry publishing rate (Hz)."""
    cmd_vel_timeout: float = 0.5
    """Stop the wheels when no ``cmd_vel`` arrived for this long (s)."""
    odom_frame_id: str = "odom"
    base_frame_id: str = "base_link"
    pose_covariance_diagonal: tuple[float, ...] = DEFAULT_POSE_COVARIANCE_DIAGONAL
    twist_covariance_diagonal: tuple[float, ...] = DEFAULT_TWIST_COVARIANCE_DIAGONAL

    def __post_init__(self) -> None:
        for name in ("wheel_radius", "wheel_separation", "counts_per_rev", "publish_rate"):
            _positive(name, getattr(self, name))
        _positive("cmd_vel_timeout", self.cmd_vel_timeout)
        _counter_bits(self.counter_bits)
        _velocity_window(self.velocity_window)
        covariance_from_diagonal(self.pose_covariance_diagonal)
        covariance_from_diagonal(self.twist_covariance_diagonal)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> DiffDriveParams:
        """Parameters from a mapping (YAML, the parameter server).

        ``counts_per_rev`` may instead be given as ``encoder_ppr``, ``decoding`` (1, 2 or 4,
        default 4) and ``gear_ratio`` (default 1).
        """
        values = dict(data)
        known = {f.name for f in fields(cls)}
        encoder_keys = {"encoder_ppr", "decoding", "gear_ratio"}
        unknown = sorted(set(values) - known - encoder_keys)
        if unknown:
            raise EncoderConfigError(
                f"unknown diff drive parameter {unknown[0]!r}; known: "
                + ", ".join(sorted(known | encoder_keys))
            )
        if encoder_keys & set(values):
            if "counts_per_rev" in values:
                raise EncoderConfigError(
                    "give either counts_per_rev or encoder_ppr/decoding/gear_ratio, not both"
                )
            ppr = _number("encoder_ppr", values.pop("encoder_ppr", None))
            decoding = values.pop("decoding", 4)
            gear = _number("gear_ratio", values.pop("gear_ratio", 1.0))
            try:
                mode = QuadratureMode(int(str(decoding).lower().lstrip("x")))
            except ValueError:
                raise EncoderConfigError(
                    f"decoding must be 1, 2 or 4 (x1, x2, x4), got {decoding!r}"
                ) from None
            values["counts_per_rev"] = counts_per_revolution(ppr, mode, gear)
        for name in ("wheel_radius", "wheel_separation", "counts_per_rev"):
            if name not in values:
                raise EncoderConfigError(f"diff drive parameter {name} is required")
        converted: dict[str, Any] = {}
        for name, value in values.items():
            if name in ("counter_bits", "velocity_window"):
                if isinstance(value, bool) or not isinstance(value, int):
                    raise EncoderConfigError(f"{name} must be an integer, got {value!r}")
                converted[name] = value
            elif name in ("odom_frame_id", "base_frame_id"):
                if not isinstance(value, str) or not value:
                    raise EncoderConfigError(f"{name} must be a frame name, got {value!r}")
                converted[name] = value
            elif name.endswith("_covariance_diagonal"):
                if not isinstance(value, (list, tuple)):
                    raise EncoderConfigError(f"{name} must be a list of 6 numbers, got {value!r}")
                converted[name] = tuple(_number(name, v) for v in value)
            else:
                converted[name] = _number(name, value)
        return cls(**converted)


def _number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise EncoderConfigError(f"diff drive parameter {name} must be a number, got {value!r}")
    return float(value)


# ---------------------------------------------------------------------- emulated base
class DiffDriveBase:
    """Emulated differential-drive base: two first-order motors, wheel encoders, true pose.

    Motors follow their speed targets (rad/s) with time constant ``motor_time_constant`` (s),
    solved exactly. Encoders count ``counts_per_rev`` per wheel turn into ``counter_bits``-bit
    counters starting at ``initial_counts``. Wheel slip (a fraction of each wheel's rotation that
    does not move the ground contact, ``|N(0, slip_std)|`` per step) and count noise (a reading
    jitter of ``N(0, count_noise_std)`` counts, rounded, drawn on every :meth:`counts`) come from
    two generators seeded from ``seed``, so reading the counters does not change the slip. The
    true pose is integrated with midpoint steps of at most ``max_substep`` seconds.
    """

    def __init__(
        self,
        wheel_radius: float,
        wheel_separation: float,
        counts_per_rev: float,
        *,
        motor_time_constant: float = 0.05,
        max_wheel_speed: float | None = None,
        counter_bits: int = 32,
        initial_counts: tuple[int, int] = (0, 0),
        slip_std: float = 0.0,
        count_noise_std: float = 0.0,
        seed: int = 0,
        pose: Pose2D = ORIGIN,
        max_substep: float = 1e-3,
    ) -> None:
        self.wheel_radius = _positive("wheel_radius", wheel_radius)
        self.wheel_separation = _positive("wheel_separation", wheel_separation)
        self.counts_per_rev = _positive("counts_per_rev", counts_per_rev)
        if motor_time_constant < 0.0:
            raise EncoderConfigError(
                f"motor_time_constant must not be negative, got {motor_time_constant!r}"
            )
        self.motor_time_constant = motor_time_constant
        self.max_wheel_speed = max_wheel_speed
        self.counter_bits = _counter_bits(counter_bits)
        self.slip_std = slip_std
        self.count_noise_std = count_noise_std
        self.max_substep = _positive("max_substep", max_substep)
        slip_seed, noise_seed = np.random.SeedSequence(seed).spawn(2)
        self._slip_rng = np.random.default_rng(slip_seed)
        self._noise_rng = np.random.default_rng(noise_seed)
        self._initial_counts = initial_counts
        self._targets = (0.0, 0.0)
        self._speeds = [0.0, 0.0]
        self._angles = [0.0, 0.0]
        self._x, self._y, self._theta = pose.x, pose.y, pose.theta
        self.time = 0.0
        """Simulated time (s)."""
        self.distance = 0.0
        """True path length of the base's centre (m)."""

    @property
    def pose(self) -> Pose2D:
        """Ground-truth pose (heading wrapped into [-pi, pi))."""
        return Pose2D(self._x, self._y, normalize_angle(self._theta))

    @property
    def wheel_speeds(self) -> tuple[float, float]:
        """Present wheel speeds (left, right) in rad/s."""
        return self._speeds[0], self._speeds[1]

    @property
    def wheel_angles(self) -> tuple[float, float]:
        """Total wheel rotation (left, right) in rad."""
        return self._angles[0], self._angles[1]

    def set_wheel_targets(self, left: float, right: float) -> None:
        """Speed targets (rad/s) for the motor controllers, clipped to ``max_wheel_speed``."""
        limit = self.max_wheel_speed
        if limit is not None:
            left, right = (max(-limit, min(limit, v)) for v in (left, right))
        self._targets = (left, right)

    def counts(self) -> tuple[int, int]:
        """Encoder counters (left, right) as the board reads them: wrapped, with noise."""
        result = []
        for index in (0, 1):
            true = math.floor(self._angles[index] / (2.0 * math.pi) * self.counts_per_rev)
            noise = 0
            if self.count_noise_std > 0.0:
                noise = round(float(self._noise_rng.normal(0.0, self.count_noise_std)))
            result.append(
                wrap_counter(self._initial_counts[index] + true + noise, self.counter_bits)
            )
        return result[0], result[1]

    def step(self, dt: float) -> None:
        """Advance the simulation by ``dt`` seconds."""
        if dt < 0.0:
            raise EncoderConfigError(f"cannot step back in time (dt={dt!r})")
        slip = (0.0, 0.0)
        if self.slip_std > 0.0:
            drawn = np.abs(self._slip_rng.normal(0.0, self.slip_std, size=2))
            slip = (min(float(drawn[0]), 1.0), min(float(drawn[1]), 1.0))
        substeps = max(1, math.ceil(dt / self.max_substep))
        h = dt / substeps
        tau = self.motor_time_constant
        decay = math.exp(-h / tau) if tau > 0.0 else 0.0
        r, sep = self.wheel_radius, self.wheel_separation
        for _ in range(substeps):
            moved = [0.0, 0.0]
            for i in (0, 1):
                target, speed = self._targets[i], self._speeds[i]
                if tau > 0.0:
                    moved[i] = target * h + (speed - target) * tau * (1.0 - decay)
                    self._speeds[i] = target + (speed - target) * decay
                else:
                    moved[i] = target * h
                    self._speeds[i] = target
                self._angles[i] += moved[i]
            d_left = r * moved[0] * (1.0 - slip[0])
            d_right = r * moved[1] * (1.0 - slip[1])
            travel = 0.5 * (d_left + d_right)
            turn = (d_right - d_left) / sep
            heading = self._theta + 0.5 * turn
            self._x += travel * math.cos(heading)
            self._y += travel * math.sin(heading)
            self._theta += turn
            self.distance += abs(travel)
        self.time += dt
