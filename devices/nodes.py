"""Host-side device nodes: a board's raw readings in, standard ROS messages out.

Each node attaches to the graph next to a board (same namespace) and does the host's share of a
device plugin:

- :class:`DiffDriveNode`: ``wheel_ticks`` (hwbridge_msgs/WheelTicks) -> ``odom``
  (nav_msgs/Odometry) and ``/tf``; ``cmd_vel`` (geometry_msgs/Twist) -> ``wheel_targets``,
  with the 0.5 s command timeout;
- :class:`SonarNode`: ``sonar_echo`` (hwbridge_msgs/SonarEcho) -> ``range`` (sensor_msgs/Range);
- :class:`ImuNode`: ``imu_raw`` (hwbridge_msgs/ImuRaw) -> ``imu`` (sensor_msgs/Imu), and on an
  MPU-9250 with its magnetometer read, ``mag`` (sensor_msgs/MagneticField).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any, Final

from hwbridge.devices.encoders import (
    CommandWatchdog,
    DiffDriveOdometry,
    DiffDriveParams,
    wrap_delta,
)
from hwbridge.devices.imu.mpu import ACCEL_RANGES_G, GYRO_RANGES_DPS, MPU6050, MPU9250, ChipSpec
from hwbridge.devices.imu.plugin import MpuImu, RawSample, sensitivity_adjustment
from hwbridge.devices.ultrasonic import UltrasonicRanger
from hwbridge.graph import Node

__all__ = ["DiffDriveNode", "ImuNode", "SonarNode"]

log = logging.getLogger("hwbridge.devices")


class DiffDriveNode:
    """Wheel ticks -> odometry and tf; cmd_vel -> wheel targets (stops after 0.5 s silence).

    A thread repeats the latest targets at 10 Hz; when cmd_vel has been quiet for the timeout
    it sends one stop (zero targets), then nothing until the next command. ``clock`` gives the
    time (s) the timeout is measured in.
    """

    def __init__(
        self,
        node: Node,
        params: DiffDriveParams,
        *,
        max_wheel_speed: float = 50.0,
        clock: Callable[[], float] = time.monotonic,
        ticks_topic: str = "wheel_ticks",
        targets_topic: str = "wheel_targets",
    ) -> None:
        self.node = node
        self.params = params
        self.odometry = DiffDriveOdometry.from_params(params)
        self.max_counts_per_s = max_wheel_speed / (2 * math.pi) * params.counts_per_rev
        """Faster counting than this means the counters restarted (a board reset)."""
        self.rereferences = 0
        self._last: tuple[int, int, float] | None = None
        self.watchdog = CommandWatchdog(params.cmd_vel_timeout)
        self._clock = clock
        self._command_lock = threading.Lock()
        """Held from reading the watchdog to publishing what it said, on both paths (a new
        cmd_vel, a control cycle), so the targets sent last are always the latest decision."""
        self._stopped = True
        """The last targets sent were the watchdog's stop (or nothing was commanded yet)."""
        self.latest: Any = None
        """The last nav_msgs/Odometry published."""
        self._odom = node.publisher("odom", "nav_msgs/Odometry")
        self._tf = node.publisher("/tf", "tf2_msgs/TFMessage")
        self._targets = node.publisher(targets_topic, "hwbridge_msgs/WheelTargets")
        self._inputs = (
            node.subscriber(ticks_topic, "hwbridge_msgs/WheelTicks", self._on_ticks),
            node.subscriber("cmd_vel", "geometry_msgs/Twist", self._on_cmd_vel),
        )
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._drive, name="diffdrive", daemon=True)
        self._thread.start()

    def _on_ticks(self, ticks: Any) -> None:
        stamp = _seconds(ticks.header.stamp)
        left, right = int(ticks.left), int(ticks.right)
        if self._implausible(left, right, stamp):
            # The board restarted (its counters began again): keep the pose, take this reading
            # as the new reference, so odometry never jumps (REP-105: odom is continuous).
            self.rereferences += 1
            log.warning(
                "%s: wheel counters jumped (board reset?); odometry re-referenced", self.node.name
            )
            self.odometry.reset(self.odometry.state.pose)
        self._last = (left, right, stamp)
        state = self.odometry.update(left, right, stamp)
        self.latest = self.odometry.to_odometry_msg(state)
        self._odom.publish(self.latest)
        self._tf.publish(self.odometry.to_tf_msg(state))

    def _implausible(self, left: int, right: int, stamp: float) -> bool:
        if self._last is None:
            return False
        last_left, last_right, last_stamp = self._last
        bits = self.params.counter_bits
        moved = max(
            abs(wrap_delta(left, last_left, bits)), abs(wrap_delta(right, last_right, bits))
        )
        gap = stamp - last_stamp
        if not 0.0 <= gap <= 5.0:
            return True  # the board's clock restarted or jumped: its counters may have too
        return moved > self.max_counts_per_s * (gap + 0.1) + 2

    def _on_cmd_vel(self, twist: Any) -> None:
        targets = self.odometry.wheel_targets(float(twist.linear.x), float(twist.angular.z))
        with self._command_lock:
            self.watchdog.command(targets, self._clock())
            self._stopped = False
            self._send(targets)

    def _send(self, targets: tuple[float, float]) -> None:
        self._targets.publish({"left": targets[0], "right": targets[1]})

    def tick(self) -> None:
        """One control cycle: repeat the latest targets, or send the stop once when cmd_vel
        has been quiet for the timeout (the drive thread calls it every 0.1 s)."""
        with self._command_lock:
            now = self._clock()
            if self.watchdog.expired(now):
                if self._stopped:
                    return  # stopped already; the board's own timeout holds the motors too
                self._stopped = True
            self._send(self.watchdog.targets(now))

    def _drive(self) -> None:
        while not self._stop.wait(0.1):
            self.tick()

    def stop(self) -> None:
        """Stop the control thread (the node's topics stay; :meth:`tick` still works)."""
        self._stop.set()
        self._thread.join(1)

    def close(self) -> None:
        """Stop the control thread and take the node's topics off the graph."""
        self.stop()
        for endpoint in (*self._inputs, self._odom, self._tf, self._targets):
            endpoint.close()


