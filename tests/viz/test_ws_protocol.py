"""Foxglove-protocol viewers of every generation against ``hwbridge up --viz`` and
``hwbridge viz``, with a client nobody here wrote: ``FoxgloveClient`` of the npm package
``@foxglove/ws-protocol`` under Node.js (``tests/viz/js``), offering ``foxglove.websocket.v1``
(the spec's name, what Lichtblick offers) or ``foxglove.sdk.v1`` (Foxglove's current name).

The robot is the emulated demo diffbot (``hwbridge emulate diffbot`` over TCP) brought up by
``hwbridge up examples/robots/diffbot.yaml --viz``; a service for the service-call cases is
served on the same graph by this test process."""

from __future__ import annotations

import json
import math
import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("websockets.asyncio.server")

from hwbridge.graph import Graph
from hwbridge.graph.config import GraphConfig
from tests.hwbridge.test_up import DIFFBOT, Processes
from tests.netutil import free_port, wait_until
from tests.viz.jsclient import Event, NodeClient, node_or_skip
from tests.viz.test_foxglove import LAYOUT, layout_topics

SPEC = "foxglove.websocket.v1"
SDK = "foxglove.sdk.v1"
FLAG_SERVICE = "/viztest/set_flag"
BROKEN_SERVICE = "/viztest/broken"


class Robot:
    """The running robot's two Foxglove servers and the test's own graph node."""

    def __init__(self, up_url: str, viz_url: str, graph: Graph, tmp: Path) -> None:
        self.up_url = up_url
        self.viz_url = viz_url
        self.graph = graph
        self.tmp = tmp
        self.flags: list[bool] = []

    def client(self, subprotocol: str, name: str, url: str | None = None) -> NodeClient:
        return NodeClient(url or self.up_url, subprotocol, self.tmp / f"{name}.node.log")


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Robot]:
    node_or_skip()
    tmp = tmp_path_factory.mktemp("ws_protocol")
    procs = Processes(tmp)
    try:
        link = procs.emulate("diffbot", "--tcp", str(free_port()))
        port = free_port()
        _up, log = procs.start(
            "up", "up", str(DIFFBOT), "--link", f"base={link}", "--viz", "--viz-port", str(port)
        )
        assert wait_until(lambda: "Foxglove WebSocket on" in log.read_text(), 60), log.read_text()
        served = re.search(r"Foxglove WebSocket on (\S+)", log.read_text())
        assert served is not None
        viz, viz_log = procs.start("viz", "viz", "--port", "0")
        assert viz.stdout is not None
        viz_url = viz.stdout.readline().strip()
        assert viz_url.startswith("ws://"), viz_log.read_text()
        env = procs.env
        graph = Graph(
            GraphConfig.attached([env["HWBRIDGE_ENDPOINT"]], domain=env["HWBRIDGE_DOMAIN"])
        )
        running = Robot(served.group(1), viz_url, graph, tmp)

        def set_flag(request: Any) -> dict[str, Any]:
            running.flags.append(bool(request.data))
            return {"success": True, "message": f"flag is {'on' if request.data else 'off'}"}

        def broken(_request: Any) -> dict[str, Any]:
            raise RuntimeError("the pump is unplugged")

        node = graph.node("viztest")
        node.service(FLAG_SERVICE, "std_srvs/SetBool", set_flag)
        node.service(BROKEN_SERVICE, "std_srvs/Trigger", broken)
        try:
            yield running
        finally:
            graph.close()
    finally:
        procs.stop()


def _advertised(client: NodeClient, topic: str) -> Event:
    return client.event("advertise", 60, topic=topic)


def _messages(client: NodeClient, topic: str, start: int = 0) -> list[Event]:
    return [
        e
        for e in client.events[start:]
        if e["event"] == "message" and e.get("topic") == topic and "message" in e
    ]


