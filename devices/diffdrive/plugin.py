"""``diffdrive``: two motors with quadrature encoders on a board, as a device plugin
(:mod:`hwbridge.robot.plugin`): its settings, its model on a virtual board, its pin-level model
(:mod:`.pins`) and its host node (:mod:`.node`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, ClassVar

from hwbridge import msg
from hwbridge.devices.common import RATE, encode
from hwbridge.devices.diffdrive import firmware as onboard
from hwbridge.devices.diffdrive.encoders import DiffDriveParams, wrap_counter
from hwbridge.devices.diffdrive.node import DiffDriveNode
from hwbridge.devices.diffdrive.pins import DiffDrivePins
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

__all__ = ["TARGET_TIMEOUT", "DiffDrivePlugin"]

TARGET_TIMEOUT = 0.5
"""Seconds without wheel targets after which the board stops its motors (as the firmware)."""


class DiffDrivePlugin(DevicePlugin):
    """Two motors with quadrature encoders: ``wheel_ticks`` out, ``wheel_targets`` in; the host
    node makes ``odom`` and ``/tf`` and takes ``cmd_vel``."""

    type = "diffdrive"
    summary = "wheel encoders and motors: wheel_ticks -> odom and /tf, cmd_vel -> wheel_targets"
    firmware = (
        "hwbridge/drivers/quadrature.h: QuadratureEncoder; "
        "hwbridge/drivers/motor.h: DiffDriveMotors"
    )
    fields: ClassVar[tuple[Field, ...]] = (
        Field("ticks_topic", str, "wheel_ticks", "board topic of the counters"),
        Field("targets_topic", str, "wheel_targets", "board topic of the wheel speed targets"),
        RATE,
        Field("wheel_radius", float, doc="m", minimum=1e-4),
        Field("wheel_separation", float, doc="m, between the wheels' contact points", minimum=1e-4),
        Field("counts_per_rev", float, doc="counts per wheel turn (4x decoding)", minimum=1.0),
        Field("counter_bits", int, 32, "width of the board's counters", choices=(16, 32)),
        Field("cmd_vel_timeout", float, 0.5, "s without cmd_vel before stopping", minimum=0.05),
        Field("max_wheel_speed", float, 50.0, "rad/s; faster means a counter reset", minimum=0.1),
        Field("odom_frame_id", str, "odom", "frame odometry is given in"),
        Field("base_frame_id", str, "base_link", "the robot's frame (odom's child frame)"),
        Field(
            "pins",
            dict,
            {},
            "{left_encoder: [A, B], right_encoder: [A, B], left_motor: [PWM, DIR], "
            "right_motor: [PWM, DIR]}; default DiffDriveBase's wiring for the board",
        ),
        Field(
            "motor_max_speed",
            float,
            20.0,
            "rad/s of a wheel at full PWM (compiled into generated firmware)",
            minimum=0.1,
        ),
    )

    def emulate(self, settings: Mapping[str, Any], board: EmulatedBoard) -> None:
        world = board.world
        bits = int(settings["counter_bits"])
        motors = _Motors()

        def read() -> bytes:
            left, right = world.base.counts()
            left0, right0 = motors.offset
            return encode(
                board,
                "hwbridge_msgs/WheelTicks",
                {
                    "header": board.header(settings["base_frame_id"]),
                    "left": _as_int32(wrap_counter(left - left0, bits)),
                    "right": _as_int32(wrap_counter(right - right0, bits)),
                    "counter_bits": bits,
                },
            )

        def on_targets(payload: bytes) -> None:
            targets = msg.decode(payload, "hwbridge_msgs/WheelTargets", board.registry)
            motors.targets = (float(targets.left), float(targets.right))
            motors.commanded_at = world.time

        def step(now: float) -> None:
            if now - motors.commanded_at > TARGET_TIMEOUT:  # the firmware's own command timeout
                motors.targets = (0.0, 0.0)
            world.base.set_wheel_targets(*motors.targets)

        def reset() -> None:  # counters start again from zero, motors stop
            motors.offset = world.base.counts()
            motors.targets, motors.commanded_at = (0.0, 0.0), -1e9

        board.publisher(settings["ticks_topic"], "hwbridge_msgs/WheelTicks", settings["rate"], read)
        board.subscriber(settings["targets_topic"], "hwbridge_msgs/WheelTargets", on_targets)
        board.on_step(step)
        board.on_reset(reset)

    def topics(self, settings: Mapping[str, Any]) -> tuple[TopicUse, ...]:
        ticks, targets = settings["ticks_topic"], settings["targets_topic"]
        return (
            TopicUse(ticks, "hwbridge_msgs/WheelTicks", "publishes", "board"),
            TopicUse(targets, "hwbridge_msgs/WheelTargets", "subscribes", "board"),
            TopicUse(ticks, "hwbridge_msgs/WheelTicks", "subscribes"),
            TopicUse(targets, "hwbridge_msgs/WheelTargets", "publishes"),
            TopicUse("odom", "nav_msgs/Odometry", "publishes"),
            TopicUse("/tf", "tf2_msgs/TFMessage", "publishes", shared=True),
            TopicUse("cmd_vel", "geometry_msgs/Twist", "subscribes"),
        )

    def pin_model(self, settings: Mapping[str, Any], board: PinBoard) -> PinModel:
        return DiffDrivePins(onboard.pins_of(settings, board.pins.name))

    def wiring(self, settings: Mapping[str, Any], board: McuBoard) -> Wiring:
        return onboard.wiring(settings, board)

    def sketch(self, settings: Mapping[str, Any], context: SketchContext) -> SketchPart:
        return onboard.sketch(settings, context)

    def host_node(self, settings: Mapping[str, Any], context: HostContext) -> Closeable:
        params = DiffDriveParams.from_dict(
            {
                key: settings[key]
                for key in (
                    "wheel_radius",
                    "wheel_separation",
                    "counts_per_rev",
                    "counter_bits",
                    "cmd_vel_timeout",
                    "odom_frame_id",
                    "base_frame_id",
                )
            }
            | {"publish_rate": settings["rate"]}
        )
        return DiffDriveNode(
            context.node,
            params,
            max_wheel_speed=settings["max_wheel_speed"],
            ticks_topic=settings["ticks_topic"],
            targets_topic=settings["targets_topic"],
        )


class _Motors:
    """The emulated diffdrive firmware's state: wheel targets, when they came, counter zero."""

    def __init__(self) -> None:
        self.targets = (0.0, 0.0)
        self.commanded_at = -1e9
        self.offset: tuple[int, int] = (0, 0)


def _as_int32(value: int) -> int:
    """A counter register value as the int32 field carries it (two's complement)."""
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value >= 1 << 31 else value
