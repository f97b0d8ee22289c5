"""``/tf`` and ``/tf_static`` in ROS 2 from the PyPI wheels alone: ``tf2_msgs`` built by
``hwbridge ros2 --interfaces`` (once, into the user's cache) and used by the gateway and by a
plain rclpy node that sources the printed ``setup.sh``, as the README tells users to.

The build is cached across runs (``$XDG_CACHE_HOME/hwbridge/ros2-interfaces``): only the first
run on a machine pays for it. Without the ``[ros2]`` wheels the module is skipped, saying so.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from hwbridge import msg
from hwbridge.graph import Graph
from tests.gateway.harness import PEER, Robot
from tests.gateway.test_ros2 import rclpy_problem, ros2_env
from tests.netutil import ros_domain_id

DOMAIN_ID = ros_domain_id(1)  # not test_ros2's: both may run at once
ROS2_TF_HASH = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
"""tf2_msgs/msg/TFMessage's type hash in ROS 2 (Jazzy and later): what RViz and Nav2 expect."""


def _ros2_env() -> dict[str, str]:
    return ros2_env(DOMAIN_ID)


_PROBLEM = rclpy_problem("rclpy, geometry_msgs.msg, rosidl_generator_c")
pytestmark = pytest.mark.skipif(
    _PROBLEM is not None,
    reason=f"the ROS 2 wheels are not installed (pip install 'hwbridge[ros2]'): {_PROBLEM}",
)


