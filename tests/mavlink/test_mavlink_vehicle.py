"""A MAVLink vehicle (pymavlink on the far end of a UDP socket) brought up from a robot file: its
messages on the graph, commands from the graph reaching it, link loss and return reported."""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("pymavlink")

from hwbridge.emulator.mavlink_vehicle import MavlinkVehicle
from hwbridge.errors import LinkError
from hwbridge.graph import Graph
from hwbridge.links import create_link
from hwbridge.mavlink.link import translate
from hwbridge.mavlink.msgdefs import raw_type, write_package
from hwbridge.protocols.msgtypes import TypeRegistry
from hwbridge.robot.config import load_robot
from hwbridge.robot.runtime import RobotRuntime
from tests.netutil import call_when_ready, free_port, wait_until

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "robots" / "mavlink_vehicle.yaml"


def _udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class _Topic:
    """Every message of one topic, kept in order."""

    def __init__(self, node: Any, topic: str, type_name: str, raw: bool = False) -> None:
        self.messages: list[Any] = []
        self.changed = threading.Event()
        node.subscriber(topic, type_name, self._take, raw=raw)

    def _take(self, message: Any) -> None:
        self.messages.append(message)
        self.changed.set()

    def wait(self, condition: Any = lambda m: True, timeout: float = 10.0) -> Any:
        assert wait_until(lambda: any(condition(m) for m in self.messages), timeout), self.messages[
            -3:
        ]
        return next(m for m in reversed(self.messages) if condition(m))


