"""The dynamixel_bus plugin's node against emulated servos on a pty, on a real graph: joint
commands by name, effort, hardware errors and silent servos on /diagnostics."""

from __future__ import annotations

from typing import Any

import pytest

from hwbridge.devices.dynamixel.servo import Error1
from hwbridge.graph import Graph
from hwbridge.robot.config import device_config
from hwbridge.robot.plugin import HostContext
from hwbridge.robot.registry import get_device
from tests.devices.dxl_helpers import serve
from tests.netutil import call_when_ready, wait_until


def _start(router: Graph, slave: str, protocol: int, namespace: str = "/arm") -> Any:
    device = device_config(
        {"type": "dynamixel_bus", "protocol": protocol, "rate": 50, "joints": {"pan": 1, "tilt": 2}}
    )
    context = HostContext(router, router.node("arm", namespace=namespace), namespace, None, slave)
    return get_device("dynamixel_bus").host_node(device.settings, context)


@pytest.mark.parametrize(("bus_name", "protocol"), [("dxl-bus", 2), ("dxl-bus-p1", 1)])
def test_joint_command_moves_the_servos_by_name(
    bus_name: str, protocol: int, router: Graph, client: Graph
) -> None:
    with serve(bus_name) as runner:
        running = _start(router, runner.slave_path, protocol)
        try:
            states: list[Any] = []
            watcher = client.node("watcher")
            watcher.subscriber("/arm/joint_states", "sensor_msgs/JointState", states.append)
            caller = client.node("caller")
            reply = call_when_ready(
                caller, "/arm/torque_enable", "std_srvs/SetBool", {"data": True}
            )
            assert reply.success, reply.message
            command = watcher.publisher("/arm/joint_command", "sensor_msgs/JointState")

            def arrived() -> bool:
                command.publish({"name": ["tilt", "nosuch"], "position": [0.4, 1.0]})
                return bool(states) and abs(float(states[-1].position[1]) - 0.4) < 0.01

            assert wait_until(arrived, 30), states[-1] if states else None
            last = states[-1]
            assert list(last.name) == ["pan", "tilt"]
            assert len(last.effort) == 2 and all(-1.0 <= float(e) <= 1.0 for e in last.effort)
        finally:
            running.close()


@pytest.mark.parametrize(
    ("bus_name", "protocol", "bits", "said"),
    [("dxl-bus", 2, 0x20, "overload"), ("dxl-bus-p1", 1, int(Error1.OVERHEATING), "overheating")],
)
def test_hardware_errors_and_silent_servos_reach_diagnostics(
    bus_name: str,
    protocol: int,
    bits: int,
    said: str,
    router: Graph,
    client: Graph,
    caplog: pytest.LogCaptureFixture,
) -> None:
    with serve(bus_name) as runner:
        running = _start(router, runner.slave_path, protocol)
        try:
            reports: list[Any] = []
            client.node("diag").subscriber(
                "/diagnostics", "diagnostic_msgs/DiagnosticArray", reports.append
            )

            def status(joint: str) -> Any:
                for report in reversed(reports):
                    for item in report.status:
                        if item.name == f"dynamixel/{joint}":
                            return item
                return None

            assert wait_until(lambda: status("tilt") is not None and status("pan") is not None)
            assert status("tilt").level == 0 and status("tilt").message == "OK"
            assert status("tilt").hardware_id.startswith("id 2 ")

            runner.call(lambda bus: bus.servo(2).inject_hardware_error(bits))
            assert wait_until(lambda: said in status("tilt").message, 10), status("tilt")
            assert status("tilt").level == 2
            assert status("pan").level == 0
            assert any(said in r.getMessage() for r in caplog.records if r.levelname == "WARNING")

            # The pan servo's cable comes off: it stops answering.
            runner.call(lambda bus: bus.servos.remove(bus.servo(1)))
            assert wait_until(lambda: status("pan").message == "no status", 15), status("pan")
            assert status("pan").level == 2
        finally:
            running.close()
