"""``mavlink_vehicle``: a flight controller or any MAVLink-speaking board, as a host device
(:mod:`hwbridge.robot.plugin`) with a link of its own::

    host_devices:
      - type: mavlink_vehicle
        name: fc
        link: mavlink://udpin:0.0.0.0:14550      # or mavlink:///dev/ttyACM0?baud=115200
        namespace: /fc
        system: 0            # the vehicle's MAVLink system id; 0: the first one heard
        heartbeat_rate: 1    # our ground-station heartbeats per second
        link_timeout: 3      # s without a heartbeat before the vehicle counts as lost
        raw: ["*"]           # MAVLink messages also published raw as mavlink/NAME ([] for none)

Its host node is a :class:`~hwbridge.mavlink.node.MavlinkNode`; registered through the
``hwbridge.devices`` entry point ``mavlink_vehicle`` (needs the ``[mavlink]`` extra).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

from hwbridge.errors import HwBridgeError
from hwbridge.robot.plugin import Closeable, DevicePlugin, Field, HostContext, TopicUse

__all__ = ["MavlinkVehiclePlugin"]


class MavlinkVehiclePlugin(DevicePlugin):
    """A MAVLink vehicle on a host link: Imu, NavSatFix, BatteryState, arm, mode, cmd_vel."""

    type = "mavlink_vehicle"
    summary = "MAVLink vehicle (flight controller): imu, gps/fix, battery, arm, set_mode, cmd_vel"
    where = "host"
    fields: ClassVar[tuple[Field, ...]] = (
        Field(
            "system",
            int,
            0,
            "vehicle's MAVLink system id (0: the first heard)",
            minimum=0,
            maximum=255,
        ),
        Field(
            "heartbeat_rate",
            float,
            1.0,
            "ground-station heartbeats per second",
            minimum=0,
            maximum=50,
        ),
        Field(
            "link_timeout",
            float,
            3.0,
            "s without a heartbeat before the link counts as lost",
            minimum=0.1,
            maximum=600,
        ),
        Field("raw", list, ["*"], "MAVLink messages also published raw on mavlink/NAME (* all)"),
        Field("frame_id", str, "base_link", "header frame of imu, gps/fix and battery"),
        Field("dialect", str, "ardupilotmega", "pymavlink dialect (common, ardupilotmega...)"),
    )

    def topics(self, settings: Mapping[str, Any]) -> tuple[TopicUse, ...]:
        """The fixed topics (the raw ``mavlink/NAME`` ones depend on what the vehicle sends)."""
        return (
            TopicUse("imu", "sensor_msgs/Imu"),
            TopicUse("gps/fix", "sensor_msgs/NavSatFix"),
            TopicUse("battery", "sensor_msgs/BatteryState"),
            TopicUse("armed", "std_msgs/Bool"),
            TopicUse("mode", "std_msgs/String"),
            TopicUse("connected", "std_msgs/Bool"),
            TopicUse("/diagnostics", "diagnostic_msgs/DiagnosticArray", shared=True),
            TopicUse("set_mode", "std_msgs/String", "subscribes"),
            TopicUse("cmd_vel", "geometry_msgs/Twist", "subscribes"),
            TopicUse("arm", "std_srvs/SetBool", "serves"),
        )

    def host_node(self, settings: Mapping[str, Any], context: HostContext) -> Closeable:
        from hwbridge.links import create_link
        from hwbridge.mavlink.node import MavlinkNode

        if context.link is None:
            raise HwBridgeError(
                "a mavlink_vehicle needs a link, e.g. mavlink://udpin:0.0.0.0:14550"
            )
        raw = settings["raw"]
        if not all(isinstance(name, str) for name in raw):
            raise HwBridgeError(f"raw: expected MAVLink message names, got {raw!r}")
        options = {"baud": context.baud} if context.baud is not None else {}
        link = create_link(context.link, **options)
        return MavlinkNode(
            context.graph,
            link,
            node=context.node,
            system=settings["system"],
            heartbeat_rate=settings["heartbeat_rate"],
            link_timeout=settings["link_timeout"],
            raw=tuple(raw),
            frame_id=settings["frame_id"],
            dialect=settings["dialect"],
        )
