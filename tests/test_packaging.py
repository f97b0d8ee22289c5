"""The wheel maps protocols/ and devices/ into hwbridge and carries the data files."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_wheel_layout_and_data(tmp_path: Path) -> None:
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path),
            str(ROOT),
        ],
        check=True,
        timeout=300,
    )
    (wheel,) = tmp_path.glob("hwbridge-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for required in (
        "hwbridge/__init__.py",
        "hwbridge/cli/__init__.py",
        "hwbridge/protocols/__init__.py",
        "hwbridge/protocols/msgtypes.py",
        "hwbridge/protocols/msg/rosserial_msgs/msg/TopicInfo.msg",
        "hwbridge/protocols/msg/rosserial_msgs/srv/RequestParam.srv",
        "hwbridge/protocols/vectors/md5.json",
        "hwbridge/protocols/PROTOCOL.md",
        "hwbridge/devices/__init__.py",
        "hwbridge/devices/dynamixel/buses.yaml",
        "hwbridge/emulator/robots/diffbot.yaml",
        "hwbridge/protocols/msg/hwbridge_msgs/msg/WheelTicks.msg",
        "hwbridge/protocols/vectors/native_frames.json",
    ):
        assert required in names, required
    assert not any(n.startswith(("protocols/", "devices/", "tests/")) for n in names)
    entry_points = next(n for n in names if n.endswith("entry_points.txt"))
    assert "hwbridge = hwbridge.cli:entry" in zipfile.ZipFile(wheel).read(entry_points).decode()

    target = tmp_path / "site"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--no-deps",
            "-q",
            "--target",
            str(target),
            str(wheel),
        ],
        check=True,
        timeout=300,
    )
    probe = (
        "import hwbridge.protocols.msgtypes as m, hwbridge.msg as msg;"
        "print(m.__file__); print(msg.md5('rosserial_msgs/TopicInfo'))"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe],
        env={"PYTHONPATH": str(target), "PATH": "/usr/bin:/bin"},
        cwd=tmp_path,
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    where, md5 = done.stdout.split()
    assert where.startswith(str(target))
    assert md5 == "0ad51f88fc44892f8c10684077646005"
