"""Robot files stay honest: two devices that would publish one topic are refused with both lines,
a ``--link`` URL that takes no baud rate gets a note naming the file's ``baud`` line instead of
failing, and ``hwbridge robot check`` and ``hwbridge up`` give the same verdict and the same
messages on every robot file (real processes, real robot files, the real emulator).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from hwbridge.robot import registry
from hwbridge.robot.config import load_robot
from hwbridge.robot.model import RobotFileError
from tests.cliutil import run_hwbridge
from tests.netutil import free_port, reap, wait_until

ROOT = Path(__file__).resolve().parents[2]
PLUGINS = ROOT / "tests" / "plugins"
GOOD_FILES = sorted((ROOT / "examples" / "robots").glob("*.yaml")) + sorted(
    (ROOT / "hwbridge" / "emulator" / "robots").glob("*.yaml")
)

ROVER = """\
robot: rover
boards:
  - name: base
    link: /dev/ttyACM0
    namespace: /rover
    devices:
      - type: hcsr04
        name: front
      - type: hcsr04
        name: rear
"""


def _run(
    *argv: str, cwd: Path | None = None, timeout: float = 60
) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "HWBRIDGE_ENDPOINT": f"tcp/127.0.0.1:{free_port()}"}
    return run_hwbridge(*argv, timeout=timeout, env=env, cwd=cwd)


def _errors(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith(("error:", "note:"))]


def test_two_sonars_on_one_topic_are_refused_with_both_lines(tmp_path: Path) -> None:
    robot = tmp_path / "rover.yaml"
    robot.write_text(ROVER)
    done = _run("robot", "check", str(robot))
    assert done.returncode == 1, done.stdout + done.stderr
    assert _errors(done.stderr) == [
        f"error: {robot}:9: board base: rear: would publish /rover/sonar_echo and /rover/range, "
        "as board base: front at line 7 does: two devices cannot share one; give one of them "
        "other topic names in its settings"
    ]
    # other topic names: fine
    robot.write_text(ROVER + "        topic: rear_echo\n        range_topic: rear_range\n")
    done = _run("robot", "check", str(robot))
    assert done.returncode == 0, done.stderr


WHEELS = "{type: diffdrive, wheel_radius: 0.03, wheel_separation: 0.2, counts_per_rev: 1000}"


def test_host_devices_and_namespaces_are_part_of_the_check(tmp_path: Path) -> None:
    """A board device and a host device in one namespace clash; the same devices in two
    namespaces do not, nor do two publishers of /tf (meant to have many)."""
    text = (
        "robot: arm_rover\n"
        "boards:\n"
        "  - name: left\n"
        "    link: /dev/ttyACM0\n"
        "    namespace: /rover\n"
        "    devices:\n"
        "      - {type: dynamixel, state_topic: joint_states, bus: {servos: [{id: 1, model: "
        "XL430-W250}]}}\n"
        "  - name: right\n"
        "    link: /dev/ttyACM1\n"
        "    namespace: /rover/right\n"
        "    devices:\n"
        f"      - {WHEELS}\n"
        "  - name: other\n"
        "    link: /dev/ttyACM2\n"
        "    namespace: /rover/other\n"
        "    devices:\n"
        f"      - {WHEELS}\n"
        "host_devices:\n"
        "  - type: dynamixel_bus\n"
        "    name: arm\n"
        "    link: /dev/ttyUSB0\n"
        "    namespace: /rover\n"
        "    joints: {shoulder: 1}\n"
    )
    robot = tmp_path / "arm_rover.yaml"
    robot.write_text(text)
    with pytest.raises(RobotFileError) as caught:
        load_robot(robot)
    assert caught.value.problems == [
        f"{robot}:19: host device arm (dynamixel_bus): would publish /rover/joint_states, as "
        "board left: dynamixel at line 7 does: two devices cannot share one; give one of them "
        "other topic names in its settings"
    ]
    robot.write_text(text.replace("namespace: /rover\n    joints", "namespace: /arm\n    joints"))
    assert len(load_robot(robot).boards) == 3


@pytest.fixture
def thermo_installed(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.syspath_prepend(str(PLUGINS))
    registry.refresh()
    yield
    monkeypatch.undo()
    registry.refresh()


def test_a_plugin_that_does_not_name_its_topics_is_left_out(
    thermo_installed: None, tmp_path: Path
) -> None:
    """The test plugin ``thermo`` says nothing of its topics: two of them on one board are not
    refused, while two sonars on the same board are."""
    robot = tmp_path / "greenhouse.yaml"
    robot.write_text(
        ROVER.replace("robot: rover", "robot: greenhouse")
        + "      - {type: thermo, rate: 20}\n"
        + "      - {type: thermo, rate: 20}\n"
    )
    with pytest.raises(RobotFileError) as caught:
        load_robot(robot)
    assert [p.split(": ", 2)[1] for p in caught.value.problems] == ["board base"]
    assert caught.value.problems[0].startswith(f"{robot}:9: board base: rear: would publish")


class Emulators:
    """``hwbridge emulate`` processes serving a robot's boards and servo buses."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.running: list[subprocess.Popen[str]] = []

    def start(self, *argv: str) -> str:
        """The URL the emulator prints first."""
        process = subprocess.Popen(
            [sys.executable, "-m", "hwbridge", "emulate", *argv],
            stdout=subprocess.PIPE,
            stderr=(self.tmp / f"emulate-{len(self.running)}.log").open("w"),
            text=True,
        )
        self.running.append(process)
        assert process.stdout is not None
        url = process.stdout.readline().strip()
        assert url, f"hwbridge emulate {argv} printed no URL"
        return url

    def links(self, robot_file: Path) -> list[str]:
        """``--link`` options pointing every board and host device of a robot file at an
        emulator (a MAVLink vehicle at a UDP port of its own)."""
        robot = load_robot(robot_file)
        links = [
            f"{b.name}={self.start(str(robot_file), '--board', b.name, '--tcp', '0')}"
            for b in robot.boards
        ]
        for host in robot.host_devices:
            if host.device.type == "dynamixel_bus":
                links.append(f"{host.device.name}={self.start('dxl-bus')}")
            elif host.device.type == "mavlink_vehicle":
                links.append(f"{host.device.name}=mavlink://udpin:127.0.0.1:{free_port()}")
            else:
                raise AssertionError(f"no emulator for {host.device.type}")
        return [arg for link in links for arg in ("--link", link)]

    def stop(self) -> None:
        for process in self.running:
            process.send_signal(signal.SIGINT)
        for process in self.running:
            reap(process)


