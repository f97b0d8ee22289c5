"""``hwbridge board scan`` and the ``usb:VID:PID`` and ``auto`` links: the port table, by-id
names, link resolution (with fake port records: there is no USB here), the real command, and a
probe of real emulated boards on pseudo-terminals."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from hwbridge.cli import main
from hwbridge.errors import LinkError
from hwbridge.graph import Graph
from hwbridge.links import discovery, open_link
from hwbridge.links.discovery import (
    KNOWN_USB_IDS,
    SerialPort,
    by_id_names,
    list_serial_ports,
    parse_usb_link,
    probe_port,
    resolve_link,
)
from hwbridge.robot.config import parse_robot
from hwbridge.robot.model import RobotFileError
from hwbridge.robot.runtime import RobotRuntime
from tests.boards import PtyBoard, native_sketch, rosserial_sketch, wait_for


@dataclass
class FakePort:
    """What pyserial's ListPortInfo gives for a port (the attributes discovery reads)."""

    device: str
    vid: int | None = None
    pid: int | None = None
    serial_number: str | None = None
    description: str = "n/a"


UNO = FakePort("/dev/ttyACM0", 0x2341, 0x0043, "7563331303135171D0B1", "Arduino Uno")
CH340 = FakePort("/dev/ttyUSB0", 0x1A86, 0x7523, None, "USB Serial")
MOUSE_UART = FakePort("/dev/ttyUSB1", 0x1234, 0x5678, "X1", "Something else")
BUILTIN = FakePort("/dev/ttyS0")


def ports(*records: FakePort, by_id: Path | None = None) -> list[SerialPort]:
    return list_serial_ports(lambda: records, by_id or Path("/nonexistent/by-id"))


def test_the_table_names_what_is_behind_each_usb_id() -> None:
    found = {p.device: p for p in ports(UNO, CH340, MOUSE_UART, BUILTIN)}
    assert list(found) == sorted(found)
    uno = found["/dev/ttyACM0"]
    assert uno.usb_id == "2341:0043"
    assert uno.board is not None and "Uno" in uno.board
    assert uno.serial_number == "7563331303135171D0B1"
    assert found["/dev/ttyUSB0"].board is not None and "CH340" in found["/dev/ttyUSB0"].board
    assert found["/dev/ttyUSB1"].board is None
    assert found["/dev/ttyS0"].usb_id is None and found["/dev/ttyS0"].board is None
    row = uno.as_dict()
    assert row["usb_id"] == "2341:0043" and row["vid"] == 0x2341 and row["by_id"] is None


@pytest.mark.parametrize(
    ("usb_id", "word"),
    [
        ((0x2341, 0x0043), "Uno"),
        ((0x2341, 0x0042), "Mega"),
        ((0x2341, 0x0010), "Mega"),
        ((0x2341, 0x8036), "Leonardo"),
        ((0x2A03, 0x0043), "Uno"),
        ((0x1A86, 0x7523), "CH340"),
        ((0x0403, 0x6001), "FT232"),
        ((0x10C4, 0xEA60), "CP210x"),
        ((0x16C0, 0x0483), "Teensy"),
        ((0x303A, 0x1001), "ESP32"),
        ((0x1A86, 0x55D4), "ESP32"),
    ],
)
def test_known_ids(usb_id: tuple[int, int], word: str) -> None:
    assert word in KNOWN_USB_IDS[usb_id]


def by_id_folder(tmp_path: Path) -> tuple[Path, Path]:
    """A fake /dev with a tty and a by-id folder of relative symlinks to it, as udev makes."""
    dev = tmp_path / "dev"
    (dev / "serial" / "by-id").mkdir(parents=True)
    tty = dev / "ttyACM0"
    tty.touch()
    folder = dev / "serial" / "by-id"
    name = "usb-Arduino__www.arduino.cc__0043_7563331303135171D0B1-if00"
    (folder / name).symlink_to(Path("../../ttyACM0"))
    (folder / "usb-Other_device-if00").symlink_to(Path("../../ttyUSB9"))  # dangling: ignored
    return tty, folder / name