class SonarNode:
    """HC-SR04 echo widths -> sensor_msgs/Range (REP-117 values for no echo, too close, error)."""

    def __init__(
        self,
        node: Node,
        frame_id: str = "sonar_link",
        *,
        echo_topic: str = "sonar_echo",
        range_topic: str = "range",
        ranger: UltrasonicRanger | None = None,
    ) -> None:
        self.ranger = ranger if ranger is not None else UltrasonicRanger(frame_id=frame_id)
        self.latest: Any = None
        self._range = node.publisher(range_topic, "sensor_msgs/Range")
        self._echo = node.subscriber(echo_topic, "hwbridge_msgs/SonarEcho", self._on_echo)

    def close(self) -> None:
        self._echo.close()
        self._range.close()

    def _on_echo(self, echo: Any) -> None:
        temperature = float(echo.temperature)
        if temperature != self.ranger.temperature_c:
            self.ranger = dataclasses.replace(self.ranger, temperature_c=temperature)
        stamp = _seconds(echo.header.stamp)
        self.latest = self.ranger.to_range_msg(float(echo.echo_us), stamp)
        self._range.publish(self.latest)


_RAW_CHIPS: Final[dict[int, ChipSpec]] = {0: MPU6050, 1: MPU9250}
"""hwbridge_msgs/ImuRaw ``chip`` values (its MPU6050 and MPU9250 constants) -> the chip."""


