"""The emulator: world geometry, a virtual board through the real bridge, emulate and demo."""

from __future__ import annotations

import dataclasses
import math
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import yaml

from hwbridge import msg
from hwbridge.bridge import BoardSpec, Bridge
from hwbridge.devices.imu.node import ImuNode
from hwbridge.emulator import BoardConfig, VirtualBoard, World, WorldConfig, load_board
from hwbridge.errors import HwBridgeError
from hwbridge.graph import Graph
from hwbridge.links import Link, LinkClosedError, open_link
from hwbridge.protocols.native.control import EntryKind
from hwbridge.robot.config import device_config
from hwbridge.robot.plugin import HostContext
from hwbridge.robot.registry import get_device
from tests.bridgeproc import BridgeProcess
from tests.netutil import free_port, wait_until


def test_world_sonar_and_imu_ground_truth() -> None:
    world = World(WorldConfig(room=(6.0, 4.0), sonar_offset=0.1))
    # Facing +x from the centre: the wall is 3 m away, the sonar sits 0.1 m ahead.
    assert world.sonar_distance(rays=1) == pytest.approx(2.9)
    truth = world.imu_truth()
    assert truth.specific_force == (0.0, 0.0, pytest.approx(9.80665))
    world.base.set_wheel_targets(10.0, 10.0)
    for _ in range(400):
        world.step(0.005)
    assert world.pose.x > 0.5
    assert world.sonar_distance(rays=1) == pytest.approx(2.9 - world.pose.x, abs=1e-6)


def host_nodes(graph: Graph, config: BoardConfig, namespace: str) -> dict[str, Any]:
    """Each device's host node, started by its plugin (as ``hwbridge up`` does)."""
    started: dict[str, Any] = {}
    for device in config.devices:
        context = HostContext(
            graph, graph.node(f"dev_{device.name}", namespace=namespace), namespace, "base", None
        )
        node = get_device(device.type).host_node(device.settings, context)
        if node is not None:
            started[device.type] = node
    return started


def test_unknown_board_lists_the_ready_ones() -> None:
    with pytest.raises(HwBridgeError, match=r"ready robots are .*diffbot"):
        load_board("nosuchbot")


def test_a_board_of_a_robot_file_by_name(tmp_path: Path) -> None:
    path = tmp_path / "two.yaml"
    path.write_text(
        "robot: two\nworld: {room: [3.0, 2.0]}\nboards:\n"
        "  - {name: front, link: pty://, devices: [{type: hcsr04}]}\n"
        "  - {name: rear, link: pty://, devices: [{type: mpu6050, rate: 20}]}\n"
    )
    first = load_board(str(path))  # default: the first board
    assert [d.type for d in first.devices] == ["hcsr04"]
    rear = load_board(str(path), "rear")
    assert [(d.type, d.settings["rate"]) for d in rear.devices] == [("mpu6050", 20)]
    assert rear.world.room == (3.0, 2.0)
    with pytest.raises(HwBridgeError, match=r"no board named 'side' \(boards: front, rear\)"):
        load_board(str(path), "side")


