"""The built-in board device plugins (``devices/<device>/plugin.py``): their settings, and each
emulated model paired with the plugin's own host node, with the robot file's settings honoured
(topics, frames, ranges). No link and no bridge here: a :class:`RecordingBoard` is the virtual
board and a :class:`Wire` carries its bytes to and from the graph as the bridge would; the same
pairing through a real bridge is in tests/hwbridge/test_emulator.py.
"""

from __future__ import annotations

import ast
import math
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from hwbridge import msg
from hwbridge.emulator import VirtualBoard, World, WorldConfig
from hwbridge.graph import Graph, Publisher, RawMessage, Subscriber
from hwbridge.robot.config import check_value, device_config
from hwbridge.robot.plugin import EmulatedBoard, HostContext
from hwbridge.robot.registry import BUILTIN_DEVICES, get_device
from tests.netutil import wait_until

NAMESPACE = "/t"
ROOT = Path(__file__).resolve().parents[2]


class RecordingBoard:
    """An :class:`EmulatedBoard` the test steps by hand: it keeps what the devices declare and
    stamps readings with the world's time."""

    def __init__(self, world: WorldConfig | None = None, seed: int = 0) -> None:
        self.world = World(world or WorldConfig(), seed)
        self.seed = seed
        self.registry = msg.registry()
        self.publishers: dict[str, tuple[str, float, Callable[[], bytes | None]]] = {}
        self.subscribers: dict[str, tuple[str, Callable[[bytes], None]]] = {}
        self.steps: list[Callable[[float], None]] = []
        self.resets: list[Callable[[], None]] = []

    def publisher(
        self, topic: str, type_name: str, rate: float, read: Callable[[], bytes | None]
    ) -> int:
        self.publishers[topic] = (type_name, rate, read)
        return len(self.publishers) + len(self.subscribers)

    def subscriber(self, topic: str, type_name: str, handle: Callable[[bytes], None]) -> int:
        self.subscribers[topic] = (type_name, handle)
        return len(self.publishers) + len(self.subscribers)

    def header(self, frame_id: str) -> dict[str, Any]:
        return {"stamp": 1000.0 + self.world.time, "frame_id": frame_id}

    def on_step(self, step: Callable[[float], None]) -> None:
        self.steps.append(step)

    def on_reset(self, reset: Callable[[], None]) -> None:
        self.resets.append(reset)

    def run(self, seconds: float, dt: float = 0.005) -> None:
        for _ in range(round(seconds / dt)):
            self.world.step(dt)
            for step in self.steps:
                step(self.world.time)

    def reset(self) -> None:
        for reset in self.resets:
            reset()

    def reading(self, topic: str) -> Any:
        type_name, _, read = self.publishers[topic]
        payload = read()
        assert payload is not None
        return msg.decode(payload, type_name, self.registry)

    def deliver(self, topic: str, message: dict[str, Any]) -> None:
        type_name, handle = self.subscribers[topic]
        handle(msg.encode(msg.from_dict(type_name, message, self.registry)))


def _board_types_check(virtual: VirtualBoard, recording: RecordingBoard) -> list[EmulatedBoard]:
    """Both boards are EmulatedBoards (checked by mypy and pyright, not run)."""
    return [virtual, recording]


class Wire:
    """The board's topics on the graph in ``NAMESPACE``, bytes unchanged (the bridge's job)."""

    def __init__(self, board: RecordingBoard, graph: Graph) -> None:
        node = graph.node("wire", namespace=NAMESPACE)
        self.outputs: list[tuple[Publisher, Callable[[], bytes | None]]] = [
            (node.raw_publisher(topic, type_name, board.registry.md5(type_name)), read)
            for topic, (type_name, _, read) in board.publishers.items()
        ]
        self.inputs: list[Subscriber] = []
        for topic, (type_name, handle) in board.subscribers.items():
            self.inputs.append(node.subscriber(topic, type_name, _raw(handle), raw=True))

    def wait_for_host(self) -> None:
        for publisher, _ in self.outputs:
            assert publisher.wait_for_subscribers(10)

    def publish(self) -> None:
        for publisher, read in self.outputs:
            payload = read()
            if payload is not None:
                publisher.publish_raw(payload)

    def close(self) -> None:
        for publisher, _ in self.outputs:
            publisher.close()
        for subscriber in self.inputs:
            subscriber.close()


def _raw(handle: Callable[[bytes], None]) -> Callable[[RawMessage], None]:
    return lambda message: handle(message.data)


