"""``hwbridge monitor`` headless against the demo robot (an emulated diffbot brought up from its
robot file on a pty): its board with link state and counters, its topics with rates, the last
log lines."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Iterator

import pytest

from hwbridge.emulator.board import ROBOTS_DIR, VirtualBoard, load_board
from hwbridge.graph import Graph
from hwbridge.links import open_link
from hwbridge.monitor.model import Monitor
from hwbridge.monitor.view import render
from hwbridge.robot.config import load_robot
from hwbridge.robot.runtime import RobotRuntime
from tests.netutil import wait_until

ROBOT = ROBOTS_DIR / "diffbot.yaml"


@pytest.fixture(scope="module")
def diffbot(router: Graph) -> Iterator[RobotRuntime]:
    robot = load_robot(ROBOT)
    board = VirtualBoard(load_board(str(ROBOT), "base"), seed=2)
    link = open_link("pty://")
    board.start(link)
    runtime = RobotRuntime(
        robot.with_links({"base": link.slave_path}),  # type: ignore[attr-defined]
        router,
    ).start()
    try:
        assert wait_until(lambda: runtime.bridge.boards["base"].state == "connected", 30)
        yield runtime
    finally:
        runtime.stop()
        board.stop()
        link.close()


@pytest.fixture
def log_lines(router: Graph) -> Iterator[None]:
    """A node that says something on /rosout twice a second (as a board's log line goes)."""
    node = router.node("talker")
    rosout = node.publisher("/rosout", "rosgraph_msgs/Log")
    stop = threading.Event()

    def talk() -> None:
        while not stop.wait(0.5):
            rosout.publish({"level": 4, "name": "/talker", "msg": "left wheel stalled"})

    thread = threading.Thread(target=talk, daemon=True)
    thread.start()
    yield
    stop.set()
    thread.join(2)
    rosout.close()


def test_monitor_model_sees_board_topics_rates_and_logs(
    diffbot: RobotRuntime, client: Graph, log_lines: None
) -> None:
    with Monitor(client) as monitor:
        monitor.poll()

        def ready() -> bool:
            snapshot = monitor.poll()
            rates = {t.name: t.rate for t in snapshot.topics}
            boards = {b.name: b for b in snapshot.boards}
            return (
                rates.get("/diffbot/odom", 0) > 0
                and "base" in boards
                and boards["base"].rx_rate is not None
                and bool(snapshot.log)
            )

        assert wait_until(ready, 20, step=0.3)
        snapshot = monitor.poll()
    (board,) = snapshot.boards
    assert (board.name, board.state, board.protocol) == ("base", "connected", "native")
    assert board.url.startswith("/dev/pts/") or "pty" in board.url
    assert board.stats["frames_received"] > 0 and board.stats["crc_errors"] == 0
    assert board.rx_rate is not None and board.rx_rate > 0
    topics = {t.name: t for t in snapshot.topics}
    odom = topics["/diffbot/odom"]
    assert odom.type == "nav_msgs/Odometry" and odom.publishers >= 1
    assert odom.bandwidth > 0 and odom.messages > 0
    for name in ("/diffbot/range", "/diffbot/imu", "/diffbot/joint_states", "/tf"):
        assert name in topics, sorted(topics)
    assert any(line.text == "left wheel stalled" and line.level == "WARN" for line in snapshot.log)
    # the picture holds all of it
    from rich.console import Console

    console = Console(width=200, record=True, file=open(os.devnull, "w"))  # noqa: SIM115, PTH123
    console.print(render(snapshot))
    text = console.export_text()
    for expected in ("base", "connected", "/diffbot/odom", "nav_msgs/Odometry", "Hz"):
        assert expected in text
    assert "left wheel stalled" in text


def test_hwbridge_monitor_once_prints_the_demo_robot(
    diffbot: RobotRuntime, endpoint: str, graph_domain: str, log_lines: None
) -> None:
    env = {
        **os.environ,
        "HWBRIDGE_ENDPOINT": endpoint,
        "HWBRIDGE_DOMAIN": graph_domain,
    }
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "monitor", "--once", "--wait", "2", "--width", "220"],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    out = done.stdout
    boards = out[out.index("boards") : out.index("topics")]
    assert "base" in boards and "connected" in boards and "native" in boards
    assert "CRC errors" in boards and "drops" in boards
    row = next(line for line in boards.splitlines() if line.startswith("base "))
    assert "B/s" in row  # the board's byte rates are measured
    topics = out[out.index("topics") : out.index("last log lines")]
    odom = next(line for line in topics.splitlines() if "/diffbot/odom " in line)
    assert "nav_msgs/Odometry" in odom
    rate = float(odom.split("Hz")[0].split()[-1])
    assert rate > 0  # it flows (the value itself is not a unit test's business)
    assert "left wheel stalled" in out[out.index("last log lines") :]
