"""Robot files: read, checked, every problem reported with its file and line."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from hwbridge.errors import HwBridgeError
from hwbridge.robot.config import load_robot, parse_robot
from hwbridge.robot.model import RobotFileError

ROOT = Path(__file__).resolve().parents[2]

GOOD = """\
robot: bot
boards:
  - name: base
    link: serial:///dev/ttyACM0?baud=57600
    namespace: /bot
    protocol: rosserial
    devices:
      - {type: hcsr04, rate: 10}
      - {type: hcsr04, topic: rear_echo, range_topic: rear_range}
host_devices:
  - {type: dynamixel_bus, name: arm, link: /dev/ttyUSB0, baud: 1000000, joints: {a: 1}}
"""


def problems(text: str) -> list[str]:
    with pytest.raises(RobotFileError) as info:
        parse_robot(text, "r.yaml")
    return info.value.problems


def test_a_good_file_with_defaults_filled_in() -> None:
    robot = parse_robot(GOOD, "r.yaml")
    (board,) = robot.boards
    assert (board.name, board.namespace, board.protocol) == ("base", "/bot", "rosserial")
    first, second = board.devices
    assert (first.name, second.name) == ("hcsr04", "hcsr04_2")  # repeats are numbered
    assert first.settings["rate"] == 10.0 and isinstance(first.settings["rate"], float)
    assert first.settings["topic"] == "sonar_echo"  # a default
    assert first.source == "r.yaml:8"
    (arm,) = robot.host_devices
    assert (arm.device.name, arm.link, arm.baud) == ("arm", "/dev/ttyUSB0", 1000000)
    assert arm.device.settings["protocol"] == 2


def test_every_problem_is_reported_with_its_line() -> None:
    text = (
        "robot: bot\n"  # 1
        "colour: red\n"  # 2
        "boards:\n"  # 3
        "  - name: base\n"  # 4
        "    link: socket://host:notaport\n"  # 5
        "    protocol: morse\n"  # 6
        "    devices:\n"  # 7
        "      - {type: lidar9000}\n"  # 8
        "      - {type: hcsr04, rate: fast, colour: 1}\n"  # 9
        "      - {type: diffdrive, wheel_radius: 0.03}\n"  # 10
        "      - {type: mpu6050, accel_range_g: 3}\n"  # 11
        "      - {type: dynamixel_bus, joints: {a: 1}}\n"  # 12
        "      - rate: 3\n"  # 13
    )
    found = problems(text)
    lines = {p.split(":")[1] for p in found}
    assert {"2", "5", "6", "8", "9", "10", "11", "12", "13"} <= lines, found
    text_of = "\n".join(found)
    assert "unknown key 'colour'" in text_of
    assert "notaport" in text_of
    assert "unknown protocol 'morse'" in text_of
    assert "unknown device type 'lidar9000'" in text_of
    assert "rate: expected a number, got 'fast'" in text_of
    assert "missing setting 'wheel_separation'" in text_of
    assert "accel_range_g: must be one of 2, 4, 8, 16, not 3" in text_of
    assert "list it under host_devices" in text_of
    assert "missing 'type'" in text_of


@pytest.mark.parametrize(
    ("text", "said"),
    [
        (
            "robot: x\nboards:\n  - {name: a, link: 'pty://'}\n  - {name: a, link: 'pty://'}\n",
            "two",
        ),
        ("robot: x\nboards: [\n", "not valid YAML"),
        ("", "empty"),
        ("- 1\n- 2\n", "must be a mapping"),
        ("robot: x\n", "no boards"),
        ("robot: x\nboards:\n  - {name: 'b-1', link: 'pty://'}\n", "letters, digits and _"),
        ("robot: x\nboards:\n  - {name: b, link: 'pty://', namespace: 'bad name'}\n", "namespace"),
        ("robot: x\nboards:\n  - {name: b, link: 'pty://', baud: -5}\n", "baud"),
        ("robot: x\nboards:\n  - {name: b, link: 'pty://', service_timeout: 0}\n", "timeout"),
        ("robot: x\nhost_devices:\n  - {type: hcsr04, name: s, link: 'pty://'}\n", "board"),
    ],
)
def test_bad_files(text: str, said: str) -> None:
    found = problems(text)
    assert any(said in p for p in found), found
    assert all(p.startswith("r.yaml:") for p in found)


def test_missing_and_non_utf8_files(tmp_path: Path) -> None:
    with pytest.raises(RobotFileError, match="no such robot file"):
        load_robot(tmp_path / "nope.yaml")
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(b"robot: \xff\xfe\n")
    with pytest.raises(RobotFileError, match="not a text file"):
        load_robot(binary)


def test_with_links_overrides_by_name() -> None:
    robot = parse_robot(GOOD, "r.yaml").with_links({"base": "socket://h:1", "arm": "/dev/ttyS9"})
    assert robot.boards[0].link == "socket://h:1"
    assert robot.host_devices[0].link == "/dev/ttyS9"
    with pytest.raises(HwBridgeError, match="--link names nosuch"):
        robot.with_links({"nosuch": "pty://"})


@pytest.mark.parametrize("name", ["diffbot.yaml", "dxl_arm.yaml"])
def test_the_examples_check(name: str) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "robot", "check", str(ROOT / "examples/robots" / name)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert f"robot {name.removesuffix('.yaml')}" in done.stdout


def test_robot_check_prints_each_problem_and_exits_1(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(
        "robot: bad\nboards:\n  - name: b\n    link: pty://\n    devices:\n"
        "      - {type: hcsr04, rate: fast}\n      - {type: nosuch}\n"
    )
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "robot", "check", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 1
    assert "Traceback" not in done.stderr
    errors = done.stderr.splitlines()
    assert errors[0].startswith(f"error: {path}:6: ")
    assert errors[1].startswith(f"error: {path}:7: ")