@pytest.fixture
def host(router: Graph) -> Iterator[Callable[[dict[str, Any]], Any]]:
    """Start a device's host node from a robot-file entry, as ``hwbridge up`` does."""
    started: list[Any] = []

    def start(entry: dict[str, Any]) -> Any:
        device = device_config(entry)
        node = router.node(f"dev_{device.name}_{len(started)}", namespace=NAMESPACE)
        context = HostContext(router, node, NAMESPACE, "base", None)
        result = get_device(device.type).host_node(device.settings, context)
        started.append(result)
        return result

    yield start
    for node in started:
        if node is not None:
            node.close()


def _emulated(entry: dict[str, Any], world: WorldConfig | None = None) -> RecordingBoard:
    board = RecordingBoard(world, seed=4)
    device = device_config(entry)
    get_device(device.type).emulate(device.settings, board)
    return board


def _collect(client: Graph, topic: str, type_name: str) -> list[Any]:
    received: list[Any] = []
    client.node("listener").subscriber(topic, type_name, received.append)
    return received


@pytest.mark.parametrize("name", sorted(BUILTIN_DEVICES))
def test_every_builtin_plugin_declares_settings_a_robot_file_can_take(name: str) -> None:
    plugin = get_device(name)
    assert plugin.type == name
    assert plugin.summary
    names = [f.name for f in plugin.fields]
    assert len(names) == len(set(names)), names
    for field in plugin.fields:
        if field.required:
            continue
        value, why = check_value(field, field.default)
        assert why is None, f"{name}: {field.name}: default {field.default!r}: {why}"
        assert value == field.default
        if field.choices:
            assert field.default in field.choices


