"""``hwbridge up``: the example robots against the emulator, in real processes.

As a user would: ``hwbridge emulate ... --tcp PORT`` in one process, ``hwbridge up ROBOT.yaml
--link NAME=URL`` in another, and the CLI tools in more.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from tests.netutil import free_port, reap, wait_until

ROOT = Path(__file__).resolve().parents[2]
DIFFBOT = ROOT / "examples" / "robots" / "diffbot.yaml"
DXL_ARM = ROOT / "examples" / "robots" / "dxl_arm.yaml"


class Processes:
    """Background hwbridge processes on one graph endpoint, stopped at the end."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.env = {**os.environ, "HWBRIDGE_ENDPOINT": endpoint, "HWBRIDGE_DOMAIN": "up"}
        self.running: list[tuple[subprocess.Popen[str], Path]] = []

    def start(self, name: str, *argv: str) -> tuple[subprocess.Popen[str], Path]:
        log = self.tmp / f"{name}.log"
        process = subprocess.Popen(
            [sys.executable, "-m", "hwbridge", *argv],
            env=self.env,
            stdout=subprocess.PIPE,
            stderr=log.open("w"),
            text=True,
        )
        self.running.append((process, log))
        return process, log

    def emulate(self, *argv: str) -> str:
        """Start ``hwbridge emulate ARGV``; the URL it prints first."""
        process, log = self.start("emulate", "emulate", *argv)
        assert process.stdout is not None
        url = process.stdout.readline().strip()
        assert url, log.read_text()
        return url

    def cli(self, *argv: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "hwbridge", *argv],
            env=self.env,
            capture_output=True,
            text=True,
            timeout=timeout,
            check=False,
        )

    def stop(self) -> None:
        for process, _log in reversed(self.running):
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        for process, log in self.running:
            if not reap(process):
                pytest.fail(f"{process.args} did not stop on SIGINT:\n{log.read_text()}")


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Processes]:
    running = Processes(tmp_path)
    yield running
    running.stop()


def _echo(procs: Processes, topic: str) -> dict[str, object]:
    done = procs.cli("topic", "echo", topic, "-n", "1", "--json", "--timeout", "30")
    assert done.returncode == 0, done.stderr
    value: dict[str, object] = json.loads(done.stdout.splitlines()[0])
    return value


def test_diffbot_up_against_the_emulator(procs: Processes) -> None:
    port = free_port()
    url = procs.emulate("diffbot", "--tcp", str(port))
    assert url == f"socket://127.0.0.1:{port}"
    up, log = procs.start("up", "up", str(DIFFBOT), "--link", f"base={url}")
    assert wait_until(lambda: "robot diffbot up" in log.read_text(), 30), log.read_text()

    odom = _echo(procs, "/diffbot/odom")
    assert odom["child_frame_id"]
    assert _echo(procs, "/diffbot/range")["radiation_type"] == 0  # ULTRASOUND
    imu = _echo(procs, "/diffbot/imu")
    assert abs(imu["linear_acceleration"]["z"] - 9.8) < 1.0  # type: ignore[index]
    joints = _echo(procs, "/diffbot/joint_states")
    assert joints["name"] == ["pan"]

    hz = procs.cli("topic", "hz", "/diffbot/odom", "--duration", "2.5", "--json")
    assert hz.returncode == 0, hz.stderr
    assert hz.stdout.strip(), "topic hz printed no rate"

    start = odom["pose"]["pose"]["position"]["x"]  # type: ignore[index]
    drive = procs.start(
        "pub",
        "topic",
        "pub",
        "-r",
        "10",
        "/diffbot/cmd_vel",
        "geometry_msgs/Twist",
        "{linear: {x: 0.2}}",
    )[0]
    try:
        moved = [0.0]

        def has_moved() -> bool:
            now = _echo(procs, "/diffbot/odom")["pose"]["pose"]["position"]["x"]  # type: ignore[index]
            moved[0] = float(now) - float(start)
            return moved[0] > 0.1

        assert wait_until(has_moved, 30, step=0.5), moved
    finally:
        drive.send_signal(signal.SIGINT)
        drive.wait(10)
    assert up.poll() is None, log.read_text()