def test_by_id_names_resolve_the_symlinks(tmp_path: Path) -> None:
    tty, stable = by_id_folder(tmp_path)
    names = by_id_names(stable.parent)
    assert names[os.path.realpath(tty)] == str(stable)
    assert by_id_names(tmp_path / "missing") == {}
    found = ports(FakePort(str(tty), 0x2341, 0x0043, "S"), by_id=stable.parent)
    assert found[0].by_id == str(stable)
    assert found[0].path == str(stable)  # what a usb: link opens: survives a replug


def test_usb_links_parse() -> None:
    assert parse_usb_link("/dev/ttyACM0") is None
    assert parse_usb_link("socket://host:1") is None
    selector = parse_usb_link("usb:2341:0043")
    assert selector is not None and (selector.vid, selector.pid) == (0x2341, 0x0043)
    assert str(selector) == "usb:2341:0043"
    selector = parse_usb_link("usb:2341:0043:A:B?baud=57600")
    assert selector is not None and selector.serial_number == "A:B"
    assert selector.query == "baud=57600"
    auto = parse_usb_link("auto")
    assert auto is not None and auto.auto
    for bad in ("usb:", "usb:2341", "usb:xyz:0043", "usb:12345:1", "usb:2341:0043:"):
        with pytest.raises(LinkError, match="usb:VID:PID"):
            parse_usb_link(bad)


def test_usb_link_picks_the_matching_port(tmp_path: Path) -> None:
    found = ports(UNO, CH340, BUILTIN)
    assert resolve_link("usb:2341:0043", found)[0] == "/dev/ttyACM0"
    assert resolve_link("USB:2341:43?baud=57600", found)[0] == "/dev/ttyACM0?baud=57600"
    assert resolve_link("usb:2341:0043:7563331303135171D0B1", found)[0] == "/dev/ttyACM0"
    assert resolve_link("/dev/ttyS0", found) == ("/dev/ttyS0", None)
    tty, stable = by_id_folder(tmp_path)
    with_by_id = ports(FakePort(str(tty), 0x2341, 0x0043, "S"), by_id=stable.parent)
    assert resolve_link("usb:2341:0043", with_by_id)[0] == str(stable)


def test_usb_link_errors_name_what_was_found() -> None:
    with pytest.raises(LinkError) as none:
        resolve_link("usb:0403:6001", ports(UNO, BUILTIN))
    text = str(none.value)
    assert "no serial port has USB ID usb:0403:6001" in text
    assert "/dev/ttyACM0 (2341:0043" in text and "/dev/ttyS0" in text
    assert "hwbridge board scan" in text
    with pytest.raises(LinkError, match=r"ports found: none"):
        resolve_link("usb:0403:6001", [])
    with pytest.raises(LinkError, match="no serial port"):
        resolve_link("usb:2341:0043:OTHER", ports(UNO))
    twins = ports(UNO, FakePort("/dev/ttyACM1", 0x2341, 0x0043, "SECOND"))
    with pytest.raises(LinkError) as several:
        resolve_link("usb:2341:0043", twins)
    text = str(several.value)
    assert "2 serial ports have USB ID usb:2341:0043" in text
    assert "/dev/ttyACM0" in text and "/dev/ttyACM1" in text and "SERIAL" in text
    assert resolve_link("usb:2341:0043:SECOND", twins)[0] == "/dev/ttyACM1"


def test_auto_is_the_one_known_board() -> None:
    assert resolve_link("auto", ports(UNO, MOUSE_UART, BUILTIN))[0] == "/dev/ttyACM0"
    assert resolve_link("auto?baud=57600", ports(CH340, BUILTIN))[0] == "/dev/ttyUSB0?baud=57600"
    with pytest.raises(LinkError) as none:
        resolve_link("auto", ports(MOUSE_UART, BUILTIN))
    assert "no serial port has a known board" in str(none.value)
    assert "/dev/ttyUSB1 (1234:5678" in str(none.value)
    with pytest.raises(LinkError) as several:
        resolve_link("auto", ports(UNO, CH340))
    assert "2 serial ports have a known board" in str(several.value)
    assert "/dev/ttyACM0" in str(several.value) and "/dev/ttyUSB0" in str(several.value)


