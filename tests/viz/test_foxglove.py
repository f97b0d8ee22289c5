"""``hwbridge viz`` against a Foxglove WebSocket client: a plain ``websockets`` client speaking
the published protocol (offering ``foxglove.sdk.v1`` and ``foxglove.websocket.v1``, two names of
one protocol) subscribes to an emulated diffbot's ``/diffbot/odom``
and decodes what it receives from the advertised ROS 1 schema alone. The recorder's MCAP
schemas are checked to be the same text (what Foxglove opens)."""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

websockets_sync = pytest.importorskip("websockets.sync.client")

from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

from hwbridge.emulator.board import ROBOTS_DIR, VirtualBoard, load_board  # noqa: E402
from hwbridge.graph import Graph  # noqa: E402
from hwbridge.links import open_link  # noqa: E402
from hwbridge.recorder import Recorder  # noqa: E402
from hwbridge.robot.config import load_robot  # noqa: E402
from hwbridge.robot.runtime import RobotRuntime  # noqa: E402
from hwbridge.viz.foxglove import start_viz  # noqa: E402
from tests.netutil import wait_until  # noqa: E402

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
ROBOT = ROBOTS_DIR / "diffbot.yaml"
SEPARATOR = "=" * 80
LAYOUT = Path(__file__).resolve().parents[2] / "examples" / "foxglove" / "layout.json"


def layout_topics() -> set[str]:
    """The topics the example Foxglove layout's panels show."""
    panels = json.loads(LAYOUT.read_text(encoding="utf-8"))["configById"]
    topics: set[str] = set()
    for config in panels.values():
        topics.update(config.get("topics", {}))
        topics.update(path["value"].split(".", 1)[0] for path in config.get("paths", []))
        if config.get("topicPath"):
            topics.add(config["topicPath"].split(".", 1)[0])
    return topics


def decode_ros1(schema_name: str, schema: str, data: bytes) -> Any:
    """Decode ROS 1 bytes knowing only the ``ros1msg`` schema text (as Foxglove does)."""
    blocks = schema.split("\n" + SEPARATOR + "\n")
    types: dict[str, Any] = {}

    def full(name: str) -> str:
        pkg, _, short = name.partition("/")
        return f"{pkg}/msg/{short}"

    types.update(get_types_from_msg(blocks[0], full(schema_name)))
    for block in blocks[1:]:
        first, _, text = block.partition("\n")
        assert first.startswith("MSG: "), first
        types.update(get_types_from_msg(text, full(first[5:].strip())))
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    return store.deserialize_ros1(data, full(schema_name))


@pytest.fixture(scope="module")
def diffbot(router: Graph) -> Iterator[RobotRuntime]:
    """The demo robot up on the module's graph, its board a virtual one on a pty."""
    robot = load_robot(ROBOT)
    board = VirtualBoard(load_board(str(ROBOT), "base"), seed=1)
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


class FoxgloveClient:
    """The protocol's client side: serverInfo, advertise, subscribe, binary message data."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.channels: dict[str, dict[str, Any]] = {}
        self.server_info: dict[str, Any] = {}
        self.log: list[str] = []
        self.subscriptions: dict[int, dict[str, Any]] = {}
        """The ops of the JSON messages received, in order."""

    def wait_for_channel(self, topic: str, timeout: float = 20.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while topic not in self.channels:
            try:
                self._receive_one(deadline)
            except TimeoutError:
                pytest.fail(f"no channel {topic}; channels: {sorted(self.channels)}")
        return self.channels[topic]

    def _receive_one(self, deadline: float) -> bytes | None:
        frame = self.ws.recv(timeout=max(0.01, deadline - time.monotonic()))
        if isinstance(frame, str):
            message = json.loads(frame)
            self.log.append(message.get("op", "?") if message.get("op") == "advertise" else frame)
            if message["op"] == "serverInfo":
                self.server_info = message
            elif message["op"] == "advertise":
                for channel in message["channels"]:
                    self.channels[channel["topic"]] = channel
            return None
        return bytes(frame)

    def subscribe(self, subscription: int, channel: dict[str, Any]) -> None:
        self.subscriptions[subscription] = channel
        self.ws.send(
            json.dumps(
                {
                    "op": "subscribe",
                    "subscriptions": [{"id": subscription, "channelId": channel["id"]}],
                }
            )
        )

    def messages(self, subscription: int, count: int, timeout: float = 20.0) -> list[bytes]:
        """Payloads of the next ``count`` Message Data frames (opcode 1) of ``subscription``."""
        deadline = time.monotonic() + timeout
        payloads: list[bytes] = []
        others: dict[int, int] = {}
        while len(payloads) < count:
            try:
                frame = self._receive_one(deadline)
            except TimeoutError:
                pytest.fail(
                    f"{len(payloads)} of {count} messages of subscription {subscription}; "
                    f"frames of others: {others}; channels: {self.channels}; "
                    f"log: {self.log[-10:]}"
                )
            if frame is None or frame[0] != 0x01:
                continue
            sub_id, _log_time = struct.unpack_from("<IQ", frame, 1)
            if sub_id == subscription:
                payloads.append(frame[13:])
            else:
                others[sub_id] = others.get(sub_id, 0) + 1
        return payloads


def connect(url: str) -> Any:
    """A WebSocket connection offering Foxglove's subprotocols (use it with ``with``)."""
    return websockets_sync.connect(url, subprotocols=SUBPROTOCOLS, open_timeout=10)