@pytest.mark.parametrize("subprotocol", [SPEC, SDK])
def test_viewer_connects_with_either_subprotocol_and_sees_the_capabilities(
    robot: Robot, subprotocol: str
) -> None:
    """Today's main answers HTTP 400 to ``foxglove.websocket.v1`` and advertises no
    capabilities to ``foxglove.sdk.v1``."""
    with robot.client(subprotocol, f"caps-{subprotocol}") as client:
        opened = client.event("open")
        assert opened["protocol"] == subprotocol  # the server answers with the one offered
        info = client.event("serverInfo")["info"]
        assert {"clientPublish", "services", "time"} <= set(info["capabilities"])
        assert {"ros1", "json"} <= set(info["supportedEncodings"])
        first = client.event("time")
        assert abs(int(first["timestamp"]) / 1e9 - time.time()) < 600  # the wall clock
        odom = _advertised(client, "/diffbot/odom")
        assert (odom["schemaName"], odom["encoding"], odom["schemaEncoding"]) == (
            "nav_msgs/Odometry",
            "ros1",
            "ros1msg",
        )
        assert odom.get("problem") is None  # Foxglove's parser takes the schema


def test_tf_drives_frames_and_odometry_decodes_in_the_viewer(robot: Robot) -> None:
    """A 3D panel's frames: ``/tf`` decoded by Foxglove's own ROS 1 reader, odom -> base_link."""
    with robot.client(SPEC, "tf") as client:
        tf = _advertised(client, "/tf")
        assert tf["schemaName"] == "tf2_msgs/TFMessage" and tf.get("problem") is None
        client.send(cmd="subscribe", topic="/tf")
        client.send(cmd="subscribe", topic="/diffbot/odom")
        message = client.event("message", 60, topic="/tf")["message"]
        (transform,) = message["transforms"]
        assert transform["header"]["frame_id"] == "odom"
        assert transform["child_frame_id"] == "base_link"
        rotation = transform["transform"]["rotation"]
        assert math.isclose(sum(v * v for v in rotation.values()), 1.0, rel_tol=1e-6)
        odom = client.event("message", 60, topic="/diffbot/odom")["message"]
        assert (odom["header"]["frame_id"], odom["child_frame_id"]) == ("odom", "base_link")


def _position(event: Event) -> tuple[float, float]:
    position = event["message"]["pose"]["pose"]["position"]
    return float(position["x"]), float(position["y"])


@pytest.mark.parametrize(
    ("subprotocol", "encoding", "speed"), [(SPEC, "ros1", 0.3), (SDK, "json", -0.3)]
)
def test_teleop_twist_on_cmd_vel_moves_the_robot(
    robot: Robot, subprotocol: str, encoding: str, speed: float
) -> None:
    """What a Teleop panel does: advertise ``/diffbot/cmd_vel`` as ``geometry_msgs/Twist`` in one
    of the server's encodings and publish; the emulated robot drives (its odometry moves)."""
    with robot.client(subprotocol, f"teleop-{encoding}") as client:
        client.event("serverInfo")
        _advertised(client, "/diffbot/odom")
        client.send(cmd="subscribe", topic="/diffbot/odom")
        start = _position(client.event("message", 60, topic="/diffbot/odom"))
        schema = robot.graph.registry.definition("geometry_msgs/Twist")
        client.send(
            cmd="advertise",
            topic="/diffbot/cmd_vel",
            schemaName="geometry_msgs/Twist",
            encoding=encoding,
            schema=schema,
        )
        client.event("advertised", topic="/diffbot/cmd_vel")
        drive = {"linear": {"x": speed, "y": 0.0, "z": 0.0}, "angular": {"x": 0, "y": 0, "z": 0}}
        stop = {"linear": {"x": 0.0, "y": 0.0, "z": 0.0}, "angular": {"x": 0, "y": 0, "z": 0}}

        def moved() -> bool:
            client.send(cmd="publish", topic="/diffbot/cmd_vel", message=drive)  # as Teleop: again
            odom = _messages(client, "/diffbot/odom")
            return bool(odom) and math.dist(_position(odom[-1]), start) > 0.05

        try:
            assert wait_until(moved, 60, step=0.1), (
                f"odometry did not move from {start}; status: "
                f"{sorted({e['message'] for e in client.events if e['event'] == 'status'})}"
            )
        finally:
            client.send(cmd="publish", topic="/diffbot/cmd_vel", message=stop)
        assert client.find(lambda e: e["event"] == "status") is None


