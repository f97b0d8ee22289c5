"""Robot files: read, checked, every problem reported with its file and line."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from hwbridge.errors import HwBridgeError
from hwbridge.robot import registry
from hwbridge.robot.config import load_robot, parse_robot
from hwbridge.robot.model import Robot, RobotFileError
from hwbridge.robot.plugin import DevicePlugin, Field

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


ONE_BOARD = "robot: x\nboards:\n  - {name: b, link: 'pty://'}\n"


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
        (f"{ONE_BOARD}ros: {{ros2: 1}}\n", "r.yaml:4: ros: ros2 must be true or false, not 1"),
        (f"{ONE_BOARD}ros: [ros2]\n", "ros must be a mapping"),
        (f"{ONE_BOARD}ros: {{ros3: true}}\n", "ros: unknown key 'ros3' (did you mean 'ros2'?)"),
    ],
)
def test_bad_files(text: str, said: str) -> None:
    found = problems(text)
    assert any(said in p for p in found), found
    assert all(p.startswith("r.yaml:") for p in found)


@pytest.mark.parametrize(
    ("section", "ros2", "ros1"),
    [
        ("", False, False),
        ("ros:\n", False, False),
        ("ros: {ros1: true}\n", False, True),
        ("ros:\n  ros2: true\n  ros1: false\n", True, False),
    ],
)
def test_the_ros_section_names_the_gateways_up_starts(section: str, ros2: bool, ros1: bool) -> None:
    robot = parse_robot(ONE_BOARD + section, "r.yaml")
    assert (robot.ros2, robot.ros1) == (ros2, ros1)


def test_robot_check_and_show_carry_the_ros_section(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from hwbridge.cli import main

    path = tmp_path / "r.yaml"
    path.write_text(ONE_BOARD + "ros: {ros2: true, ros1: true}\n")
    assert main(["robot", "check", str(path)]) == 0
    assert "'up' starts the ROS 2 and ROS 1 gateways" in capsys.readouterr().out
    assert main(["robot", "show", str(path)]) == 0
    shown = capsys.readouterr().out
    assert yaml.safe_load(shown)["ros"] == {"ros2": True, "ros1": True}
    path.write_text(shown)
    again = load_robot(path)  # show's output reads back
    assert (again.ros2, again.ros1) == (True, True)


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


# ----------------------------------------------------------------- with fake device plugins
# The checks above use the built-in plugins; these pin the checks themselves to plugins whose
# fields the tests own, registered through the public register_device.


class FakeSensor(DevicePlugin):
    type = "fake_sensor"
    summary = "a sensor for the tests"
    fields = (
        Field("pin", int, doc="the board pin", minimum=0, maximum=53),
        Field("rate", float, 10.0, minimum=0.1, maximum=100),
        Field("mode", str, "fast", choices=("fast", "slow")),
        Field("frame_id", str, "sensor"),
        Field("offsets", list, []),
    )


class FakeBus(DevicePlugin):
    type = "fake_bus"
    summary = "a host adapter for the tests"
    where = "host"
    fields = (Field("ids", dict), Field("rate", float, 50.0, minimum=1))


@pytest.fixture
def fakes() -> Iterator[None]:
    """fake_sensor, fake_bus and fake_broken (a plugin that fails to import), registered for
    the test and forgotten after it."""
    registry.register_device(FakeSensor)
    registry.register_device(FakeBus())
    registry.register_device("hwbridge_no_such_module_xyz:Plugin", "fake_broken")
    yield
    for name in ("fake_sensor", "fake_bus", "fake_broken"):
        registry.unregister_device(name)


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "robot.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def problems_in(path: Path) -> list[str]:
    with pytest.raises(RobotFileError) as info:
        load_robot(path)
    return info.value.problems


def line_numbers(path: Path, found: list[str]) -> list[int]:
    return [int(p.removeprefix(f"{path}:").split(":", 1)[0]) for p in found]


FAKE = """\
robot: fake
world: {room: [2, 3]}
boards:
  - name: base
    link: pty://
    namespace: fake
    devices:
      - {type: fake_sensor, pin: 3}
      - {type: fake_sensor, pin: 4, rate: 5, mode: slow}
      - {type: fake_sensor, name: left, pin: 5, offsets: [1, 2]}
      - {type: fake_sensor, pin: 6}
host_devices:
  - {type: fake_bus, name: bus, link: 'socket://127.0.0.1:9', ids: {a: 1}}
