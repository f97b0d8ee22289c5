"""``hwbridge up ROBOT.yaml --ros2`` with its default QoS, against plain rclpy nodes.

What most ROS 2 code writes, ``create_subscription(T, topic, cb, 10)`` (reliable, volatile:
Nav2, robot_localization, RViz), and ``qos_profile_sensor_data`` (best effort) must both receive
every topic the gateway publishes; and a teleop node's default (reliable) publisher and a
driver's sensor-data (best effort) publisher must both reach the boards. The topics are the
gateway's own list (its log), checked against the graph's publishers, not a list written here.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections.abc import Iterator
from typing import Any

import pytest

from hwbridge.gateway.common import GATEWAY_NODE
from hwbridge.graph import Graph
from tests.boards import native_chatter
from tests.gateway.harness import PEER, Robot, odom_x
from tests.gateway.test_ros2 import needs_rclpy, peer, ros2_env
from tests.netutil import wait_until

pytestmark = needs_rclpy

_TO_ROS = re.compile(r"(/\S*): graph -> ROS 2 \(([^,)]+)")
_FROM_ROS = re.compile(r"(/\S*): ROS 2 -> graph \(([^,)]+)")
_UNMAPPED = re.compile(r": (\S+) has no ROS 2 counterpart")


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Robot]:
    from hwbridge.protocols.native.control import LogLevel

    running = Robot(tmp_path_factory.mktemp("ros2qos"), ros2_env())
    try:
        running.up("--ros2")
        running.wait_log("up", "ROS 2 gateway up")
        running.wait_log("up", "/aux/reset")  # the aux board is connected
        aux = running.aux
        assert aux is not None
        # The aux board's topics carry data too: chatter, and a log line now and then.
        aux.every(0.2, native_chatter([0]))
        aux.every(0.5, lambda session: session.log(LogLevel.INFO, "aux: still here"))
        yield running
    finally:
        running.stop()


@pytest.fixture(scope="module")
def published(robot: Robot, graph: Graph) -> dict[str, str]:
    """Topic -> ROS 2 type of everything the gateway publishes in ROS 2, once it has taken up
    every topic published on the graph (mirrored, or of a type ROS 2 lacks here)."""

    def accounted() -> bool:
        text = robot.log("up")
        mirrored = {m[1] for m in _TO_ROS.finditer(text)}
        unmapped = set(_UNMAPPED.findall(text))
        publishers = [
            entity
            for entity in graph.snapshot().of_kind("pub")
            if not entity.node.rsplit("/", 1)[-1].startswith(GATEWAY_NODE)
        ]
        return bool(publishers) and all(
            entity.name in mirrored or entity.type in unmapped for entity in publishers
        )

    assert wait_until(accounted, 60, step=0.5), robot.log("up")
    topics = {m[1]: m[2] for m in _TO_ROS.finditer(robot.log("up"))}
    # The case, and a board's topic of a plain type.
    assert {"/diffbot/odom", "/aux/chatter", "/rosout"} <= set(topics), topics
    return topics


@pytest.mark.parametrize("qos", ["default", "sensor"])
def test_every_topic_reaches_default_and_sensor_data_subscribers(
    robot: Robot, published: dict[str, str], qos: str
) -> None:
    pairs = [f"{topic}={type_name}" for topic, type_name in sorted(published.items())]
    done = peer("receive", qos, *pairs, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr + robot.log("up")
    result = json.loads(done.stdout.splitlines()[-1])
    assert result["missing"] == []
    assert set(result["received"]) == set(published)


def test_the_gateway_offers_reliable_and_asks_best_effort(
    robot: Robot, published: dict[str, str]
) -> None:
    # Reliable publishers match every subscriber; best-effort subscriptions match every
    # publisher. (/rosout keeps its log-for-late-joiners profile: test_ros2.py.)
    subscribed = {m[1] for m in _FROM_ROS.finditer(robot.log("up"))}
    assert "/diffbot/cmd_vel" in subscribed
    topics = sorted(set(published) - {"/rosout"} | subscribed)
    done = peer("qos", *topics)
    assert done.returncode == 0, done.stdout + done.stderr + robot.log("up")
    found: dict[str, list[dict[str, Any]]] = {}
    for line in done.stdout.splitlines():
        endpoint = json.loads(line)
        found.setdefault(endpoint.pop("topic"), []).append(endpoint)
    for topic in topics:
        if topic in subscribed:
            expected = {"kind": "subscription", "reliability": "best_effort"}
        elif topic.endswith("/tf_static"):
            expected = {"kind": "publisher", "reliability": "reliable"}
        else:
            expected = {"kind": "publisher", "reliability": "reliable", "durability": "volatile"}
        for endpoint in found[topic]:
            assert endpoint | expected == endpoint, (topic, found[topic])


@pytest.mark.parametrize("qos", ["default", "sensor"])
def test_default_and_sensor_data_publishers_both_drive_the_robot(robot: Robot, qos: str) -> None:
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
            "60",
            qos,
        ],
        env=ros2_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        assert wait_until(lambda: odom_x(robot) - start > 0.1, 40, step=0.5), robot.log("up")
    finally:
        drive.kill()
        drive.wait(10)
