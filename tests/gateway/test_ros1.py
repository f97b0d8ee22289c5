"""``hwbridge up ROBOT.yaml`` with ``ros: {ros1: true}`` in the robot file (what ``--ros1``
does) against a real ``roscore`` and the ROS 1 command-line tools.

The ROS side is Debian's packages (ros-core, python3-rostopic, python3-rosservice, the message
packages); without ``roscore`` the module is skipped, saying so. Each run uses a master port of
its own.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import xmlrpc.client
from collections.abc import Iterator
from typing import Any

import pytest
import yaml

from hwbridge import msg
from hwbridge.graph import Graph
from tests.gateway.harness import ROOT, Robot, odom_x
from tests.netutil import free_port, wait_until

TOOLS = ("roscore", "rostopic", "rosservice", "rosparam")
_MISSING = [tool for tool in TOOLS if shutil.which(tool) is None]
pytestmark = pytest.mark.skipif(
    bool(_MISSING),
    reason=f"ROS 1 is not installed ({', '.join(_MISSING)} missing): apt-get install ros-core "
    "python3-rospy python3-rostopic python3-rosservice and the message packages",
)

RESPONDER = """
import sys, rospy
from std_srvs.srv import Trigger, TriggerResponse
rospy.init_node("gateway_test_responder")
rospy.Service("/ros1_side/hello", Trigger, lambda _req: TriggerResponse(True, "ros1 says hi"))
print("ready", flush=True)
rospy.spin()
"""

WRONG_LISTENER = """
import rospy
from std_msgs.msg import String
rospy.init_node("gateway_test_wrong_listener")
rospy.Subscriber("/diffbot/imu", String, lambda _m: None)
rospy.spin()
"""


class Ros1Robot(Robot):
    def __init__(self, tmp: Any) -> None:
        self.master_port = free_port()
        self.master_uri = f"http://127.0.0.1:{self.master_port}"
        super().__init__(tmp, {"ROS_MASTER_URI": self.master_uri})
        self.roscore: subprocess.Popen[str] | None = None

    def start_master(self) -> None:
        self.roscore = self.start("roscore", ["roscore", "-p", str(self.master_port)])
        assert wait_until(self.master_answers, 30, step=0.2), self.log("roscore")

    def master_answers(self) -> bool:
        try:
            code, _, _ = xmlrpc.client.ServerProxy(self.master_uri).getPid("/test")  # type: ignore[misc]
        except OSError:
            return False
        return bool(code == 1)

    def ros(self, *argv: str, timeout: float = 40) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            list(argv), env=self.env, capture_output=True, text=True, timeout=timeout, check=False
        )


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Ros1Robot]:
    running = Ros1Robot(tmp_path_factory.mktemp("ros1"))
    try:
        running.start_master()
        set_before = running.ros("rosparam", "set", "/aux/initial", "7")
        assert set_before.returncode == 0, set_before.stderr
        running.up(ros={"ros1": True})  # the robot file's section, not a flag
        running.wait_log("up", "starting 'hwbridge ros1' (the robot file's 'ros: {ros1: true}')")
        running.wait_log("up", "ROS 1 gateway up")
        running.wait_log("up", "/diffbot/imu: graph -> ROS 1")
        running.wait_log("up", "/aux/reset: graph service in ROS 1")
        yield running
    finally:
        running.stop()


def _echo(robot: Ros1Robot, topic: str, *extra: str) -> dict[str, Any]:
    done = robot.ros("rostopic", "echo", "-n", "1", *extra, topic)
    assert done.returncode == 0, done.stderr + robot.log("up")
    value: dict[str, Any] = yaml.safe_load(done.stdout.split("\n---")[0])
    return value


@pytest.mark.parametrize(
    ("topic", "type_name"),
    [("/diffbot/imu", "sensor_msgs/Imu"), ("/diffbot/odom", "nav_msgs/Odometry")],
)
def test_board_messages_arrive_intact_in_ros1(
    robot: Ros1Robot, graph: Graph, topic: str, type_name: str
) -> None:
    seen: dict[tuple[int, int], dict[str, Any]] = {}
    lock = threading.Lock()

    def keep(message: Any) -> None:
        value = msg.to_dict(message)
        stamp = value["header"]["stamp"]
        with lock:
            seen[stamp["secs"], stamp["nsecs"]] = value

    sub = graph.node("gateway_test").subscriber(topic, type_name, keep)
    try:
        received = _echo(robot, topic)
    finally:
        sub.close()
    stamp = received["header"]["stamp"]
    with lock:
        original = seen.get((stamp["secs"], stamp["nsecs"]))
    assert original is not None, received["header"]
    assert received == original  # header.seq included: ROS 1 bytes pass through unchanged


def test_a_rostopic_pub_moves_the_robot(robot: Ros1Robot) -> None:
    start = odom_x(robot)
    drive = robot.start(
        "rostopic_pub",
        [
            "rostopic",
            "pub",
            "-r",
            "10",
            "/diffbot/cmd_vel",
            "geometry_msgs/Twist",
            "{linear: {x: 0.3}}",
        ],
    )
    try:
        assert wait_until(lambda: odom_x(robot) - start > 0.1, 30, step=0.5), robot.log("up")
    finally:
        robot.stop_process(drive)


def test_rosservice_call_reaches_a_board_service(robot: Ros1Robot) -> None:
    done = robot.ros("rosservice", "call", "/aux/reset")
    assert done.returncode == 0, done.stderr + robot.log("up")
    assert yaml.safe_load(done.stdout) == {"success": True, "message": "done"}


def test_a_board_log_reaches_rosout(robot: Ros1Robot) -> None:
    text = f"gateway test {os.getpid()}"
    stop = threading.Event()

    def keep_logging() -> None:
        while not stop.wait(0.3):
            robot.board_log(text)

    thread = threading.Thread(target=keep_logging, daemon=True)
    thread.start()
    try:
        entry = _echo(robot, "/rosout_agg", "--filter", f"m.msg == {text!r}")
    finally:
        stop.set()
        thread.join(5)
    assert entry["msg"] == text
    assert entry["level"] == 4  # WARN
    assert entry["name"].endswith("aux")


def test_parameters_from_the_ros_parameter_server_reach_the_graph(robot: Ros1Robot) -> None:
    # Set before the gateway started: copied when it subscribed.
    before = robot.cli("param", "get", "/aux/initial")
    assert (before.returncode, before.stdout.strip()) == (0, "7"), before.stderr
    # Set while it runs: followed.
    done = robot.ros("rosparam", "set", "/aux/gain", "2.5")
    assert done.returncode == 0, done.stderr

    def copied() -> bool:
        got = robot.cli("param", "get", "/aux/gain")
        return got.returncode == 0 and got.stdout.strip() == "2.5"

    assert wait_until(copied, 20, step=0.3), robot.log("up")


def test_any_type_passes_through(robot: Ros1Robot) -> None:
    # hwbridge_msgs have no Python classes in ROS 1 here; the topic is there with its type.
    done = robot.ros("rostopic", "list", "-v")
    assert done.returncode == 0, done.stderr
    assert "/diffbot/wheel_ticks [hwbridge_msgs/WheelTicks]" in done.stdout
    bw = robot.ros("rostopic", "type", "/diffbot/wheel_ticks")
    assert bw.stdout.strip() == "hwbridge_msgs/WheelTicks"


def test_a_ros_type_that_does_not_map_is_reported_once(robot: Ros1Robot) -> None:
    # A ROS node publishes a String where the board subscribes a Twist, and one subscribes
    # to the Imu topic as a String: both refused, each said once, nothing else disturbed.
    wrong = robot.start(
        "rostopic_wrong",
        ["rostopic", "pub", "-r", "5", "/diffbot/cmd_vel", "std_msgs/String", "data: nope"],
    )
    try:
        robot.wait_log("up", "/diffbot/cmd_vel: the ROS publisher", 30)
    finally:
        robot.stop_process(wrong)
    listener = robot.start("wrong_listener", ["/usr/bin/python3", "-c", WRONG_LISTENER])
    try:
        robot.wait_log("up", "subscribes with std_msgs/String", 30)
    finally:
        robot.stop_process(listener)
    robot.wait_log("up", "subscribes with std_msgs/String", 30)
    text = robot.log("up")
    assert text.count("/diffbot/cmd_vel: the ROS publisher") == 1, text
    assert "a type that does not map" in text
    assert _echo(robot, "/diffbot/imu")["header"]["frame_id"]


def test_a_ros1_service_is_served_on_the_graph(robot: Ros1Robot) -> None:
    responder = robot.start("responder", ["/usr/bin/python3", "-c", RESPONDER])
    gateway = robot.hwbridge(
        "gw1b",
        "ros1",
        "--ros-service",
        "/ros1_side/*",
        "--topic",
        "/none",
        "--service",
        "/none",
        "--node-name",
        "hwbridge_gateway_b",
        "--no-rosout",
    )
    try:
        assert responder.stdout is not None
        assert responder.stdout.readline().strip() == "ready", robot.log("responder")

        def answered() -> bool:
            done = robot.cli("service", "call", "/ros1_side/hello", "{}", "--timeout", "2")
            return done.returncode == 0 and "ros1 says hi" in done.stdout

        assert wait_until(answered, 40, step=0.5), robot.log("gw1b")
    finally:
        robot.stop_process(gateway)
        robot.stop_process(responder)


def test_the_gateway_waits_for_the_master_and_recovers_when_it_restarts(
    robot: Ros1Robot,
) -> None:
    assert robot.roscore is not None
    robot.roscore.send_signal(signal.SIGINT)
    robot.roscore.wait(20)
    robot.wait_log("up", "is not running", 20)
    robot.start_master()
    robot.wait_log("up", "restarted: registered", 30)
    received = _echo(robot, "/diffbot/imu")
    assert received["header"]["frame_id"]
    done = robot.ros("rosservice", "call", "/aux/reset")
    assert done.returncode == 0, done.stderr


def test_the_cli_is_importable_without_ros() -> None:
    # The gateway is pure Python: importing it needs neither rospy nor rclpy.
    done = subprocess.run(
        [sys.executable, "-c", "import hwbridge.gateway.ros1, hwbridge.gateway.tcpros"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
