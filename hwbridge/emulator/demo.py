"""``hwbridge demo``: the whole path on one machine with nothing plugged in.

The demo robot's file (``examples/robots/diffbot.yaml``) is brought up exactly as ``hwbridge up``
brings up a real robot (:class:`~hwbridge.robot.runtime.RobotRuntime`), with its board's link
pointed at a virtual board on a pseudo-terminal: the bridge speaks the native protocol to it and
the device plugins' host nodes turn its raw readings into odometry, Range and Imu. A small driver
steers it around its room with ``cmd_vel`` (turning away when the sonar sees a wall), reading the
graph as any node would. The screen shows what the graph sees next to the emulator's ground
truth, and the run ends with how far odometry drifted.

The run itself (robot up, driver, screen, path plot, summary) is :func:`drive`, whatever the
board is: a :class:`BoardSide` says how to start the board and what its world truly is. This
module's is the Python board (:class:`VirtualBoardSide`); ``hwbridge demo --firmware``
(:mod:`hwbridge.emulator.firmware_demo`) gives the real firmware in simavr.
"""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, ClassVar, Generic, Protocol, TypeVar

from rich.console import Console
from rich.live import Live
from rich.table import Table

from hwbridge.emulator.board import ROBOTS_DIR, VirtualBoard, load_board
from hwbridge.emulator.world import WorldConfig
from hwbridge.errors import HwBridgeError
from hwbridge.graph import Graph, GraphConfig
from hwbridge.links import Link, open_link
from hwbridge.robot.config import load_robot
from hwbridge.robot.model import Robot
from hwbridge.robot.runtime import RobotRuntime
from hwbridge.viz.pathplot import PathPlot, write_svg

__all__ = ["BoardSide", "DemoResult", "Seen", "Truth", "VirtualBoardSide", "drive", "run_demo"]

ROBOT_FILE = ROBOTS_DIR / "diffbot.yaml"
BOARD = "base"
WATCHED = {"odom": "nav_msgs/Odometry", "range": "sensor_msgs/Range", "imu": "sensor_msgs/Imu"}
"""The topics every demo watches (relative to the board's namespace)."""


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
    """What every demo reports at its end."""

    @property
    def distance(self) -> float: ...
    @property
    def error(self) -> float: ...
    @property
    def error_percent(self) -> float: ...


R = TypeVar("R", bound=Outcome)


@dataclass(frozen=True)
class Truth:
    """The emulator's world at one moment: the robot's position (m), the distance it has driven
    and what its sonar truly sees (None: nothing in range)."""

    x: float
    y: float
    distance: float
    sonar: float | None


class Seen:
    """The latest message of each topic a demo watches, by relative name, and how many came."""

    def __init__(self, node: Any, topics: Mapping[str, str]) -> None:
        self.values: dict[str, Any] = dict.fromkeys(topics)
        self.counts: dict[str, int] = dict.fromkeys(topics, 0)
        for topic, type_name in topics.items():
            node.subscriber(topic, type_name, lambda m, t=topic: self._set(t, m))

    def _set(self, topic: str, message: Any) -> None:
        self.values[topic] = message
        self.counts[topic] += 1

    def __getitem__(self, topic: str) -> Any:
        return self.values[topic]


