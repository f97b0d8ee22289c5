"""``hcsr04`` on an MCU board: its pins (``pins: {trigger: 8, echo: 12}``, the DiffDriveBase
wiring by default) and its part of a generated sketch (``drivers/hcsr04.h``: the echo is timed
in the echo pin's external interrupt where it has one, else polled from ``loop()``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final

from hwbridge.firmware.boards import McuBoard, PinName
from hwbridge.robot.plugin import PinUse, SketchContext, SketchPart, Wiring, WiringError

__all__ = ["DEFAULT_PINS", "pins_of", "sketch", "wiring"]

DEFAULT_PINS: Final[dict[str, PinName]] = {"trigger": 8, "echo": 12}


def pins_of(settings: Mapping[str, Any]) -> dict[str, PinName]:
    """Trigger and echo: the ``pins`` setting over the defaults."""
    given = settings.get("pins") or {}
    if not isinstance(given, Mapping):
        raise WiringError("pins", "pins must be a mapping {trigger: PIN, echo: PIN}")
    pins = dict(DEFAULT_PINS)
    for key, value in given.items():
        if key not in DEFAULT_PINS:
            raise WiringError(f"pins.{key}", f"pins: unknown {key!r}; known: trigger, echo")
        if not isinstance(value, int | str) or isinstance(value, bool):
            raise WiringError(f"pins.{key}", f"pins: {key} must be a pin, not {value!r}")
        pins[key] = value
    return pins


def wiring(settings: Mapping[str, Any], board: McuBoard) -> Wiring:
    given = settings.get("pins") or {}
    return Wiring(
        pins=tuple(
            PinUse(pin, f"sonar {key}", f"pins.{key}" if key in given else "")
            for key, pin in pins_of(settings).items()
        )
    )


def sketch(settings: Mapping[str, Any], context: SketchContext) -> SketchPart:
    pins = pins_of(settings)
    trigger, echo = context.board.number(pins["trigger"]), context.board.number(pins["echo"])
    p, nh = context.name, context.node
    period = max(1, round(1000.0 / float(settings["rate"])))
    return SketchPart(
        includes=("hwbridge/drivers/hcsr04.h", "hwbridge_msgs/SonarEcho.h"),
        globals=f"""\
// {p}: an HC-SR04, trigger {trigger}, echo {echo}
HcSr04<{trigger}, {echo}> {p}_sonar;
hwbridge_msgs::SonarEcho {p}_msg;
hwbridge::Publisher<hwbridge_msgs::SonarEcho> {p}_pub("{settings["topic"]}");
""",
        setup=f"""\
{nh}.advertise({p}_pub);
{p}_msg.header.frame_id.assign("{settings["frame_id"]}");
{p}_sonar.begin({period});
""",
        loop=f"""\
if ({p}_sonar.update()) {{
  {p}_sonar.fill({p}_msg, {float(settings["temperature"])!r}f);
  {nh}.now(&{p}_msg.header.stamp.sec, &{p}_msg.header.stamp.nsec);
  ++{p}_msg.header.seq;
  {p}_pub.publish({p}_msg);
}}
""",
    )
