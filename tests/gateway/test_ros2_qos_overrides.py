"""Per-topic ROS 2 QoS rules: the robot file's ``ros: {qos: ...}`` and ``hwbridge up
--ros2-qos``, checked (FILE:LINE, usage errors) and then seen by a plain rclpy node in the QoS
the gateway's endpoints offer."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from hwbridge.robot.config import load_robot, parse_robot
from hwbridge.robot.model import RobotFileError
from tests.gateway.harness import Robot
from tests.gateway.test_ros2 import DOMAIN_ID, needs_rclpy, peer, ros2_env

ONE_BOARD = "robot: x\nboards:\n  - {name: b, link: 'pty://'}\n"


def _problems(text: str) -> list[str]:
    with pytest.raises(RobotFileError) as info:
        parse_robot(text, "r.yaml")
    return info.value.problems


def test_the_ros_section_reads_qos_rules_in_file_order() -> None:
    robot = parse_robot(
        ONE_BOARD + "ros:\n  ros2: true\n  qos:\n    /x/imu: sensor\n    '/x/*': reliable\n"
        "    /tf_static: latched\n    /tf: tf\n",
        "r.yaml",
    )
    assert robot.ros2_qos == (
        ("/x/imu", "sensor"),
        ("/x/*", "reliable"),
        ("/tf_static", "latched"),
        ("/tf", "tf"),
    )
    assert parse_robot(ONE_BOARD + "ros: {ros2: true, qos: }\n", "r.yaml").ros2_qos == ()


@pytest.mark.parametrize(
    ("section", "said"),
    [
        (
            "ros:\n  qos:\n    /x/imu: fast\n",
            "r.yaml:6: ros: qos: /x/imu: unknown QoS kind 'fast'; "
            "known: reliable, sensor, tf, latched",
        ),
        ("ros:\n  qos:\n    /x/imu: 3\n", "r.yaml:6: ros: qos: /x/imu: 3 is no QoS kind"),
        ("ros:\n  qos:\n    x/imu: sensor\n", "r.yaml:6: ros: qos: topic pattern 'x/imu' must"),
        ("ros:\n  qos:\n    '/x/[ab': sensor\n", "r.yaml:6: ros: qos: topic pattern '/x/[ab'"),
        ("ros:\n  qos:\n    /x y: sensor\n", "r.yaml:6: ros: qos: topic pattern '/x y' has"),
        ("ros:\n  qos: [/x/imu]\n", "r.yaml:5: ros: qos must be a mapping"),
        (
            "ros:\n  qos:\n    /x/imu: sensor\n    /x/imu: tf\n",
            "r.yaml:7: ros: qos: '/x/imu' is given twice",
        ),
        ("ros: {qso: {}}\n", "ros: unknown key 'qso' (did you mean 'qos'?)"),
    ],
)
def test_bad_qos_rules_name_their_line(section: str, said: str) -> None:
    found = _problems(ONE_BOARD + section)
    assert any(said in p for p in found), found


def test_robot_check_and_show_carry_the_qos_rules(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from hwbridge.cli import main

    path = tmp_path / "r.yaml"
    path.write_text(ONE_BOARD + "ros: {ros2: true, qos: {/x/imu: sensor, '/x/*': latched}}\n")
    assert main(["robot", "check", str(path)]) == 0
    assert "ROS 2 QoS /x/imu=sensor, /x/*=latched" in capsys.readouterr().out
    assert main(["robot", "show", str(path)]) == 0
    shown = capsys.readouterr().out
    assert yaml.safe_load(shown)["ros"]["qos"] == {"/x/imu": "sensor", "/x/*": "latched"}
    path.write_text(shown)
    assert load_robot(path).ros2_qos == (("/x/imu", "sensor"), ("/x/*", "latched"))


def _cli(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hwbridge", *argv],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**os.environ, "HWBRIDGE_ENDPOINT": "tcp/127.0.0.1:1", "COLUMNS": "300"},
    )


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--ros2", "--ros2-qos", "/diffbot/imu=fast"], "unknown QoS kind 'fast'"),
        (["--ros2", "--ros2-qos", "/diffbot/imu"], "write PATTERN=KIND"),
        (["--ros2", "--ros2-qos", "diffbot/*=sensor"], "must be a full name"),
        (["--ros2-qos", "/diffbot/imu=sensor"], "the ROS 2 gateway is not started"),
    ],
)
def test_up_ros2_qos_usage_errors(argv: list[str], said: str) -> None:
    robot = Path(__file__).resolve().parents[2] / "examples" / "robots" / "diffbot.yaml"
    done = _cli("up", str(robot), "--link", "base=socket://127.0.0.1:1", *argv)
    assert done.returncode == 2, done.stderr
    assert said in done.stderr
    assert "--ros2-qos" in done.stderr


def test_ros2_qos_usage_error() -> None:
    done = _cli("ros2", "--qos", "/diffbot/imu=best_effort")
    assert done.returncode == 2, done.stderr
    assert "unknown QoS kind 'best_effort'" in done.stderr


# The robot file says imu sensor, odom latched, cmd_vel reliable; the command line says imu
# reliable (it wins) and range sensor; joint_states has no rule.
FILE_RULES = {"/diffbot/imu": "sensor", "/diffbot/odom": "latched", "/diffbot/cmd_vel": "reliable"}
COMMAND_LINE = ["--ros2-qos", "/diffbot/imu=reliable", "--ros2-qos", "/diffbot/r*=sensor"]
DOMAIN = str((int(DOMAIN_ID) + 45) % 90 + 10)  # not test_ros2.py's, should both be up


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Robot]:
    running = Robot(tmp_path_factory.mktemp("ros2qosrules"), ros2_env(DOMAIN))
    try:
        running.up(*COMMAND_LINE, ros={"ros2": True, "qos": FILE_RULES})
        running.wait_log("up", "starting 'hwbridge ros2' (the robot file's")
        for topic in ("/diffbot/imu", "/diffbot/odom", "/diffbot/range", "/diffbot/cmd_vel"):
            running.wait_log("up", f"{topic}: ")
        yield running
    finally:
        running.stop()


def _offered(robot: Robot, *topics: str) -> dict[str, set[tuple[str, str, str]]]:
    """Topic -> (kind, reliability, durability) of the gateway's endpoints on it."""
    done = peer("qos", *topics, env=ros2_env(DOMAIN))
    assert done.returncode == 0, done.stdout + done.stderr + robot.log("up")
    found: dict[str, set[tuple[str, str, str]]] = {}
    for line in done.stdout.splitlines():
        e = json.loads(line)
        found.setdefault(e["topic"], set()).add((e["kind"], e["reliability"], e["durability"]))
    return found


@needs_rclpy
def test_the_robot_files_qos_rules_reach_ros2(robot: Robot) -> None:
    found = _offered(robot, "/diffbot/odom", "/diffbot/cmd_vel", "/diffbot/joint_states")
    assert found == {
        "/diffbot/odom": {("publisher", "reliable", "transient_local")},
        "/diffbot/cmd_vel": {("subscription", "reliable", "volatile")},
        "/diffbot/joint_states": {("publisher", "reliable", "volatile")},  # no rule: default
    }


@needs_rclpy
def test_up_ros2_qos_rules_reach_ros2_before_the_files(robot: Robot) -> None:
    found = _offered(robot, "/diffbot/imu", "/diffbot/range")
    assert found == {
        "/diffbot/imu": {("publisher", "reliable", "volatile")},  # the file said sensor
        "/diffbot/range": {("publisher", "best_effort", "volatile")},
    }