def test_virtual_board_through_bridge_and_device_nodes(tmp_path: Path) -> None:
    """Drive the board through the bridge; odometry tracks ground truth, sensors look right."""
    config = load_board("diffbot")
    board = VirtualBoard(config, seed=3, speed=2.0)
    link = open_link(f"pty://?symlink={tmp_path / 'diffbot'}")
    board.start(link)
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="emu")
    bridge = Bridge(graph)
    try:
        bridge.add_board(
            BoardSpec(str(tmp_path / "diffbot"), protocol="auto", namespace="/bot", start_delay=0.1)
        )
        nodes = host_nodes(graph, config, "/bot")  # the device plugins' host side
        node = graph.node("devices", namespace="/bot")
        drive, sonar, imu = nodes["diffdrive"], nodes["hcsr04"], nodes["mpu6050"]
        cmd = graph.node("driver", namespace="/bot").publisher("cmd_vel", "geometry_msgs/Twist")
        assert wait_until(lambda: None not in (drive.latest, imu.latest, sonar.latest), 30)
        assert imu.latest.linear_acceleration.z == pytest.approx(9.81, abs=1.2)
        truth_range = board.world.sonar_distance()
        assert truth_range is not None
        assert float(sonar.latest.range) == pytest.approx(truth_range, abs=0.05)
        deadline = time.monotonic() + 4.0
        while time.monotonic() < deadline:
            cmd.publish({"linear": {"x": 0.2}, "angular": {"z": 0.3}})
            time.sleep(0.1)
        cmd.publish({})
        truth_moved = board.world.base.distance
        assert truth_moved > 0.5
        time.sleep(1.0)  # the board stops (0.5 s timeout) and the last ticks arrive
        assert wait_until(lambda: abs(float(drive.latest.twist.twist.linear.x)) < 1e-3, 5)
        odom = drive.latest.pose.pose.position
        truth = board.world.pose
        error = math.hypot(float(odom.x) - truth.x, float(odom.y) - truth.y)
        assert error / board.world.base.distance < 0.005

        # The pan servo on the board's Dynamixel bus follows its goal.
        joints: list[Any] = []
        node.subscriber("joint_states", "sensor_msgs/JointState", joints.append)
        pan = graph.node("pan_driver", namespace="/bot").publisher(
            "pan/goal_position", "std_msgs/Float64"
        )
        assert pan.wait_for_subscribers(10)

        def pan_reached() -> bool:
            pan.publish({"data": 0.5})
            return bool(joints) and abs(float(joints[-1].position[0]) - 0.5) < 0.01

        assert wait_until(pan_reached, 20)
        assert joints[-1].name == ["pan"]
        for started in nodes.values():
            started.close()
    finally:
        bridge.stop()
        graph.close()
        board.stop()
        link.close()


def test_mpu9250_board_gives_imu_and_magnetic_field_through_the_bridge(tmp_path: Path) -> None:
    """An MPU-9250 on a virtual board: the board reads the AK8963 as firmware would (bypass,
    fuse ROM, continuous 16-bit), ImuRaw carries it, and ImuNode publishes the field in tesla."""
    diffbot = load_board("diffbot")
    devices = tuple(
        device_config({**device.settings, "type": "mpu9250"})
        if device.type == "mpu6050"
        else device
        for device in diffbot.devices
        if device.type in ("diffdrive", "mpu6050")
    )
    board = VirtualBoard(dataclasses.replace(diffbot, devices=devices), seed=9, speed=2.0)
    link = open_link(f"pty://?symlink={tmp_path / 'imubot'}")
    board.start(link)
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="emumag")
    bridge = Bridge(graph)
    fields: list[Any] = []
    try:
        bridge.add_board(BoardSpec(str(tmp_path / "imubot"), namespace="/bot", start_delay=0.1))
        imu = ImuNode(graph.node("devices", namespace="/bot"))
        graph.node("listener").subscriber("/bot/mag", "sensor_msgs/MagneticField", fields.append)
        assert wait_until(lambda: len(fields) >= 5 and imu.latest is not None, 30)
        truth = board.world.imu_truth().magnetic_field  # the robot stands still: constant
        for got in fields:
            assert got.header.frame_id == "imu_link"
            field = got.magnetic_field
            # 16-bit output is 0.15 uT per count, scaled back by the chip's adjustment (<1.5)
            for value, expected in zip((field.x, field.y, field.z), truth, strict=True):
                assert float(value) == pytest.approx(expected, abs=0.12e-6)
        assert imu.latest.linear_acceleration.z == pytest.approx(9.81, abs=1.2)
    finally:
        bridge.stop()
        graph.close()
        board.stop()
        link.close()


