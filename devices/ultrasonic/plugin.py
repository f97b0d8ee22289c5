"""``hcsr04``: an HC-SR04 ultrasonic ranger on a board, as a device plugin
(:mod:`hwbridge.robot.plugin`): its settings, its model on a virtual board, its pin-level model
(:mod:`.pins`) and its host node (:mod:`.node`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, ClassVar

from hwbridge.devices.common import encode
from hwbridge.devices.ultrasonic import firmware as onboard
from hwbridge.devices.ultrasonic.hcsr04 import MAX_RANGE, MIN_RANGE, HcSr04Model, UltrasonicRanger
from hwbridge.devices.ultrasonic.node import SonarNode
from hwbridge.devices.ultrasonic.pins import SonarPins
from hwbridge.robot.plugin import (
    Closeable,
    DevicePlugin,
    EmulatedBoard,
    Field,
    HostContext,
    PinBoard,
    PinModel,
    SketchContext,
    SketchPart,
    TopicUse,
    Wiring,
)

if TYPE_CHECKING:
    from hwbridge.firmware.boards import McuBoard

__all__ = ["HcSr04Plugin"]


class HcSr04Plugin(DevicePlugin):
    """An HC-SR04: echo widths on ``sonar_echo``; the host node makes ``range``."""

    type = "hcsr04"
    summary = "ultrasonic ranger: sonar_echo -> range (sensor_msgs/Range)"
    firmware = "hwbridge/drivers/hcsr04.h: HcSr04"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("topic", str, "sonar_echo", "board topic of the echo widths"),
        Field("range_topic", str, "range", "host topic of sensor_msgs/Range"),
        Field("rate", float, 15.0, "readings per second", minimum=0.1, maximum=40.0),
        Field("temperature", float, 20.0, "air temperature, C", minimum=-40.0, maximum=85.0),
        Field("noise_std", float, 0.002, "emulator: echo noise, m", minimum=0.0),
        Field("frame_id", str, "sonar_link"),
        Field("min_range", float, MIN_RANGE, "m", minimum=0.0),
        Field("max_range", float, MAX_RANGE, "m", minimum=0.01),
        Field("pins", dict, {}, "{trigger: PIN, echo: PIN}; default {trigger: 8, echo: 12}"),
    )

    def emulate(self, settings: Mapping[str, Any], board: EmulatedBoard) -> None:
        sonar = HcSr04Model(
            temperature_c=settings["temperature"],
            noise_std=settings["noise_std"],
            seed=board.seed + 2,
        )

        def read() -> bytes:
            echo = sonar.measure(board.world.sonar_distance())
            return encode(
                board,
                "hwbridge_msgs/SonarEcho",
                {
                    "header": board.header(settings["frame_id"]),
                    "echo_us": int(echo),
                    "temperature": sonar.temperature_c,
                },
            )

        board.publisher(settings["topic"], "hwbridge_msgs/SonarEcho", settings["rate"], read)

    def topics(self, settings: Mapping[str, Any]) -> tuple[TopicUse, ...]:
        return (
            TopicUse(settings["topic"], "hwbridge_msgs/SonarEcho", "publishes", "board"),
            TopicUse(settings["topic"], "hwbridge_msgs/SonarEcho", "subscribes"),
            TopicUse(settings["range_topic"], "sensor_msgs/Range", "publishes"),
        )

    def pin_model(self, settings: Mapping[str, Any], board: PinBoard) -> PinModel:
        return SonarPins(settings, onboard.pins_of(settings), board.seed)

    def wiring(self, settings: Mapping[str, Any], board: McuBoard) -> Wiring:
        return onboard.wiring(settings, board)

    def sketch(self, settings: Mapping[str, Any], context: SketchContext) -> SketchPart:
        return onboard.sketch(settings, context)

    def host_node(self, settings: Mapping[str, Any], context: HostContext) -> Closeable:
        ranger = UltrasonicRanger(
            frame_id=settings["frame_id"],
            temperature_c=settings["temperature"],
            min_range=settings["min_range"],
            max_range=settings["max_range"],
        )
        return SonarNode(
            context.node,
            echo_topic=settings["topic"],
            range_topic=settings["range_topic"],
            ranger=ranger,
        )