def test_viz_serves_odometry_that_a_foxglove_client_decodes(
    diffbot: RobotRuntime, endpoint: str, graph_domain: str, tmp_path: Path
) -> None:
    env = {**os.environ, "HWBRIDGE_ENDPOINT": endpoint, "HWBRIDGE_DOMAIN": graph_domain}
    viz = subprocess.Popen(
        [sys.executable, "-m", "hwbridge", "viz", "--port", "0"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=(tmp_path / "viz.log").open("w"),
        text=True,
    )
    try:
        assert viz.stdout is not None
        url = viz.stdout.readline().strip()
        assert url.startswith("ws://127.0.0.1:"), url + (tmp_path / "viz.log").read_text()
        with connect(url) as ws:
            client = FoxgloveClient(ws)
            odom = client.wait_for_channel("/diffbot/odom")
            assert client.server_info.get("op") == "serverInfo"
            assert odom["encoding"] == "ros1"
            assert odom["schemaEncoding"] == "ros1msg"
            assert odom["schemaName"] == "nav_msgs/Odometry"
            client.subscribe(1, odom)
            payloads = client.messages(1, 5)
            decoded = [decode_ros1(odom["schemaName"], odom["schema"], p) for p in payloads]
            for message in decoded:
                assert message.header.frame_id == "odom"
                assert message.child_frame_id == "base_link"
                assert abs(message.pose.pose.orientation.w) <= 1.0
            stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in decoded]
            assert stamps == sorted(stamps) and stamps[-1] > stamps[0]
            # other topics are there too, with their ROS 1 schemas: all the example layout shows
            for topic, type_name in (
                ("/diffbot/range", "sensor_msgs/Range"),
                ("/diffbot/imu", "sensor_msgs/Imu"),
                ("/tf", "tf2_msgs/TFMessage"),
            ):
                assert client.wait_for_channel(topic)["schemaName"] == type_name
            for topic in layout_topics():
                client.wait_for_channel(topic)
    finally:
        viz.send_signal(signal.SIGINT)
        assert viz.wait(15) == 0, (tmp_path / "viz.log").read_text()


def test_start_viz_in_process_and_the_mcap_schema_is_the_same(
    diffbot: RobotRuntime, router: Graph, tmp_path: Path
) -> None:
    """What ``hwbridge up --viz`` calls; and ``hwbridge record``'s MCAP (ros1msg schemas, ros1
    messages) carries the very schema text Foxglove got over the WebSocket."""
    from mcap.reader import make_reader

    server = start_viz(router, port=0, topics=["/diffbot/odom"])
    recording = tmp_path / "odom.mcap"
    recorder = Recorder(router, recording, ["/diffbot/odom"], limit=5)
    try:
        recorder.start()
        with connect(server.url) as ws:
            client = FoxgloveClient(ws)
            odom = client.wait_for_channel("/diffbot/odom")
            assert set(client.channels) == {"/diffbot/odom"}  # --topic honoured
            client.subscribe(3, odom)
            (payload,) = client.messages(3, 1)
            assert decode_ros1(odom["schemaName"], odom["schema"], payload).header.frame_id == (
                "odom"
            )
        assert recorder.wait(20)
        assert wait_until(lambda: server.stats().get("/diffbot/odom", 0) > 0, 5)
    finally:
        recorder.stop()
        server.close()
    with recording.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None
        (schema,) = summary.schemas.values()
        (channel,) = summary.channels.values()
        assert (schema.name, schema.encoding) == ("nav_msgs/Odometry", "ros1msg")
        assert channel.message_encoding == "ros1"
        assert schema.data.decode() == odom["schema"]
        for _schema, _channel, message in reader.iter_messages():
            decoded = decode_ros1(schema.name, schema.data.decode(), message.data)
            assert decoded.child_frame_id == "base_link"