@pytest.mark.parametrize("magnetometer", [True, False])
def test_mpu9250_magnetometer_option(magnetometer: bool) -> None:
    device = device_config(
        {"type": "mpu9250", "topic": "imu_raw", "rate": 50, "magnetometer": magnetometer}
    )
    config = dataclasses.replace(load_board("diffbot"), devices=(device,))
    board = VirtualBoard(config, seed=1)
    assert [(t.name, t.kind) for t in board.topics] == [("imu_raw", EntryKind.PUBLISHER)]
    raws = []
    for _ in range(3):
        board.world.step(0.02)  # the AK8963 measures at 100 Hz: one is ready every reading
        payload = board.read("imu_raw")
        assert payload is not None
        raws.append(msg.decode(payload, "hwbridge_msgs/ImuRaw"))
    assert [bool(raw.mag_valid) for raw in raws] == [magnetometer] * 3
    if magnetometer:
        assert all(150 <= int(value) < 200 for value in raws[-1].mag_asa)  # the model's fuses
        assert int(raws[-1].mag_st2) == 0x10  # 16-bit output, no overflow
    else:
        assert list(raws[-1].mag) == [0, 0, 0]
    with pytest.raises(HwBridgeError, match="publishes no topic 'imu'"):
        board.read("imu")


def test_a_failing_device_reading_is_logged_and_the_board_keeps_running(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    board = VirtualBoard(load_board("diffbot"), seed=5, speed=2.0)

    def broken() -> bytes:
        raise ValueError("I2C bus stuck")

    board.publisher("stuck", "std_msgs/Empty", 100.0, broken)  # fails at every reading
    link = open_link(f"pty://?symlink={tmp_path / 'diffbot'}")
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="emufail")
    bridge = Bridge(graph)
    imu: list[Any] = []
    try:
        with caplog.at_level("ERROR", logger="hwbridge.emulator"):
            board.start(link)
            bridge.add_board(BoardSpec(str(tmp_path / "diffbot"), namespace="/bot"))
            graph.node("listener").subscriber("/bot/imu_raw", "hwbridge_msgs/ImuRaw", imu.append)
            assert wait_until(lambda: len(imu) > 20 and board.read_errors > 20, 30)
        assert board.running  # a failing reading does not end the board
        failures = [r for r in caplog.records if "a device reading failed" in r.getMessage()]
        assert len(failures) == 1  # once, with its traceback; then counted
        assert failures[0].exc_info is not None and "I2C bus stuck" in str(failures[0].exc_info[1])
    finally:
        bridge.stop()
        graph.close()
        board.stop()
        link.close()


class _UnreadLink(Link):
    """A link whose peer never reads: a write blocks until close() wakes it, as one to a full
    pty or socket does (a host that stopped reading); reads find nothing."""

    scheme = "unread"

    def __init__(self) -> None:
        super().__init__("unread://")
        self.writing = threading.Event()
        """Set once a write is blocked."""
        self._woken = threading.Event()

    def _open(self) -> None:
        self._woken.clear()

    def _read(self, max_bytes: int, timeout: float | None) -> bytes:
        del max_bytes
        self._woken.wait(timeout)
        return b""

    def _write(self, data: memoryview) -> None:
        del data
        self.writing.set()
        self._woken.wait()
        raise LinkClosedError("unread://: closed during a write")

    def _close(self) -> None:
        pass

    def _wake(self) -> None:
        self._woken.set()


