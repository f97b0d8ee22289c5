"""``hwbridge demo``: the whole path on one machine with nothing plugged in.

The demo robot's file (``examples/robots/diffbot.yaml``) is brought up exactly as ``hwbridge up``
brings up a real robot (:class:`~hwbridge.robot.runtime.RobotRuntime`), with its board's link
pointed at a virtual board on a pseudo-terminal: the bridge speaks the native protocol to it and
the device plugins' host nodes turn its raw readings into odometry, Range and Imu. A small driver
steers it around its room with ``cmd_vel`` (turning away when the sonar sees a wall), reading the
graph as any node would. The screen shows what the graph sees next to the emulator's ground
truth, and the run ends with how far odometry drifted.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from rich.console import Console
from rich.live import Live
from rich.table import Table

from hwbridge.emulator.board import ROBOTS_DIR, VirtualBoard, load_board
from hwbridge.errors import HwBridgeError
from hwbridge.graph import Graph, GraphConfig
from hwbridge.links import open_link
from hwbridge.robot.config import load_robot
from hwbridge.robot.runtime import RobotRuntime
from hwbridge.viz.pathplot import PathPlot, write_svg

__all__ = ["DemoResult", "run_demo"]

ROBOT_FILE = ROBOTS_DIR / "diffbot.yaml"
BOARD = "base"


@dataclass(frozen=True)
class DemoResult:
    """How the run went: distance driven (ground truth) and final odometry error."""

    distance: float
    error: float
    messages: int

    @property
    def error_percent(self) -> float:
        return 100.0 * self.error / self.distance if self.distance > 0 else 0.0


class Outcome(Protocol):
    """What both demos report at their end."""

    @property
    def distance(self) -> float: ...
    @property
    def error(self) -> float: ...
    @property
    def error_percent(self) -> float: ...


def print_ending(
    out: Console, result: Outcome, path_plot: PathPlot, plot: Path | None, note: str = ""
) -> None:
    """The demos' last lines: the path plot written to ``plot`` (if any) and ``odometry error:
    E% of D m`` (the line scripts and tests read)."""
    if plot is not None:
        path_plot.notes.append(
            f"{note}drove {result.distance:.2f} m; final odometry error {result.error:.3f} m "
            f"({result.error_percent:.3f}%)"
        )
        written = write_svg(path_plot, plot)
        out.print(f"path plot: {written}", soft_wrap=True, highlight=False, markup=False)
    out.print(f"odometry error: {result.error_percent:.3f}% of {result.distance:.2f} m")


class _Latest:
    """The latest message of each topic the demo watches, by relative name."""

    def __init__(self, node: Any, topics: dict[str, str]) -> None:
        self.values: dict[str, Any] = dict.fromkeys(topics)
        for topic, type_name in topics.items():
            node.subscriber(topic, type_name, lambda m, t=topic: self.values.__setitem__(t, m))

    def __getitem__(self, topic: str) -> Any:
        return self.values[topic]


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
    plot: Path | None = None,
) -> DemoResult:
    """Run the demo; returns its result (after Ctrl-C too). With ``plot``, the driven path
    (odometry) and the ground truth are drawn into that SVG file before the summary's last line."""
    out = console or Console(stderr=False)
    robot = load_robot(ROBOT_FILE)
    namespace = robot.board(BOARD).namespace
    board = VirtualBoard(load_board(str(ROBOT_FILE), BOARD), seed=seed)
    link = open_link("pty://")
    board.start(link)
    graph = Graph(GraphConfig.embedded([endpoint] if endpoint else None))
    runtime: RobotRuntime | None = None
    try:
        path = link.slave_path  # type: ignore[attr-defined]
        runtime = RobotRuntime(robot.with_links({BOARD: path}), graph).start()
        view = graph.node("demo_driver", namespace=namespace)
        seen = _Latest(
            view,
            {
                "odom": "nav_msgs/Odometry",
                "range": "sensor_msgs/Range",
                "imu": "sensor_msgs/Imu",
                "joint_states": "sensor_msgs/JointState",
            },
        )
        cmd_vel = view.publisher("cmd_vel", "geometry_msgs/Twist")
        pan_goal = view.publisher("pan/goal_position", "std_msgs/Float64")
        out.print(
            f"[bold]hwbridge demo[/]: robot {robot.name} ({ROBOT_FILE.name}) up with board "
            f"{BOARD} on a virtual board at {path}; graph on {graph.config.describe()}; "
            f"topics under {namespace}"
        )
        wait_connected(runtime, 20.0)
        driver = _Driver()
        world = board.world.config
        path_plot = PathPlot(
            room=world.room,
            obstacles=world.obstacles,
            title=f"hwbridge demo: {robot.name}, odometry against ground truth (seed {seed})",
        )
        started = time.monotonic()
        result: DemoResult | None = None
        try:
            with Live(
                _table(board, seen, namespace, 0.0), console=out, refresh_per_second=4
            ) as live:
                while True:
                    elapsed = time.monotonic() - started
                    if elapsed >= duration:
                        break
                    v, w = driver.command(elapsed, seen["range"])
                    cmd_vel.publish({"linear": {"x": v}, "angular": {"z": w}})
                    pan_goal.publish({"data": 0.8 * math.sin(elapsed * 0.5)})
                    live.update(_table(board, seen, namespace, elapsed))
                    _sample(path_plot, board, seen["odom"])
                    time.sleep(0.1)
                cmd_vel.publish({})
                time.sleep(0.8)  # the robot stops; the last ticks arrive
                _sample(path_plot, board, seen["odom"])
                # the table's last picture states the distance the last line states
                result = _result(board, seen["odom"])
                elapsed = time.monotonic() - started
                live.update(_table(board, seen, namespace, elapsed, result.distance))
            out.print()
            if keep:
                out.print(
                    "The board and bridge keep running: try 'hwbridge topic list' in another "
                    "terminal. Ctrl-C ends."
                )
                while True:
                    time.sleep(1.0)
        except KeyboardInterrupt:
            out.print("interrupted")
        if result is None:  # interrupted while driving
            result = _result(board, seen["odom"])
        out.print(
            f"{board.world.time:.1f} s of board time; {board.published} board messages; "
            f"link: {_link_summary(runtime)}"
        )
        print_ending(out, result, path_plot, plot)
        return result
    finally:
        if runtime is not None:
            runtime.stop()
        graph.close()
        board.stop()
        link.close()


