"""What a new user meets first with the topic, board, service and param tools.

Every case runs ``hwbridge`` as a subprocess against a real graph: the emulated diffbot brought
up as on a bench (``hwbridge emulate diffbot --tcp PORT`` and ``hwbridge up diffbot.yaml``), or,
where no board is needed, a graph node of the test's own on that robot's graph.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from hwbridge.graph import Graph
from tests.hwbridge.test_up import DIFFBOT, Processes
from tests.netutil import free_port, wait_until


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Processes]:
    """The emulated diffbot, up: board ``base`` in ``/diffbot``, host nodes for its devices."""
    procs = Processes(tmp_path_factory.mktemp("robot"))
    try:
        url = procs.emulate("diffbot", "--tcp", str(free_port()))
        _up, log = procs.start("up", "up", str(DIFFBOT), "--link", f"base={url}")
        assert wait_until(lambda: "robot diffbot up" in log.read_text(), 60), log.read_text()
        # Up means the board's endpoints are declared; wait until its data flows.
        first = procs.cli("topic", "echo", "/diffbot/odom", "-n", "1", "--timeout", "60")
        assert first.returncode == 0, first.stderr
        yield procs
    finally:
        procs.stop()


@pytest.fixture
def node(robot: Processes) -> Iterator[Graph]:
    """A graph client of the test's own on the robot's graph."""
    graph = Graph.attached(
        connect=[robot.env["HWBRIDGE_ENDPOINT"]], domain=robot.env["HWBRIDGE_DOMAIN"]
    )
    yield graph
    graph.close()


def _failed(done: subprocess.CompletedProcess[str]) -> str:
    """The one error line of a command that failed as a user error should."""
    assert done.returncode == 1, (done.returncode, done.stdout, done.stderr)
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    return lines[0]


def _yaml_docs(text: str) -> list[Any]:
    return [yaml.safe_load(doc) for doc in text.split("---\n") if doc.strip()]


# ---------------------------------------------------------------------- a. topic pub's type
def test_pub_refuses_a_type_other_than_the_boards(robot: Processes) -> None:
    done = robot.cli("topic", "pub", "-1", "/diffbot/cmd_vel", "std_msgs/String", "{data: hi}")
    line = _failed(done)
    assert line.startswith("error: /diffbot/cmd_vel is geometry_msgs/Twist on the graph"), line
    assert "subscribed by /diffbot/" in line and line.endswith("not std_msgs/String"), line


def test_pub_infers_the_type_of_a_live_topic(robot: Processes, node: Graph) -> None:
    received: list[Any] = []
    node.node("listener").subscriber("/diffbot/cmd_vel", "geometry_msgs/Twist", received.append)
    done = robot.cli("topic", "pub", "-r", "20", "-n", "10", "/diffbot/cmd_vel", "{linear: {x: 0}}")
    assert done.returncode == 0, done.stderr
    assert wait_until(lambda: bool(received), 30)
    assert received[-1].linear.x == 0.0


def test_pub_without_a_type_on_a_topic_nobody_uses(robot: Processes) -> None:
    line = _failed(robot.cli("topic", "pub", "-1", "/diffbot/cmd_vell", "{linear: {x: 0.2}}"))
    assert "cannot tell the type of /diffbot/cmd_vell" in line, line
    assert "did you mean /diffbot/cmd_vel?" in line and "give the type" in line, line


# ---------------------------------------------------------------------- b. nobody publishes
@pytest.mark.parametrize("tool", ["echo", "hz", "bw"])
def test_a_topic_nobody_publishes_is_reported(robot: Processes, tool: str) -> None:
    line = _failed(robot.cli("topic", tool, "/diffbot/odm"))
    assert "no publisher of /diffbot/odm yet; did you mean /diffbot/odom?" in line, line


def test_info_of_a_topic_unknown_to_the_graph(robot: Processes) -> None:
    line = _failed(robot.cli("topic", "info", "/diffbot/odm"))
    assert "nothing publishes or subscribes /diffbot/odm; did you mean /diffbot/odom?" in line
    known = robot.cli("topic", "info", "/diffbot/cmd_vel")  # subscribed only: still shown
    assert known.returncode == 0, known.stderr
    assert "Type: geometry_msgs/Twist" in known.stdout


def test_type_of_a_topic_unknown_to_the_graph_suggests(robot: Processes) -> None:
    line = _failed(robot.cli("topic", "type", "/diffbot/odm"))
    assert line == (
        "error: no publisher or typed subscriber on /diffbot/odm; did you mean /diffbot/odom? "
        "(see 'hwbridge topic list')"
    )


@pytest.mark.parametrize(
    "argv",
    [
        ("topic", "echo", "/diffbot/odom/", "-n", "1"),
        ("topic", "hz", "/diffbot/odom/"),
        ("topic", "bw", "/diffbot/odom/"),
        ("topic", "type", "/diffbot/odom/"),
        ("topic", "info", "/diffbot/odom/"),
        ("topic", "pub", "-1", "/diffbot/odom/", "{}"),
        ("record", "/diffbot/odom/", "--duration", "1", "-o", "/nonexistent/never.mcap"),
    ],
    ids=lambda argv: " ".join(argv[:2]),
)
def test_a_topic_with_a_trailing_slash_is_refused_naming_the_topic_meant(
    robot: Processes, argv: tuple[str, ...]
) -> None:
    """As the graph's names are: '/diffbot/odom/' is no topic name (before, echo, hz and bw
    said nothing published it, pub and type failed without naming the topic meant)."""
    line = _failed(robot.cli(*argv))
    assert line == (
        "error: '/diffbot/odom/': a topic name does not end with '/'; did you mean /diffbot/odom?"
    )


def test_a_field_path_with_a_trailing_slash_is_refused_too(robot: Processes) -> None:
    line = _failed(robot.cli("topic", "echo", "/diffbot/odom/pose/", "-n", "1"))
    assert line.endswith("does not end with '/'; did you mean /diffbot/odom/pose?"), line


def test_a_relative_topic_name_is_resolved_in_the_root_namespace(robot: Processes) -> None:
    done = robot.cli("topic", "type", "diffbot/odom")
    assert (done.returncode, done.stdout) == (0, "nav_msgs/Odometry\n"), done.stderr
    done = robot.cli("topic", "echo", "diffbot/odom/pose/pose/position/z", "-n", "1")
    assert (done.returncode, done.stdout) == (0, "0.0\n---\n"), done.stderr


def test_echo_with_wait_says_so_once_then_waits_for_a_publisher(
    robot: Processes, node: Graph
) -> None:
    echo = subprocess.Popen(
        [sys.executable, "-m", "hwbridge", "topic", "echo", "/diffbot/late", "-n", "1", "--wait"],
        env=robot.env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert echo.stderr is not None
        note = echo.stderr.readline()
        assert note.startswith("no publisher of /diffbot/late yet"), note
        assert echo.poll() is None  # still waiting
        late = node.node("late").publisher("/diffbot/late", "std_msgs/String")
        stop = threading.Event()

        def publish() -> None:
            while not stop.is_set():
                late.publish({"data": "at last"})
                stop.wait(0.05)

        thread = threading.Thread(target=publish, daemon=True)
        thread.start()
        try:
            out, err = echo.communicate(timeout=60)
        finally:
            stop.set()
            thread.join()
    finally:
        if echo.poll() is None:
            echo.kill()
            echo.wait()
    assert echo.returncode == 0, err
    assert _yaml_docs(out) == [{"data": "at last"}]
    assert "no publisher" not in err  # the note was said once


# ---------------------------------------------------------------------- c. fields
def test_echo_selects_a_field(robot: Processes) -> None:
    done = robot.cli("topic", "echo", "/diffbot/odom/pose/pose/position", "-n", "2")
    assert done.returncode == 0, done.stderr
    docs = _yaml_docs(done.stdout)
    assert len(docs) == 2 and all(set(doc) == {"x", "y", "z"} for doc in docs), done.stdout


def test_echo_selects_a_list_element_as_json(robot: Processes) -> None:
    done = robot.cli("topic", "echo", "/diffbot/joint_states/position/0", "-n", "1", "--json")
    assert done.returncode == 0, done.stderr
    assert isinstance(json.loads(done.stdout), float), done.stdout


def test_echo_of_a_field_that_does_not_exist(robot: Processes) -> None:
    line = _failed(robot.cli("topic", "echo", "/diffbot/odom/pose/pos"))
    assert "no field 'pos'" in line and "its fields are pose, covariance" in line, line


# ---------------------------------------------------------------------- d. the only board
def test_board_info_and_stats_default_to_the_only_board(robot: Processes) -> None:
    info = robot.cli("board", "info", "--json")
    assert info.returncode == 0, info.stderr
    assert json.loads(info.stdout)["name"] == "base"
    stats = robot.cli("board", "stats", "--json")
    assert stats.returncode == 0, stats.stderr
    assert json.loads(stats.stdout)["board"] == "base"


def test_board_info_with_several_boards_lists_them(tmp_path: Path) -> None:
    procs = Processes(tmp_path)
    try:
        urls = [procs.emulate("diffbot", "--tcp", str(free_port())) for _ in range(2)]
        _bridge, log = procs.start("connect", "connect", *urls, "--name", "left", "--name", "right")
        assert wait_until(lambda: "hwbridge: bridging" in log.read_text(), 60), log.read_text()

        def both_listed() -> bool:
            rows = procs.cli("board", "list").stdout.splitlines()
            return {"left", "right"} <= {row.split("\t")[0] for row in rows}

        assert wait_until(both_listed, 60, step=0.5), log.read_text()
        line = _failed(procs.cli("board", "info"))
        assert "2 boards are connected (left, right)" in line, line
    finally:
        procs.stop()


def test_board_info_with_no_board(endpoint: str) -> None:
    with Graph.embedded(listen=[endpoint], domain="noboard"):
        done = subprocess.run(
            [sys.executable, "-m", "hwbridge", "board", "stats"],
            env={**os.environ, "HWBRIDGE_ENDPOINT": endpoint, "HWBRIDGE_DOMAIN": "noboard"},
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
    assert "no board is connected" in _failed(done)


# ---------------------------------------------------------------------- e. what echo shows
def test_echo_shows_no_constants(robot: Processes) -> None:
    done = robot.cli("topic", "echo", "/diffbot/range", "-n", "1")
    assert done.returncode == 0, done.stderr
    (doc,) = _yaml_docs(done.stdout)
    assert doc["radiation_type"] == 0
    assert "ULTRASOUND" not in doc and "INFRARED" not in doc, doc


def test_echo_shows_the_publishers_header_seq(robot: Processes) -> None:
    done = robot.cli("topic", "echo", "/diffbot/range/header/seq", "-n", "3", "--json")
    assert done.returncode == 0, done.stderr
    seqs = [json.loads(line) for line in done.stdout.splitlines()]
    assert len(seqs) == 3 and seqs[0] > 0, seqs
    assert seqs == sorted(set(seqs)), seqs


# ---------------------------------------------------------------------- services, params
def test_service_call_of_a_missing_service_suggests(robot: Processes, node: Graph) -> None:
    node.node("resetter", namespace="/diffbot").service(
        "reset", "std_srvs/Trigger", lambda _: {"success": True}
    )
    assert wait_until(lambda: "/diffbot/reset" in robot.cli("service", "list").stdout, 30)
    line = _failed(robot.cli("service", "call", "/diffbot/rest"))
    assert "no server for service /diffbot/rest; did you mean /diffbot/reset?" in line, line


def test_param_get_of_a_missing_parameter_suggests(robot: Processes) -> None:
    assert robot.cli("param", "set", "/diffbot/max_speed", "0.5").returncode == 0
    line = _failed(robot.cli("param", "get", "/diffbot/max_sped"))
    assert "no parameter /diffbot/max_sped; did you mean /diffbot/max_speed?" in line, line


@pytest.mark.parametrize(
    ("argv", "kind", "meant"),
    [
        (("service", "call", "/diffbot/reset/"), "service", "/diffbot/reset"),
        (("service", "type", "diffbot/reset/"), "service", "/diffbot/reset"),
        (("param", "get", "/diffbot/max_speed/"), "parameter", "/diffbot/max_speed"),
        (("param", "set", "/diffbot/max_speed/", "1"), "parameter", "/diffbot/max_speed"),
        (("param", "delete", "/diffbot/max_speed/"), "parameter", "/diffbot/max_speed"),
    ],
    ids=["service call", "service type", "param get", "param set", "param delete"],
)
def test_a_service_or_parameter_with_a_trailing_slash_names_the_one_meant(
    robot: Processes, argv: tuple[str, ...], kind: str, meant: str
) -> None:
    """As topics are (before: 'no server for service /diffbot/reset/', or the graph's bare rule
    for a parameter, naming nothing)."""
    line = _failed(robot.cli(*argv))
    assert line == f"error: {argv[2]!r}: a {kind} name does not end with '/'; did you mean {meant}?"


def test_relative_service_and_parameter_names_are_resolved_as_topics_are(
    robot: Processes, node: Graph
) -> None:
    """In the root namespace (before, 'service type diffbot/reset' found no server: the name
    was looked up as typed), and a namespace may end with '/' (before, 'param dump --namespace
    /diffbot/' was refused)."""
    node.node("resetter", namespace="/diffbot").service(
        "reset", "std_srvs/Trigger", lambda _: {"success": True, "message": "reset"}
    )
    assert wait_until(lambda: "/diffbot/reset" in robot.cli("service", "list").stdout, 30)
    done = robot.cli("service", "type", "diffbot/reset")
    assert (done.returncode, done.stdout) == (0, "std_srvs/Trigger\n"), done.stderr
    done = robot.cli("service", "call", "diffbot/reset")
    assert (done.returncode, done.stdout) == (0, "success: true\nmessage: reset\n"), done.stderr
    line = _failed(robot.cli("service", "call", "diffbot/rest"))
    assert "no server for service /diffbot/rest; did you mean /diffbot/reset?" in line, line
    assert robot.cli("param", "set", "diffbot/first/gain", "3").returncode == 0
    done = robot.cli("param", "get", "/diffbot/first/gain")
    assert (done.returncode, done.stdout) == (0, "3\n"), done.stderr
    done = robot.cli("param", "dump", "--namespace", "/diffbot/first/")
    assert (done.returncode, done.stdout) == (0, "gain: 3\n"), done.stderr
