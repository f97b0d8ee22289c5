"""End to end: the firmware identity (PROTOCOL.md 2.6.1) of a real C++ board through a real bridge.

``sketches/Identity`` names itself as a sketch generated from a robot file does
(``HWBRIDGE_FIRMWARE_NAME``, ``HWBRIDGE_BUILD_TAG``) and is built with ``hwbridge firmware build
--board host`` into a native program on a pty; ``hwbridge connect`` or ``hwbridge up`` (their own
processes) bridge it and ``hwbridge board info`` (the real CLI) shows what it sent. A second build
defines another schema hash, as firmware built with another hwbridge version: the bridge warns
once however often that board reconnects. An old board (a Python device session whose BOARD_INFO
has no identity) connects without a word about its firmware.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from hwbridge.bridge.identity import host_hashes, library_version
from hwbridge.msg import registry
from hwbridge.robot.identity import build_tag
from tests.boards import PtyBoard, native_sketch
from tests.bridgeproc import BridgeProcess, new_sessions
from tests.netutil import free_port, stop_child, wait_until

SKETCH = Path(__file__).parent / "sketches" / "Identity"
ROBOT_YAML = b"robot: demo\nboards:\n  - name: base\n    link: /dev/ttyACM0\n    protocol: native\n"
"""The robot file ``hwbridge up`` brings up here (the tag of the 'stale' build is its tag)."""
STALE_SCHEMA = "0badf00d"
STALE_WARNING = "was built with another hwbridge version"
CONNECT_WAIT = 90.0
"""Seconds for a board to connect (generous: the machine may be busy)."""
CLI_TIMEOUT = 180.0

pytestmark = pytest.mark.skipif(
    shutil.which("g++") is None, reason="g++ is not installed (Debian package g++)"
)


@pytest.fixture(scope="module")
def named(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The sketch as it is: firmware demo/base, tag demo/base@000000000000."""
    from hwbridge.firmware.build import build_host_sketch

    return build_host_sketch(SKETCH, tmp_path_factory.mktemp("ident_named"))


