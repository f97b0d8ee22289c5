"""``hwbridge demo``: the whole path on one machine with nothing plugged in.

A virtual ``diffbot`` board runs on a pseudo-terminal; the bridge opens it like a serial port and
speaks the native protocol to it; host device nodes turn its raw readings into odometry, Range and
Imu; a small driver steers it around its room with ``cmd_vel`` (turning away when the sonar sees a
wall). The screen shows what the graph sees, and the run ends with how far odometry drifted from
the emulator's ground truth.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

from rich.console import Console
from rich.live import Live
from rich.table import Table

from hwbridge.bridge import BoardSpec, Bridge
from hwbridge.devices.encoders import DiffDriveParams
from hwbridge.devices.nodes import DiffDriveNode, ImuNode, SonarNode
from hwbridge.emulator.board import VirtualBoard, load_board
from hwbridge.errors import HwBridgeError
from hwbridge.graph import Graph, GraphConfig
from hwbridge.links import open_link

__all__ = ["DemoResult", "run_demo"]

NAMESPACE = "/diffbot"


@dataclass(frozen=True)
class DemoResult:
    """How the run went: distance driven (ground truth) and final odometry error."""

    distance: float
    error: float
    messages: int

    @property
    def error_percent(self) -> float:
        return 100.0 * self.error / self.distance if self.distance > 0 else 0.0


class _Driver:
    """Cruise forward; turn in place while the sonar sees something closer than 0.5 m."""

    def __init__(self) -> None:
        self.turning_until = 0.0

    def command(self, now: float, sonar: Any) -> tuple[float, float]:
        near = sonar is not None and math.isfinite(sonar.range) and sonar.range < 0.5
        if near or (sonar is not None and sonar.range == -math.inf):
            self.turning_until = now + 0.8
        if now < self.turning_until:
            return 0.0, 1.2
        wobble = 0.3 * math.sin(now * 0.7)
        return 0.25, wobble


def run_demo(
    *,
    duration: float = 30.0,
    seed: int = 0,
    endpoint: str | None = None,
    keep: bool = False,
    console: Console | None = None,
) -> DemoResult:
    """Run the demo; returns its result (after Ctrl-C too)."""
    out = console or Console(stderr=False)
    config = load_board("diffbot")
    board = VirtualBoard(config, seed=seed)
    link = open_link("pty://")
    board.start(link)
    graph = Graph(GraphConfig.embedded([endpoint] if endpoint else None))
    bridge = Bridge(graph)
    nodes: list[Any] = []
    try:
        path = link.slave_path  # type: ignore[attr-defined]
        bridge.add_board(
            BoardSpec(path, protocol="native", namespace=NAMESPACE, name="diffbot", start_delay=0.2)
        )
        node = graph.node("diffbot_devices", namespace=NAMESPACE)
        drive = DiffDriveNode(node, DiffDriveParams.from_dict(config.host.get("diffdrive", {})))
        sonar, imu = SonarNode(node), ImuNode(node)
        nodes.append(drive)
        driver_node = graph.node("demo_driver", namespace=NAMESPACE)
        cmd_vel = driver_node.publisher("cmd_vel", "geometry_msgs/Twist")
        pan_goal = driver_node.publisher("pan/goal_position", "std_msgs/Float64")
        joints: list[Any] = [None]
        driver_node.subscriber(
            "joint_states", "sensor_msgs/JointState", lambda m: joints.__setitem__(0, m)
        )
        out.print(
            f"[bold]hwbridge demo[/]: virtual diffbot on {path}, graph on "
            f"{graph.config.describe()}; topics under {NAMESPACE}"
        )
        _wait_connected(bridge, 20.0)
        driver = _Driver()
        started = time.monotonic()
        try:
            with Live(
                _table(board, drive, sonar, imu, 0.0, None), console=out, refresh_per_second=4
            ) as live:
                while True:
                    elapsed = time.monotonic() - started
                    if elapsed >= duration:
                        break
                    v, w = driver.command(elapsed, sonar.latest)
                    cmd_vel.publish({"linear": {"x": v}, "angular": {"z": w}})
                    pan_goal.publish({"data": 0.8 * math.sin(elapsed * 0.5)})
                    live.update(_table(board, drive, sonar, imu, elapsed, joints[0]))
                    time.sleep(0.1)
            out.print()
            cmd_vel.publish({})
            time.sleep(0.8)  # the robot stops; the last ticks arrive
            if keep:
                out.print(
                    "The board and bridge keep running: try 'hwbridge topic list' in another "
                    "terminal. Ctrl-C ends."
                )
                while True:
                    time.sleep(1.0)
        except KeyboardInterrupt:
            out.print("interrupted")
        result = _result(board, drive)
        out.print(
            f"drove {result.distance:.2f} m in {board.world.time:.1f} s of board time; "
            f"{board.published} board messages; link: {_link_summary(bridge)}"
        )
        out.print(f"odometry error: {result.error_percent:.3f}% of {result.distance:.2f} m")
        return result
    finally:
        for item in nodes:
            item.close()
        bridge.stop()
        graph.close()
        board.stop()
        link.close()


def _wait_connected(bridge: Bridge, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    board = bridge.boards["diffbot"]
    while board.state != "connected":
        if time.monotonic() > deadline:
            raise HwBridgeError(f"the virtual board did not connect (state {board.state})")
        time.sleep(0.05)


def _result(board: VirtualBoard, drive: DiffDriveNode) -> DemoResult:
    truth = board.world.pose
    odom = drive.latest
    if odom is None:
        raise HwBridgeError("no odometry arrived: the board's ticks did not reach the host")
    position = odom.pose.pose.position
    error = math.hypot(float(position.x) - truth.x, float(position.y) - truth.y)
    return DemoResult(board.world.base.distance, error, board.published)


def _link_summary(bridge: Bridge) -> str:
    stats = bridge.boards["diffbot"].info().get("stats", {})
    keys = ("frames_received", "crc_errors", "be_frames_lost", "retransmits", "rtt")
    return ", ".join(
        f"{k} {stats[k]:.4f}" if isinstance(stats.get(k), float) else f"{k} {stats.get(k)}"
        for k in keys
        if k in stats
    )


def _table(
    board: VirtualBoard,
    drive: DiffDriveNode,
    sonar: SonarNode,
    imu: ImuNode,
    t: float,
    joints: Any,
) -> Table:
    table = Table(title=f"diffbot, {t:5.1f} s", show_header=True, header_style="bold")
    table.add_column("what")
    table.add_column("graph sees")
    table.add_column("ground truth")
    truth = board.world.pose
    odom = drive.latest
    if odom is not None:
        p = odom.pose.pose.position
        table.add_row(
            "/diffbot/odom x, y",
            f"{float(p.x):+.3f}, {float(p.y):+.3f} m",
            f"{truth.x:+.3f}, {truth.y:+.3f} m",
        )
        table.add_row("speed", f"{float(odom.twist.twist.linear.x):+.2f} m/s", "")
    rng = sonar.latest
    if rng is not None:
        truth_range = board.world.sonar_distance()
        table.add_row(
            "/diffbot/range",
            f"{float(rng.range):.3f} m",
            f"{truth_range:.3f} m" if truth_range is not None else "nothing",
        )
    reading = imu.latest
    if reading is not None:
        a, g = reading.linear_acceleration, reading.angular_velocity
        table.add_row(
            "/diffbot/imu accel z, gyro z",
            f"{float(a.z):.2f} m/s², {float(g.z):+.2f} rad/s",
            "",
        )
    if joints is not None and len(joints.position):
        servo = board.dynamixel_bus.servo(1) if board.dynamixel_bus is not None else None
        truth_pan = servo.model.ticks_to_radians(servo.get("Present Position")) if servo else None
        table.add_row(
            "/diffbot/joint_states pan",
            f"{float(joints.position[0]):+.3f} rad",
            f"{truth_pan:+.3f} rad" if truth_pan is not None else "",
        )
    table.add_row("distance driven", "", f"{board.world.base.distance:.2f} m")
    return table
