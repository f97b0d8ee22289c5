"""A thermometer as a device plugin that hwbridge knows only through its entry point (a test
plugin): the board publishes the raw ADC reading of an NTC divider on ``thermo_raw``
(std_msgs/UInt16); the host node turns it into ``temperature`` (sensor_msgs/Temperature).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar

from hwbridge import msg
from hwbridge.robot.plugin import DevicePlugin, EmulatedBoard, Field, HostContext

__all__ = ["ThermoPlugin", "adc_for", "celsius_for"]

_BETA, _R25, _T25 = 3950.0, 10_000.0, 298.15


def adc_for(celsius: float) -> int:
    """The 10-bit ADC count of a 10 k NTC (beta 3950) under a 10 k pull-up at ``celsius``."""
    resistance = _R25 * math.exp(_BETA * (1 / (celsius + 273.15) - 1 / _T25))
    return round(1023 * resistance / (resistance + _R25))


def celsius_for(adc: int) -> float:
    resistance = _R25 * adc / (1023 - adc)
    return 1 / (math.log(resistance / _R25) / _BETA + 1 / _T25) - 273.15


class _Node:
    def __init__(self, context: HostContext, settings: Mapping[str, Any]) -> None:
        self.out = context.node.publisher(settings["temperature_topic"], "sensor_msgs/Temperature")
        self.inp = context.node.subscriber(settings["topic"], "std_msgs/UInt16", self._on_raw)

    def _on_raw(self, raw: Any) -> None:
        self.out.publish({"temperature": celsius_for(int(raw.data)), "variance": 0.25})

    def close(self) -> None:
        self.inp.close()
        self.out.close()


class ThermoPlugin(DevicePlugin):
    type = "thermo"
    summary = "an NTC thermometer on an ADC pin: thermo_raw -> temperature"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("topic", str, "thermo_raw"),
        Field("temperature_topic", str, "temperature"),
        Field("rate", float, 5.0, minimum=0.1),
        Field("room_celsius", float, 21.5, "emulator: the room's temperature"),
    )

    def emulate(self, settings: Mapping[str, Any], board: EmulatedBoard) -> None:
        count = adc_for(settings["room_celsius"])

        def read() -> bytes:
            return msg.encode(msg.from_dict("std_msgs/UInt16", {"data": count}, board.registry))

        board.publisher(settings["topic"], "std_msgs/UInt16", settings["rate"], read)

    def host_node(self, settings: Mapping[str, Any], context: HostContext) -> _Node:
        return _Node(context, settings)
