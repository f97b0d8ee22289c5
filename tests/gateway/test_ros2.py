"""``hwbridge up ROBOT.yaml --ros2`` against real rclpy nodes in other processes.

The ROS 2 side is the PyPI wheels of the ``[ros2]`` extra (rclpy, Fast DDS); without them the
module is skipped, saying so. Each run uses a ROS_DOMAIN_ID of its own.
"""

from __future__ import annotations

import functools
import json
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from hwbridge import msg
from hwbridge.errors import HwBridgeError
from hwbridge.gateway.ros2 import ros2_environment
from hwbridge.graph import Graph
from tests.gateway.harness import PEER, Robot, odom_x
from tests.netutil import ros_domain_id, wait_until

DOMAIN_ID = ros_domain_id(0)


def ros2_env(domain: str = DOMAIN_ID) -> dict[str, str]:
    env = ros2_environment()
    env["ROS_DOMAIN_ID"] = domain
    env["_ROS_WHEELS_BOOTSTRAP_COMPLETE"] = "1"  # the paths are set already: no re-exec
    return env


def rclpy_problem(
    imports: str = "rclpy, sensor_msgs.msg, nav_msgs.msg, std_srvs.srv",
) -> str | None:
    """Why ``import IMPORTS`` fails in a ROS 2 process, None when it works."""
    try:
        done = subprocess.run(
            [sys.executable, "-c", f"import {imports}"],
            env=ros2_env(),
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
    except subprocess.TimeoutExpired:
        return "importing rclpy took over 60 s"
    if done.returncode != 0:
        return done.stderr.strip().splitlines()[-1] if done.stderr.strip() else "import failed"
    return None


_PROBLEM = rclpy_problem()
needs_rclpy = pytest.mark.skipif(
    _PROBLEM is not None,
    reason=f"the ROS 2 wheels are not installed (pip install 'hwbridge[ros2]'): {_PROBLEM}",
)
pytestmark = needs_rclpy


@functools.lru_cache(maxsize=1)
def _interfaces() -> Any:
    """The message packages the gateway builds (tf2_msgs), None if they cannot be built here
    (test_ros2_tf.py says why)."""
    from hwbridge.gateway.ros2_interfaces import ensure_interfaces

    try:
        return ensure_interfaces()
    except HwBridgeError:
        return None


def peer_env(domain: str = DOMAIN_ID) -> dict[str, str]:
    """:func:`ros2_env` for a plain rclpy node of the user's: with tf2_msgs on its paths, as
    after ``source "$(hwbridge ros2 --interfaces)"``."""
    from hwbridge.gateway.ros2_interfaces import interfaces_environment

    built = _interfaces()
    env = ros2_env(domain)
    return env if built is None else interfaces_environment(built, env)


def peer(
    *argv: str, timeout: float = 40, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """Run the plain rclpy node once (in ``env``, default :func:`peer_env`)."""
    return subprocess.run(
        [sys.executable, str(PEER), *argv],
        env=env or peer_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Robot]:
    running = Robot(tmp_path_factory.mktemp("ros2"), ros2_env())
    try:
        running.up("--ros2")
        running.wait_log("up", "starting 'hwbridge ros2' (--ros2)")
        running.wait_log("up", "ROS 2 gateway up")
        running.wait_log("up", "/diffbot/imu: graph -> ROS 2")
        running.wait_log("up", "/aux/reset")
        yield running
    finally:
        running.stop()


def _stamp(header: dict[str, Any]) -> tuple[int, int]:
    stamp = header["stamp"]
    if "sec" in stamp:
        return int(stamp["sec"]), int(stamp["nanosec"])
    return int(stamp["secs"]), int(stamp["nsecs"])


def _without_seq(value: Any) -> Any:
    """A graph message as ROS 2 shows it: no header.seq, time as sec/nanosec."""
    if isinstance(value, dict):
        if set(value) == {"secs", "nsecs"}:
            return {"sec": value["secs"], "nanosec": value["nsecs"]}
        # (constants, such as Range's ULTRASOUND, are no fields in ROS 2's messages)
        return {k: _without_seq(v) for k, v in value.items() if k != "seq" and not k.isupper()}
    if isinstance(value, list):
        return [_without_seq(v) for v in value]
    return value


@pytest.mark.parametrize(
    ("topic", "ros1", "ros2", "added"),
    [
        ("/diffbot/imu", "sensor_msgs/Imu", "sensor_msgs/msg/Imu", {}),
        ("/diffbot/odom", "nav_msgs/Odometry", "nav_msgs/msg/Odometry", {}),
        # ROS 2's Range has a variance ROS 1's lacks: zero.
        ("/diffbot/range", "sensor_msgs/Range", "sensor_msgs/msg/Range", {"variance": 0.0}),
    ],
)
def test_board_messages_arrive_intact_in_ros2(
    robot: Robot, graph: Graph, topic: str, ros1: str, ros2: str, added: dict[str, Any]
) -> None:
    seen: dict[tuple[int, int], dict[str, Any]] = {}
    lock = threading.Lock()

    def keep(message: Any) -> None:
        value = msg.to_dict(message)
        with lock:
            seen[_stamp(value["header"])] = value

    sub = graph.node("gateway_test").subscriber(topic, ros1, keep)
    try:
        done = peer("echo", topic, ros2, "3")
        assert done.returncode == 0, done.stderr + robot.log("up")
        received = [json.loads(line) for line in done.stdout.splitlines()]
    finally:
        sub.close()
    assert len(received) == 3
    for message in received:
        with lock:
            original = seen.get(_stamp(message["header"]))
        assert original is not None, f"no graph message with the stamp of {message['header']}"
        assert message == {**_without_seq(original), **added}


def test_a_ros2_twist_publisher_moves_the_robot(robot: Robot) -> None:
    start = odom_x(robot)
    drive = subprocess.Popen(
        [
            sys.executable,
            str(PEER),
            "pub",
            "/diffbot/cmd_vel",
            "geometry_msgs/msg/Twist",
            json.dumps({"linear": {"x": 0.3}}),
            "10",
            "30",
        ],
        env=ros2_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        assert wait_until(lambda: odom_x(robot) - start > 0.1, 30, step=0.5), robot.log("up")
    finally:
        drive.kill()
        drive.wait(10)


def test_a_ros2_client_calls_a_board_service(robot: Robot) -> None:
    done = peer("call", "/aux/reset", "std_srvs/srv/Trigger", "{}")
    assert done.returncode == 0, done.stderr + robot.log("up")
    assert json.loads(done.stdout.splitlines()[-1]) == {"success": True, "message": "done"}


def test_a_board_log_appears_on_rosout(robot: Robot) -> None:
    text = f"gateway test {os.getpid()}"
    listener = subprocess.Popen(
        [sys.executable, str(PEER), "rosout", text],
        env=ros2_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert listener.stdout is not None
        assert json.loads(listener.stdout.readline()) == {"ready": True}
        stop = threading.Event()

        def keep_logging() -> None:  # discovery takes a moment: log until it is seen
            while not stop.wait(0.3):
                robot.board_log(text)

        thread = threading.Thread(target=keep_logging, daemon=True)
        thread.start()
        try:
            out, err = listener.communicate(timeout=40)
        finally:
            stop.set()
            thread.join(5)
    finally:
        if listener.poll() is None:
            listener.kill()
            listener.wait(5)
    assert listener.returncode == 0, err + robot.log("up")
    entry = json.loads(out.splitlines()[-1])
    assert entry["msg"] == text
    assert entry["level"] == 30  # WARN
    assert entry["name"].endswith("aux")


def test_a_ros2_service_is_served_on_the_graph(tmp_path: Path, robot: Robot) -> None:
    server = subprocess.Popen(
        [sys.executable, str(PEER), "serve", "/ros2_side/hello", "60"],
        env=ros2_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    gateway = robot.hwbridge(
        "gw2",
        "ros2",
        "--ros-service",
        "/ros2_side/*",
        "--topic",
        "/none",
        "--service",
        "/none",
        "--no-rosout",
    )
    try:
        assert server.stdout is not None
        assert json.loads(server.stdout.readline()) == {"ready": True}

        def answered() -> bool:
            done = robot.cli("service", "call", "/ros2_side/hello", "{}", "--timeout", "2")
            return done.returncode == 0 and "ros2 says hi" in done.stdout

        assert wait_until(answered, 40, step=0.5), robot.log("gw2")
    finally:
        robot.stop_process(gateway)
        server.kill()
        server.wait(5)


@pytest.mark.parametrize(
    ("topic", "kind", "reliability", "durability"),
    [
        ("/diffbot/imu", "publisher", "reliable", "volatile"),
        ("/diffbot/odom", "publisher", "reliable", "volatile"),
        ("/diffbot/cmd_vel", "subscription", "best_effort", "volatile"),
        ("/rosout", "publisher", "reliable", "transient_local"),
    ],
)
def test_qos_per_topic(
    robot: Robot, topic: str, kind: str, reliability: str, durability: str
) -> None:
    # Published reliable (default and sensor-data subscribers match), subscribed best effort
    # (reliable and best-effort publishers match), logs kept for late joiners. (On /rosout the
    # gateway's node has rclpy's own log publisher too, with the same QoS.)
    done = peer("qos", topic)
    assert done.returncode == 0, done.stderr + robot.log("up")
    found = [json.loads(line) for line in done.stdout.splitlines()]
    expected = {
        "topic": topic,
        "kind": kind,
        "reliability": reliability,
        "durability": durability,
    }
    assert found
    assert all(endpoint == expected for endpoint in found), found


def test_types_without_a_ros2_counterpart_are_reported_once(robot: Robot) -> None:
    text = robot.log("up")
    assert text.count("hwbridge_msgs/WheelTicks has no ROS 2 counterpart") == 1, text
    # The gateway kept going: the topics that map are mirrored.
    assert "/diffbot/odom: graph -> ROS 2" in text


def test_the_gateway_waits_for_the_graph_and_survives_ros2_nodes_restarting(
    robot: Robot,
) -> None:
    # A gateway started before any bridge says so and retries; a peer that comes and goes is
    # DDS discovery's business: each new node gets the data.
    lonely = robot.start(
        "lonely",
        [sys.executable, "-m", "hwbridge", "--endpoint", "tcp/127.0.0.1:1", "ros2"],
    )
    try:
        robot.wait_log("lonely", "waiting for the hwbridge graph", 60)
        assert lonely.poll() is None
    finally:
        robot.stop_process(lonely)
    assert lonely.returncode in (0, 130), robot.log("lonely")  # Ctrl-C while waiting: 130
    for _ in range(2):
        done = peer("echo", "/diffbot/imu", "sensor_msgs/msg/Imu", "1")
        assert done.returncode == 0, done.stderr