"""


def test_fake_plugins_settings_checked_and_defaults_filled(fakes: None, tmp_path: Path) -> None:
    robot = load_robot(write(tmp_path, FAKE))
    assert robot.name == "fake" and robot.world == {"room": [2, 3]}
    assert robot.path == tmp_path / "robot.yaml"
    (board,) = robot.boards
    assert board.namespace == "/fake"  # resolved as a graph name
    assert (board.protocol, board.baud, board.service_timeout, board.start_delay) == (
        "auto",
        None,
        5.0,
        0.0,
    )
    assert [d.name for d in board.devices] == [
        "fake_sensor",
        "fake_sensor_2",
        "left",
        "fake_sensor_4",
    ]
    first, second, third, _ = board.devices
    assert dict(first.settings) == {
        "pin": 3,
        "rate": 10.0,
        "mode": "fast",
        "frame_id": "sensor",
        "offsets": [],
    }
    assert second.settings["rate"] == 5.0 and isinstance(second.settings["rate"], float)
    assert second.settings["mode"] == "slow"
    assert third.settings["offsets"] == [1, 2]
    assert first.source == f"{tmp_path / 'robot.yaml'}:8"
    (bus,) = robot.host_devices
    assert (bus.device.type, bus.device.name, bus.link, bus.namespace) == (
        "fake_bus",
        "bus",
        "socket://127.0.0.1:9",
        "/",
    )
    assert dict(bus.device.settings) == {"ids": {"a": 1}, "rate": 50.0}


BOARD = "robot: fake\nboards:\n  - name: base\n    link: pty://\n    devices:\n"  # lines 1-5


@pytest.mark.parametrize(
    ("device", "said"),
    [
        ("{type: lidar9000}", "unknown device type 'lidar9000'; use one of"),
        ("{type: fake_sensor}", "fake_sensor: missing setting 'pin' (the board pin)"),
        ("{type: fake_sensor, pin: 1, rate: fast}", "rate: expected a number, got 'fast'"),
        ("{type: fake_sensor, pin: 1, rate: true}", "rate: expected a number, got True"),
        ("{type: fake_sensor, pin: 1.5}", "pin: expected a whole number, got 1.5"),
        ("{type: fake_sensor, pin: 1, rate: 500}", "rate: must be at most 100, not 500"),
        ("{type: fake_sensor, pin: -1}", "pin: must be at least 0, not -1"),
        ("{type: fake_sensor, pin: 1, mode: turbo}", "mode: must be one of 'fast', 'slow'"),
        ("{type: fake_sensor, pin: 1, rate: .nan}", "expected a finite number"),
        ("{type: fake_sensor, pin: 1, offsets: 3}", "offsets: expected a list, got 3"),
        ("{type: fake_sensor, pin: 1, rate: !!float abc}", "rate: YAML cannot read this value"),
        (
            "{type: fake_sensor, pin: 1, rat: 3}",
            "unknown key 'rat' (did you mean 'rate'?); known: type, name, pin, rate, mode, "
            "frame_id, offsets, only_on",
        ),
        (
            "{type: fake_broken}",
            "the device type 'fake_broken' is provided by hwbridge_no_such_module_xyz:Plugin, "
            "which failed to load: No module named",
        ),
        ("{type: fake_bus, ids: {}}", "a host device: list it under host_devices"),
        ("{name: x}", "missing 'type'"),
        ("[fake_sensor]", "must be a mapping"),
    ],
)
def test_one_device_problem_at_its_line(
    fakes: None, tmp_path: Path, device: str, said: str
) -> None:
    path = write(tmp_path, BOARD + f"      - {{type: fake_sensor, pin: 2}}\n      - {device}\n")
    (problem,) = problems_in(path)
    assert problem.startswith(f"{path}:7: board base: "), problem
    assert said in problem, problem


@pytest.mark.parametrize(
    ("text", "line", "said"),
    [
        (BOARD.replace("    link: pty://\n", ""), 3, "board base: missing 'link'"),
        (BOARD.replace("pty://", "socket://host"), 4, "link: 'socket://host' has no port"),
        (BOARD.replace("pty://", "frob://x"), 4, "link: unknown link scheme 'frob'"),
        (BOARD.replace("pty://", "tcp-listen://:99999"), 4, "bad port"),
        (BOARD.replace("pty://", "serial:///dev/ttyS0?baud=fast"), 4, "option 'baud'"),
        (BOARD + "    lnk: 3\n", 6, "unknown key 'lnk' (did you mean 'link'?); known: name, link"),
        (BOARD.replace("robot:", "robt:"), 1, "unknown key 'robt' (did you mean 'robot'?)"),
        (BOARD + "    protocol: morse\n", 6, "protocol: unknown protocol 'morse'"),
        (BOARD + "    baud: 0\n", 6, "baud: expected a whole number above 0, got 0"),
        (BOARD + "    start_delay: -1\n", 6, "start_delay: expected seconds"),
        (BOARD + "    service_timeout: 0\n", 6, "service_timeout: service timeout must be"),
        (BOARD + "    namespace: 'a b'\n", 6, "namespace:"),
        (BOARD + "world: 3\n", 6, "world must be a mapping"),
        (BOARD + "      - {type: fake_sensor, pin: 1\n", 7, "not valid YAML"),
        (BOARD + "\tbad: tab\n", 6, "not valid YAML"),
        (
            "robot: fake\nhost_devices:\n  - {type: fake_sensor, name: s, link: 'pty://'}\n",
            3,
            "a board device: list it under a board's devices",
        ),
        (
            "robot: fake\nhost_devices:\n  - {type: fake_bus, link: 'pty://', ids: {}}\n",
            3,
            "missing 'name'",
        ),
        (
            "robot: fake\nhost_devices:\n  - {type: fake_bus, name: b, ids: {}}\n",
            3,
            "missing 'link'",
        ),
        (
            "robot: fake\nhost_devices:\n  - {type: fake_bus, name: b, link: 'x://'}\n",
            3,
            "missing setting 'ids'",
        ),
        ("robot: fake\n", 1, "no boards and no host_devices"),
        (
            "boards: []\nhost_devices:\n  - {type: fake_bus, name: b, link: 'pty://', ids: {}}\n",
            1,
            "missing 'robot'",
        ),
    ],
)
def test_one_problem_at_its_line(
    fakes: None, tmp_path: Path, text: str, line: int, said: str
) -> None:
    path = write(tmp_path, text)
    found = problems_in(path)
    assert any(p.startswith(f"{path}:{line}: ") and said in p for p in found), found


def test_duplicate_names(fakes: None, tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "robot: fake\n"  # 1
        "boards:\n"  # 2
        "  - name: base\n"  # 3
        "    link: pty://\n"  # 4
        "    devices:\n"  # 5
        "      - {type: fake_sensor, name: s, pin: 1}\n"  # 6
        "      - {type: fake_sensor, name: s, pin: 2}\n"  # 7
        "  - name: base\n"  # 8
        "    link: 'socket://nohost'\n"  # 9: a bad link does not hide the repeated name
        "host_devices:\n"  # 10
        "  - {type: fake_bus, name: base, link: 'pty://', ids: {}}\n",  # 11
    )
    found = problems_in(path)
    assert line_numbers(path, found) == [7, 8, 9, 11], found
    assert "two devices named 's' on board base" in found[0]
    assert "two boards or host devices named 'base' (the other is at line 3)" in found[1]
    assert "two boards or host devices named 'base' (the other is at line 3)" in found[3]


def test_several_problems_together_in_file_order(fakes: None, tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "robot: fake\n"  # 1
        "colour: red\n"  # 2  unknown top-level key
        "boards:\n"  # 3
        "  - name: base\n"  # 4
        "    baud: -1\n"  # 5  bad baud
        "    link: socket://h:port\n"  # 6  bad link
        "    devices:\n"  # 7
        "      - type: fake_sensor\n"  # 8  missing pin
        "        rate: fast\n"  # 9  wrong type
        "      - type: nosuch\n"  # 10 unknown type
        "      - type: fake_sensor\n"  # 11
        "        pin: 99\n"  # 12 out of range
        "        mood: 1\n"  # 13 unknown setting
        "host_devices:\n"  # 14
        "  - type: fake_broken\n"  # 15 fails to import
        "    name: arm\n"  # 16
        "  - type: fake_bus\n"  # 17
        "    name: bus\n"  # 18
        "    link: 'pty://'\n"  # 19
        "    ids: [1, 2]\n",  # 20 a list, not a mapping
    )
    found = problems_in(path)
    assert line_numbers(path, found) == [2, 5, 6, 8, 9, 10, 12, 13, 15, 20], found
    with pytest.raises(RobotFileError) as info:
        load_robot(path)
    assert str(info.value) == "\n".join(found)  # one line each


def test_not_utf8_and_missing(tmp_path: Path) -> None:
    path = tmp_path / "latin1.yaml"
    path.write_bytes("robot: caf\u00e9\n".encode("latin-1"))
    (problem,) = problems_in(path)
    assert problem.startswith(f"{path}: not a text file (UTF-8)")
    (problem,) = problems_in(tmp_path / "missing.yaml")
    assert problem == f"{tmp_path / 'missing.yaml'}: no such robot file"


def test_with_links_keeps_everything_else(fakes: None, tmp_path: Path) -> None:
    robot = load_robot(write(tmp_path, FAKE))
    moved = robot.with_links({"bus": "/dev/ttyUSB3"})
    assert moved.host_devices[0].link == "/dev/ttyUSB3"
    assert moved.boards == robot.boards
    assert moved.host_devices[0].device == robot.host_devices[0].device
    assert robot.host_devices[0].link == "socket://127.0.0.1:9"  # the original is unchanged
    with pytest.raises(HwBridgeError, match="--link names left, but the robot has base, bus"):
        robot.with_links({"left": "pty://"})  # a device on a board is not a link


def test_cli_in_process(fakes: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from hwbridge.cli import main

    path = write(tmp_path, FAKE)
    assert main(["robot", "check", str(path)]) == 0
    out = capsys.readouterr().out
    assert out == f"{path}: robot fake: 1 board (base: 4 devices), 1 host device\n"

    assert main(["robot", "show", str(path)]) == 0
    shown = yaml.safe_load(capsys.readouterr().out)
    assert shown["boards"][0]["devices"][0] == {
        "type": "fake_sensor",
        "name": "fake_sensor",
        "pin": 3,
        "rate": 10.0,
        "mode": "fast",
        "frame_id": "sensor",
        "offsets": [],
    }
    assert shown["host_devices"][0]["rate"] == 50.0
    assert shown["world"] == {"room": [2, 3]}
    again = load_robot(write(tmp_path, yaml.safe_dump(shown)))  # show's output reads back
    robot = load_robot(write(tmp_path, FAKE))

    def strip(r: Robot) -> list[object]:
        boards = [dataclasses.replace(b, source="", devices=()) for b in r.boards]
        devices = [(d.type, d.name, dict(d.settings)) for b in r.boards for d in b.devices]
        hosts = [
            (h.link, h.namespace, h.baud, h.device.name, dict(h.device.settings))
            for h in r.host_devices
        ]
        return [r.name, dict(r.world), boards, devices, hosts]

    assert strip(again) == strip(robot)

    path = write(tmp_path, BOARD + "      - {type: fake_broken}\n      - {type: fake_sensor}\n")
    assert main(["robot", "check", str(path)]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.splitlines() == [
        f"error: {path}:6: board base: device 1: the device type 'fake_broken' is provided by "
        "hwbridge_no_such_module_xyz:Plugin, which failed to load: No module named "
        "'hwbridge_no_such_module_xyz'; reinstall the package that provides it",
        f"error: {path}:7: board base: fake_sensor: missing setting 'pin' (the board pin)",
    ]


@pytest.mark.parametrize(
    ("args", "status", "said"),
    [
        (["robot", "check"], 2, "Missing argument"),
        (["robot", "check", "good.yaml", "bad.yaml"], 2, "unexpected extra argument"),
        (["robot", "check", "nope.yaml"], 2, "File 'nope.yaml' does not exist."),
        (["robot", "check", "good.yaml"], 0, ""),
        (["robot", "check", "bad.yaml"], 1, "error: bad.yaml:2: not valid YAML: mapping values"),
    ],
)
def test_robot_check_exit_status(tmp_path: Path, args: list[str], status: int, said: str) -> None:
    (tmp_path / "good.yaml").write_text("robot: r\nboards:\n  - {name: b, link: 'pty://'}\n")
    (tmp_path / "bad.yaml").write_text("robot: r\n  x: 1\nboards: []\n")
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", *args],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        cwd=tmp_path,
    )
    assert done.returncode == status, done.stderr
    assert said in done.stderr
    assert "Traceback" not in done.stderr
    if status == 0:
        assert done.stdout == "good.yaml: robot r: 1 board (b: 0 devices), 0 host devices\n"


@pytest.mark.parametrize(
    ("extra", "delay"),
    [
        ("", 0.0),
        ("    mcu: uno\n", 0.0),
        ("    mcu: mega\n", 2.0),
        ("    mcu: mega\n    start_delay: 0\n", 0.0),
    ],
)
def test_a_mega_board_waits_before_probing_unless_the_file_says(
    tmp_path: Path, extra: str, delay: float
) -> None:
    """A Mega's stk500v2 bootloader keeps the board while bytes come in after a reset, so a
    board with ``mcu: mega`` lets the sketch speak first (2 s) unless ``start_delay`` is given."""
    text = "robot: r\nboards:\n  - name: base\n    link: pty://\n" + extra
    (board,) = load_robot(write(tmp_path, text)).boards
    assert board.start_delay == delay
