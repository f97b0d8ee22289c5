"""A board's own log lines (``nh.logInfo``) show in ``hwbridge connect``'s output by default, named
by board, as rosserial shows them; ``--quiet`` hides the info ones but not the warnings.

The board is the Parameters example built with ``hwbridge firmware build --board host`` (a native
program on a pty): it logs the ``gains`` parameter at INFO, then warns that ``blink_period_ms``
is not set.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.netutil import free_port, stop_child, wait_until

ROOT = Path(__file__).resolve().parents[2]
PARAMETERS = ROOT / "firmware" / "HwBridge" / "examples" / "Parameters"
INFO = "INFO [uno] gains (x1000) = 1000 500 10"
HWBRIDGE = (sys.executable, "-m", "hwbridge")
WARNING = "WARNING [uno] blink_period_ms is not set: blinking every 500 ms"

pytestmark = pytest.mark.skipif(
    shutil.which("g++") is None, reason="g++ is not installed (Debian package g++)"
)


@pytest.fixture(scope="module")
def program(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("parameters")
    built = subprocess.run(
        [*HWBRIDGE, "firmware", "build", str(PARAMETERS), "--board", "host", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert built.returncode == 0, built.stderr
    return out / "Parameters"


@pytest.fixture
def board_url(program: Path) -> Iterator[str]:
    board = subprocess.Popen(
        [str(program)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True
    )
    try:
        assert board.stdout is not None
        url = board.stdout.readline().strip()
        assert url, "the board program printed no URL"
        yield url
    finally:
        stop_child(board, signal.SIGTERM)


def _connect(url: str, tmp: Path, *extra: str, up: bool = False) -> str:
    """``hwbridge connect URL`` (no -v), or ``hwbridge up`` of a robot file with that board,
    until the board's warning shows; its stderr."""
    params = tmp / "params.yaml"
    params.write_text("gains: [1.0, 0.5, 0.01]\n")
    log = tmp / "connect.log"
    env = {**os.environ, "HWBRIDGE_DOMAIN": "boardlogs"}
    listen = ("--listen", f"tcp/127.0.0.1:{free_port()}")
    if up:
        robot = tmp / "robot.yaml"
        robot.write_text("robot: logs\nboards:\n  - name: uno\n    link: /dev/ttyACM0\n")
        command = ["up", str(robot), "--link", f"uno={url}"]
    else:
        command = ["connect", url, "--name", "uno"]
    with log.open("w") as err:
        process = subprocess.Popen(
            [*HWBRIDGE, *command, "--params", str(params), *extra, *listen],
            stdout=subprocess.DEVNULL,
            stderr=err,
            env=env,
        )
        try:
            shown = wait_until(
                lambda: WARNING in log.read_text() or process.poll() is not None, 90, 0.05
            )
            assert shown and process.poll() is None, log.read_text()
        finally:
            stop_child(process)
    return log.read_text()


def test_connect_shows_the_boards_log_lines(board_url: str, tmp_path: Path) -> None:
    output = _connect(board_url, tmp_path)
    lines = output.splitlines()
    assert INFO in lines, output
    assert lines.index(INFO) < lines.index(WARNING)
    assert "speaks native" not in output  # the bridge's own info lines still need -v


def test_quiet_hides_the_info_lines_but_not_the_warnings(board_url: str, tmp_path: Path) -> None:
    output = _connect(board_url, tmp_path, "--quiet")
    assert WARNING in output.splitlines()
    assert "gains (x1000)" not in output, output


def test_up_shows_the_boards_log_lines_too(board_url: str, tmp_path: Path) -> None:
    output = _connect(board_url, tmp_path, up=True)
    assert INFO in output.splitlines(), output
