"""Pausing a board of a running bridge (what ``hwbridge firmware upload`` does to a bridge that
holds the port): a real :class:`~hwbridge.bridge.Bridge` on a real Zenoh graph, a native board
emulation on a real pty, and the client :class:`~hwbridge.bridge.control.BridgePause` asking
through the board's control queryable from another graph session, as the uploader does."""

from __future__ import annotations

import logging
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from hwbridge.bridge import BoardSpec, Bridge
from hwbridge.bridge.board import BoardConnection, link_device
from hwbridge.bridge.control import BridgePause, find_holding_board
from hwbridge.errors import HwBridgeError
from hwbridge.firmware.upload import PortBusyError, check_port
from hwbridge.graph import Graph
from tests.boards import PtyBoard, native_sketch, wait_for
from tests.netutil import free_port

PROMPT = 30.0
"""Generous: the machine may be busy."""


@pytest.fixture
def board_path(tmp_path: Path) -> Iterator[Path]:
    path = tmp_path / "ttyHWB"
    board = PtyBoard(path, native_sketch(), name="pause").start()
    yield path
    board.stop()


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def bridge(board_path: Path, endpoint: str, caplog: pytest.LogCaptureFixture) -> Iterator[Bridge]:
    caplog.set_level(logging.INFO, logger="hwbridge")
    graph = Graph.embedded(listen=[endpoint], domain="pause")
    bridge = Bridge(graph)
    try:
        bridge.add_board(BoardSpec(str(board_path), name="uno", start_delay=0.2))
        yield bridge
    finally:
        bridge.stop()
        graph.close()


@pytest.fixture
def client(bridge: Bridge, endpoint: str) -> Iterator[Graph]:
    del bridge
    graph = Graph.attached(connect=[endpoint], domain="pause")
    yield graph
    graph.close()


def _on_graph(client: Graph, topic: str) -> bool:
    return topic in client.snapshot(timeout=1.0).topics()


def _connected(board: BoardConnection) -> bool:
    return board.state == "connected" and "/chatter" in board.info()["topics"].get("publishes", ())