@pytest.fixture
def emulators(tmp_path: Path) -> Iterator[Emulators]:
    running = Emulators(tmp_path)
    yield running
    running.stop()


@dataclass
class Up:
    """How ``hwbridge up`` went: its exit status (None: it came up and was stopped) and its
    notes and errors."""

    returncode: int | None
    messages: list[str]


def _up(tmp: Path, robot_file: Path, links: list[str]) -> Up:
    """``hwbridge up`` until it exits or says the robot is up (then Ctrl-C)."""
    log = tmp / f"up-{robot_file.stem}.log"
    env = {**os.environ, "HWBRIDGE_DOMAIN": "honest"}
    listen = f"tcp/127.0.0.1:{free_port()}"
    with log.open("w") as out:
        process = subprocess.Popen(
            [sys.executable, "-m", "hwbridge", "up", str(robot_file), *links, "--listen", listen],
            stdout=subprocess.DEVNULL,
            stderr=out,
            text=True,
            env=env,
        )
        try:
            came_up = wait_until(
                lambda: process.poll() is not None or " up on " in log.read_text(), 60, 0.05
            )
            assert came_up, log.read_text()
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
                process.wait(30)
                return Up(None, _errors(log.read_text()))
            return Up(process.returncode, _errors(log.read_text()))
        finally:
            if process.poll() is None:
                process.kill()
                process.wait(5)


BAD_FILES: dict[str, tuple[str, list[str]]] = {
    "two_sonars": (ROVER, []),
    "unknown_key": (ROVER.replace("namespace: /rover", "namespace: /rover\n    bawd: 9600"), []),
    "bad_setting": (ROVER.replace("name: rear", "name: rear\n        rate: fast"), []),
    "baud_on_socket": (
        ROVER.replace("/dev/ttyACM0", "socket://127.0.0.1:1\n    baud: 57600").replace(
            "name: rear", "name: rear\n        range_topic: rear_range\n        topic: rear_echo"
        ),
        [],
    ),
    "bad_link_override": (
        ROVER.replace("name: rear", "name: rear\n        topic: rear"),
        [
            "--link",
            "base=nonsense://here",
        ],
    ),
    "unknown_link_name": (
        ROVER.replace("name: rear", "name: rear\n        topic: rear"),
        [
            "--link",
            "bass=socket://127.0.0.1:1",
        ],
    ),
}


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_check_and_up_refuse_a_bad_file_alike(name: str, tmp_path: Path) -> None:
    text, links = BAD_FILES[name]
    robot_file = tmp_path / f"{name}.yaml"
    robot_file.write_text(text)
    check = _run("robot", "check", str(robot_file), *links)
    assert check.returncode == 1, check.stdout + check.stderr
    messages = _errors(check.stderr)
    assert messages and all(str(robot_file) in m for m in messages), check.stderr
    up = _up(tmp_path, robot_file, links)
    assert up == Up(1, messages)


@pytest.mark.parametrize("robot_file", GOOD_FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_check_and_up_accept_every_shipped_robot_alike(
    robot_file: Path, emulators: Emulators, tmp_path: Path
) -> None:
    links = emulators.links(robot_file)
    check = _run("robot", "check", str(robot_file), *links)
    assert check.returncode == 0, check.stderr
    up = _up(tmp_path, robot_file, links)
    assert up == Up(None, _errors(check.stderr))


def test_a_baud_that_the_link_given_does_not_take_is_a_note(
    emulators: Emulators, tmp_path: Path
) -> None:
    """The robot's serial board has ``baud: 57600``; ``--link base=socket://...`` (the
    emulator) has no baud rate: check and up say so, naming the line, and the robot comes up."""
    text = (ROOT / "examples" / "robots" / "diffbot.yaml").read_text()
    text = text.replace("    link: /dev/ttyACM0\n", "    link: /dev/ttyACM0\n    baud: 57600\n", 1)
    robot_file = tmp_path / "diffbot.yaml"
    robot_file.write_text(text)
    line = text.splitlines().index("    baud: 57600") + 1
    url = emulators.start(str(robot_file), "--tcp", "0")
    note = f"note: {robot_file}:{line}: baud 57600 does not apply to {url}; ignored"
    check = _run("robot", "check", str(robot_file), "--link", f"base={url}")
    assert check.returncode == 0, check.stderr
    assert _errors(check.stderr) == [note]
    assert _up(tmp_path, robot_file, ["--link", f"base={url}"]) == Up(None, [note])
    # a serial link keeps it: no note
    check = _run("robot", "check", str(robot_file), "--link", "base=serial:///dev/ttyS9")
    assert check.returncode == 0 and _errors(check.stderr) == [], check.stderr
