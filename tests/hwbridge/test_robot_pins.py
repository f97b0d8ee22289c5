"""Pins in robot files: each wiring mistake ``hwbridge robot check`` reports against the board's
pin table, at the line of the offending value (the line marked ``# <-`` below), through the
function (load_robot) and through the real CLI (a subprocess)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from hwbridge.firmware.boards import MCU_BOARDS
from hwbridge.robot.config import load_robot
from hwbridge.robot.model import RobotFileError

ROOT = Path(__file__).resolve().parents[2]

HEAD = """\
robot: pinbot
boards:
  - name: base
    link: socket://127.0.0.1:2323
    mcu: {mcu}
    devices:
"""
DIFFDRIVE = """\
      - type: diffdrive
        wheel_radius: 0.033
        wheel_separation: 0.16
        counts_per_rev: 660
        pins:
          left_encoder: {left_encoder}
          right_encoder: [3, 5]
          left_motor: {left_motor}
          right_motor: [10, 11]
"""
SONAR = """\
      - type: hcsr04
        pins:
          trigger: {trigger}
          echo: {echo}
"""
IMU = """\
      - type: mpu6050
        address: 0x68
"""
IMU2 = """\
      - type: mpu6050
        name: second_imu
        topic: imu2_raw
        imu_topic: imu2
        address: 0x68 # <-
"""
SONAR2 = """\
      - type: hcsr04
        name: rear_sonar
        topic: rear_echo
        range_topic: rear_range
        pins: {trigger: 9, echo: A5} # <-
"""
SERVO = """\
      - type: dynamixel
        serial: Serial2 # <-
        direction_pin: 9
        bus: {protocol: 2, baud: 57600, servos: [{id: 1, model: XL430-W250}]}
"""


def _robot(
    mcu: str = "uno",
    left_encoder: str = "[2, 4]",
    left_motor: str = "[6, 7]",
    trigger: str = "8",
    echo: str = "12",
    extra: str = "",
) -> str:
    return (
        HEAD.format(mcu=mcu)
        + DIFFDRIVE.format(left_encoder=left_encoder, left_motor=left_motor)
        + SONAR.format(trigger=trigger, echo=echo)
        + IMU
        + extra
    )


CASES = {
    "pin not on the board": (
        _robot(echo="22 # <-"),
        "hcsr04: sonar echo: no pin 22: the uno has pins 0-19 and A0-A5",
    ),
    "analog pin not on the board": (
        _robot(echo="A6 # <-"),
        "hcsr04: sonar echo: no pin A6",
    ),
    "pin used twice": (
        _robot(trigger="6 # <-"),
        "hcsr04: pin 6 (sonar trigger) is used twice: also diffdrive's left motor PWM at line 14",
    ),
    "pin of the link": (
        _robot(trigger="1 # <-"),
        "hcsr04: pin 1 (sonar trigger) is used twice: also Serial TX (the link to the host)",
    ),
    "pin of the I2C bus": (
        _robot(extra=SONAR2),
        "rear_sonar: pin 19 (A5) (sonar echo) is used twice: also mpu6050's I2C SCL at line 21",
    ),
    "encoder A without an interrupt": (
        _robot(left_encoder="[4, 2] # <-"),
        "diffdrive: left encoder A on pin 4, which has no external interrupt (the uno has them "
        "on pins 2, 3)",
    ),
    "motor PWM pin without PWM": (
        _robot(left_motor="[7, 6] # <-"),
        "diffdrive: left motor PWM on pin 7, which has no PWM (the uno has it on pins 3, 5, 6, "
        "9, 10, 11)",
    ),
    "a second UART on an Uno": (
        _robot(extra=SERVO),
        "dynamixel: Serial2 cannot be the device's UART: the uno has no UART besides Serial, "
        "which carries the link to the host",
    ),
    "a second UART on a Nano": (
        _robot(mcu="nano", extra=SERVO),
        "dynamixel: Serial2 cannot be the device's UART: the nano has no UART besides Serial",
    ),
    "the link's UART on a Mega": (
        _robot(mcu="mega", extra=SERVO.replace("Serial2", "Serial")),
        "dynamixel: Serial cannot be the device's UART: use one of Serial1, Serial2, Serial3 "
        "(Serial carries the link to the host)",
    ),
    "two I2C devices at one address": (
        _robot(extra=IMU2),
        "second_imu: I2C address 0x68 is used twice: also mpu6050 at line 21",
    ),
}


def _expected_line(text: str) -> int:
    (line,) = [n for n, row in enumerate(text.splitlines(), 1) if "# <-" in row]
    return line


@pytest.mark.parametrize("case", list(CASES))
def test_each_pin_mistake_at_its_line(case: str, tmp_path: Path) -> None:
    text, message = CASES[case]
    path = tmp_path / "robot.yaml"
    path.write_text(text)
    with pytest.raises(RobotFileError) as caught:
        load_robot(path)
    line = _expected_line(text)
    found = [p for p in caught.value.problems if message in p]
    assert found, caught.value.problems
    assert found[0].startswith(f"{path}:{line}: board base ("), found


@pytest.mark.parametrize(
    "case", ["pin used twice", "encoder A without an interrupt", "a second UART on an Uno"]
)
def test_robot_check_command_reports_the_line(case: str, tmp_path: Path) -> None:
    """The real CLI: exit 1, the problem as FILE:LINE on stderr."""
    text, message = CASES[case]
    path = tmp_path / "robot.yaml"
    path.write_text(text)
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "robot", "check", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        cwd=ROOT,
    )
    assert done.returncode == 1, done.stdout + done.stderr
    assert f"{path}:{_expected_line(text)}: " in done.stderr, done.stderr
    assert message in done.stderr.replace("\n", " "), done.stderr


def test_a_good_wiring_passes_on_every_board_that_has_the_pins(tmp_path: Path) -> None:
    for mcu in MCU_BOARDS:
        path = tmp_path / f"{mcu}.yaml"
        path.write_text(_robot(mcu=mcu))
        assert load_robot(path).boards[0].mcu == mcu


def test_only_on_leaves_a_device_off_other_boards(tmp_path: Path) -> None:
    """The servo needs a spare UART: marked only_on: [mega], an Uno's file checks."""
    path = tmp_path / "robot.yaml"
    servo = SERVO.replace("- type: dynamixel\n", "- type: dynamixel\n        only_on: [mega]\n")
    path.write_text(_robot(extra=servo))
    robot = load_robot(path)
    assert [d.only_on for d in robot.boards[0].devices][-1] == ("mega",)


def test_no_mcu_no_pin_check(tmp_path: Path) -> None:
    """A board without mcu: (a host-only or older robot file) is not pin-checked."""
    path = tmp_path / "robot.yaml"
    path.write_text(_robot(trigger="6").replace("    mcu: uno\n", ""))
    assert load_robot(path).boards[0].mcu is None


def test_unknown_mcu_board(tmp_path: Path) -> None:
    path = tmp_path / "robot.yaml"
    path.write_text(_robot(mcu="due"))
    with pytest.raises(RobotFileError) as caught:
        load_robot(path)
    assert f"{path}:5: board base: mcu: unknown MCU board 'due'" in str(caught.value)


def test_bad_pin_settings_shape(tmp_path: Path) -> None:
    path = tmp_path / "robot.yaml"
    path.write_text(_robot(left_encoder="[2] # <-"))
    with pytest.raises(RobotFileError) as caught:
        load_robot(path)
    line = _expected_line(path.read_text())
    assert f"{path}:{line}: board base (uno): diffdrive: pins: left_encoder must be two pins" in (
        str(caught.value)
    )
