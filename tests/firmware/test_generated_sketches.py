"""``hwbridge firmware generate ROBOT.yaml``: sketches generated from robot files build for every
MCU board that has the pins (each built-in board device alone, and the example robots), carry
the robot file's identity, and are refused, with the file's line, where the wiring does not fit.

The builds go through the simulator's build cache (one folder per sketch text), so a second run
on the same machine builds nothing."""

from __future__ import annotations

import hashlib
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hwbridge.firmware.build import BOARDS, firmware_size
from hwbridge.robot.config import load_robot
from hwbridge.robot.model import RobotFileError
from hwbridge.sketchgen import build_tag, generate_sketch, generated_elf, pick_board

pytestmark = pytest.mark.skipif(
    shutil.which("avr-g++") is None or not Path("/usr/share/arduino/hardware/arduino/avr").is_dir(),
    reason="the AVR toolchain (gcc-avr avr-libc binutils-avr arduino-core-avr) is not installed",
)

ROOT = Path(__file__).resolve().parents[2]
ROBOTS = ROOT / "examples" / "robots"

DEVICES = {
    "diffdrive": "wheel_radius: 0.033\n        wheel_separation: 0.16\n        counts_per_rev: 660",
    "hcsr04": "rate: 10",
    "mpu6050": "rate: 50",
    "mpu9250": "rate: 50",
    "bme280": "mode: normal",
    "dynamixel": (
        "serial: Serial1\n        direction_pin: 22\n"
        "        bus: {protocol: 2, baud: 57600, servos: [{id: 1, model: XL430-W250}]}"
    ),
}
"""Each built-in board device with the settings it needs (its pins: its defaults)."""
NEEDS_A_SPARE_UART = {"dynamixel"}


def _alone(device: str, mcu: str) -> str:
    return (
        f"robot: {device}_alone\n"
        "boards:\n"
        "  - name: board\n"
        "    link: /dev/ttyACM0\n"
        f"    mcu: {mcu}\n"
        "    devices:\n"
        f"      - type: {device}\n"
        f"        {DEVICES[device]}\n"
    )


MATRIX = [
    (device, mcu)
    for device in DEVICES
    for mcu in BOARDS
    if not (device in NEEDS_A_SPARE_UART and mcu != "mega")
]


@pytest.mark.parametrize(("device", "mcu"), MATRIX)
def test_each_device_alone_builds(device: str, mcu: str, tmp_path: Path) -> None:
    path = tmp_path / f"{device}.yaml"
    path.write_text(_alone(device, mcu))
    elf = generated_elf(path, mcu)
    size = firmware_size(elf)
    assert 0 < size.flash <= BOARDS[mcu].flash and 0 < size.sram < BOARDS[mcu].sram


@pytest.mark.parametrize("mcu", ["uno", "nano"])
def test_a_servo_bus_needs_a_spare_uart(mcu: str, tmp_path: Path) -> None:
    path = tmp_path / "dynamixel.yaml"
    path.write_text(_alone("dynamixel", mcu))
    with pytest.raises(RobotFileError, match=rf"{path}:8: .*the {mcu} has no UART besides Serial"):
        load_robot(path)


@pytest.mark.parametrize(
    ("robot", "mcu"),
    [("diffbot.yaml", "mega"), ("diffbot_uno.yaml", "uno"), ("diffbot_uno.yaml", "nano")],
)
def test_the_example_robots_build(robot: str, mcu: str) -> None:
    elf = generated_elf(ROBOTS / robot, mcu)
    size = firmware_size(elf)
    assert size.flash <= BOARDS[mcu].flash and size.sram < BOARDS[mcu].sram


def test_the_mega_robot_does_not_fit_an_uno() -> None:
    """diffbot.yaml's right encoder (18, 19) is the Uno's A4/A5: no interrupt, and the I2C
    bus's pins; the generator refuses before writing anything."""
    robot = load_robot(ROBOTS / "diffbot.yaml")
    with pytest.raises(RobotFileError) as caught:
        generate_sketch(robot, b"", robot.boards[0], "uno")
    text = str(caught.value)
    assert "right encoder A on pin 18 (A4), which has no external interrupt" in text
    assert "I2C SDA) is used twice: also diffdrive's right encoder A" in text


def test_the_only_on_device_is_left_out_elsewhere() -> None:
    robot = load_robot(ROBOTS / "diffbot.yaml")
    mega = generate_sketch(robot, b"x", robot.boards[0], "mega")
    assert "dynamixel" in mega.devices and "Serial2" in mega.text
    uno_file = load_robot(ROBOTS / "diffbot_uno.yaml")
    uno = generate_sketch(uno_file, b"x", uno_file.boards[0], "uno")
    assert "dynamixel" not in uno.devices


def test_identity_macros_come_before_the_library() -> None:
    data = (ROBOTS / "diffbot.yaml").read_bytes()
    robot = load_robot(ROBOTS / "diffbot.yaml")
    sketch = generate_sketch(robot, data, pick_board(robot, None), "mega")
    digest = hashlib.sha256(data).hexdigest()[:12]
    assert build_tag("diffbot", "base", data) == f"diffbot/base@{digest}"
    # BOARD is the robot file's board, as 'hwbridge up' expects it of the board
    lines = sketch.text.splitlines()
    name = lines.index('#define HWBRIDGE_FIRMWARE_NAME "diffbot/base"')
    tag = lines.index(f'#define HWBRIDGE_BUILD_TAG "diffbot/base@{digest}"')
    assert name < tag < lines.index("#include <HwBridge.h>")
    # the settings the host reads are the ones compiled in
    assert 'ticks_pub("wheel_ticks")' in sketch.text and "20.0f" in sketch.text
    assert "requestParam" not in sketch.text  # nothing asked of the host at run time


def test_the_cli_writes_builds_and_measures(tmp_path: Path) -> None:
    robot = tmp_path / "robot.yaml"
    robot.write_text(_alone("hcsr04", "nano"))
    hwbridge = [sys.executable, "-m", "hwbridge", "firmware", "generate"]
    done = subprocess.run(
        [*hwbridge, str(robot), "--no-build"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    ino = tmp_path / "firmware" / "hcsr04_alone_nano" / "hcsr04_alone_nano.ino"
    assert done.stdout.strip() == str(ino.resolve())
    assert "HcSr04<8, 12>" in ino.read_text()
    done = subprocess.run(
        [*hwbridge, str(robot), "--board", "uno", "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == str(tmp_path / "out" / "hcsr04_alone_uno.ino")
    assert re.match(
        r".*/hcsr04_alone_uno\.elf: flash \d+ B of 32256 .*SRAM \d+ B of 2048", lines[1]
    )
    assert lines[2].endswith(
        "hcsr04_alone_uno.hex: the image to upload (hwbridge firmware upload, or avrdude)"
    )
    assert "[1/" in done.stderr  # progress


def test_the_cli_refuses_a_wiring_that_does_not_fit(tmp_path: Path) -> None:
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "hwbridge",
            "firmware",
            "generate",
            str(ROBOTS / "diffbot.yaml"),
            "--board",
            "nano",
            "--no-build",
            "--out",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 1, done.stdout + done.stderr
    assert "diffbot.yaml:" in done.stderr and "board base (nano)" in done.stderr
    assert not list(tmp_path.iterdir())  # nothing written
