"""An input path on the command line that does not exist is a usage error (status 2) for every
command that reads one, with Click's one error line naming the argument and the path, the usage
line and where help is (as ``exists=True`` gives): nothing is started first."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.cliutil import run_hwbridge

MISSING: list[tuple[str, ...]] = [
    ("up", "nope.yaml"),
    ("up", "--params", "nope.yaml", "robot.yaml"),
    ("connect", "--params", "nope.yaml", "socket://127.0.0.1:9"),
    ("robot", "check", "nope.yaml"),
    ("robot", "show", "nope.yaml"),
    ("robot", "acl", "nope.yaml"),
    ("param", "load", "nope.yaml"),
    ("topic", "pub", "-f", "nope.yaml", "/x", "std_msgs/String"),
    ("play", "nope.mcap"),
    ("firmware", "build", "nope"),
    ("firmware", "size", "nope.elf"),
    ("firmware", "generate", "nope.yaml"),
    ("firmware", "sim", "nope.elf"),
    ("firmware", "sim", "--mcu", "stm32f405", "nope.elf"),
    ("firmware", "sim", "HelloWorld", "--robot", "nope.yaml"),
    ("firmware", "upload", "--port", "/dev/null", "nope.hex"),
    ("emulate", "nope.yaml"),
    ("--zenoh-config", "nope.json5", "topic", "list"),
]


@pytest.mark.parametrize("argv", MISSING, ids=" ".join)
def test_a_missing_input_path_is_a_usage_error(tmp_path: Path, argv: tuple[str, ...]) -> None:
    (tmp_path / "robot.yaml").write_text("robot: r\nboards:\n  - {name: b, link: 'pty://'}\n")
    done = run_hwbridge(*argv, timeout=60, cwd=tmp_path)
    assert done.returncode == 2, (done.returncode, done.stderr)
    first, *rest = done.stderr.splitlines()
    missing = next(arg for arg in argv if arg.startswith("nope"))
    assert first.startswith("error: Invalid value for '"), done.stderr
    assert f"'{missing}' does not exist" in first, done.stderr
    assert [line.split()[0] for line in rest] == ["Usage:", "Try"], done.stderr
    assert done.stdout == ""


def test_a_name_that_is_no_ready_robot_is_a_usage_error_too(tmp_path: Path) -> None:
    done = run_hwbridge("emulate", "diffbott", timeout=60, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines()[0] == (
        "error: Invalid value for 'ROBOT': Path 'diffbott' does not exist (nor is it a ready "
        "robot: diffbot, diffbot_uno)."
    )


def test_a_folder_given_for_a_file_is_a_usage_error(tmp_path: Path) -> None:
    done = run_hwbridge("robot", "check", str(tmp_path), timeout=60)
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith(f"error: Invalid value for 'ROBOT.yaml': File '{tmp_path}'")


@pytest.mark.parametrize("mcu", ["atmega328p", "stm32f405"])
def test_firmware_sim_does_not_read_a_path_that_is_no_file(tmp_path: Path, mcu: str) -> None:
    """A FIFO (or /dev/null, a pipe from ``<(...)``) exists and is no folder, so it passes for
    the firmware on the command line. The check of the MCU it was built for leaves it unread
    (opening a FIFO with no writer waits for one: the command would hang), and the simulator
    refuses it: status 1, nothing started."""
    fifo = tmp_path / "firmware.elf"
    os.mkfifo(fifo)
    done = run_hwbridge("firmware", "sim", "--mcu", mcu, str(fifo), timeout=60)
    assert done.returncode == 1, done.stderr
    said = f"no firmware at {fifo}" if mcu == "atmega328p" else f"{fifo}: no such ELF file"
    assert done.stderr == f"error: {said}\n"
    assert done.stdout == ""
