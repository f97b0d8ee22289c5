"""Access control for a robot on a network (issue 19, item 7).

``hwbridge robot acl`` writes a Zenoh router config from the running robot's topics; the robot is
restarted with it, and then, in real processes over Zenoh: a viewer can read the odometry but its
``cmd_vel`` does not move the robot and its service calls are refused, while an operator's
``cmd_vel`` does move it (so the check can fail), and a client with a wrong password gets nothing.
"""

from __future__ import annotations

import json
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hwbridge.graph.acl import RobotSurface, access_control, surface_of
from hwbridge.graph.snapshot import GraphEntity, GraphSnapshot
from tests.hwbridge.test_up import DIFFBOT, Processes
from tests.netutil import free_port, wait_until


def _entity(kind: str, name: str, session: str = "robot") -> GraphEntity:
    return GraphEntity(kind, "/diffbot/node", name, "std_msgs/Empty", session)


def test_surface_sorts_topics_by_who_subscribes() -> None:
    snapshot = GraphSnapshot(
        [
            _entity("pub", "/diffbot/odom"),
            _entity("pub", "/diffbot/wheel_targets"),
            _entity("sub", "/diffbot/wheel_targets"),  # published and subscribed: a command
            _entity("sub", "/diffbot/cmd_vel"),
            _entity("srv", "/diffbot/reset"),
            _entity("node", "/diffbot/node"),
            _entity("pub", "/other/odom"),  # another robot's namespace
            _entity("sub", "/diffbot/odom", session="me"),  # the asking tool's own subscriber
        ]
    )
    surface = surface_of(snapshot, ["/diffbot"], exclude_sessions=["me"])
    assert surface == RobotSurface(
        readable=("/diffbot/odom",),
        commands=("/diffbot/cmd_vel", "/diffbot/wheel_targets"),
        services=("/diffbot/reset",),
    )
    assert surface_of(snapshot, ["/"]).readable == ("/other/odom",)


def test_viewers_never_get_ingress_puts() -> None:
    surface = RobotSurface(("/r/odom",), ("/r/cmd_vel",), ("/r/reset",))
    section = access_control(surface, "hwbridge/0")
    rules = {rule["id"]: rule for rule in section["rules"]}
    viewer = next(p for p in section["policies"] if p["id"] == "viewers")
    for rule_id in viewer["rules"]:
        rule = rules[rule_id]
        assert not ("put" in rule["messages"] and "ingress" in rule["flows"]), rule
        assert "query" not in rule["messages"], rule
    assert section["default_permission"] == "deny"
    assert "hwbridge/0/t/r/cmd_vel" in rules["receive"]["key_exprs"]


CLIENT = """{{
  connect: {{ endpoints: ["{endpoint}"] }},
  scouting: {{ multicast: {{ enabled: false }}, gossip: {{ enabled: false }} }},
  transport: {{ auth: {{ usrpwd: {{ user: "{user}", password: "{password}" }} }} }},
}}
"""


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Processes]:
    running = Processes(tmp_path)
    yield running
    running.stop()


def _x(procs: Processes, config: Path) -> float:
    done = procs.cli(
        "--zenoh-config",
        str(config),
        "topic",
        "echo",
        "/diffbot/odom",
        "-n",
        "1",
        "--json",
        "--timeout",
        "20",
    )
    assert done.returncode == 0, done.stderr
    odom = json.loads(done.stdout.splitlines()[0])
    return float(odom["pose"]["pose"]["position"]["x"])


def _drive(procs: Processes, config: Path, name: str) -> subprocess.Popen[str]:
    return procs.start(
        name,
        "--zenoh-config",
        str(config),
        "topic",
        "pub",
        "-r",
        "10",
        "/diffbot/cmd_vel",
        "geometry_msgs/Twist",
        "{linear: {x: 0.3}}",
    )[0]


