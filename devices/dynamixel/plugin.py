"""Dynamixel servos as device plugins (:mod:`hwbridge.robot.plugin`): ``dynamixel``, a servo on
a board's own bus that the board drives (with a pin-level model, :mod:`.pins`), and
``dynamixel_bus``, a chain of servos on the host's own serial adapter (a U2D2 or any
USB-TTL/RS-485 adapter).

In a robot file it is a host device with a link of its own::

    host_devices:
      - type: dynamixel_bus
        name: arm
        link: /dev/ttyUSB0
        baud: 57600
        namespace: /arm
        protocol: 2
        joints: {shoulder: 1, elbow: 2}     # joint name: servo id

Its host node is a :class:`~hwbridge.devices.dynamixel.node.DynamixelNode` in the device's
namespace: ``joint_states``, ``joint_command``, per-joint goal topics, ``torque_enable`` and
``/diagnostics``.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, ClassVar

from hwbridge import msg
from hwbridge.devices.common import encode
from hwbridge.devices.dynamixel import firmware as onboard
from hwbridge.devices.dynamixel import packets
from hwbridge.devices.dynamixel.bus import DynamixelBus
from hwbridge.devices.dynamixel.emulator import EmulatedDynamixelBus
from hwbridge.devices.dynamixel.node import DynamixelNode
from hwbridge.devices.dynamixel.pins import DynamixelPins
from hwbridge.devices.dynamixel.tables import find_model
from hwbridge.errors import HwBridgeError
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

__all__ = ["BoardServoPlugin", "DynamixelBusPlugin"]


class BoardServoPlugin(DevicePlugin):
    """A Dynamixel servo on the board's own bus (its second UART), driven by the board: it
    publishes the joint's state and takes goal positions itself, so the host needs no node."""

    type = "dynamixel"
    summary = "a Dynamixel servo the board drives: joint_states, <joint>/goal_position"
    firmware = "hwbridge/drivers/dynamixel.h: DynamixelBus"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("joint", str, "pan", "joint name"),
        Field("id", int, 1, "servo id", minimum=0, maximum=252),
        Field("rate", float, 20.0, "joint state readings per second", minimum=0.1),
        Field("state_topic", str, "joint_states", "board topic of sensor_msgs/JointState"),
        Field("bus", dict, doc="the board's bus: {protocol, baud, servos: [{id, model}]}"),
        Field("serial", str, "Serial2", "the bus's UART (a Mega's Serial1..Serial3)"),
        Field("direction_pin", (int, str), 22, "the half-duplex buffer's direction pin"),
    )

    def emulate(self, settings: Mapping[str, Any], board: EmulatedBoard) -> None:
        bus = EmulatedDynamixelBus.from_config(settings["bus"])
        servo_id, joint = int(settings["id"]), str(settings["joint"])
        protocol = int(settings["bus"].get("protocol", 2))
        model = find_model(bus.servo(servo_id).model.name)
        table = model.table
        world = board.world
        lock = threading.Lock()
        bus_time = [0.0]

        def transact(packet: Any) -> Any:
            now = max(bus_time[0], world.time)
            reply = bus.feed(packets.encode(packet), now) + bus.advance(now + 0.005)
            bus_time[0] = now + 0.005
            return packets.decode(reply, protocol, "status") if reply else None

        address = table["Torque Enable"].address
        transact(packets.write_packet(protocol, servo_id, address, bytes([1])))

        def read() -> bytes:
            found = table["Present Position"]
            with lock:
                status = transact(
                    packets.read_packet(protocol, servo_id, found.address, found.size)
                )
            ticks = int.from_bytes(status.params, "little", signed=True) if status else 0
            return encode(
                board,
                "sensor_msgs/JointState",
                {
                    "header": board.header(""),
                    "name": [joint],
                    "position": [model.ticks_to_radians(ticks)],
                },
            )

        def on_goal(payload: bytes) -> None:
            goal = msg.decode(payload, "std_msgs/Float64", board.registry)
            found = table["Goal Position"]
            ticks = model.radians_to_ticks(float(goal.data))
            with lock:
                transact(
                    packets.write_packet(
                        protocol,
                        servo_id,
                        found.address,
                        ticks.to_bytes(found.size, "little", signed=True),
                    )
                )

        board.publisher(settings["state_topic"], "sensor_msgs/JointState", settings["rate"], read)
        board.subscriber(f"{joint}/goal_position", "std_msgs/Float64", on_goal)

    def pin_model(self, settings: Mapping[str, Any], board: PinBoard) -> PinModel | None:
        uart = board.pins.uart(str(settings["serial"]))
        if uart is None or uart is board.pins.link:
            return None  # no such UART for the bus on this board (an Uno has none)
        number = onboard.uart_number(uart.name)
        return DynamixelPins(settings, number) if number is not None else None

    def wiring(self, settings: Mapping[str, Any], board: McuBoard) -> Wiring:
        return onboard.wiring(settings, board)

    def sketch(self, settings: Mapping[str, Any], context: SketchContext) -> SketchPart:
        return onboard.sketch(settings, context)

    def topics(self, settings: Mapping[str, Any]) -> tuple[TopicUse, ...]:
        return (
            TopicUse(settings["state_topic"], "sensor_msgs/JointState", "publishes", "board"),
            TopicUse(
                f"{settings['joint']}/goal_position", "std_msgs/Float64", "subscribes", "board"
            ),
        )