@pytest.fixture(scope="module")
def running(router: Graph, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    port = _udp_port()
    robot_file = tmp_path_factory.mktemp("robot") / "vehicle.yaml"
    robot_file.write_text(
        EXAMPLE.read_text(encoding="utf-8").replace("link_timeout: 3.0", "link_timeout: 1.5"),
        encoding="utf-8",
    )
    robot = load_robot(robot_file).with_links({"fc": f"mavlink://udpin:127.0.0.1:{port}"})
    runtime = RobotRuntime(robot, router).start()
    vehicle = MavlinkVehicle(f"udpout:127.0.0.1:{port}").start()
    try:
        yield runtime, vehicle
    finally:
        vehicle.close()
        runtime.stop()


@pytest.fixture
def view(client: Graph) -> Any:
    return client.node("mavlink_test")


def test_attitude_is_an_imu_in_enu(running: Any, view: Any) -> None:
    imu = view.wait_for_message("/fc/imu", "sensor_msgs/Imu", timeout=10.0)
    # the vehicle heads north (yaw 0 in NED): in ENU that is +90 degrees about z
    q = imu.orientation
    yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
    assert yaw == pytest.approx(math.pi / 2, abs=0.01)
    pitch = math.asin(max(-1.0, min(1.0, 2 * (q.w * q.y - q.z * q.x))))
    assert pitch == pytest.approx(0.02, abs=1e-3)  # the vehicle's nose-down -0.02 rad, FLU
    assert imu.angular_velocity.x == pytest.approx(0.05)
    assert imu.linear_acceleration_covariance[0] == -1.0  # not given by ATTITUDE
    assert imu.header.frame_id == "base_link"


def test_position_and_battery(running: Any, view: Any) -> None:
    fix = view.wait_for_message("/fc/gps/fix", "sensor_msgs/NavSatFix", timeout=10.0)
    assert fix.latitude == pytest.approx(47.397742, abs=1e-6)
    assert fix.longitude == pytest.approx(8.545594, abs=1e-6)
    assert fix.altitude == pytest.approx(488.0)
    assert fix.status.status == 0
    battery = view.wait_for_message("/fc/battery", "sensor_msgs/BatteryState", timeout=10.0)
    assert list(battery.cell_voltage) == pytest.approx([3.95, 3.95, 3.95])
    assert battery.voltage == pytest.approx(11.85, abs=1e-4)
    assert battery.percentage == pytest.approx(0.76)
    assert battery.temperature == pytest.approx(25.0)


def test_every_message_raw_as_its_own_type(running: Any, view: Any, tmp_path: Path) -> None:
    topic = _Topic(view, "/fc/mavlink/ATTITUDE", "*", raw=True)
    message = topic.wait()
    info = raw_type("ATTITUDE")
    assert (message.type, message.md5) == ("mavlink/Attitude", info.md5)
    # the definitions written as a package decode the bytes, with the same md5
    registry = TypeRegistry([write_package(tmp_path).parent])
    assert registry.md5("mavlink/Attitude") == info.md5
    decoded = registry.deserialize(message.data, "mavlink/Attitude")
    assert decoded.time_boot_ms > 0 and float(decoded.pitch) == pytest.approx(-0.02)
    heartbeat = _Topic(view, "/fc/mavlink/HEARTBEAT", "*", raw=True).wait()
    assert heartbeat.type == "mavlink/Heartbeat"


def test_arm_mode_and_velocity_reach_the_vehicle(running: Any, view: Any) -> None:
    _runtime, vehicle = running
    armed = _Topic(view, "/fc/armed", "std_msgs/Bool")
    mode = _Topic(view, "/fc/mode", "std_msgs/String")
    reply = call_when_ready(view, "/fc/arm", "std_srvs/SetBool", {"data": True})
    assert reply.success, reply.message
    assert "ACCEPTED" in reply.message
    assert vehicle.state.armed
    armed.wait(lambda m: m.data is True)

    set_mode = view.publisher("/fc/set_mode", "std_msgs/String")
    assert set_mode.wait_for_subscribers(5.0)
    set_mode.publish({"data": "GUIDED"})
    assert wait_until(lambda: vehicle.state.custom_mode == 15, 5.0)  # Rover's GUIDED
    mode.wait(lambda m: m.data == "GUIDED")

    cmd_vel = view.publisher("/fc/cmd_vel", "geometry_msgs/Twist")
    assert cmd_vel.wait_for_subscribers(5.0)
    cmd_vel.publish({"linear": {"x": 1.5, "y": 0.25}, "angular": {"z": 0.5}})
    assert wait_until(lambda: vehicle.state.setpoints > 0, 5.0)
    with vehicle.lock:
        assert vehicle.state.velocity == pytest.approx((1.5, -0.25, 0.0))  # FLU -> FRD
        assert vehicle.state.yaw_rate == pytest.approx(-0.5)
    cmd_vel.publish({})

    reply = call_when_ready(view, "/fc/arm", "std_srvs/SetBool", {"data": False})
    assert reply.success and not vehicle.state.armed
    assert vehicle.state.commands.count(400) >= 2  # MAV_CMD_COMPONENT_ARM_DISARM, twice


def test_our_heartbeats_are_kept(running: Any) -> None:
    _runtime, vehicle = running
    before = vehicle.state.gcs_heartbeats
    assert wait_until(lambda: vehicle.state.gcs_heartbeats >= before + 2, 5.0)


def test_link_loss_and_return_are_reported(
    running: Any, view: Any, caplog: pytest.LogCaptureFixture
) -> None:
    runtime, vehicle = running
    connected = _Topic(view, "/fc/connected", "std_msgs/Bool")
    diagnostics = _Topic(view, "/diagnostics", "diagnostic_msgs/DiagnosticArray")
    connected.wait(lambda m: m.data is True)
    node = runtime.devices[0].node
    losses = node.stats()["link_losses"]
    with caplog.at_level("WARNING", logger="hwbridge.mavlink"):
        vehicle.pause()
        connected.wait(lambda m: m.data is False)
        assert node.stats()["link_losses"] == losses + 1
        diagnostics.wait(lambda m: any(s.level == 2 for s in m.status))
        count = len(connected.messages)
        vehicle.resume()
        assert wait_until(lambda: any(m.data for m in connected.messages[count:]), 10.0), (
            "the vehicle's return was not reported"
        )
    text = caplog.text
    assert "lost: no heartbeat" in text and "connected" in text


def test_a_corrupted_packet_is_counted_not_published(running: Any) -> None:
    runtime, vehicle = running
    node = runtime.devices[0].node
    before = node.stats()["crc_errors"]
    vehicle.send_corrupted()
    assert wait_until(lambda: node.stats()["crc_errors"] == before + 1, 5.0)


@pytest.mark.parametrize(
    ("url", "link"),
    [
        ("mavlink://udpin:0.0.0.0:14550", "udp-listen://0.0.0.0:14550"),
        ("mavlink://udp::14550", "udp-listen://:14550"),
        ("mavlink://udpout:10.0.0.2:14550", "udp://10.0.0.2:14550"),
        ("mavlink://tcp:127.0.0.1:5760", "socket://127.0.0.1:5760"),
        ("mavlink://tcpin:0.0.0.0:5760", "tcp-listen://0.0.0.0:5760"),
        ("mavlink:///dev/ttyACM0?baud=57600", "serial:///dev/ttyACM0?baud=57600"),
        ("mavlink://serial:/dev/ttyUSB0", "serial:///dev/ttyUSB0"),
    ],
)
def test_urls_as_pymavlink_writes_them(url: str, link: str) -> None:
    assert translate(url) == link
    create_link(url)  # parses, does not open


@pytest.mark.parametrize(
    "url",
    ["mavlink://", "mavlink://udpout:14550", "mavlink://carrier-pigeon:1", "mavlink://tcp:x:y"],
)
def test_bad_urls_say_what_is_accepted(url: str) -> None:
    with pytest.raises(LinkError, match=r"udpin|HOST:PORT"):
        create_link(url)


def test_the_example_robot_file_loads() -> None:
    robot = load_robot(EXAMPLE)
    (host,) = robot.host_devices
    assert host.device.type == "mavlink_vehicle" and host.link.startswith("mavlink://")
    assert free_port() > 0


def test_foxglove_shows_the_vehicle_raw_messages_included(running: Any, router: Graph) -> None:
    pytest.importorskip("foxglove")
    from hwbridge.viz.foxglove import start_viz
    from tests.viz.test_foxglove import FoxgloveClient, connect, decode_ros1

    server = start_viz(router, port=0, topics=["/fc/imu", "/fc/mavlink/ATTITUDE"])
    try:
        with connect(server.url) as ws:
            client = FoxgloveClient(ws)
            raw = client.wait_for_channel("/fc/mavlink/ATTITUDE")
            assert (raw["schemaName"], raw["schemaEncoding"]) == ("mavlink/Attitude", "ros1msg")
            imu = client.wait_for_channel("/fc/imu")
            client.subscribe(1, raw)
            client.subscribe(2, imu)
            (payload,) = client.messages(1, 1)
            attitude = decode_ros1(raw["schemaName"], raw["schema"], payload)
            assert float(attitude.pitch) == pytest.approx(-0.02)
            (payload,) = client.messages(2, 1)
            decoded = decode_ros1(imu["schemaName"], imu["schema"], payload)
            assert decoded.header.frame_id == "base_link"
    finally:
        server.close()


def test_a_vehicle_on_a_serial_line(router: Graph, client: Graph) -> None:
    """The same device over a serial line: the vehicle's pymavlink opens the far end of the
    pty the node's link made (as a flight controller's USB port)."""
    from hwbridge.links import open_link
    from hwbridge.mavlink.node import MavlinkNode

    link = open_link("pty://")
    node = MavlinkNode(router, link, node=router.node("fc_serial", namespace="/serial"))
    vehicle = MavlinkVehicle(link.slave_path, baud=115200)  # type: ignore[attr-defined]
    try:
        vehicle.start()
        imu = client.node("serial_view").wait_for_message("/serial/imu", "sensor_msgs/Imu", 10.0)
        assert imu.header.frame_id == "base_link"
        assert wait_until(lambda: node.stats()["connected"], 5.0)
        assert wait_until(lambda: vehicle.state.gcs_heartbeats > 0, 5.0)
    finally:
        vehicle.close()
        node.close()
