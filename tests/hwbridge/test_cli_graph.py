"""``hwbridge topic|service|param|node`` against a real graph (router in this process)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from hwbridge.cli import main
from hwbridge.graph import Graph, ParamServer
from tests.netutil import free_port, wait_until


@pytest.fixture(scope="module")
def board(endpoint: str) -> Iterator[dict[str, Any]]:
    """A fake board graph: publishes /diffbot/chatter and /diffbot/odom, serves, holds params."""
    graph = Graph.embedded(listen=[endpoint], domain="clitest")
    node = graph.node("fake_board", namespace="/diffbot")
    chatter = node.publisher("chatter", "std_msgs/String")
    odom = node.publisher("odom", "nav_msgs/Odometry")
    sonar = node.publisher("sonar", "sensor_msgs/Range")
    received: list[Any] = []
    node.subscriber("cmd_vel", "geometry_msgs/Twist", received.append)
    node.service("reset", "std_srvs/Trigger", lambda _: {"success": True, "message": "reset done"})
    ParamServer(graph, {"/diffbot": {"wheel_radius": 0.033}})
    stop = threading.Event()

    def run() -> None:
        count = 0
        while not stop.is_set():
            chatter.publish({"data": f"hello {count}"})
            odom.publish({"header": {"seq": count, "frame_id": "odom"}})
            # Nothing in range (REP-117: +inf), and a field of no meaning here left NaN.
            sonar.publish({"range": math.inf, "field_of_view": math.nan, "min_range": 0.02})
            count += 1
            stop.wait(0.02)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    yield {"graph": graph, "cmd_vel": received}
    stop.set()
    thread.join()
    graph.close()


@pytest.fixture(autouse=True)
def _attach(endpoint: str, monkeypatch: pytest.MonkeyPatch, board: dict[str, Any]) -> None:
    monkeypatch.setenv("HWBRIDGE_ENDPOINT", endpoint)
    monkeypatch.setenv("HWBRIDGE_DOMAIN", "clitest")


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_topic_list_info_type(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "topic", "list")
    assert code == 0
    assert {"/diffbot/chatter", "/diffbot/odom", "/diffbot/cmd_vel"} <= set(out.split())
    code, out, _ = run(capsys, "topic", "list", "--json")
    rows = {row["topic"]: row for row in json.loads(out)}
    assert rows["/diffbot/odom"]["types"] == ["nav_msgs/Odometry"]
    assert rows["/diffbot/odom"]["publishers"] == ["/diffbot/fake_board"]
    assert run(capsys, "topic", "type", "/diffbot/chatter") == (0, "std_msgs/String\n", "")
    code, out, _ = run(capsys, "topic", "info", "/diffbot/odom")
    assert "Type: nav_msgs/Odometry (md5 cd5e73d190d741a2f92e81eda573aca7)" in out
    assert " * /diffbot/fake_board" in out
    code, _, err = run(capsys, "topic", "type", "/nothing/here")
    assert code == 1
    assert "no publisher" in err


def _refuse(token: str) -> None:
    raise AssertionError(f"not strict JSON: {token}")


def test_topic_echo(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "topic", "echo", "/diffbot/chatter", "-n", "2")
    assert code == 0
    docs = [d for d in out.split("---\n") if d.strip()]
    assert len(docs) == 2
    assert all(yaml.safe_load(d)["data"].startswith("hello ") for d in docs)
    code, out, _ = run(capsys, "topic", "echo", "/diffbot/odom", "-n", "1", "--json")
    assert json.loads(out)["header"]["frame_id"] == "odom"
    # Strict JSON: no bare Infinity/NaN tokens, which jq and most readers refuse.
    code, out, _ = run(capsys, "topic", "echo", "/diffbot/sonar", "-n", "1", "--json")
    assert code == 0
    sonar = json.loads(out, parse_constant=_refuse)
    assert (sonar["range"], sonar["field_of_view"]) == ("Infinity", "NaN")
    assert sonar["min_range"] == pytest.approx(0.02)
    code, _, err = run(capsys, "topic", "echo", "/silent", "--timeout", "0.3")
    assert code == 1
    assert "no message on /silent" in err


def test_topic_echo_of_an_index_past_a_fixed_length_list(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, _ = run(capsys, "topic", "echo", "/diffbot/odom/pose/covariance/35", "-n", "1")
    assert (code, out) == (0, "0.0\n---\n")
    # A covariance has 36 elements in every message: index 36 is refused before any arrives,
    # not skipped in each message until -n is reached (status 0, nothing printed).
    code, out, err = run(capsys, "topic", "echo", "/diffbot/odom/pose/covariance/36", "-n", "1")
    assert (code, out) == (1, "")
    assert err == (
        "error: /diffbot/odom: nav_msgs/Odometry pose.covariance has 36 elements: no index 36 "
        "(0 to 35)\n"
    )


def test_topic_hz_and_bw(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "topic", "hz", "/diffbot/chatter", "--duration", "1.5", "--json")
    assert code == 0
    line = json.loads(out.splitlines()[-1])
    assert line["rate_hz"] > 0
    assert line["messages"] >= 2
    code, out, _ = run(capsys, "topic", "bw", "/diffbot/odom", "--duration", "1.2")
    assert code == 0
    assert "average:" in out
    assert "mean: 704.00B" in out  # an Odometry with an empty frame id is 704 bytes


def test_topic_pub_reaches_the_board(
    capsys: pytest.CaptureFixture[str], board: dict[str, Any]
) -> None:
    code, _, err = run(
        capsys, "topic", "pub", "/diffbot/cmd_vel", "geometry_msgs/Twist", "{linear: {x: 0.25}}"
    )
    assert (code, err) == (0, "")
    assert wait_until(lambda: bool(board["cmd_vel"]))
    assert board["cmd_vel"][-1].linear.x == 0.25
    code, _, _ = run(
        capsys,
        "topic",
        "pub",
        "-r",
        "50",
        "-n",
        "5",
        "/diffbot/cmd_vel",
        "geometry_msgs/Twist",
        "{angular: {z: 1}}",
    )
    assert code == 0
    assert wait_until(lambda: sum(m.angular.z == 1.0 for m in board["cmd_vel"]) == 5)
    code, _, err = run(
        capsys, "topic", "pub", "/diffbot/cmd_vel", "geometry_msgs/Twist", "{linear: {x: fast}}"
    )
    assert code == 1
    assert "linear.x: expected a number" in err
    code, _, _ = run(capsys, "topic", "pub", "-1", "-r", "2", "/x", "std_msgs/Empty")
    assert code == 2


def test_services(capsys: pytest.CaptureFixture[str]) -> None:
    assert run(capsys, "service", "list") == (0, "/diffbot/reset\n", "")
    assert run(capsys, "service", "type", "/diffbot/reset") == (0, "std_srvs/Trigger\n", "")
    code, out, _ = run(capsys, "service", "call", "/diffbot/reset")
    assert code == 0
    assert yaml.safe_load(out) == {"success": True, "message": "reset done"}
    code, out, _ = run(capsys, "service", "call", "/diffbot/reset", "--json")
    assert json.loads(out)["message"] == "reset done"
    code, _, err = run(capsys, "service", "call", "/diffbot/missing", "--timeout", "0.5")
    assert code == 1
    assert "no server for service /diffbot/missing" in err


def test_a_call_waits_within_its_timeout_for_a_server_to_appear(
    capsys: pytest.CaptureFixture[str], board: dict[str, Any]
) -> None:
    """A board's services leave the graph while its session is negotiated again (after a link
    loss or a reset); a call made meanwhile waits for the server instead of failing at once."""
    graph: Graph = board["graph"]
    node = graph.node("late_server", namespace="/diffbot")
    started = threading.Event()

    def serve_later() -> None:
        started.wait(30)
        # a chosen delay, not a wait: declared after the call's first discovery (--wait 0.2)
        time.sleep(1.0)
        node.service("late", "std_srvs/Trigger", lambda _: {"success": True, "message": "late"})

    thread = threading.Thread(target=serve_later, daemon=True)
    thread.start()
    started.set()
    code, out, err = run(
        capsys, "service", "call", "/diffbot/late", "--wait", "0.2", "--timeout", "30"
    )
    thread.join(30)
    assert code == 0, err
    assert yaml.safe_load(out) == {"success": True, "message": "late"}


def test_a_call_that_no_server_took_goes_again_once_a_server_is_there(
    capsys: pytest.CaptureFixture[str], board: dict[str, Any]
) -> None:
    """A service still listed when its server has gone (a board's session ending, its
    liveliness not yet withdrawn): the request reaches nobody, and nothing acted on it, so the
    call goes again when a server is back, within its timeout."""
    graph: Graph = board["graph"]
    node = graph.node("flaky_server", namespace="/diffbot")
    token = graph.announce("srv", node.name, "/diffbot/flaky", "std_srvs/Trigger")  # listed only
    answered: list[str] = []
    listed = threading.Event()

    def serve_later() -> None:
        listed.wait(30)
        time.sleep(1.0)  # a chosen delay, not a wait: after the call's first request
        node.service(
            "flaky", "std_srvs/Trigger", lambda _: answered.append("x") or {"success": True}
        )

    thread = threading.Thread(target=serve_later, daemon=True)
    thread.start()
    assert wait_until(lambda: "/diffbot/flaky" in graph.snapshot(timeout=0.2).services(), 10)
    listed.set()
    try:
        code, out, err = run(capsys, "service", "call", "/diffbot/flaky", "--timeout", "30")
    finally:
        thread.join(30)
        token.undeclare()
    assert code == 0, err
    assert yaml.safe_load(out) == {"success": True, "message": ""}
    assert answered == ["x"]  # asked again, answered once


def test_params(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert run(capsys, "param", "get", "/diffbot/wheel_radius") == (0, "0.033\n", "")
    assert run(capsys, "param", "set", "/diffbot/max_speed", "0.5")[0] == 0
    code, out, _ = run(capsys, "param", "get", "/diffbot")
    assert yaml.safe_load(out) == {"max_speed": 0.5, "wheel_radius": 0.033}
    config = tmp_path / "robot.yaml"
    config.write_text("sonar:\n  rate: 10\n  frame: sonar_link\nnames: [a, b]\n")
    assert run(capsys, "param", "load", str(config), "/lab")[0] == 0
    code, out, _ = run(capsys, "param", "list", "--json")
    assert {"/lab/sonar/rate", "/lab/sonar/frame", "/lab/names"} <= set(json.loads(out))
    dump = tmp_path / "dump.yaml"
    assert run(capsys, "param", "dump", str(dump), "--namespace", "/lab")[0] == 0
    assert yaml.safe_load(dump.read_text()) == {
        "names": ["a", "b"],
        "sonar": {"frame": "sonar_link", "rate": 10},
    }
    assert run(capsys, "param", "delete", "/lab")[0] == 0
    code, _, err = run(capsys, "param", "get", "/lab")
    assert code == 1
    assert "no parameter /lab" in err


def test_param_dump_to_a_file_that_cannot_be_written(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    code, out, err = run(capsys, "param", "dump", str(blocker / "params.yaml"))
    assert (code, out) == (1, "")
    assert err == f"error: {blocker / 'params.yaml'}: Not a directory\n"


def test_node_list_in_a_subprocess(endpoint: str) -> None:
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "hwbridge",
            "--endpoint",
            endpoint,
            "--domain",
            "clitest",
            "node",
            "list",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert "/diffbot/fake_board" in done.stdout.split()


def test_no_bridge_is_reported(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "--endpoint", f"tcp/127.0.0.1:{free_port()}", "topic", "list")
    assert code == 1
    assert "is a bridge running" in err


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--endpoint", "127.0.0.1:7447", "topic", "list"], "tcp/127.0.0.1:7447"),
        (["graph", "--listen", "localhost:7447"], "tcp/localhost:7447"),
        (["--endpoint", "robot", "topic", "list"], "tcp/127.0.0.1:7447"),
    ],
)
def test_an_endpoint_without_its_protocol(
    capsys: pytest.CaptureFixture[str], argv: list[str], said: str
) -> None:
    code, _, err = run(capsys, *argv)
    endpoint = argv[argv.index("--endpoint" if "--endpoint" in argv else "--listen") + 1]
    assert code == 1
    assert err == (
        f"error: {endpoint!r} is not a Zenoh endpoint: write PROTOCOL/ADDRESS, e.g. {said}\n"
    )
