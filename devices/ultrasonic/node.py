"""The host node of ``hcsr04``: ``sonar_echo`` (hwbridge_msgs/SonarEcho) -> ``range``
(sensor_msgs/Range), next to the board on the graph (same namespace)."""

from __future__ import annotations

import dataclasses
from typing import Any

from hwbridge.devices.common import stamp_seconds
from hwbridge.devices.ultrasonic.hcsr04 import UltrasonicRanger
from hwbridge.graph import Node

__all__ = ["SonarNode"]


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
        stamp = stamp_seconds(echo.header.stamp)
        self.latest = self.ranger.to_range_msg(float(echo.echo_us), stamp)
        self._range.publish(self.latest)
