"""``hwbridge monitor`` as a user sees it: live in an 80x24 terminal (a real tmux), and as JSON
for scripts, against a real bridge (``hwbridge connect``) of an emulated board
(``hwbridge emulate``), each a process of its own."""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator

import pytest

from tests.bridgeproc import BridgeProcess
from tests.netutil import wait_until

TOPIC_LINE = re.compile(r"^(?P<topic>/\w+)\s+(?P<rate>\d+\.\d) Hz\s+\d+(\.\d)? k?B/s\b")


@pytest.fixture(scope="module")
def bridge(tmp_path_factory: pytest.TempPathFactory) -> Iterator[BridgeProcess]:
    """An emulated diffbot board on a pty, bridged on an endpoint and domain of its own."""
    tmp = tmp_path_factory.mktemp("monitor")
    out = tmp / "emulate.out"
    with out.open("w") as stdout, (tmp / "emulate.err").open("w") as stderr:
        board = subprocess.Popen(
            [sys.executable, "-m", "hwbridge", "emulate", "diffbot"], stdout=stdout, stderr=stderr
        )
    try:
        assert wait_until(lambda: "\n" in out.read_text(), 120, step=0.05)
        url = out.read_text().splitlines()[0]
        bridge = BridgeProcess(url, tmp, f"monitorterm{os.getpid()}", "--name", "base")
        try:
            bridge.wait_ready()
            yield bridge
        finally:
            bridge.stop()
    finally:
        board.send_signal(signal.SIGINT)
        try:
            board.wait(30)
        finally:
            if board.poll() is None:
                board.kill()


def board_connected(bridge: BridgeProcess) -> bool:
    listed = bridge.cli("board", "list", "--json")
    return listed.returncode == 0 and bool(json.loads(listed.stdout or "[]"))


@pytest.mark.skipif(shutil.which("tmux") is None, reason="needs tmux")
def test_monitor_live_in_an_80x24_terminal(bridge: BridgeProcess) -> None:
    socket = f"hwbridge-monitor-{os.getpid()}"
    env = {k: bridge.env[k] for k in ("HWBRIDGE_ENDPOINT", "HWBRIDGE_DOMAIN")}
    env["PYTHONPATH"] = os.environ.get("PYTHONPATH", "")
    command = (
        shlex.join(["env", *(f"{k}={v}" for k, v in env.items()), sys.executable, "-m", "hwbridge"])
        + " monitor --interval 0.5"
    )
    tmux = ["tmux", "-L", socket]
    subprocess.run(
        [*tmux, "new-session", "-d", "-s", "mon", "-x", "80", "-y", "24", command],
        check=True,
        timeout=60,
    )
    try:
        screen: list[str] = []

        def shows_the_robot() -> bool:
            # -J joins a line the terminal wrapped: a wrapped line shows as one too long
            done = subprocess.run(
                [*tmux, "capture-pane", "-p", "-J", "-t", "mon"],
                capture_output=True,
                text=True,
                timeout=60,
                check=False,
            )
            screen[:] = done.stdout.splitlines()
            rates = [m for m in map(TOPIC_LINE.match, screen) if m and float(m["rate"]) > 0]
            board = [line for line in screen if line.startswith("base ")]
            return bool(rates) and bool(board) and "B/s" in board[0]

        assert wait_until(shows_the_robot, 120, step=0.3), "\n".join(screen)
        text = "\n".join(screen)
        too_long = [line for line in screen if len(line) > 80]
        assert not too_long, text
        assert len(screen) <= 24
        assert screen[0].startswith("hwbridge monitor"), text
        header = next(line for line in screen if line.startswith("board "))
        for column in ("state", "rx", "tx", "crc", "drop"):
            assert re.search(rf"\b{column}\b", header, re.I), header
        (row,) = [line for line in screen if line.startswith("base ")]
        assert " connected " in row
        topics = {m["topic"] for m in map(TOPIC_LINE.match, screen) if m}
        assert {"/wheel_ticks", "/imu_raw"} <= topics, text
        # Ctrl-C ends it promptly (the session goes with it)
        subprocess.run([*tmux, "send-keys", "-t", "mon", "C-c"], check=True, timeout=60)

        def session_gone() -> bool:
            alive = subprocess.run(
                [*tmux, "has-session", "-t", "mon"], capture_output=True, timeout=60, check=False
            )
            return alive.returncode != 0

        assert wait_until(session_gone, 60, step=0.1)
    finally:
        subprocess.run([*tmux, "kill-server"], capture_output=True, timeout=60, check=False)


def test_monitor_json_once(bridge: BridgeProcess) -> None:
    assert wait_until(lambda: board_connected(bridge), 60, step=0.2)
    done = bridge.cli("monitor", "--json", "--once", "--wait", "2")
    assert done.returncode == 0, done.stderr
    assert len(done.stdout.splitlines()) == 1
    snapshot = json.loads(done.stdout)
    (board,) = snapshot["boards"]
    assert board["name"] == "base" and board["state"] == "connected"
    assert board["stats"]["frames_received"] > 0 and board["rx_rate"] > 0
    topics = {topic["name"]: topic for topic in snapshot["topics"]}
    assert topics["/wheel_ticks"]["rate"] > 0
    assert topics["/wheel_ticks"]["type"] == "hwbridge_msgs/WheelTicks"
    assert isinstance(snapshot["log"], list)
    assert snapshot["endpoint"].find(bridge.endpoint) >= 0