class DynamixelBusPlugin(DevicePlugin):
    """Servos on a host adapter: joint states, joint commands, torque, diagnostics."""

    type = "dynamixel_bus"
    summary = "Dynamixel servos on a host serial adapter (U2D2): joint_states, joint_command"
    firmware = "hwbridge/drivers/dynamixel.h: DynamixelBus"
    """The same bus driven by a board instead of the U2D2 (examples/DxlArm)."""
    where = "host"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("joints", dict, doc="joint name: servo id, e.g. {shoulder: 1, elbow: 2}"),
        Field("protocol", int, 2, "Dynamixel protocol", choices=(1, 2)),
        Field("rate", float, 50.0, "joint state readings per second", minimum=0.1, maximum=1000),
        Field("frame_id", str, "", "header frame of joint_states"),
        Field("timeout", float, 0.05, "s to wait for a status beyond its bytes' time", minimum=0),
        Field("retries", int, 1, "resends after a timeout or corrupt status", minimum=0),
    )

    def topics(self, settings: Mapping[str, Any]) -> tuple[TopicUse, ...]:
        joints = [str(name) for name in settings["joints"]]
        return (
            TopicUse("joint_states", "sensor_msgs/JointState", "publishes"),
            TopicUse("joint_command", "sensor_msgs/JointState", "subscribes"),
            *(
                TopicUse(f"{joint}/goal_{what}", "std_msgs/Float64", "subscribes")
                for joint in joints
                for what in ("position", "velocity")
            ),
            TopicUse("torque_enable", "std_srvs/SetBool", "serves"),
            TopicUse("/diagnostics", "diagnostic_msgs/DiagnosticArray", "publishes", shared=True),
        )

    def host_node(self, settings: Mapping[str, Any], context: HostContext) -> Closeable:
        joints = _joints(settings["joints"])
        if context.link is None:
            raise HwBridgeError("a dynamixel_bus needs a link (its adapter's port)")
        bus = DynamixelBus(
            context.link,
            settings["protocol"],
            timeout=settings["timeout"],
            retries=settings["retries"],
            baud=context.baud,
        )
        try:
            node = DynamixelNode(
                context.graph,
                bus,
                joints,
                rate_hz=settings["rate"],
                namespace=context.namespace,
                frame_id=settings["frame_id"],
                node=context.node,
            )
        except (HwBridgeError, ValueError) as exc:
            bus.close()
            raise HwBridgeError(f"servos {dict(joints)} on {context.link}: {exc}") from exc
        return _Running(node, bus)


def _joints(value: Mapping[str, Any]) -> dict[str, int]:
    joints: dict[str, int] = {}
    for name, servo in value.items():
        if not isinstance(servo, int) or isinstance(servo, bool) or not 0 <= servo <= 252:
            raise HwBridgeError(f"joints: {name}: expected a servo id 0-252, got {servo!r}")
        joints[str(name)] = servo
    if not joints:
        raise HwBridgeError("joints: give at least one, e.g. {shoulder: 1}")
    return joints


class _Running:
    """The node and the bus it opened: closing stops the node, then closes the port."""

    def __init__(self, node: DynamixelNode, bus: DynamixelBus) -> None:
        self.node, self.bus = node, bus

    def close(self) -> None:
        self.node.close()
        self.bus.close()