def robot_text(link: str, second: str | None = None) -> str:
    text = f"robot: r\nboards:\n  - name: base\n    link: {link}\n    protocol: native\n"
    if second:
        text += f"  - name: arm\n    link: {second}\n"
    return text


def test_robot_files_check_usb_links() -> None:
    assert parse_robot(robot_text("auto")).boards[0].link == "auto"
    assert parse_robot(robot_text("usb:2341:0043:ABC")).boards[0].link == "usb:2341:0043:ABC"
    with pytest.raises(RobotFileError, match=r"<robot>:4: board base: link: .*usb:VID:PID"):
        parse_robot(robot_text("usb:nope"))


def test_up_refuses_links_it_cannot_resolve(router: Graph) -> None:
    robot = parse_robot(robot_text("auto"), "robot.yaml")
    runtime = RobotRuntime(robot, router, list_ports=lambda: ports(UNO, CH340))
    with pytest.raises(RobotFileError) as problem:
        runtime.start()
    assert "robot.yaml:3: board base: link auto: 2 serial ports" in str(problem.value)
    robot = parse_robot(robot_text("usb:2341:0043", "auto"), "robot.yaml")
    runtime = RobotRuntime(robot, router, list_ports=lambda: ports(UNO, MOUSE_UART))
    with pytest.raises(RobotFileError, match="board arm: link auto is /dev/ttyACM0, which board"):
        runtime.start()


@pytest.fixture
def native_board(tmp_path: Path) -> Iterator[Path]:
    path = tmp_path / "ttyHWB"
    board = PtyBoard(path, native_sketch(), name="scan").start()
    yield path
    board.stop()


def test_up_opens_the_port_a_usb_link_names(router: Graph, native_board: Path) -> None:
    robot = parse_robot(robot_text("usb:2341:0043?baud=115200"), "robot.yaml")
    uno = SerialPort(str(native_board), "Arduino Uno", 0x2341, 0x0043, "S", "Arduino Uno")
    runtime = RobotRuntime(robot, router, list_ports=lambda: [uno])
    try:
        runtime.start()
        assert runtime.robot.boards[0].link == f"{native_board}?baud=115200"
        board = runtime.bridge.boards["base"]
        assert wait_for(lambda: board.state == "connected"), board.info()
    finally:
        runtime.stop()


def test_probe_tells_native_and_rosserial_and_lets_go(tmp_path: Path, native_board: Path) -> None:
    assert probe_port(str(native_board), 10.0).protocol == "native"
    assert probe_port(str(native_board), 10.0).protocol == "native"  # the port was let go
    path = tmp_path / "ttyROS"
    board = PtyBoard(path, rosserial_sketch(), name="ros").start()
    try:
        assert probe_port(str(path), 10.0).protocol == "rosserial"
    finally:
        board.stop()
    silent = open_link(f"pty://?symlink={tmp_path / 'ttyQUIET'}")
    try:
        result = probe_port(str(tmp_path / "ttyQUIET"), 0.3)
        assert (result.protocol, result.problem) == (None, "silent")
    finally:
        silent.close()
    missing = probe_port(str(tmp_path / "ttyNONE"), 0.3)
    assert missing.protocol is None and (missing.problem or "").startswith("cannot open")


def test_scan_probe_command(
    native_board: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    record = FakePort(str(native_board), 0x2341, 0x0043, "S", "Arduino Uno")
    monkeypatch.setattr(discovery, "_pyserial_comports", lambda: [record])
    assert main(["board", "scan", "--probe", "--probe-timeout", "10", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [(r["device"], r["usb_id"], r["protocol"]) for r in rows] == [
        (str(native_board), "2341:0043", "native")
    ]
    assert main(["board", "scan", "--probe", "--probe-timeout", "10"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["PORT", "USB", "ID", "WHAT", "ANSWERS", "BY-ID"]
    assert lines[1].startswith(str(native_board)) and " native " in lines[1]


def test_the_real_scan_command_runs() -> None:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).parents[2])}
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "board", "scan"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        env=env,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(("no serial ports found", "PORT ")), done.stdout
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "board", "scan", "--json"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        env=env,
    )
    assert done.returncode == 0, done.stderr
    assert isinstance(json.loads(done.stdout), list)
