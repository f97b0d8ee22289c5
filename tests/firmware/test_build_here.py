"""``hwbridge firmware build .`` in a sketch's folder (as a user in a terminal would): the sketch is
found by the folder's real name, and the build ends with the paths of the ELF and of the Intel
HEX file to upload, which exist."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hwbridge.firmware.build import BOARDS

HELLO = Path(__file__).resolve().parents[2] / "firmware" / "HwBridge" / "examples" / "HelloWorld"

pytestmark = pytest.mark.skipif(
    shutil.which("avr-g++") is None or not BOARDS, reason="needs gcc-avr and arduino-core-avr"
)


def test_build_dot_in_the_sketch_folder_prints_the_hex(tmp_path: Path) -> None:
    sketch = tmp_path / "HelloWorld"
    shutil.copytree(HELLO, sketch, ignore=shutil.ignore_patterns("build"))
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "firmware", "build", ".", "--board", "uno"],
        cwd=sketch,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    elf, hex_file = (Path(line.split(": ", 1)[0]) for line in lines[-2:])
    assert elf == sketch / "build" / "uno" / "HelloWorld.elf" and elf.is_file(), done.stdout
    assert hex_file == elf.with_suffix(".hex") and hex_file.is_file(), done.stdout
    assert hex_file.read_text().startswith(":"), "not Intel HEX"


def test_a_relative_sketch_path_from_below(tmp_path: Path) -> None:
    """``hwbridge firmware build .. --board host`` from a folder inside the sketch's."""
    if shutil.which("g++") is None:
        pytest.skip("g++ is not installed")
    shutil.copytree(HELLO, tmp_path / "HelloWorld", ignore=shutil.ignore_patterns("build"))
    (tmp_path / "HelloWorld" / "notes").mkdir()
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "firmware", "build", "..", "-b", "host"],
        cwd=tmp_path / "HelloWorld" / "notes",
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    program = Path(done.stdout.splitlines()[-1].split(": ", 1)[0])
    assert program.resolve() == tmp_path / "HelloWorld" / "build" / "host" / "HelloWorld"
    assert program.is_file()