class ImuNode:
    """Raw MPU-6050/9250 registers -> sensor_msgs/Imu in SI units (REP-145); the MPU-9250's
    magnetometer readings -> sensor_msgs/MagneticField (tesla, NaN on overflow) on ``mag``,
    advertised with the first of them. Each reading is converted with the figures (temperature,
    noise) of the chip the board names; readings naming an unknown chip are dropped (counted in
    :attr:`dropped`, logged once)."""

    def __init__(
        self,
        node: Node,
        *,
        raw_topic: str = "imu_raw",
        imu_topic: str = "imu",
        mag_topic: str = "mag",
        frame_id: str = "imu_link",
    ) -> None:
        self.latest: Any = None
        self.latest_field: Any = None
        self.temperature_c: float | None = None
        """The die temperature (C) of the latest reading."""
        self.dropped = 0
        """Readings dropped because they name a chip this node does not know."""
        self.frame_id = frame_id
        """The frame of the Imu and MagneticField messages."""
        self._node = node
        self._converters: dict[tuple[str, int, int], MpuImu] = {}
        self._imu = node.publisher(imu_topic, "sensor_msgs/Imu")
        self._mag: Any = None
        self._mag_topic = mag_topic
        self._closed = False
        self._raw = node.subscriber(raw_topic, "hwbridge_msgs/ImuRaw", self._on_raw)

    def close(self) -> None:
        self._closed = True  # a reading still in _on_raw publishes nothing more (or a no-op)
        self._raw.close()
        self._imu.close()
        if self._mag is not None:
            self._mag.close()

    def _converter(self, chip: ChipSpec, accel_config: int, gyro_config: int) -> MpuImu:
        accel_fs, gyro_fs = (accel_config >> 3) & 3, (gyro_config >> 3) & 3
        key = (chip.name, accel_fs, gyro_fs)
        found = self._converters.get(key)
        if found is None:
            found = MpuImu(
                _NoPort(),
                accel_range_g=ACCEL_RANGES_G[accel_fs],
                gyro_range_dps=GYRO_RANGES_DPS[gyro_fs],
                chip=chip,
                frame_id=self.frame_id,
            )
            self._converters[key] = found
        return found

    def _on_raw(self, raw: Any) -> None:
        chip = _RAW_CHIPS.get(int(raw.chip))
        if chip is None:
            self.dropped += 1
            if self.dropped == 1:
                log.warning(
                    "%s: imu_raw names chip %d, which is neither MPU6050 (0) nor MPU9250 (1); "
                    "dropping such readings",
                    self._node.name,
                    int(raw.chip),
                )
            return
        words = [int(v) for v in raw.burst]
        converter = self._converter(chip, int(raw.accel_config), int(raw.gyro_config))
        accel, gyro, temperature = converter.convert(
            RawSample((words[0], words[1], words[2]), words[3], (words[4], words[5], words[6]))
        )
        stamp = _seconds(raw.header.stamp)
        self.temperature_c = temperature
        self.latest = converter.imu_msg(accel, gyro, stamp)
        self._imu.publish(self.latest)
        if raw.mag_valid:
            converter.magnetometer_adjustment = sensitivity_adjustment(
                [int(v) for v in raw.mag_asa]
            )
            mx, my, mz = (int(v) for v in raw.mag)
            field = converter.magnetometer_field((mx, my, mz), int(raw.mag_st2))
            self.latest_field = converter.magnetic_field_msg(field, stamp)
            if self._closed:
                return
            if self._mag is None:
                self._mag = self._node.publisher(self._mag_topic, "sensor_msgs/MagneticField")
            self._mag.publish(self.latest_field)


def _seconds(stamp: Any) -> float:
    """A message's time stamp (builtin_interfaces Time) in seconds."""
    return float(stamp.sec + stamp.nanosec * 1e-9)


class _NoPort:
    """The board reads the chip; the host only converts, so there is no I2C port here."""

    def write(self, address: int, reg: int, data: bytes) -> None:
        raise NotImplementedError("the board owns the I2C bus")

    def read(self, address: int, reg: int, n: int) -> bytes:
        raise NotImplementedError("the board owns the I2C bus")
