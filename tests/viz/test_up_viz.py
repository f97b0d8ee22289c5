"""``hwbridge up ROBOT.yaml --viz``: the robot comes up with its Foxglove view in one command."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip("websockets.sync.client")

from tests.hwbridge.test_up import DIFFBOT, Processes
from tests.netutil import free_port, wait_until
from tests.viz.test_foxglove import FoxgloveClient, connect, decode_ros1


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Processes]:
    running = Processes(tmp_path)
    yield running
    running.stop()


def test_up_with_viz_serves_the_robot(procs: Processes) -> None:
    url = procs.emulate("diffbot", "--tcp", str(free_port()))
    port = free_port()
    up, log = procs.start(
        "up", "up", str(DIFFBOT), "--link", f"base={url}", "--viz", "--viz-port", str(port)
    )
    assert wait_until(lambda: "Foxglove WebSocket on" in log.read_text(), 30), log.read_text()
    served = re.search(r"Foxglove WebSocket on (\S+)", log.read_text())
    assert served is not None and served.group(1) == f"ws://127.0.0.1:{port}"
    with connect(served.group(1)) as ws:
        client = FoxgloveClient(ws)
        odom = client.wait_for_channel("/diffbot/odom")
        client.subscribe(1, odom)
        (payload,) = client.messages(1, 1)
        assert decode_ros1(odom["schemaName"], odom["schema"], payload).child_frame_id
    assert up.poll() is None, log.read_text()