class BoardSide(ABC, Generic[R]):
    """The board end of a demo, for :func:`drive`: it starts the board the robot file's board
    ``base`` connects to, tells the world's ground truth, and makes the run's result."""

    robot: Robot
    """The robot brought up (its board's link is replaced by :meth:`open`'s)."""
    label: str
    """What the board is, in the error when it does not connect ('the virtual board')."""
    connect_timeout: float
    settle = 0.8
    """Seconds of the board's own time (:meth:`clock`) between the stop command and the last
    measure: the robot stops and the last ticks arrive."""
    topics: ClassVar[Mapping[str, str]] = WATCHED
    """The topics the driver watches (at least WATCHED)."""
    sweep_pan = False
    """Swing the pan servo (``pan/goal_position``) to and fro while driving."""
    live_table = False
    """Show a table redrawn in place (else a status line every 5 s)."""
    ticks_of: str
    """Whose ticks odometry is made from, in the error when none arrived ("the board's")."""
    plot_title: str
    plot_note = ""
    """The start of the path plot's note on the run."""
    keep_note: str
    """What ``keep`` leaves running, printed when the drive ends."""

    @abstractmethod
    def open(self) -> str:
        """Start the board; the URL the bridge connects to."""

    @abstractmethod
    def intro(self, graph: Graph, namespace: str) -> list[str]:
        """The lines (rich markup) that open the run, once the robot is up."""

    @property
    @abstractmethod
    def world(self) -> WorldConfig:
        """The room and its obstacles."""

    @abstractmethod
    def truth(self) -> Truth:
        """The world as it is now."""

    def during(self, elapsed: float, out: Console) -> None:
        """Called once per driver step, ``elapsed`` s into the drive (faults, resets)."""

    def clock(self) -> float:
        """Seconds of the board's own time: real time here; a simulator's time where the
        board is simulated, which falls behind real time on a busy machine."""
        return time.monotonic()

    @abstractmethod
    def result(self, distance: float, error: float) -> R:
        """The run's result, made once it is measured."""

    @abstractmethod
    def summary(self, runtime: RobotRuntime, seen: Seen, namespace: str) -> str:
        """The line before the ending: board time, messages, link."""

    @abstractmethod
    def close(self) -> None:
        """Stop the board (also when :meth:`open` failed or was not called)."""


def drive(
    side: BoardSide[R],
    *,
    duration: float,
    endpoint: str | None = None,
    keep: bool = False,
    console: Console | None = None,
    plot: Path | None = None,
) -> R:
    """Bring the robot up on ``side``'s board, drive it for ``duration`` s and report; the
    result also after Ctrl-C. With ``plot``, the driven path (odometry) and the ground truth
    are drawn into that SVG file before the summary's last line."""
    out = console or Console(stderr=False)
    namespace = side.robot.board(BOARD).namespace
    graph: Graph | None = None
    runtime: RobotRuntime | None = None
    try:
        url = side.open()
        graph = Graph(GraphConfig.embedded([endpoint] if endpoint else None))
        runtime = RobotRuntime(side.robot.with_links({BOARD: url}), graph).start()
        view = graph.node("demo_driver", namespace=namespace)
        seen = Seen(view, side.topics)
        cmd_vel = view.publisher("cmd_vel", "geometry_msgs/Twist")
        pan_goal = (
            view.publisher("pan/goal_position", "std_msgs/Float64") if side.sweep_pan else None
        )
        for line in side.intro(graph, namespace):
            out.print(line)
        wait_connected(runtime, side.connect_timeout, side.label)
        world = side.world
        path_plot = PathPlot(room=world.room, obstacles=world.obstacles, title=side.plot_title)
        screen = (
            _LiveTable(out, seen, namespace, side)
            if side.live_table
            else _StatusLines(out, seen, namespace)
        )
        driver = _Driver()
        started = time.monotonic()
        result: R | None = None
        try:
            with screen:
                while True:
                    elapsed = time.monotonic() - started
                    if elapsed >= duration:
                        break
                    side.during(elapsed, out)
                    v, w = driver.command(elapsed, seen["range"])
                    cmd_vel.publish({"linear": {"x": v}, "angular": {"z": w}})
                    if pan_goal is not None:
                        pan_goal.publish({"data": 0.8 * math.sin(elapsed * 0.5)})
                    truth = side.truth()
                    screen.show(elapsed, truth)
                    _sample(path_plot, truth, seen["odom"])
                    time.sleep(0.1)
                cmd_vel.publish({})
                _settle(side, seen)  # the robot stops; the last ticks arrive
                truth = side.truth()
                _sample(path_plot, truth, seen["odom"])
                result = _result(side, truth, seen["odom"])
                # the screen's last picture states the distance the last line states
                screen.show(time.monotonic() - started, truth, final=True)
            if keep:
                out.print(side.keep_note)
                while True:
                    time.sleep(1.0)
        except KeyboardInterrupt:
            out.print("interrupted")
        if result is None:  # interrupted while driving
            result = _result(side, side.truth(), seen["odom"])
        out.print(side.summary(runtime, seen, namespace))
        print_ending(out, result, path_plot, plot, side.plot_note)
        return result
    finally:
        if runtime is not None:
            runtime.stop()
        if graph is not None:
            graph.close()
        side.close()


