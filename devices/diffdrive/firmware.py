"""``diffdrive`` on an MCU board: its pins (:func:`wiring`) and its part of a generated sketch
(:func:`sketch`), after the DiffDriveBase example's wiring and code.

The pins are the device's ``pins`` setting, ``{left_encoder: [A, B], right_encoder: [A, B],
left_motor: [PWM, DIR], right_motor: [PWM, DIR]}``, any of them left out taking DiffDriveBase's
wiring for the board (:data:`DEFAULT_PINS`). An encoder's A counts in its external interrupt
(``drivers/quadrature.h``): both A and B on interrupt pins decode x4, A alone x2. A motor's PWM
pin must have PWM."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final

from hwbridge.firmware.boards import McuBoard, PinName
from hwbridge.robot.plugin import PinUse, SketchContext, SketchPart, Wiring, WiringError

__all__ = ["DEFAULT_PINS", "PIN_NAMES", "pins_of", "sketch", "wiring"]

PIN_NAMES: Final = ("left_encoder", "right_encoder", "left_motor", "right_motor")

_UNO: Final[dict[str, tuple[PinName, PinName]]] = {
    "left_encoder": (2, 4),
    "right_encoder": (3, 5),
    "left_motor": (6, 7),
    "right_motor": (10, 11),
}
DEFAULT_PINS: Final[dict[str, dict[str, tuple[PinName, PinName]]]] = {
    "uno": _UNO,
    "nano": _UNO,
    "mega": {**_UNO, "left_encoder": (2, 3), "right_encoder": (18, 19)},
}
"""DiffDriveBase's wiring (encoders A, B; motors PWM, direction) by MCU board."""


def pins_of(settings: Mapping[str, Any], board: str) -> dict[str, tuple[PinName, PinName]]:
    """The four pin pairs: the ``pins`` setting over the board's defaults."""
    given = settings.get("pins") or {}
    if not isinstance(given, Mapping):
        raise WiringError("pins", f"pins must be a mapping of {', '.join(PIN_NAMES)}")
    pins = dict(DEFAULT_PINS.get(board, _UNO))
    for key, value in given.items():
        if key not in PIN_NAMES:
            raise WiringError(
                f"pins.{key}", f"pins: unknown {key!r}; known: {', '.join(PIN_NAMES)}"
            )
        if (
            not isinstance(value, list)
            or len(value) != 2
            or not all(isinstance(p, int | str) and not isinstance(p, bool) for p in value)
        ):
            what = "A, B" if key.endswith("encoder") else "PWM, direction"
            raise WiringError(f"pins.{key}", f"pins: {key} must be two pins [{what}]")
        pins[key] = (value[0], value[1])
    return pins


def wiring(settings: Mapping[str, Any], board: McuBoard) -> Wiring:
    pins = pins_of(settings, board.name)
    uses = []
    for key in PIN_NAMES:
        side, part = key.split("_")
        roles = ("A", "B") if part == "encoder" else ("PWM", "direction")
        for index, (pin, role) in enumerate(zip(pins[key], roles, strict=True)):
            needs: tuple[Any, ...] = ()
            if part == "encoder" and index == 0:
                needs = ("interrupt",)
            elif part == "motor" and index == 0:
                needs = ("pwm",)
            given = key in (settings.get("pins") or {})
            uses.append(
                PinUse(pin, f"{side} {part} {role}", f"pins.{key}.{index}" if given else "", needs)
            )
    return Wiring(pins=tuple(uses))


def sketch(settings: Mapping[str, Any], context: SketchContext) -> SketchPart:
    board = context.board
    pins = {
        key: tuple(board.number(p) for p in pair)
        for key, pair in pins_of(settings, board.name).items()
    }
    p, nh = context.name, context.node
    count = "uint32_t" if int(settings["counter_bits"]) == 32 else "uint16_t"
    period = max(1, round(1000.0 / float(settings["rate"])))
    timeout = min(65535, max(1, round(1000.0 * float(settings["cmd_vel_timeout"]))))
    top, targets = float(settings["motor_max_speed"]), settings["targets_topic"]
    (la, lb), (ra, rb) = pins["left_encoder"], pins["right_encoder"]
    (lp, ld), (rp, rd) = pins["left_motor"], pins["right_motor"]
    globals_ = f"""\
// {p}: wheel encoders and motors; full PWM is {settings["motor_max_speed"]:g} rad/s
typedef QuadratureEncoder<{la}, {lb}, {count}> {p}_Left;
typedef QuadratureEncoder<{ra}, {rb}, {count}> {p}_Right;
Motor {p}_left_motor({lp}, {ld});
Motor {p}_right_motor({rp}, {rd});
DiffDriveMotors {p}_motors({p}_left_motor, {p}_right_motor, {top!r}f, {timeout});
hwbridge_msgs::WheelTicks {p}_ticks_msg;
hwbridge::Publisher<hwbridge_msgs::WheelTicks> {p}_ticks_pub("{settings["ticks_topic"]}");
unsigned long {p}_ticks_ms = 0;

void {p}_on_targets(const hwbridge_msgs::WheelTargets& targets) {{ {p}_motors.command(targets); }}
hwbridge::Subscriber<hwbridge_msgs::WheelTargets> {p}_targets_sub("{targets}",
                                                                   &{p}_on_targets);

void {p}_on_reset(const std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {{
  {p}_Left::reset();
  {p}_Right::reset();
  {p}_motors.stop();
  res.success = true;
  res.message.assign("counters reset, motors stopped");
}}
hwbridge::ServiceServer<std_srvs::Trigger> {p}_reset_srv("reset_counters", &{p}_on_reset);
"""
    setup = f"""\
{nh}.advertise({p}_ticks_pub);
{nh}.subscribe({p}_targets_sub);
{nh}.advertiseService({p}_reset_srv);
{p}_ticks_msg.header.frame_id.assign("{settings["base_frame_id"]}");
{p}_Left::begin();
{p}_Right::begin();
{p}_motors.begin();
"""
    connect = f"""\
char line[64];
snprintf(line, sizeof line, "{p}: encoders x%u (counts_per_rev = PPR x %u), %u-bit counters",
         {p}_Left::decoding(), {p}_Left::decoding(), {p}_Left::counter_bits());
{nh}.logInfo(line);
"""
    loop = f"""\
{p}_motors.update();
if (now - {p}_ticks_ms >= {period}) {{
  {p}_ticks_ms = now;
  fill_wheel_ticks<{p}_Left, {p}_Right>({p}_ticks_msg);
  {nh}.now(&{p}_ticks_msg.header.stamp.sec, &{p}_ticks_msg.header.stamp.nsec);
  ++{p}_ticks_msg.header.seq;
  {p}_ticks_pub.publish({p}_ticks_msg);
}}
"""
    return SketchPart(
        includes=(
            "hwbridge/drivers/motor.h",
            "hwbridge/drivers/quadrature.h",
            "hwbridge_msgs/WheelTargets.h",
            "hwbridge_msgs/WheelTicks.h",
            "std_srvs/Trigger.h",
        ),
        globals=globals_,
        setup=setup,
        loop=loop,
        connect=connect,
        disconnect=f"{p}_motors.stop();  // no host, no driving\n",
    )
