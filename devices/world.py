"""Small shared physics helpers for the device models: constants, planar poses, yaw quaternions,
the air around the robot.

Kept minimal on purpose: the full world model (obstacles, beams, bodies) is built on top of these
and of the device models in :mod:`hwbridge.devices.diffdrive.encoders`,
:mod:`hwbridge.devices.ultrasonic.hcsr04` and :mod:`hwbridge.devices.imu`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

__all__ = [
    "ORIGIN",
    "STANDARD_ATMOSPHERE",
    "STANDARD_GRAVITY",
    "Air",
    "Pose2D",
    "Quaternion",
    "normalize_angle",
    "yaw_to_quaternion",
]

STANDARD_GRAVITY: Final = 9.80665
"""Standard acceleration of gravity g0 in m/s^2 (the unit the IMU datasheets call 1 g)."""

Quaternion = tuple[float, float, float, float]
"""A rotation as (x, y, z, w), the field order of geometry_msgs/Quaternion."""


def normalize_angle(angle: float) -> float:
    """``angle`` (rad) wrapped into [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def yaw_to_quaternion(yaw: float) -> Quaternion:
    """Rotation about +z by ``yaw`` radians as (x, y, z, w)."""
    half = 0.5 * yaw
    return (0.0, 0.0, math.sin(half), math.cos(half))


@dataclass(frozen=True)
class Pose2D:
    """A planar pose: position (m) and heading ``theta`` (rad, counter-clockwise from +x)."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0

    def distance_to(self, other: Pose2D) -> float:
        """Euclidean distance between the two positions (m)."""
        return math.hypot(self.x - other.x, self.y - other.y)

    def quaternion(self) -> Quaternion:
        """The heading as a quaternion (x, y, z, w)."""
        return yaw_to_quaternion(self.theta)


ORIGIN: Final = Pose2D()
"""The pose at the origin, heading +x."""

STANDARD_ATMOSPHERE: Final = 101325.0
"""Sea-level pressure of the standard atmosphere, Pa."""


@dataclass(frozen=True)
class Air:
    """The air around the robot, as environmental sensors (a BME280) measure it."""

    temperature: float = 20.0
    """Degrees Celsius."""
    pressure: float = STANDARD_ATMOSPHERE
    """Pa."""
    humidity: float = 45.0
    """Relative humidity, % (0..100)."""