class VirtualBoardSide(BoardSide[DemoResult]):
    """The demo robot's board as a Python :class:`VirtualBoard` on a pseudo-terminal."""

    label = "the virtual board"
    connect_timeout = 20.0
    topics: ClassVar[Mapping[str, str]] = {**WATCHED, "joint_states": "sensor_msgs/JointState"}
    sweep_pan = True
    live_table = True
    ticks_of = "the board's"
    keep_note = (
        "The board and bridge keep running: try 'hwbridge topic list' in another terminal. "
        "Ctrl-C ends."
    )

    def __init__(self, seed: int = 0) -> None:
        self.robot = load_robot(ROBOT_FILE)
        self.board = VirtualBoard(load_board(str(ROBOT_FILE), BOARD), seed=seed)
        self.plot_title = (
            f"hwbridge demo: {self.robot.name}, odometry against ground truth (seed {seed})"
        )
        self.link: Link | None = None
        self.path = ""
        """The pty's path (the board's end is the link), once open."""

    def open(self) -> str:
        self.link = open_link("pty://")
        self.board.start(self.link)
        self.path = self.link.slave_path  # type: ignore[attr-defined]
        return self.path

    def intro(self, graph: Graph, namespace: str) -> list[str]:
        return [
            f"[bold]hwbridge demo[/]: robot {self.robot.name} ({ROBOT_FILE.name}) up with board "
            f"{BOARD} on a virtual board at {self.path}; graph on {graph.config.describe()}; "
            f"topics under {namespace}"
        ]

    @property
    def world(self) -> WorldConfig:
        return self.board.world.config

    def truth(self) -> Truth:
        world = self.board.world
        pose = world.pose
        return Truth(pose.x, pose.y, world.base.distance, world.sonar_distance())

    def result(self, distance: float, error: float) -> DemoResult:
        return DemoResult(distance, error, self.board.published)

    def summary(self, runtime: RobotRuntime, seen: Seen, namespace: str) -> str:
        return (
            f"{self.board.world.time:.1f} s of board time; {self.board.published} board "
            f"messages; link: {_link_summary(runtime)}"
        )

    def close(self) -> None:
        self.board.stop()
        if self.link is not None:
            self.link.close()


def run_demo(
    *,
    duration: float = 30.0,
    seed: int = 0,
    endpoint: str | None = None,
    keep: bool = False,
    console: Console | None = None,
    plot: Path | None = None,
) -> DemoResult:
    """Run the demo on a Python virtual board; returns its result (after Ctrl-C too). With
    ``plot``, the driven path (odometry) and the ground truth are drawn into that SVG file
    before the summary's last line."""
    return drive(
        VirtualBoardSide(seed),
        duration=duration,
        endpoint=endpoint,
        keep=keep,
        console=console,
        plot=plot,
    )


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


def _sample(plot: PathPlot, truth: Truth, odom: Any) -> None:
    position = odom.pose.pose.position if odom is not None else None
    plot.add(
        (float(position.x), float(position.y)) if position is not None else None,
        (truth.x, truth.y),
    )


SETTLE_DEADLINE = 30.0
"""Most seconds of real time :func:`_settle` waits (a board's clock that stands still)."""


def _settle(side: BoardSide[Any], seen: Seen) -> None:
    """Wait until ``side.settle`` s of the board's own time have passed since the stop command
    and an odometry message has come after that: measured on the board's clock, not the wall,
    so a simulation that runs behind real time (a busy machine) still stops before the measure.
    Gives up after :data:`SETTLE_DEADLINE` s of real time, measuring what is there."""
    deadline = time.monotonic() + SETTLE_DEADLINE
    stop_at = side.clock() + side.settle
    while side.clock() < stop_at:
        if time.monotonic() >= deadline:
            return
        time.sleep(0.02)
    counted = seen.counts["odom"]
    while seen.counts["odom"] == counted and time.monotonic() < deadline:
        time.sleep(0.02)


