"""DynamixelNode on a real Zenoh graph (router on a free loopback port), servos on a pty."""

from __future__ import annotations

import math
from typing import Any

import pytest

from hwbridge.devices.dynamixel import DynamixelNode
from hwbridge.errors import HwBridgeTimeoutError
from hwbridge.graph import Graph
from tests.devices.dxl_helpers import bench
from tests.netutil import call_when_ready, wait_until


@pytest.mark.parametrize("bus_name", ["dxl-bus", "dxl-bus-p1"])
def test_goal_moves_the_servo_and_joint_states_follow(
    bus_name: str, router: Graph, client: Graph
) -> None:
    with bench(bus_name) as b:
        node = DynamixelNode(router, b.bus, {"pan": 1, "tilt": 2}, rate_hz=50, frame_id="base")
        try:
            states: list[Any] = []
            client.node("watcher").subscriber(
                "/joint_states", "sensor_msgs/JointState", states.append
            )
            assert wait_until(lambda: bool(states))
            first = states[-1]
            assert list(first.name) == ["pan", "tilt"]
            assert list(first.position) == [0.0, 0.0] and list(first.velocity) == [0.0, 0.0]
            assert first.header.frame_id == "base" and first.header.stamp.sec > 0

            caller = client.node("caller")
            reply = call_when_ready(caller, "/torque_enable", "std_srvs/SetBool", {"data": True})
            assert reply.success, reply.message
            assert reply.message == "torque on for 2 joints"
            assert b.runner.call(lambda e: [s.torque for s in e.servos]) == [True, True]

            model = node.models["tilt"]
            goal = model.radians_to_ticks(-0.6)
            commander = client.node("commander")
            pub = commander.publisher("/tilt/goal_position", "std_msgs/Float64")

            def goal_arrived() -> bool:
                current = b.runner.call(lambda e: e.servo(2).get("Goal Position"))
                if current != goal:
                    pub.publish({"data": -0.6})
                return bool(current == goal)

            assert wait_until(goal_arrived)
            assert wait_until(
                lambda: abs(states[-1].position[1] - model.ticks_to_radians(goal)) < 1e-9
            )
            assert states[-1].position[0] == 0.0
            assert any(s.velocity[1] < -1.0 for s in states)  # it moved at a real speed
            assert math.isclose(states[-1].velocity[1], 0.0)

            speed = commander.publisher("/pan/goal_velocity", "std_msgs/Float64")
            register = "Profile Velocity" if bus_name == "dxl-bus" else "Moving Speed"
            expected = node.models["pan"].rad_s_to_velocity(2.0)

            def speed_arrived() -> bool:
                current = b.runner.call(lambda e: e.servo(1).get(register))
                if current != expected:
                    speed.publish({"data": 2.0})
                return bool(current == expected)

            assert wait_until(speed_arrived)

            reply = caller.call("/torque_enable", "std_srvs/SetBool", {"data": False}, timeout=5)
            assert reply.success
            assert b.runner.call(lambda e: [s.torque for s in e.servos]) == [False, False]
            assert node.published > 0 and node.read_errors == 0
        finally:
            node.close()


def test_torque_service_reports_failures_and_reads_keep_going(router: Graph, client: Graph) -> None:
    with bench("dxl-bus") as b:
        node = DynamixelNode(router, b.bus, {"arm": 1}, rate_hz=100, name="dxl_faulty")
        try:
            b.runner.call(lambda e: e.servo(1).inject_hardware_error(0x20))
            caller = client.node("caller2")
            reply = call_when_ready(caller, "/torque_enable", "std_srvs/SetBool", {"data": True})
            assert not reply.success
            assert "arm: servo 1: Result Fail" in reply.message
            b.runner.call(lambda e: e.servo(1).set("Baud Rate", 3))  # servo gone from the bus
            assert wait_until(lambda: node.read_errors > 0)
            assert isinstance(node.last_error, HwBridgeTimeoutError)
            b.runner.call(lambda e: e.servo(1).set("Baud Rate", 1))
            count = node.published
            assert wait_until(lambda: node.published > count + 2)
        finally:
            node.close()


def test_node_needs_joints(router: Graph) -> None:
    with bench("dxl-bus") as b, pytest.raises(ValueError, match="at least one joint"):
        DynamixelNode(router, b.bus, {})