def test_a_viewer_cannot_move_the_robot(procs: Processes, tmp_path: Path) -> None:
    url = procs.emulate("diffbot", "--tcp", str(free_port()))
    endpoint = procs.env["HWBRIDGE_ENDPOINT"]

    # 1. The robot up as on a bench, and its config written from what it declares.
    up, log = procs.start("up", "up", str(DIFFBOT), "--link", f"base={url}")
    assert wait_until(lambda: "robot diffbot up" in log.read_text(), 30), log.read_text()
    router = tmp_path / "router.json5"
    users = tmp_path / "users.txt"
    users.write_text("viewer:look-only\noperator:drive-it\n")
    written = procs.cli(
        "robot", "acl", str(DIFFBOT), "-o", str(router), "--users", str(users),
        "--listen", endpoint,
    )  # fmt: skip
    assert written.returncode == 0, written.stderr
    text = router.read_text()
    assert "/diffbot/cmd_vel" in text and "/diffbot/odom" in text, text
    up.send_signal(signal.SIGINT)
    assert up.wait(20) == 0, log.read_text()

    # 2. The same robot with the config.
    up, log = procs.start(
        "up-acl", "--zenoh-config", str(router), "up", str(DIFFBOT), "--link", f"base={url}"
    )
    assert wait_until(lambda: "robot diffbot up" in log.read_text(), 30), log.read_text()
    viewer = tmp_path / "viewer.json5"
    viewer.write_text(CLIENT.format(endpoint=endpoint, user="viewer", password="look-only"))
    operator = tmp_path / "operator.json5"
    operator.write_text(CLIENT.format(endpoint=endpoint, user="operator", password="drive-it"))
    stranger = tmp_path / "stranger.json5"
    stranger.write_text(CLIENT.format(endpoint=endpoint, user="viewer", password="guess"))

    start = _x(procs, viewer)  # the viewer reads the odometry
    drive = _drive(procs, viewer, "viewer-pub")
    try:
        time.sleep(3.0)  # 30 commands at 0.3 m/s would move it ~0.9 m
        still = _x(procs, viewer)
    finally:
        drive.send_signal(signal.SIGINT)
        drive.wait(10)
    assert abs(still - start) < 0.02, (start, still)

    # Parameters are queries to the bridge: refused to a viewer, answered to an operator.
    for config, status in ((viewer, "refused"), (operator, "answered")):
        done = procs.cli("--zenoh-config", str(config), "param", "set", "/diffbot/speed", "2")
        assert (done.returncode == 0) == (status == "answered"), (status, done.stderr)

    refused = procs.cli("--zenoh-config", str(stranger), "topic", "list")
    assert refused.returncode != 0 and "cannot join the graph" in refused.stderr

    drive = _drive(procs, operator, "operator-pub")
    try:
        moved = [0.0]

        def has_moved() -> bool:
            moved[0] = _x(procs, operator) - still
            return moved[0] > 0.1

        assert wait_until(has_moved, 30, step=0.5), moved
    finally:
        drive.send_signal(signal.SIGINT)
        drive.wait(10)
    assert up.poll() is None, log.read_text()


def test_services_answer_operators_only(tmp_path: Path) -> None:
    """The generated config in a real Zenoh router: a board-like service refuses a viewer."""
    from hwbridge.errors import HwBridgeError
    from hwbridge.graph import Graph, GraphConfig
    from hwbridge.graph.acl import router_config

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    users = tmp_path / "users.txt"
    users.write_text("viewer:v\noperator:o\n")
    surface = RobotSurface(("/r/odom",), ("/r/cmd_vel",), ("/r/reset",))
    router = tmp_path / "router.json5"
    router.write_text(
        router_config(
            surface, robot="r", prefix="hwbridge/acl", listen=[endpoint], users_file=str(users)
        )
    )
    calls: list[object] = []

    def reset(request: object) -> dict[str, bool]:
        calls.append(request)
        return {"success": True}

    with Graph(GraphConfig.from_file(router, "router", domain="acl")) as robot:
        robot.node("board", "/r").service("reset", "std_srvs/Trigger", reset)
        for user, password, answered in (("viewer", "v", False), ("operator", "o", True)):
            client = tmp_path / f"{user}.json5"
            client.write_text(CLIENT.format(endpoint=endpoint, user=user, password=password))
            with Graph(GraphConfig.from_file(client, "client", domain="acl")) as graph:
                node = graph.node("tool")
                if answered:
                    assert node.call("/r/reset", "std_srvs/Trigger", {}, timeout=5).success
                else:
                    with pytest.raises(HwBridgeError):
                        node.call("/r/reset", "std_srvs/Trigger", {}, timeout=1.0)
    assert len(calls) == 1
