"""The host node of ``diffdrive``: ``wheel_ticks`` (hwbridge_msgs/WheelTicks) -> ``odom``
(nav_msgs/Odometry) and ``/tf``; ``cmd_vel`` (geometry_msgs/Twist) -> ``wheel_targets``, with the
0.5 s command timeout. It attaches to the graph next to the board (same namespace)."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

from hwbridge.devices.common import stamp_seconds
from hwbridge.devices.diffdrive.encoders import (
    CommandWatchdog,
    DiffDriveOdometry,
    DiffDriveParams,
    wrap_delta,
)
from hwbridge.graph import Node

__all__ = ["DiffDriveNode"]

log = logging.getLogger("hwbridge.devices")

CLOCK_STEP_BACK = 1.0
"""Seconds a board's stamps may go back without meaning a restart: a time sync that sets a
slow board's clock back to host time (the firmware syncs every 5 s)."""


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
        stamp = stamp_seconds(ticks.header.stamp)
        left, right = int(ticks.left), int(ticks.right)
        if self._implausible(left, right, stamp):
            # The board restarted (its counters began again): keep the pose, take this reading
            # as the new reference, so odometry never jumps (REP-105: odom is continuous).
            self.rereferences += 1
            log.warning(
                "%s: wheel counters jumped (board reset?); odometry re-referenced", self.node.name
            )
            self.odometry.rereference()
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
        if not -CLOCK_STEP_BACK <= gap <= 5.0:
            return True  # the board's clock restarted or jumped: its counters may have too
        # A stamp a little older than the last is the board's clock set back by a time sync
        # (a board that runs slow, such as simavr on a busy machine, falls behind host time
        # between two syncs): the counters alone say whether they restarted.
        return moved > self.max_counts_per_s * (max(gap, 0.0) + 0.1) + 2

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