def test_a_paused_board_lets_go_of_its_port_until_told_to_resume(
    bridge: Bridge, client: Graph, board_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    board = bridge.boards["uno"]
    assert wait_for(lambda: _connected(board), PROMPT), board.info()
    assert wait_for(lambda: _on_graph(client, "/chatter"), PROMPT)
    with pytest.raises(PortBusyError) as busy:  # the bridge holds the port's lock
        check_port(str(board_path))
    assert busy.value.pid == os.getpid()

    held = find_holding_board(client, str(board_path), busy.value.pid)
    assert held is not None and held.name == "uno" and held.pid == os.getpid()
    assert find_holding_board(client, str(board_path), os.getpid() + 1) is None  # not that one
    assert find_holding_board(client, "/dev/null", None) is None

    pause = BridgePause(client, held)
    pause.pause()
    # the reply came after the link closed: the port is free at once, the session ended
    check_port(str(board_path))
    assert board.state == "paused" and board.link is None
    assert board.info()["topics"] == {}
    assert wait_for(lambda: not _on_graph(client, "/chatter"), PROMPT)
    assert "uno: released " in caplog.text and "for an upload; holding off" in caplog.text
    # it stays off the port (a bridge reopening a device path would grab whatever appears)
    assert not wait_for(lambda: board.state != "paused", 2.0), board.info()
    check_port(str(board_path))

    pause.resume()
    assert wait_for(lambda: _connected(board), PROMPT), board.info()
    assert wait_for(lambda: _on_graph(client, "/chatter"), PROMPT)
    assert "uno: resuming: reopening" in caplog.text
    with pytest.raises(PortBusyError):
        check_port(str(board_path))


def test_a_pause_that_nobody_ends_ends_at_its_deadline(
    bridge: Bridge, board_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    board = bridge.boards["uno"]
    assert wait_for(lambda: _connected(board), PROMPT), board.info()
    assert board.pause(0.5)
    assert wait_for(lambda: _connected(board), PROMPT), board.info()
    assert "no resume came before the pause's deadline" in caplog.text
    with pytest.raises(HwBridgeError, match="pause seconds"):
        board.pause(0)


def test_control_requests_that_make_no_sense_get_an_error(bridge: Bridge, client: Graph) -> None:
    from hwbridge.bridge.control import HeldBoard

    board = bridge.boards["uno"]
    assert wait_for(lambda: _connected(board), PROMPT), board.info()
    odd = BridgePause(client, HeldBoard("uno", "", os.getpid()))
    with pytest.raises(HwBridgeError, match="pause: a number of seconds"):
        odd.request({"pause": "soon"})
    with pytest.raises(HwBridgeError, match="resume"):
        odd.request({})
    assert board.state == "connected"
    missing = BridgePause(client, HeldBoard("nosuch", "", os.getpid()))
    with pytest.raises(HwBridgeError, match="did not answer"):
        missing.request({"resume": True}, timeout=1.0)


def test_link_device() -> None:
    assert link_device("/dev/null") == "/dev/null"
    assert link_device("serial:///dev/null?baud=57600") == "/dev/null"
    assert link_device("spy+serial:///dev/null") == "/dev/null"
    assert link_device("socket://127.0.0.1:1") is None
    assert link_device("pty://") is None


def test_upload_names_a_holder_that_is_no_bridge_and_leaves_it(
    tmp_path: Path, endpoint: str
) -> None:
    """``flock`` holds the port as a serial monitor would: the upload names it and does not
    touch it, even with --pause-bridge (no bridge on the graph has the port)."""
    port = tmp_path / "ttyHELD"
    pty = PtyBoard(port, native_sketch(), name="held").start()
    holder = subprocess.Popen(["flock", str(port), "sleep", "600"])
    try:
        assert wait_for(lambda: _busy(port), PROMPT)
        graph = Graph.embedded(listen=[endpoint], domain="pause")  # a graph, but no bridge
        try:
            image = tmp_path / "empty.hex"
            image.write_text(":0400000000000000FC\n:00000001FF\n")
            done = subprocess.run(
                [sys.executable, "-m", "hwbridge", "firmware", "upload", str(image),
                 "--port", str(port), "--pause-bridge"],
                capture_output=True,
                text=True,
                timeout=120,
                check=False,
                env={**os.environ, "HWBRIDGE_ENDPOINT": endpoint, "HWBRIDGE_DOMAIN": "pause"},
            )  # fmt: skip
        finally:
            graph.close()
        assert done.returncode == 1, done.stderr
        assert f"port {port.resolve()} is busy" in done.stderr or "is busy" in done.stderr
        assert f"pid {holder.pid}: flock" in done.stderr, done.stderr
        assert "pause:" not in done.stderr
        assert holder.poll() is None  # left alone
    finally:
        holder.kill()
        holder.wait(10)
        pty.stop()


def _busy(port: Path) -> bool:
    try:
        check_port(str(port))
    except PortBusyError:
        return True
    return False


def test_an_upload_stopped_with_ctrl_c_gives_the_port_back(
    bridge: Bridge, board_path: Path, endpoint: str, tmp_path: Path
) -> None:
    """``firmware upload --pause-bridge`` into a port the bridge holds, whose board has no
    bootloader (avrdude keeps trying to get in sync), stopped with SIGINT as Ctrl-C does: the
    bridge is told to resume and the board comes back."""
    board = bridge.boards["uno"]
    assert wait_for(lambda: _connected(board), PROMPT), board.info()
    if shutil.which("avrdude") is None:
        pytest.skip("avrdude is not installed (apt-get install avrdude)")
    image = tmp_path / "empty.hex"
    image.write_text(":0400000000000000FC\n:00000001FF\n")
    log = tmp_path / "upload.log"
    with log.open("w") as out:
        upload = subprocess.Popen(
            [sys.executable, "-m", "hwbridge", "firmware", "upload", str(image),
             "--port", str(board_path), "--pause-bridge"],
            stdout=out,
            stderr=subprocess.STDOUT,
            env={**os.environ, "HWBRIDGE_ENDPOINT": endpoint, "HWBRIDGE_DOMAIN": "pause"},
        )  # fmt: skip
        try:
            assert wait_for(lambda: "reset: " in log.read_text(), PROMPT), log.read_text()
            assert board.state == "paused"
            upload.send_signal(signal.SIGINT)
            assert upload.wait(60) == 130, log.read_text()
        finally:
            if upload.poll() is None:
                upload.kill()
                upload.wait(10)
    assert "resume: board uno" in log.read_text(), log.read_text()
    assert wait_for(lambda: _connected(board), PROMPT), board.info()
