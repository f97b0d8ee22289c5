"""The dynamixel_bus plugin's node against emulated servos on a pty, on a real graph: joint
commands by name, effort, hardware errors and silent servos on /diagnostics."""

from __future__ import annotations

import logging
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

            def tilt(state: Any) -> float | None:
                """The state's tilt position; None when that read of the bus missed the servo
                (a busy machine can miss a status packet's deadline: the state then names
                only the joints that answered)."""
                names = list(state.name)
                return float(state.position[names.index("tilt")]) if "tilt" in names else None

            def arrived() -> bool:
                command.publish({"name": ["tilt", "nosuch"], "position": [0.4, 1.0]})
                position = tilt(states[-1]) if states else None
                return position is not None and abs(position - 0.4) < 0.01

            assert wait_until(arrived, 30), states[-1] if states else None
            full = [s for s in states if list(s.name) == ["pan", "tilt"]]
            assert full, states[-5:]
            last = full[-1]
            assert len(last.effort) == 2 and all(-1.0 <= float(e) <= 1.0 for e in last.effort)
        finally:
            running.close()


def _status(reports: list[Any], joint: str) -> Any:
    """The latest DiagnosticStatus of ``joint`` (None before the first)."""
    for report in reversed(reports):
        for item in report.status:
            if item.name == f"dynamixel/{joint}":
                return item
    return None


@pytest.mark.parametrize(
    ("bus_name", "protocol", "warn_bits", "error_bits", "error_said"),
    [
        ("dxl-bus", 2, 0x01, 0x20, "overload"),
        ("dxl-bus-p1", 1, int(Error1.INPUT_VOLTAGE), int(Error1.OVERHEATING), "overheating"),
    ],
)
def test_hardware_errors_reach_diagnostics_and_the_log(
    bus_name: str,
    protocol: int,
    warn_bits: int,
    error_bits: int,
    error_said: str,
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
                return _status(reports, joint)

            assert wait_until(lambda: status("tilt") is not None and status("pan") is not None)
            assert status("tilt").level == 0 and status("tilt").message == "OK"
            assert status("tilt").hardware_id == f"id 2 {running.node.models['tilt'].name}"

            # Not in the Shutdown register (torque stays on): WARN. In it: ERROR.
            runner.call(lambda bus: bus.servo(1).inject_hardware_error(warn_bits))
            runner.call(lambda bus: bus.servo(2).inject_hardware_error(error_bits))
            assert wait_until(lambda: error_said in status("tilt").message, 10), status("tilt")
            assert status("tilt").level == 2
            assert wait_until(lambda: "input voltage" in status("pan").message, 10)
            assert status("pan").level == 1
            warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
            assert sum(f"servo 2 (tilt): {error_said}" in w for w in warnings) == 1, warnings
            assert sum("servo 1 (pan): input voltage" in w for w in warnings) == 1, warnings
        finally:
            running.close()


@pytest.mark.parametrize(("bus_name", "protocol"), [("dxl-bus", 2), ("dxl-bus-p1", 1)])
def test_a_silent_servo_is_reported_and_comes_back(
    bus_name: str,
    protocol: int,
    router: Graph,
    client: Graph,
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="hwbridge.devices.dynamixel")
    with serve(bus_name) as runner:
        running = _start(router, runner.slave_path, protocol)
        try:
            reports: list[Any] = []
            states: list[Any] = []
            watcher = client.node("diag")
            watcher.subscriber("/diagnostics", "diagnostic_msgs/DiagnosticArray", reports.append)
            watcher.subscriber("/arm/joint_states", "sensor_msgs/JointState", states.append)
            assert wait_until(lambda: _status(reports, "pan") is not None and bool(states))

            # The pan servo's cable comes off: it stops answering; tilt is still published.
            pan = runner.call(lambda bus: bus.servo(1))
            runner.call(lambda bus: bus.servos.remove(pan))
            assert wait_until(lambda: _status(reports, "pan").message == "no status", 15)
            assert _status(reports, "pan").level == 2
            assert _status(reports, "tilt").level == 0
            count = len(states)
            assert wait_until(lambda: len(states) > count + 3)
            assert list(states[-1].name) == ["tilt"] and len(states[-1].position) == 1

            # Plugged in again: back in joint_states and OK on /diagnostics.
            runner.call(lambda bus: bus.servos.insert(0, pan))
            assert wait_until(lambda: _status(reports, "pan").level == 0, 15)
            assert wait_until(lambda: list(states[-1].name) == ["pan", "tilt"])
            said = [(r.levelname, r.getMessage()) for r in caplog.records]
            assert ("WARNING", "/arm/arm: servo 1 (pan): no status") in said, said
            assert ("INFO", "/arm/arm: servo 1 (pan) is fine again") in said, said
        finally:
            running.close()