def test_the_emulator_names_no_device_type() -> None:
    """The virtual board, its world and its robots' loading build devices only through the
    plugins: no string in them is a device type (the test plugin's ``thermo`` included)."""
    types = {*BUILTIN_DEVICES, "thermo"}
    for path in sorted((ROOT / "hwbridge" / "emulator").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                assert node.value not in types, f"{path.name}:{node.lineno}: {node.value!r}"
    for folder in ("hwbridge", "devices"):
        for path in (ROOT / folder).rglob("*.py"):
            assert "thermo" not in path.read_text(), path


DIFFDRIVE = {
    "type": "diffdrive",
    "ticks_topic": "enc",
    "targets_topic": "motors",
    "rate": 50,
    "wheel_radius": 0.033,
    "wheel_separation": 0.16,
    "counts_per_rev": 1320,
    "counter_bits": 16,
    "base_frame_id": "chassis",
}


def test_diffdrive_model_stops_without_targets_and_counts_from_zero_after_reset() -> None:
    board = _emulated(DIFFDRIVE)
    assert set(board.publishers) == {"enc"} and set(board.subscribers) == {"motors"}
    board.deliver("motors", {"left": 10.0, "right": 10.0})
    board.run(0.4)
    assert board.world.base.wheel_speeds[0] > 9.0  # driving (time constant 0.08 s)
    board.run(0.6)  # nothing new for 0.5 s: the firmware's own timeout stops the motors
    assert board.world.base.wheel_speeds == pytest.approx((0.0, 0.0), abs=0.05)
    ticks = board.reading("enc")
    assert ticks.header.frame_id == "chassis"
    assert int(ticks.counter_bits) == 16 and int(ticks.left) > 1000
    board.reset()
    board.run(0.1)
    ticks = board.reading("enc")
    assert (int(ticks.left), int(ticks.right)) == (0, 0)


def test_diffdrive_host_node_turns_the_models_ticks_into_odometry(
    host: Callable[[dict[str, Any]], Any], router: Graph, client: Graph
) -> None:
    board = _emulated(DIFFDRIVE)
    wire = Wire(board, router)
    drive = host(DIFFDRIVE)
    odoms = _collect(client, f"{NAMESPACE}/odom", "nav_msgs/Odometry")
    cmd = client.node("driver", namespace=NAMESPACE).publisher("cmd_vel", "geometry_msgs/Twist")
    try:
        wire.wait_for_host()
        assert cmd.wait_for_subscribers(10)
        for index in range(150):  # 3 s, about real time: the host repeats targets at 10 Hz
            if index % 5 == 0:
                cmd.publish({"linear": {"x": 0.2}, "angular": {"z": 0.4}} if index < 100 else {})
            board.run(0.02)
            wire.publish()
            time.sleep(0.02)
        assert board.world.base.distance > 0.3
        final = 1000.0 + board.world.time

        def caught_up() -> bool:
            stamp = odoms[-1].header.stamp if odoms else None
            return stamp is not None and stamp.sec + stamp.nanosec * 1e-9 >= final - 0.03

        assert wait_until(caught_up, 10)
        odom = odoms[-1]
        assert (odom.header.frame_id, odom.child_frame_id) == ("odom", "chassis")
        truth = board.world.pose
        position = odom.pose.pose.position
        error = math.hypot(float(position.x) - truth.x, float(position.y) - truth.y)
        assert error / board.world.base.distance < 0.01
        assert drive.latest is not None
    finally:
        wire.close()


def test_hcsr04_host_node_turns_the_models_echoes_into_range(
    host: Callable[[dict[str, Any]], Any], router: Graph, client: Graph
) -> None:
    entry = {
        "type": "hcsr04",
        "topic": "sonar",
        "range_topic": "front_range",
        "frame_id": "front_sonar",
        "max_range": 2.0,
        "noise_std": 0.0,
    }
    board = _emulated(entry, WorldConfig(room=(2.4, 2.0), sonar_offset=0.08))
    wire = Wire(board, router)
    host(entry)
    ranges = _collect(client, f"{NAMESPACE}/front_range", "sensor_msgs/Range")
    try:
        wire.wait_for_host()

        def arrived() -> bool:
            wire.publish()
            return bool(ranges)

        assert wait_until(arrived, 10)
        got = ranges[-1]
        assert got.header.frame_id == "front_sonar"
        assert float(got.max_range) == pytest.approx(2.0)
        truth = board.world.sonar_distance()
        assert truth == pytest.approx(1.12, abs=0.01)
        assert float(got.range) == pytest.approx(truth, abs=0.02)
    finally:
        wire.close()


@pytest.mark.parametrize("chip", ["mpu6050", "mpu9250"])
def test_imu_host_node_turns_the_models_registers_into_imu(
    chip: str, host: Callable[[dict[str, Any]], Any], router: Graph, client: Graph
) -> None:
    entry = {
        "type": chip,
        "topic": "raw9",
        "imu_topic": "imu9",
        "accel_range_g": 8,
        "gyro_range_dps": 1000,
        "frame_id": "imu_top",
    } | ({"mag_topic": "compass"} if chip == "mpu9250" else {})
    board = _emulated(entry)
    raw = board.reading("raw9")
    assert (int(raw.accel_config) >> 3, int(raw.gyro_config) >> 3) == (2, 2)  # 8 g, 1000 dps
    assert int(raw.chip) == (1 if chip == "mpu9250" else 0)
    wire = Wire(board, router)
    host(entry)
    imus = _collect(client, f"{NAMESPACE}/imu9", "sensor_msgs/Imu")
    fields = _collect(client, f"{NAMESPACE}/compass", "sensor_msgs/MagneticField")
    try:
        wire.wait_for_host()

        def arrived() -> bool:
            board.run(0.02)  # the AK8963 measures at 100 Hz
            wire.publish()
            return bool(imus) and (chip == "mpu6050" or bool(fields))

        assert wait_until(arrived, 10)
        imu = imus[-1]
        assert imu.header.frame_id == "imu_top"
        assert float(imu.linear_acceleration.z) == pytest.approx(9.81, abs=0.6)
        if chip == "mpu9250":
            assert fields[-1].header.frame_id == "imu_top"
            truth = board.world.imu_truth().magnetic_field
            got = fields[-1].magnetic_field
            for value, expected in zip((got.x, got.y, got.z), truth, strict=True):
                assert float(value) == pytest.approx(expected, abs=0.12e-6)
    finally:
        wire.close()


def test_board_servo_follows_its_goal_and_needs_no_host_node() -> None:
    entry = {
        "type": "dynamixel",
        "joint": "tilt",
        "id": 3,
        "state_topic": "tilt_state",
        "bus": {"protocol": 2, "baud": 57600, "servos": [{"id": 3, "model": "XL430-W250"}]},
    }
    device = device_config(entry)
    context = HostContext(None, None, NAMESPACE, "base", None)
    assert get_device("dynamixel").host_node(device.settings, context) is None
    board = _emulated(entry)
    assert set(board.publishers) == {"tilt_state"}
    assert set(board.subscribers) == {"tilt/goal_position"}
    board.deliver("tilt/goal_position", {"data": 0.5})
    board.run(1.0)
    state = board.reading("tilt_state")
    assert state.name == ["tilt"]
    assert float(state.position[0]) == pytest.approx(0.5, abs=0.01)