def test_a_flag_overrides_the_robot_files_ros_section(procs: Processes, tmp_path: Path) -> None:
    """The file asks for the ROS 1 gateway, --no-ros1 says no: the robot comes up without it."""
    robot = yaml.safe_load(DIFFBOT.read_text())
    robot["ros"] = {"ros1": True}
    robot_file = tmp_path / "diffbot_ros1.yaml"
    robot_file.write_text(yaml.safe_dump(robot))
    url = procs.emulate("diffbot", "--tcp", str(free_port()))
    up, log = procs.start("up", "up", str(robot_file), "--link", f"base={url}", "--no-ros1")
    assert wait_until(lambda: "robot diffbot up" in log.read_text(), 30), log.read_text()
    _echo(procs, "/diffbot/odom")  # up for a while: the gateway would have been started by now
    assert "starting 'hwbridge ros1'" not in log.read_text(), log.read_text()
    assert up.poll() is None, log.read_text()


def test_dxl_arm_up_against_the_emulated_bus(procs: Processes) -> None:
    url = procs.emulate("dxl-bus")
    up, log = procs.start("up", "up", str(DXL_ARM), "--link", f"arm={url}")
    assert wait_until(lambda: "robot dxl_arm up" in log.read_text(), 30), log.read_text()
    arm = yaml.safe_load(DXL_ARM.read_text())["host_devices"][0]
    namespace = arm.get("namespace", "/")
    first = _echo(procs, f"{namespace}/joint_states")
    joint = first["name"][0]  # type: ignore[index]
    goal = 1.0 if abs(first["position"][0] - 1.0) > 0.3 else -1.0  # type: ignore[index]
    torque = procs.cli("service", "call", f"{namespace}/torque_enable", "{data: true}")
    assert torque.returncode == 0, torque.stderr
    assert yaml.safe_load(torque.stdout)["success"] is True
    command = json.dumps({"name": [joint], "position": [goal]})
    pub = procs.start(
        "pub",
        "topic",
        "pub",
        "-r",
        "5",
        f"{namespace}/joint_command",
        "sensor_msgs/JointState",
        command,
    )[0]
    try:
        position = [float("nan")]

        def arrived() -> bool:
            state = _echo(procs, f"{namespace}/joint_states")
            names = state["name"]  # only the joints that answered this read of the bus
            if joint not in names:  # type: ignore[operator]
                return False
            position[0] = state["position"][names.index(joint)]  # type: ignore[index,union-attr]
            return abs(position[0] - goal) < 0.05

        assert wait_until(arrived, 30, step=0.5), position
    finally:
        pub.send_signal(signal.SIGINT)
        pub.wait(10)
    assert up.poll() is None, log.read_text()


def _robot(tmp: Path, device: str, link: str = "pty://") -> Path:
    """A one-board robot file whose only device entry (line 6) is ``device``."""
    path = tmp / "robot.yaml"
    path.write_text(
        f"robot: bad\nboards:\n  - name: base\n    link: {link}\n    devices:\n      {device}\n"
    )
    return path


@pytest.mark.parametrize(
    ("devices", "line", "says"),
    [
        ("- type: lidar9000", 6, "lidar9000"),
        ("- {type: hcsr04, rate: fast}", 6, "rate"),
        ("- {type: diffdrive, wheel_radius: -1}", 6, "wheel_radius"),
        ("- {rate: 5}", 6, "type"),
    ],
)
def test_bad_robot_files_give_one_line_errors(
    procs: Processes, tmp_path: Path, devices: str, line: int, says: str
) -> None:
    path = _robot(tmp_path, devices)
    done = procs.cli("up", str(path))
    assert done.returncode == 1, done.stdout + done.stderr
    assert "Traceback" not in done.stderr
    errors = [e for e in done.stderr.splitlines() if e.startswith("error:")]
    assert errors, done.stderr
    assert errors[0].startswith(f"error: {path}:{line}: "), errors
    assert says in errors[0]


def test_a_link_that_does_not_open_is_an_error_with_its_line(
    procs: Processes, tmp_path: Path
) -> None:
    path = _robot(tmp_path, "- {type: hcsr04}", link="/dev/ttyNOTHERE0")
    done = procs.cli("up", str(path))
    assert done.returncode == 1, done.stdout + done.stderr
    assert "Traceback" not in done.stderr
    (error,) = [e for e in done.stderr.splitlines() if e.startswith("error:")]
    assert re.match(
        rf"error: {re.escape(str(path))}:[34]: board base: link /dev/ttyNOTHERE0 does "
        "not open: ",
        error,
    ), error
