"""Each built-in device plugin names its driver in the Arduino library, the named headers and
classes exist, and ``hwbridge robot devices`` shows them."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from hwbridge.cli import main
from hwbridge.robot.registry import BUILTIN_DEVICES, get_device

INCLUDE = Path(__file__).resolve().parents[2] / "firmware" / "HwBridge" / "src"
WITH_DRIVERS = tuple(BUILTIN_DEVICES)
"""Every built-in device names its driver (the registry's list, not a copy of it)."""


def _pairs(firmware: str) -> list[tuple[str, str]]:
    pairs = []
    for part in firmware.split("; "):
        header, _, name = part.partition(": ")
        pairs.append((header, name))
    return pairs


@pytest.mark.parametrize("name", WITH_DRIVERS)
def test_the_plugin_names_a_driver_class_in_a_library_header(name: str) -> None:
    assert name in BUILTIN_DEVICES
    firmware = get_device(name).firmware
    assert firmware, f"{name} names no firmware driver"
    for header, class_name in _pairs(firmware):
        path = INCLUDE / header
        assert path.is_file(), f"{name}: {header} is not in the library"
        text = path.read_text(encoding="utf-8")
        assert re.search(rf"^class {class_name}\b", text, re.M), (
            f"{name}: no {class_name} in {header}"
        )
        assert "namespace drivers {" in text


def test_robot_devices_shows_each_plugins_firmware_driver(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["robot", "devices"]) == 0
    out = capsys.readouterr().out
    blocks = re.split(r"^(?=\S)", out, flags=re.M)
    shown = {}
    for block in blocks:
        head = block.split(" ", 1)[0]
        found = re.search(r"^  firmware driver: (.*)$", block, re.M)
        if head and found:
            shown[head] = found.group(1)
    for name in WITH_DRIVERS:
        assert shown[name] == get_device(name).firmware
    assert shown.get("mavlink_vehicle", "none") == "none"