def test_stop_does_not_wait_for_a_write_the_host_does_not_read(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The board's first bytes block in a write (the host reads nothing), and its readings wait
    behind them; stop() closes the link, which wakes the write, before it waits for its
    threads: no wait gives up on a thread, and they have ended when it returns. (It closed the
    link last: first each join waited out its timeout, 2 s a thread, on a thread that could not
    end.)"""
    gave_up: list[str] = []
    join = threading.Thread.join

    def watched_join(thread: threading.Thread, timeout: float | None = None) -> None:
        join(thread, timeout)
        if thread.is_alive() and timeout != 0:  # (a join(0) only looks)
            gave_up.append(thread.name)

    board = VirtualBoard(load_board("diffbot"), seed=2)
    link = _UnreadLink()
    link.open()
    board.start(link)
    pump = board.pump
    assert pump is not None
    assert link.writing.wait(30)
    monkeypatch.setattr(threading.Thread, "join", watched_join)
    board.stop()
    assert gave_up == []
    assert not board.running
    assert not pump.running
    assert not link.is_open


def _env(endpoint: str) -> dict[str, str]:
    return {**os.environ, "HWBRIDGE_ENDPOINT": endpoint, "HWBRIDGE_DOMAIN": "emudemo"}


def test_demo_ends_with_the_odometry_error_line() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "demo", "--duration", "6"],
        env=_env(endpoint),
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr + done.stdout
    last = done.stdout.strip().splitlines()[-1]
    match = re.fullmatch(r"odometry error: ([0-9.]+)% of ([0-9.]+) m", last)
    assert match, last
    assert float(match[2]) > 0.5  # it drove
    assert float(match[1]) < 0.5


def test_emulate_prints_the_url_first_and_a_bridge_connects(tmp_path: Path) -> None:
    emulator = subprocess.Popen(
        [sys.executable, "-m", "hwbridge", "emulate", "diffbot", "--tcp", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    bridge = None
    try:
        assert emulator.stdout is not None
        url = emulator.stdout.readline().strip()
        assert re.fullmatch(r"socket://127\.0\.0\.1:\d+", url), url
        bridge = BridgeProcess(url, tmp_path, "emudemo")
        bridge.wait_ready()
        echo = bridge.cli("topic", "echo", "/sonar_echo", "-n", "1", "--timeout", "30")
        assert echo.returncode == 0, echo.stderr + bridge.output()
        reading = yaml.safe_load(echo.stdout.split("---")[0])
        assert reading["header"]["frame_id"] == "sonar_link"
        assert reading["echo_us"] > 0
    finally:
        if bridge is not None:
            bridge.stop()
        emulator.terminate()
        emulator.wait(15)


@pytest.mark.parametrize(
    ("bus", "protocol", "model"), [("dxl-bus", "2", "XL430-W250"), ("dxl-bus-p1", "1", "AX-12A")]
)
def test_emulate_dynamixel_bus_answers_a_scan(bus: str, protocol: str, model: str) -> None:
    emulator = subprocess.Popen(
        [sys.executable, "-m", "hwbridge", "emulate", bus],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert emulator.stdout is not None
        path = emulator.stdout.readline().strip()
        assert path.startswith("/dev/pts/"), path
        scan = subprocess.run(
            [
                sys.executable,
                "-m",
                "hwbridge",
                "dxl",
                "scan",
                path,
                "--protocol",
                protocol,
                "--ids",
                "0-5",
                "--json",
            ],
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        assert scan.returncode == 0, scan.stderr
        found = scan.stdout
        assert found.count(model) == 2, found
    finally:
        emulator.terminate()
        emulator.wait(15)


@pytest.mark.parametrize(
    ("device", "said"),
    [
        ("{type: mpu6050, accel_range_g: 2g}", "board base: mpu6050: accel_range_g: expected"),
        ("{type: hcsr04, rate: fast}", "board base: hcsr04: rate: expected a number"),
    ],
)
def test_a_setting_that_is_not_a_number_names_the_device(
    device: str, said: str, tmp_path: Path
) -> None:
    path = tmp_path / "bot.yaml"
    path.write_text(
        "robot: bot\nboards:\n  - name: base\n    link: pty://\n    devices:\n"
        f"      - type: hcsr04\n      - {device}\n"
    )
    with pytest.raises(HwBridgeError) as info:
        VirtualBoard(load_board(str(path)))
    assert f"{path}:7: {said}" in str(info.value)
