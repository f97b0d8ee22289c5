"""The emulated world: a room with walls, a differential-drive base, the air, what its sensors
feel.

Deterministic for a seed; stepped by the caller (real time or faster). Ground truth is public,
for tests and for the demo's score.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hwbridge.devices.diffdrive.encoders import DiffDriveBase
from hwbridge.devices.imu.mpu import ImuTruth
from hwbridge.devices.world import STANDARD_GRAVITY, Air, Pose2D

__all__ = ["Segment", "World", "WorldConfig"]

Segment = tuple[float, float, float, float]  # x1, y1, x2, y2


@dataclass(frozen=True)
class WorldConfig:
    """Geometry of the robot and its room."""

    wheel_radius: float = 0.033
    wheel_separation: float = 0.16
    counts_per_rev: float = 1320.0
    counter_bits: int = 16
    motor_time_constant: float = 0.08
    max_wheel_speed: float = 20.0
    slip_std: float = 0.0
    count_noise_std: float = 0.0
    room: tuple[float, float] = (6.0, 4.0)
    """Width (x) and depth (y) of a rectangular room centred on the start pose."""
    obstacles: tuple[Segment, ...] = ()
    sonar_offset: float = 0.08
    """Distance from the base's centre to the sonar, pointing forward (m)."""
    vibration: float = 0.05
    """Standard deviation of floor vibration felt by the IMU while moving (m/s^2)."""
    magnetic_field: tuple[float, float, float] = (2.0e-5, 0.0, -4.5e-5)
    """Earth's field in the world frame (T)."""
    air: Air = field(default_factory=Air)
    """The air around the robot (temperature degC, pressure Pa, humidity %); a robot file
    gives any of them as ``air: {temperature: 20.0, pressure: 101325.0, humidity: 45.0}``."""

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> WorldConfig:
        values = dict(data)
        if "room" in values:
            values["room"] = tuple(values["room"])
        if "obstacles" in values:
            values["obstacles"] = tuple(tuple(o) for o in values["obstacles"])
        if "magnetic_field" in values:
            values["magnetic_field"] = tuple(values["magnetic_field"])
        if "air" in values:
            air = values["air"]
            if not isinstance(air, dict):
                raise ValueError("air must be a mapping (temperature, pressure, humidity)")
            values["air"] = Air(**{key: float(value) for key, value in air.items()})
        return cls(**values)


@dataclass
class World:
    """One robot in one room."""

    config: WorldConfig = field(default_factory=WorldConfig)
    seed: int = 0

    def __post_init__(self) -> None:
        cfg = self.config
        self.base = DiffDriveBase(
            cfg.wheel_radius,
            cfg.wheel_separation,
            cfg.counts_per_rev,
            motor_time_constant=cfg.motor_time_constant,
            max_wheel_speed=cfg.max_wheel_speed,
            counter_bits=cfg.counter_bits,
            slip_std=cfg.slip_std,
            count_noise_std=cfg.count_noise_std,
            seed=self.seed,
        )
        half_w, half_d = cfg.room[0] / 2, cfg.room[1] / 2
        self.walls: list[Segment] = [
            (-half_w, -half_d, half_w, -half_d),
            (half_w, -half_d, half_w, half_d),
            (half_w, half_d, -half_w, half_d),
            (-half_w, half_d, -half_w, -half_d),
            *cfg.obstacles,
        ]
        self._rng = np.random.default_rng(self.seed + 1)
        self._accel = 0.0
        self.air: Air = cfg.air
        """The air now (set it to change the weather)."""

    @property
    def time(self) -> float:
        return self.base.time

    @property
    def pose(self) -> Pose2D:
        """Ground truth."""
        return self.base.pose

    def step(self, dt: float) -> None:
        before = self._speed()
        self.base.step(dt)
        after = self._speed()
        self._accel = (after - before) / dt if dt > 0 else 0.0

    def _speed(self) -> float:
        left, right = self.base.wheel_speeds
        return 0.5 * self.config.wheel_radius * (left + right)

    def _turn_rate(self) -> float:
        left, right = self.base.wheel_speeds
        return self.config.wheel_radius * (right - left) / self.config.wheel_separation

    # ------------------------------------------------------------------ sensors
    def sonar_distance(self, half_angle: float = 0.1309, rays: int = 5) -> float | None:
        """Nearest wall in the sonar's cone (m from the sonar), or None if nothing is hit."""
        pose = self.pose
        ox = pose.x + self.config.sonar_offset * math.cos(pose.theta)
        oy = pose.y + self.config.sonar_offset * math.sin(pose.theta)
        best: float | None = None
        spread = [0.0] if rays <= 1 else [-1 + 2 * i / (rays - 1) for i in range(rays)]
        for fraction in spread:
            angle = pose.theta + half_angle * fraction
            hit = _ray_cast(ox, oy, math.cos(angle), math.sin(angle), self.walls)
            if hit is not None and (best is None or hit < best):
                best = hit
        return best

    def imu_truth(self, temperature_c: float = 25.0) -> ImuTruth:
        """Specific force, rotation and field in the body frame (x forward, z up)."""
        v, w = self._speed(), self._turn_rate()
        moving = abs(v) > 1e-3 or abs(w) > 1e-3
        shake = self._rng.normal(0.0, self.config.vibration, 3) if moving else np.zeros(3)
        heading = self.pose.theta
        fx, fy, fz = self.config.magnetic_field
        c, s = math.cos(heading), math.sin(heading)
        field = (c * fx + s * fy, -s * fx + c * fy, fz)
        return ImuTruth(
            specific_force=(
                self._accel + float(shake[0]),
                v * w + float(shake[1]),
                STANDARD_GRAVITY + float(shake[2]),
            ),
            angular_velocity=(0.0, 0.0, w),
            temperature_c=temperature_c,
            magnetic_field=field,
        )


def _ray_cast(ox: float, oy: float, dx: float, dy: float, walls: list[Segment]) -> float | None:
    best: float | None = None
    for x1, y1, x2, y2 in walls:
        ex, ey = x2 - x1, y2 - y1
        denom = dx * ey - dy * ex
        if abs(denom) < 1e-12:
            continue
        t = ((x1 - ox) * ey - (y1 - oy) * ex) / denom
        u = ((x1 - ox) * dy - (y1 - oy) * dx) / denom
        if t > 0 and 0 <= u <= 1 and (best is None or t < best):
            best = t
    return best