def wait_connected(
    runtime: RobotRuntime, timeout: float, what: str = "the virtual board", board_name: str = BOARD
) -> None:
    """Wait until the demo's board is connected; an error naming ``what`` after ``timeout``."""
    deadline = time.monotonic() + timeout
    board = runtime.bridge.boards[board_name]
    while board.state != "connected":
        if time.monotonic() > deadline:
            raise HwBridgeError(f"{what} did not connect (state {board.state})")
        time.sleep(0.05)


def _sample(plot: PathPlot, board: VirtualBoard, odom: Any) -> None:
    truth = board.world.pose
    position = odom.pose.pose.position if odom is not None else None
    plot.add(
        (float(position.x), float(position.y)) if position is not None else None,
        (truth.x, truth.y),
    )


def _result(board: VirtualBoard, odom: Any) -> DemoResult:
    truth = board.world.pose
    if odom is None:
        raise HwBridgeError("no odometry arrived: the board's ticks did not reach the host")
    position = odom.pose.pose.position
    error = math.hypot(float(position.x) - truth.x, float(position.y) - truth.y)
    return DemoResult(board.world.base.distance, error, board.published)


def _link_summary(runtime: RobotRuntime) -> str:
    stats = runtime.bridge.boards[BOARD].info().get("stats", {})
    keys = ("frames_received", "crc_errors", "be_frames_lost", "retransmits", "rtt")
    return ", ".join(
        f"{k} {stats[k]:.4f}" if isinstance(stats.get(k), float) else f"{k} {stats.get(k)}"
        for k in keys
        if k in stats
    )


def _table(
    board: VirtualBoard, seen: _Latest, namespace: str, t: float, distance: float | None = None
) -> Table:
    """What the graph sees next to the ground truth; ``distance``: the run's final distance
    (while driving: the distance so far)."""
    table = Table(title=f"diffbot, {t:5.1f} s", show_header=True, header_style="bold")
    table.add_column("what")
    table.add_column("graph sees")
    table.add_column("ground truth")
    truth = board.world.pose
    odom = seen["odom"]
    if odom is not None:
        p = odom.pose.pose.position
        table.add_row(
            f"{namespace}/odom x, y",
            f"{float(p.x):+.3f}, {float(p.y):+.3f} m",
            f"{truth.x:+.3f}, {truth.y:+.3f} m",
        )
        table.add_row("speed", f"{float(odom.twist.twist.linear.x):+.2f} m/s", "")
    rng = seen["range"]
    if rng is not None:
        truth_range = board.world.sonar_distance()
        table.add_row(
            f"{namespace}/range",
            f"{float(rng.range):.3f} m",
            f"{truth_range:.3f} m" if truth_range is not None else "nothing",
        )
    reading = seen["imu"]
    if reading is not None:
        a, g = reading.linear_acceleration, reading.angular_velocity
        table.add_row(
            f"{namespace}/imu accel z, gyro z",
            f"{float(a.z):.2f} m/s², {float(g.z):+.2f} rad/s",
            "",
        )
    joints = seen["joint_states"]
    if joints is not None and len(joints.position):
        table.add_row(
            f"{namespace}/joint_states {joints.name[0]}",
            f"{float(joints.position[0]):+.3f} rad",
            "",
        )
    driven = board.world.base.distance if distance is None else distance
    table.add_row("distance driven", "", f"{driven:.2f} m")
    return table