def _hwbridge(
    *argv: str, env: dict[str, str], timeout: float = 600
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hwbridge", *argv],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


@pytest.fixture(scope="module")
def setup_script() -> Path:
    """``hwbridge ros2 --interfaces``, as a user runs it: builds tf2_msgs into the user cache
    the first time (generous deadline: two busy cores), prints the setup.sh."""
    done = _hwbridge("ros2", "--interfaces", env=_ros2_env())
    assert done.returncode == 0, done.stderr
    path = Path(done.stdout.strip().splitlines()[-1])
    assert path.name == "setup.sh", done.stdout
    assert path.is_file(), done.stdout
    assert f'source "{path}"' in done.stderr
    return path


def _sourced(setup: Path, *argv: str) -> list[str]:
    """argv run in a shell that sources ``setup`` first, as the README shows."""
    script = 'source "$1" && shift && exec "$@"'
    return ["bash", "-c", script, "bash", str(setup), *argv]


def _peer(setup: Path, *argv: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        _sourced(setup, sys.executable, str(PEER), *argv),
        env=_ros2_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _result(peer: subprocess.Popen[str], robot: Robot, timeout: float = 60) -> dict[str, Any]:
    try:
        out, err = peer.communicate(timeout=timeout)
    finally:
        if peer.poll() is None:
            peer.kill()
            peer.wait(5)
    assert peer.returncode == 0, err + robot.log("up")
    return dict(json.loads(out.splitlines()[-1]))


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory, setup_script: Path) -> Iterator[Robot]:
    # The environment of test_ros2's robot: the gateway finds tf2_msgs on its own.
    running = Robot(tmp_path_factory.mktemp("ros2tf"), _ros2_env())
    try:
        running.up("--ros2")
        running.wait_log("up", "ROS 2 gateway up", 120)
        running.wait_log("up", "/tf: graph -> ROS 2 (tf2_msgs/msg/TFMessage")
        yield running
    finally:
        running.stop()


def _ros2_view(transform: dict[str, Any]) -> dict[str, Any]:
    """A graph TransformStamped as ROS 2 has it: no header.seq, stamps as sec/nanosec."""
    header = transform["header"]
    stamp = header["stamp"]
    return {
        **transform,
        "header": {
            "stamp": {"sec": stamp["secs"], "nanosec": stamp["nsecs"]},
            "frame_id": header["frame_id"],
        },
    }


def test_a_plain_rclpy_node_gets_odom_to_base_link_from_the_robot(
    robot: Robot, graph: Graph, setup_script: Path
) -> None:
    seen: dict[tuple[int, int], dict[str, Any]] = {}
    lock = threading.Lock()

    def keep(message: Any) -> None:
        for transform in msg.to_dict(message)["transforms"]:
            stamp = transform["header"]["stamp"]
            with lock:
                seen[(stamp["secs"], stamp["nsecs"])] = transform

    sub = graph.node("tf_test").subscriber("/tf", "tf2_msgs/TFMessage", keep)
    try:
        found = _result(_peer(setup_script, "tf", "/tf", "odom", "base_link"), robot)
    finally:
        sub.close()
    transform = found["transform"]
    stamp = transform["header"]["stamp"]
    with lock:
        original = seen.get((stamp["sec"], stamp["nanosec"]))
    assert original is not None, f"no graph transform stamped {stamp}"
    assert transform == _ros2_view(original)
    # The type ROS 2 tools know: RViz or Nav2 from a ROS install take the gateway's /tf.
    assert found["type_hashes"] == [ROS2_TF_HASH]
    assert "tf2_msgs/TFMessage has no ROS 2 counterpart" not in robot.log("up")


def test_tf_static_is_latched_for_a_late_subscriber(
    robot: Robot, graph: Graph, setup_script: Path
) -> None:
    static = msg.from_dict(
        "tf2_msgs/TFMessage",
        {
            "transforms": [
                {
                    "header": {"stamp": {"secs": 7, "nsecs": 5}, "frame_id": "base_link"},
                    "child_frame_id": "laser",
                    "transform": {"translation": {"x": 0.1, "z": 0.2}, "rotation": {"w": 1.0}},
                }
            ]
        },
    )
    publisher = graph.node("tf_static_test").publisher("/tf_static", "tf2_msgs/TFMessage")
    first = _peer(setup_script, "tf", "/tf_static", "base_link", "laser", "static")
    try:
        # Publish until a first ROS 2 node has it (the gateway is subscribed then), then stop.
        stop = threading.Event()

        def keep_publishing() -> None:
            while not stop.wait(0.3):
                publisher.publish(static)

        thread = threading.Thread(target=keep_publishing, daemon=True)
        thread.start()
        try:
            _result(first, robot)
        finally:
            stop.set()
            thread.join(5)
        # A node that starts now gets it all the same: the gateway keeps it, as
        # static_transform_publisher does.
        late = _result(
            _peer(setup_script, "tf", "/tf_static", "base_link", "laser", "static"), robot
        )
    finally:
        publisher.close()
    assert late["transform"]["transform"]["translation"] == {"x": 0.1, "y": 0.0, "z": 0.2}
    assert late["transform"]["header"]["stamp"] == {"sec": 7, "nanosec": 5}


def test_a_tf2_msgs_python_can_import_already_is_used_instead(
    tmp_path: Path, setup_script: Path
) -> None:
    # A sourced ROS 2 installation that has tf2_msgs: a copy of the built one stands in for it.
    ros = tmp_path / "opt_ros"
    shutil.copytree(setup_script.parent, ros)
    site = next(ros.glob("lib/python*/site-packages"))
    env = {**_ros2_env(), "HWBRIDGE_ROS2_INTERFACES": str(tmp_path / "cache")}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(site), env.get("PYTHONPATH")) if p)
    done = _hwbridge("ros2", "--interfaces", env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "tf2_msgs comes from your ROS 2 installation: nothing to build" in done.stderr
    assert done.stdout == f"{os.devnull}\n"  # sourcing it changes nothing
    assert not (tmp_path / "cache").exists()


def test_without_a_compiler_the_build_says_what_to_install(tmp_path: Path) -> None:
    env = {
        **_ros2_env(),
        "HWBRIDGE_ROS2_INTERFACES": str(tmp_path / "cache"),
        "CC": str(tmp_path / "no-such-cc"),
    }
    done = _hwbridge("ros2", "--interfaces", env=env, timeout=120)
    assert done.returncode == 1, done.stderr
    assert "needs a C and C++ compiler" in done.stderr
    assert "apt install g++" in done.stderr
    assert not list((tmp_path / "cache").glob("rclpy-*/.complete"))


def test_the_gateway_builds_tf2_msgs_at_first_use_and_says_so(tmp_path: Path, robot: Robot) -> None:
    # A fresh cache: 'hwbridge ros2' builds before it starts (with progress lines), then mirrors
    # /tf. (This pays for one build on every run.)
    env = {**robot.env, "HWBRIDGE_ROS2_INTERFACES": str(tmp_path / "cache")}
    gateway = robot.start(
        "fresh",
        [
            sys.executable,
            "-m",
            "hwbridge",
            "ros2",
            "--topic",
            "/tf",
            "--no-rosout",
            "--node-name",
            "hwbridge_fresh",
        ],
        env,
    )
    try:
        robot.wait_log("fresh", "building ROS 2 message packages the wheels lack (tf2_msgs)", 120)
        robot.wait_log("fresh", "built tf2_msgs in", 600)
        robot.wait_log("fresh", "/tf: graph -> ROS 2 (tf2_msgs/msg/TFMessage", 120)
    finally:
        robot.stop_process(gateway)
    assert list((tmp_path / "cache").glob("rclpy-*/.complete")), robot.log("fresh")
    assert "has no ROS 2 counterpart" not in robot.log("fresh")
