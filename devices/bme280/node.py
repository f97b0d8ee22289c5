"""The host node of ``bme280``: ``air_raw`` (hwbridge_msgs/Bme280, compensated on the board)
-> ``temperature`` (sensor_msgs/Temperature, degC), ``pressure`` (sensor_msgs/FluidPressure, Pa)
and ``humidity`` (sensor_msgs/RelativeHumidity, 0..1), next to the board on the graph."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final

from hwbridge import msg
from hwbridge.devices.common import stamp_seconds
from hwbridge.graph import Node

__all__ = [
    "HUMIDITY_VARIANCE",
    "PRESSURE_VARIANCE",
    "TEMPERATURE_VARIANCE",
    "AirReading",
    "Bme280Node",
    "from_raw",
]

TEMPERATURE_VARIANCE: Final = 0.25
"""degC^2: the datasheet's absolute accuracy, +-0.5 degC at 25 degC, as one standard deviation."""
PRESSURE_VARIANCE: Final = 1.0e4
"""Pa^2: absolute accuracy +-1 hPa (0..65 degC)."""
HUMIDITY_VARIANCE: Final = 0.03**2
"""Absolute accuracy +-3 %RH, as a fraction."""


@dataclass(frozen=True)
class AirReading:
    """One reading in SI units."""

    temperature: float
    """degC."""
    pressure: float
    """Pa."""
    humidity: float
    """Relative humidity as a fraction, 0..1 (sensor_msgs/RelativeHumidity)."""


def from_raw(temperature: int, pressure: int, humidity: int) -> AirReading:
    """The compensated integers (0.01 degC, Pa in Q24.8, %RH in Q22.10) in SI units."""
    return AirReading(temperature / 100.0, pressure / 256.0, humidity / 1024.0 / 100.0)


class Bme280Node:
    """hwbridge_msgs/Bme280 -> the three sensor_msgs, each stamped and framed as the reading."""

    def __init__(
        self,
        node: Node,
        *,
        raw_topic: str = "air_raw",
        temperature_topic: str = "temperature",
        pressure_topic: str = "pressure",
        humidity_topic: str = "humidity",
    ) -> None:
        self.latest: AirReading | None = None
        self._temperature = node.publisher(temperature_topic, "sensor_msgs/Temperature")
        self._pressure = node.publisher(pressure_topic, "sensor_msgs/FluidPressure")
        self._humidity = node.publisher(humidity_topic, "sensor_msgs/RelativeHumidity")
        self._raw = node.subscriber(raw_topic, "hwbridge_msgs/Bme280", self._on_raw)

    def close(self) -> None:
        self._raw.close()
        for publisher in (self._temperature, self._pressure, self._humidity):
            publisher.close()

    def _on_raw(self, raw: Any) -> None:
        reading = from_raw(int(raw.temperature), int(raw.pressure), int(raw.humidity))
        self.latest = reading
        header = {"stamp": stamp_seconds(raw.header.stamp), "frame_id": raw.header.frame_id}
        self._temperature.publish(
            msg.from_dict(
                "sensor_msgs/Temperature",
                {
                    "header": header,
                    "temperature": reading.temperature,
                    "variance": TEMPERATURE_VARIANCE,
                },
            )
        )
        self._pressure.publish(
            msg.from_dict(
                "sensor_msgs/FluidPressure",
                {
                    "header": header,
                    "fluid_pressure": reading.pressure,
                    "variance": PRESSURE_VARIANCE,
                },
            )
        )
        self._humidity.publish(
            msg.from_dict(
                "sensor_msgs/RelativeHumidity",
                {
                    "header": header,
                    "relative_humidity": reading.humidity,
                    "variance": HUMIDITY_VARIANCE,
                },
            )
        )