def _result(side: BoardSide[R], truth: Truth, odom: Any) -> R:
    if odom is None:
        raise HwBridgeError(f"no odometry arrived: {side.ticks_of} ticks did not reach the host")
    position = odom.pose.pose.position
    error = math.hypot(float(position.x) - truth.x, float(position.y) - truth.y)
    return side.result(truth.distance, error)


def _link_summary(runtime: RobotRuntime) -> str:
    stats = runtime.bridge.boards[BOARD].info().get("stats", {})
    keys = ("frames_received", "crc_errors", "be_frames_lost", "retransmits", "rtt")
    return ", ".join(
        f"{k} {stats[k]:.4f}" if isinstance(stats.get(k), float) else f"{k} {stats.get(k)}"
        for k in keys
        if k in stats
    )


class _StatusLines:
    """The drive as a line every 5 s: the ground truth and what the graph sees."""

    def __init__(self, out: Console, seen: Seen, namespace: str) -> None:
        self.out, self.seen, self.namespace = out, seen, namespace
        self.last_line = 0.0

    def __enter__(self) -> _StatusLines:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        return None

    def show(self, elapsed: float, truth: Truth, final: bool = False) -> None:
        if final or elapsed - self.last_line < 5.0:
            return
        self.last_line = elapsed
        seen, namespace = self.seen, self.namespace
        odom, rng, imu = seen["odom"], seen["range"], seen["imu"]
        parts = [f"{elapsed:5.1f} s: truth {truth.x:+.2f}, {truth.y:+.2f} m"]
        if odom is not None:
            p = odom.pose.pose.position
            parts.append(f"{namespace}/odom {float(p.x):+.2f}, {float(p.y):+.2f} m")
        if rng is not None:
            shown = f"{truth.sonar:.2f}" if truth.sonar is not None else "-"
            parts.append(f"{namespace}/range {float(rng.range):.2f} m (truth {shown})")
        if imu is not None:
            parts.append(f"{namespace}/imu accel z {float(imu.linear_acceleration.z):.2f} m/s²")
        self.out.print("; ".join(parts))


class _LiveTable:
    """The drive as a table redrawn in place: what the graph sees next to the ground truth;
    a blank line after its last picture."""

    def __init__(self, out: Console, seen: Seen, namespace: str, side: BoardSide[Any]) -> None:
        self.out, self.seen, self.namespace = out, seen, namespace
        self.live = Live(self._table(0.0, side.truth()), console=out, refresh_per_second=4)

    def __enter__(self) -> _LiveTable:
        self.live.__enter__()
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.live.__exit__(kind, value, tb)
        if kind is None:
            self.out.print()

    def show(self, elapsed: float, truth: Truth, final: bool = False) -> None:
        self.live.update(self._table(elapsed, truth))

    def _table(self, t: float, truth: Truth) -> Table:
        namespace, seen = self.namespace, self.seen
        table = Table(title=f"diffbot, {t:5.1f} s", show_header=True, header_style="bold")
        table.add_column("what")
        table.add_column("graph sees")
        table.add_column("ground truth")
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
            table.add_row(
                f"{namespace}/range",
                f"{float(rng.range):.3f} m",
                f"{truth.sonar:.3f} m" if truth.sonar is not None else "nothing",
            )
        reading = seen["imu"]
        if reading is not None:
            a, g = reading.linear_acceleration, reading.angular_velocity
            table.add_row(
                f"{namespace}/imu accel z, gyro z",
                f"{float(a.z):.2f} m/s², {float(g.z):+.2f} rad/s",
                "",
            )
        joints = seen["joint_states"] if "joint_states" in seen.values else None
        if joints is not None and len(joints.position):
            table.add_row(
                f"{namespace}/joint_states {joints.name[0]}",
                f"{float(joints.position[0]):+.3f} rad",
                "",
            )
        table.add_row("distance driven", "", f"{truth.distance:.2f} m")
        return table
