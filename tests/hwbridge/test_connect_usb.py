"""``hwbridge connect usb:VID:PID[:SERIAL]`` and ``hwbridge connect auto``: resolved to the port as
``hwbridge up`` resolves a robot file's links (the same code), with the same errors. There is
no USB here: pyserial's port listing is replaced at its boundary (``_pyserial_comports``) by
records naming a real pty with a native board emulation behind it, in a real ``connect``
process."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from hwbridge.cli import main
from hwbridge.links import discovery
from tests.boards import PtyBoard, native_sketch
from tests.hwbridge.test_board_scan import CH340, MOUSE_UART, UNO, FakePort
from tests.netutil import free_port, wait_until

ROOT = Path(__file__).parents[2]


@pytest.mark.parametrize(
    ("urls", "records", "error"),
    [
        (["auto"], [UNO, CH340], "URL 1: link auto: 2 serial ports have a known board"),
        (["auto"], [MOUSE_UART], "URL 1: link auto: no serial port has a known board"),
        (
            ["usb:2341:0043", "auto"],
            [UNO, MOUSE_UART],
            "URL 2: link auto is /dev/ttyACM0, which URL 1 uses too",
        ),
        (
            ["usb:0403:6001", "--name", "base"],
            [UNO],
            "board base: link usb:0403:6001: no serial port has USB ID usb:0403:6001",
        ),
        (["usb:nope"], [UNO], "is not a USB link: write usb:VID:PID"),
    ],
)
def test_connect_refuses_usb_links_it_cannot_resolve(
    urls: list[str],
    records: list[FakePort],
    error: str,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setattr(discovery, "_pyserial_comports", lambda: records)
    assert main(["connect", *urls]) == 1
    assert error in capsys.readouterr().err


@pytest.fixture
def native_board(tmp_path: Path) -> Iterator[Path]:
    path = tmp_path / "ttyHWB"
    board = PtyBoard(path, native_sketch(), name="usb").start()
    yield path
    board.stop()


_CONNECT = """
import sys
from hwbridge.cli import main
from hwbridge.links import discovery
from tests.hwbridge.test_board_scan import FakePort
port = FakePort(sys.argv[1], 0x2341, 0x0043, "85036313530351D0E1C1", "Arduino Uno")
discovery._pyserial_comports = lambda: [port, FakePort("/dev/ttyS0")]
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.parametrize("url", ["usb:2341:0043:85036313530351D0E1C1?baud=115200", "auto"])
def test_connect_opens_the_port_a_usb_link_names(
    url: str, native_board: Path, tmp_path: Path
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = {
        **os.environ,
        "PYTHONPATH": str(ROOT),
        "HWBRIDGE_ENDPOINT": endpoint,
        "HWBRIDGE_DOMAIN": "connect_usb",
    }
    log = tmp_path / "connect.log"
    with log.open("w") as out:
        bridge = subprocess.Popen(
            [sys.executable, "-c", _CONNECT, str(native_board), "-v", "connect", url],
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            cwd=ROOT,
        )
        try:

            def info() -> dict[str, object] | None:
                done = subprocess.run(
                    [sys.executable, "-m", "hwbridge", "board", "info", "ttyHWB", "--json"],
                    env=env,
                    capture_output=True,
                    text=True,
                    timeout=60,
                    check=False,
                )
                return json.loads(done.stdout) if done.returncode == 0 else None

            def connected() -> bool:
                found = info()
                return found is not None and found["state"] == "connected"

            assert wait_until(connected, 60), log.read_text()
            found = info()
            assert found is not None
            query = url.partition("?")[2]
            assert found["url"] == str(native_board) + (f"?{query}" if query else "")
            assert found["topics"] == {
                "publishes": ["/chatter"],
                "subscribes": ["/led"],
                "serves": ["/reset"],
            }
            assert f"link {url} is {native_board} (2341:0043 Arduino Uno" in log.read_text()
        finally:
            bridge.send_signal(signal.SIGINT)
            try:
                bridge.wait(20)
            finally:
                if bridge.poll() is None:
                    bridge.kill()
                    bridge.wait(5)