def test_publishing_a_wrong_or_unknown_type_is_refused_with_a_status(robot: Robot) -> None:
    with robot.client(SPEC, "wrong-type") as client:
        client.event("serverInfo")
        _advertised(client, "/diffbot/odom")
        client.send(
            cmd="advertise", topic="/diffbot/cmd_vel", schemaName="std_msgs/String", encoding="json"
        )
        refused = client.wait_for(
            lambda e: e["event"] == "status" and "/diffbot/cmd_vel" in e["message"],
            "status refusing std_msgs/String on /diffbot/cmd_vel",
        )
        assert refused["level"] == 2
        assert "geometry_msgs/Twist" in refused["message"]
        assert "std_msgs/String" in refused["message"]
        client.send(
            cmd="advertise", topic="/viztest/x", schemaName="nope_msgs/Nope", encoding="json"
        )
        unknown = client.wait_for(
            lambda e: e["event"] == "status" and "nope_msgs/Nope" in e["message"],
            "status refusing nope_msgs/Nope",
        )
        assert unknown["level"] == 2 and "no definition" in unknown["message"]


@pytest.mark.parametrize(("subprotocol", "encoding"), [(SPEC, "ros1"), (SDK, "json")])
def test_a_graph_service_is_advertised_and_called(
    robot: Robot, subprotocol: str, encoding: str
) -> None:
    with robot.client(subprotocol, f"service-{encoding}") as client:
        service = client.event("advertiseServices", 60, name=FLAG_SERVICE)
        assert service["type"] == "std_srvs/SetBool"
        assert service["request"]["schemaName"] == "std_srvs/SetBoolRequest"
        assert service["request"]["schemaEncoding"] == "ros1msg"
        assert service["response"]["encoding"] == "ros1"
        before = len(robot.flags)
        client.send(cmd="call", service=FLAG_SERVICE, request={"data": True}, encoding=encoding)
        answer = client.event("serviceCallResponse", service=FLAG_SERVICE)
        assert answer["encoding"] == encoding
        assert answer["message"]["success"] is True
        assert answer["message"]["message"] == "flag is on"
        assert robot.flags[before:] == [True]


def test_a_failing_service_call_reports_the_reason(robot: Robot) -> None:
    with robot.client(SPEC, "service-failure") as client:
        client.event("advertiseServices", 60, name=BROKEN_SERVICE)
        client.send(cmd="call", service=BROKEN_SERVICE, request={})
        failure = client.event("serviceCallFailure", service=BROKEN_SERVICE)
        assert "the pump is unplugged" in failure["message"]
        assert BROKEN_SERVICE in failure["message"]


def test_hwbridge_viz_alone_serves_both_generations(robot: Robot) -> None:
    """``hwbridge viz`` next to a running robot: the same server, both subprotocols."""
    for subprotocol in (SPEC, SDK):
        with robot.client(subprotocol, f"viz-{subprotocol}", url=robot.viz_url) as client:
            assert client.event("open")["protocol"] == subprotocol
            assert "clientPublish" in client.event("serverInfo")["info"]["capabilities"]
            _advertised(client, "/tf")
            client.send(cmd="subscribe", topic="/tf")
            tf = client.event("message", 60, topic="/tf")["message"]
            assert tf["transforms"][0]["child_frame_id"] == "base_link"
            client.event("advertiseServices", 60, name=FLAG_SERVICE)


def _panels(tree: Any) -> list[str]:
    if isinstance(tree, str):
        return [tree]
    return [*_panels(tree["first"]), *_panels(tree["second"])]


def test_the_example_layout_drives_and_shows_the_demo_robot(robot: Robot) -> None:
    """examples/foxglove/layout.json: valid JSON, every panel placed, a Teleop panel on the topic
    the demo robot drives from (a Twist subscriber), a 3D panel with /tf frames and odometry, and
    every topic its panels show served to a viewer."""
    layout = json.loads(LAYOUT.read_text(encoding="utf-8"))
    configs = layout["configById"]
    assert sorted(_panels(layout["layout"])) == sorted(configs)
    (teleop,) = (c for key, c in configs.items() if key.startswith("Teleop!"))
    subscribed = {
        e.type
        for e in robot.graph.snapshot(timeout=5).of_kind("sub")
        if e.name == teleop["topic"] and e.type != "*"
    }
    assert subscribed == {"geometry_msgs/Twist"}
    three = configs["3D!diffbot"]
    assert {"/tf", "/diffbot/odom"} <= set(three["topics"])
    assert three["followTf"] == "base_link"
    with robot.client(SPEC, "layout") as client:
        assert _advertised(client, "/tf")["schemaName"] == "tf2_msgs/TFMessage"
        for topic in layout_topics():
            _advertised(client, topic)
