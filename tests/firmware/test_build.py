"""``hwbridge firmware build`` and ``size`` with the real AVR toolchain and Arduino core."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hwbridge.errors import HwBridgeError
from hwbridge.firmware.build import BOARDS, ToolchainMissingError, build_sketch, firmware_size

pytestmark = pytest.mark.skipif(
    shutil.which("avr-g++") is None or not Path("/usr/share/arduino/hardware/arduino/avr").is_dir(),
    reason="the AVR toolchain (gcc-avr avr-libc binutils-avr arduino-core-avr) is not installed",
)

BLINK = """\
static unsigned long last = 0;

void setup() {
  pinMode(LED_BUILTIN, OUTPUT);
  Serial.begin(115200);
}

void loop() {
  if (millis() - last > 500) {
    last = millis();
    digitalWrite(LED_BUILTIN, !digitalRead(LED_BUILTIN));
    Serial.println(last);
  }
}
"""


def sketch(tmp_path: Path, name: str, text: str) -> Path:
    folder = tmp_path / name
    folder.mkdir()
    (folder / f"{name}.ino").write_text(text)
    return folder


@pytest.mark.parametrize("board", ["uno", "mega"])
def test_a_sketch_builds_and_is_measured(board: str, tmp_path: Path) -> None:
    elf = build_sketch(sketch(tmp_path, "Blink", BLINK), board, tmp_path / "out", libraries=[])
    assert elf.is_file() and elf.with_suffix(".hex").is_file()
    size = firmware_size(elf)
    assert 1000 < size.flash < BOARDS[board].flash
    assert 0 < size.sram < BOARDS[board].sram
    assert size.library_sram == 0  # no HwBridge objects in this sketch
    owners = {name: owner for name, _, owner in size.objects}
    assert owners["Serial"] == "core" and owners["last"] == "sketch", size.objects
    assert sum(n for _, n, _ in size.objects) <= size.sram
    assert 150 < size.core_sram < size.sram  # Serial's rings and state


def test_warnings_in_a_sketch_are_errors(tmp_path: Path) -> None:
    text = "void setup() { int unused = 3; }\nvoid loop() {}\n"
    with pytest.raises(HwBridgeError, match=r"(?s)compiling .*Warn\.ino failed:.*unused"):
        build_sketch(sketch(tmp_path, "Warn", text), "uno", tmp_path / "out", libraries=[])


def test_not_a_sketch_and_unknown_board(tmp_path: Path) -> None:
    with pytest.raises(HwBridgeError, match="not a sketch"):
        build_sketch(tmp_path, "uno")
    with pytest.raises(HwBridgeError, match="unknown board 'due'"):
        build_sketch(sketch(tmp_path, "Blink", BLINK), "due")


def test_a_missing_toolchain_names_the_debian_packages(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))  # no avr-g++ here
    with pytest.raises(ToolchainMissingError, match="gcc-avr avr-libc binutils-avr"):
        build_sketch(sketch(tmp_path, "Blink", BLINK), "uno")


def test_the_cli_builds_and_measures(tmp_path: Path) -> None:
    folder = sketch(tmp_path, "Blink", BLINK)
    other = sketch(tmp_path, "Other", BLINK)
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}  # the core built afresh

    def build(sketch_folder: Path) -> subprocess.Popen[str]:
        command = [sys.executable, "-m", "hwbridge", "firmware", "build", str(sketch_folder)]
        return subprocess.Popen(
            [*command, "--board", "uno"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )

    # two first builds at once (two terminals, parallel CI jobs) share the core's cache entry
    first, second = build(folder), build(other)
    out, err = first.communicate(timeout=300)
    built = subprocess.CompletedProcess(first.args, first.wait(), out, err)
    out, err = second.communicate(timeout=300)
    assert second.returncode == 0, err
    assert built.returncode == 0, built.stderr
    cached = list((tmp_path / "cache" / "hwbridge" / "arduino-core").iterdir())
    assert [sorted(p.name for p in entry.iterdir()) for entry in cached] == [["core.a"]]
    assert "flash" in built.stdout and "SRAM" in built.stdout
    # progress on stderr, a line per step: the core's files once (a fresh cache), then the
    # sketch, each library file, the link
    steps = [line for line in built.stderr.splitlines() if line.startswith("hwbridge: [")]
    core = [line for line in steps if line.startswith("hwbridge: [core ")]
    assert core and core[-1].startswith(f"hwbridge: [core {len(core)}/{len(core)}]"), steps
    own = steps[len(core) :]
    assert own[0].startswith("hwbridge: [1/") and "Blink.ino" in own[0], steps
    assert own[-1].endswith("linking Blink.elf (LTO)"), steps
    total = int(own[0].split("/")[1].split("]")[0])
    assert len(own) == total, steps
    elf = folder / "build" / "uno" / "Blink.elf"
    measured = subprocess.run(
        [sys.executable, "-m", "hwbridge", "firmware", "size", str(elf), "--json"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert measured.returncode == 0, measured.stderr
    assert json.loads(measured.stdout)["flash"] == firmware_size(elf).flash
    missing = subprocess.run(
        [sys.executable, "-m", "hwbridge", "firmware", "size", str(tmp_path / "nope.elf")],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    # A path on the command line that does not exist is a usage error (docs/design.md).
    assert missing.returncode == 2 and missing.stderr.startswith("error: ")
    assert "nope.elf' does not exist" in missing.stderr