@pytest.fixture(scope="module")
def stale(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Built with another schema hash, and the build tag of :data:`ROBOT_YAML`."""
    from hwbridge.firmware.build import build_host_sketch

    tag = build_tag("demo", "base", ROBOT_YAML)
    return build_host_sketch(
        SKETCH,
        tmp_path_factory.mktemp("ident_stale"),
        defines=[f'HWBRIDGE_SCHEMA_HASH="{STALE_SCHEMA}"', f'HWBRIDGE_BUILD_TAG="{tag}"'],
    )


class Program:
    """The board program on the pty at ``path`` (it opens the path it is given)."""

    def __init__(self, exe: Path, path: Path) -> None:
        self.process = subprocess.Popen(
            [str(exe), str(path)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )

    def stop(self) -> None:
        stop_child(self.process, signal.SIGKILL)


@pytest.fixture
def bridge(tmp_path: Path) -> Iterator[BridgeProcess]:
    link = f"pty://?symlink={tmp_path / 'ttyBOARD'}"
    process = BridgeProcess(link, tmp_path, f"ident{free_port()}", "--name", "base")
    process.wait_ready()
    yield process
    process.stop()


def _info(bridge: BridgeProcess) -> dict[str, object]:
    shown = bridge.cli("board", "info", "base", "--json", timeout=CLI_TIMEOUT)
    assert shown.returncode == 0, shown.stderr + bridge.output()
    info: dict[str, object] = json.loads(shown.stdout)
    return info


def test_board_info_shows_the_firmware_identity(
    named: Path, bridge: BridgeProcess, tmp_path: Path
) -> None:
    board = Program(named, tmp_path / "ttyBOARD")
    try:
        assert wait_until(lambda: new_sessions(bridge.output(), "ident") >= 1, CONNECT_WAIT), (
            bridge.output()
        )
        schema, messages = host_hashes(registry())
        assert _info(bridge)["firmware"] == {
            "name": "demo/base",
            "version": "2.3",
            "library_version": library_version(),
            "schema_hash": schema,
            "messages_hash": messages,
            "build_tag": "demo/base@000000000000",
            "problems": [],
        }
        text = bridge.cli("board", "info", "base", timeout=CLI_TIMEOUT)
        assert text.returncode == 0, text.stderr
        for line in (
            "  name: demo/base",
            f"  schema_hash: {schema}",
            f"  messages_hash: {messages}",
            "  build_tag: demo/base@000000000000",
        ):
            assert line in text.stdout.splitlines(), text.stdout
        assert STALE_WARNING not in bridge.output()
    finally:
        board.stop()


def test_a_stale_firmware_is_warned_about_once(
    stale: Path, bridge: BridgeProcess, tmp_path: Path
) -> None:
    """Four sessions of the same firmware (the program killed and started again): one warning,
    naming the board's and the host's schema hash; board info lists the problem each time."""
    schema, _ = host_hashes(registry())
    for session in range(1, 5):
        board = Program(stale, tmp_path / "ttyBOARD")
        try:
            assert wait_until(
                lambda n=session: new_sessions(bridge.output(), "ident") >= n, CONNECT_WAIT
            ), bridge.output()
            firmware = _info(bridge)["firmware"]
            assert isinstance(firmware, dict)
            assert firmware["schema_hash"] == STALE_SCHEMA
            assert firmware["problems"] == [
                f"control schema hash {STALE_SCHEMA}, this host's {schema}"
            ]
        finally:
            board.stop()
    output = bridge.output()
    assert output.count(STALE_WARNING) == 1, output
    (warning,) = [line for line in output.splitlines() if STALE_WARNING in line]
    assert STALE_SCHEMA in warning and schema in warning and "demo/base" in warning
    assert "rebuild and upload the firmware with this hwbridge" in warning


def test_an_old_board_without_identity_connects_quietly(tmp_path: Path) -> None:
    """A BOARD_INFO of the old form (version text only): connected, firmware unknown, no
    warning about it."""
    board = PtyBoard(tmp_path / "ttyOLD", native_sketch("old")).start()
    old = BridgeProcess(tmp_path / "ttyOLD", tmp_path, f"old{free_port()}", "--name", "x")
    try:
        old.wait_ready()
        assert wait_until(lambda: "board 'old' connected" in old.output(), CONNECT_WAIT), (
            old.output()
        )
        shown = old.cli("board", "info", "x", "--json", timeout=CLI_TIMEOUT)
        assert shown.returncode == 0, shown.stderr
        assert json.loads(shown.stdout)["firmware"] is None
        assert STALE_WARNING not in old.output()
        assert "firmware" not in "\n".join(
            line for line in old.output().splitlines() if "WARNING" in line
        )
    finally:
        old.stop()
        board.stop()


def _up(robot: Path, link: str, tmp: Path, until: str) -> str:
    """``hwbridge -v up ROBOT --link base=LINK`` until ``until`` shows in its log; the log."""
    log = tmp / "up.log"
    env = {**os.environ, "HWBRIDGE_DOMAIN": f"identup{free_port()}"}
    command = [sys.executable, "-m", "hwbridge", "-v", "up", str(robot), "--link", f"base={link}"]
    command += ["--listen", f"tcp/127.0.0.1:{free_port()}"]
    with log.open("w") as out:
        process = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, env=env)
        try:
            shown = wait_until(
                lambda: until in log.read_text() or process.poll() is not None, 2 * CONNECT_WAIT
            )
            assert shown and process.poll() is None, log.read_text()
        finally:
            stop_child(process)
    return log.read_text()


@pytest.mark.parametrize("build", ["named", "stale"])
def test_up_compares_the_build_tag_with_the_robot_file(
    build: str, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    """The 'named' build carries the tag of another robot file: a warning naming both tags. The
    'stale' build was generated from this very file: an info line says so."""
    exe: Path = request.getfixturevalue(build)
    robot = tmp_path / "demo.yaml"
    robot.write_bytes(ROBOT_YAML)
    expected = build_tag("demo", "base", ROBOT_YAML)
    pty = tmp_path / "ttyUP"
    link = f"pty://?symlink={pty}"
    board: Program | None = None

    def start_board() -> None:
        nonlocal board
        if board is None and pty.exists():
            board = Program(exe, pty)

    until = "build of another robot file" if build == "named" else "generated from this robot"
    tmp = tmp_path / "up"
    tmp.mkdir()
    # the board program needs the pty that `up` creates: start it from a thread once it exists
    stop = threading.Event()

    def starter() -> None:
        while not stop.wait(0.05):
            start_board()
            if board is not None:
                return

    thread = threading.Thread(target=starter, daemon=True)
    thread.start()
    try:
        output = _up(robot, link, tmp, until)
    finally:
        stop.set()
        thread.join(5)
        if board is not None:
            board.stop()
    lines = [line for line in output.splitlines() if until in line]
    assert len(lines) == 1, output
    if build == "named":
        assert "demo/base@000000000000" in lines[0] and expected in lines[0], lines[0]
        assert lines[0].startswith("WARNING"), lines[0]
    else:
        assert lines[0].startswith("INFO"), lines[0]
        assert expected in lines[0] and str(robot) in lines[0], lines[0]
        assert "build of another robot file" not in output
