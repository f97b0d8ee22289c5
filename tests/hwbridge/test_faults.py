"""Fault injection on the emulated link: the bridge recovers and odometry stays continuous.

A virtual diffbot on a pty (this process), ``hwbridge connect`` in a subprocess, the device nodes
and a driver attached to its graph (this process). While driving, the board's link loses and
corrupts bytes, stalls, is unplugged and comes back, and the board resets.
"""

from __future__ import annotations

import itertools
import json
import math
import threading
import time
from pathlib import Path
from typing import Any

from hwbridge.devices.diffdrive.node import DiffDriveNode
from hwbridge.emulator import VirtualBoard, load_board
from hwbridge.emulator.faults import LinkFaults
from hwbridge.graph import Graph
from hwbridge.links import open_link
from hwbridge.robot.plugin import HostContext
from hwbridge.robot.registry import get_device
from tests.bridgeproc import BridgeProcess
from tests.netutil import wait_until


def test_bridge_recovers_and_odometry_stays_continuous(tmp_path: Path) -> None:
    path = tmp_path / "ttyDIFFBOT"
    config = load_board("diffbot")
    board = VirtualBoard(config, seed=7).start(open_link(f"pty://?symlink={path}"))
    bridge = BridgeProcess(path, tmp_path, "faults", "--namespace", "/bot", "--name", "diffbot")
    endpoint, log_path = bridge.endpoint, bridge.log
    graph = None
    drive = None
    stop = threading.Event()
    try:
        bridge.wait_ready()
        graph = Graph.attached(connect=[endpoint], domain="faults")
        node = graph.node("devices", namespace="/bot")
        (diffdrive,) = [d for d in config.devices if d.type == "diffdrive"]
        context = HostContext(graph, node, "/bot", "diffbot", None)
        drive = get_device("diffdrive").host_node(diffdrive.settings, context)
        assert isinstance(drive, DiffDriveNode)
        poses: list[tuple[float, float]] = []
        stamps: list[float] = []

        def on_odom(m: Any) -> None:
            stamps.append(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9)
            poses.append((float(m.pose.pose.position.x), float(m.pose.pose.position.y)))

        node.subscriber("odom", "nav_msgs/Odometry", on_odom)
        cmd = graph.node("driver", namespace="/bot").publisher("cmd_vel", "geometry_msgs/Twist")

        def drive_loop() -> None:
            while not stop.is_set():
                cmd.publish({"linear": {"x": 0.15}, "angular": {"z": 0.2}})
                stop.wait(0.1)

        driver = threading.Thread(target=drive_loop, daemon=True)
        driver.start()
        assert wait_until(lambda: len(poses) > 50, 30), log_path.read_text()

        board.inject(LinkFaults(loss=0.002, corrupt=0.002))
        time.sleep(2.0)
        board.inject(LinkFaults())
        board.stall(0.3)
        time.sleep(1.0)
        board.unplug(1.0)
        assert wait_until(lambda: "link lost" in log_path.read_text(), 15)
        count = len(poses)
        assert wait_until(lambda: len(poses) > count + 50, 30), log_path.read_text()
        board.reset()
        count = len(poses)
        assert wait_until(lambda: len(poses) > count + 50, 30), log_path.read_text()
        stop.set()
        driver.join()
        time.sleep(1.0)

        # No jump: between two odometry messages the pose moves no more than the robot can drive
        # in the time between them (it commands about 0.17 m/s; 0.3 m/s leaves a margin).
        # Outages (stall, unplug, reset) are gaps in time, not jumps in position.
        for (a, b), (ta, tb) in zip(
            itertools.pairwise(poses), itertools.pairwise(stamps), strict=True
        ):
            assert math.dist(a, b) <= 0.3 * max(tb - ta, 0.0) + 0.01, (a, b, ta, tb)
        truth = board.world.pose
        final = poses[-1]
        error = math.hypot(final[0] - truth.x, final[1] - truth.y)
        assert board.world.base.distance > 1.0
        # Ticks between the last reading before the reset and the first after are not counted,
        # and lost best-effort ticks are bridged by the absolute counters: the error stays small.
        assert error / board.world.base.distance < 0.05
        assert drive.rereferences >= 1

        stats = bridge.cli("board", "stats", "diffbot", "--json")
        info = json.loads(stats.stdout)
        assert info["protocol"] == "native"
        text = log_path.read_text()
        assert "link lost" in text and text.count("connected (native)") >= 2
        assert board.session.bytes_lost > 0 and board.session.bytes_corrupted > 0
    finally:
        stop.set()
        if drive is not None:
            drive.close()
        if graph is not None:
            graph.close()
        bridge.stop()
        board.stop()
