"""The emulator: world geometry, a virtual board through the real bridge, emulate and demo."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import yaml

from hwbridge.bridge import BoardSpec, Bridge
from hwbridge.devices.encoders import DiffDriveParams
from hwbridge.devices.nodes import DiffDriveNode, ImuNode, SonarNode
from hwbridge.emulator import VirtualBoard, World, WorldConfig, load_board
from hwbridge.errors import HwBridgeError
from hwbridge.graph import Graph
from hwbridge.links import open_link
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


def test_unknown_board_lists_the_ready_ones() -> None:
    with pytest.raises(HwBridgeError, match=r"ready boards are .*diffbot"):
        load_board("nosuchbot")


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
        node = graph.node("devices", namespace="/bot")
        drive = DiffDriveNode(node, DiffDriveParams.from_dict(config.host["diffdrive"]))
        sonar, imu = SonarNode(node), ImuNode(node)
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
        drive.close()
    finally:
        bridge.stop()
        graph.close()
        board.stop()
        link.close()


def test_a_failing_device_reading_is_logged_and_the_board_keeps_running(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    board = VirtualBoard(load_board("diffbot"), seed=5, speed=2.0)

    def broken() -> tuple[int, bytes]:
        raise ValueError("I2C bus stuck")

    board._readers.insert(0, (100.0, broken))  # a device read before the others, every step
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
        assert board._thread is not None and board._thread.is_alive()
        failures = [r for r in caplog.records if "a device reading failed" in r.getMessage()]
        assert len(failures) == 1  # once, with its traceback; then counted
        assert failures[0].exc_info is not None and "I2C bus stuck" in str(failures[0].exc_info[1])
    finally:
        bridge.stop()
        graph.close()
        board.stop()
        link.close()


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
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = _env(endpoint)
    emulator = subprocess.Popen(
        [sys.executable, "-m", "hwbridge", "emulate", "diffbot", "--tcp", "0"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    bridge = None
    try:
        assert emulator.stdout is not None
        url = emulator.stdout.readline().strip()
        assert re.fullmatch(r"socket://127\.0\.0\.1:\d+", url), url
        log = (tmp_path / "bridge.log").open("w")
        bridge = subprocess.Popen(
            [sys.executable, "-m", "hwbridge", "connect", url, "--start-delay", "0.1"],
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        assert wait_until(lambda: "bridging" in (tmp_path / "bridge.log").read_text(), 60)
        echo = subprocess.run(
            [
                sys.executable,
                "-m",
                "hwbridge",
                "topic",
                "echo",
                "/sonar_echo",
                "-n",
                "1",
                "--timeout",
                "30",
            ],
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        assert echo.returncode == 0, echo.stderr + (tmp_path / "bridge.log").read_text()
        reading = yaml.safe_load(echo.stdout.split("---")[0])
        assert reading["header"]["frame_id"] == "sonar_link"
        assert reading["echo_us"] > 0
    finally:
        for process in (bridge, emulator):
            if process is not None:
                process.terminate()
                process.wait(15)


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
