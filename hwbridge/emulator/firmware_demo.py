"""``hwbridge demo --firmware``: the demo with the real firmware instead of the Python board.

The DiffDriveBase example sketch is built for an ATmega328P (an Uno) and run in simavr
(:class:`~hwbridge.firmware.sim.SimAvr`); the emulator's world drives its pins
(:class:`~hwbridge.emulator.pins.PinWorld`: encoder edges, motor PWM read back, the sonar's
echo, the MPU-6050 on I2C). The robot file is brought up as ``hwbridge up`` brings it up
(:class:`~hwbridge.robot.runtime.RobotRuntime`) with its board's link on the simulator's pty, so
the same host nodes make ``odom``, ``range`` and ``imu`` from what the firmware publishes. The
same driver as ``hwbridge demo`` steers, and the run ends with the same line:
``odometry error: E% of D m``.

An Uno decodes its encoders x2 (one interrupt pin per wheel), so the host's ``counts_per_rev``
is halved for this run, as the sketch's comment asks of a robot file for an Uno.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.console import Console

from hwbridge.emulator.board import ROBOTS_DIR, load_board
from hwbridge.emulator.demo import print_ending, wait_connected
from hwbridge.emulator.pins import PinWorld
from hwbridge.errors import HwBridgeError
from hwbridge.firmware.sim import SimAvr
from hwbridge.firmware.sim.examples import build_example
from hwbridge.graph import Graph, GraphConfig
from hwbridge.robot.config import load_robot
from hwbridge.robot.model import Robot
from hwbridge.robot.runtime import RobotRuntime
from hwbridge.viz.pathplot import PathPlot

__all__ = ["FirmwareDemoResult", "run_firmware_demo", "uno_robot"]

ROBOT_FILE = ROBOTS_DIR / "diffbot.yaml"
BOARD = "base"
SKETCH = "DiffDriveBase"


@dataclass(frozen=True)
class FirmwareDemoResult:
    """How the run went: distance driven (ground truth), final odometry error, resets."""

    distance: float
    error: float
    sim_time: float
    resets: int

    @property
    def error_percent(self) -> float:
        return 100.0 * self.error / self.distance if self.distance > 0 else 0.0


def uno_robot(robot: Robot, board: str = BOARD, decoding: int = 2) -> Robot:
    """``robot`` with the ``counts_per_rev`` of its board's devices (the diffdrive's) for a
    board decoding ``decoding`` edges of the 4 per encoder line (an Uno: 2)."""
    boards = []
    for entry in robot.boards:
        if entry.name == board:
            devices = tuple(
                dataclasses.replace(
                    d,
                    settings={
                        **d.settings,
                        "counts_per_rev": d.settings["counts_per_rev"] * decoding / 4,
                    },
                )
                if "counts_per_rev" in d.settings
                else d
                for d in entry.devices
            )
            boards.append(dataclasses.replace(entry, devices=devices))
        else:
            boards.append(entry)
    return dataclasses.replace(robot, boards=tuple(boards))


class _Driver:
    """Cruise forward; turn in place while the sonar sees something closer than 0.5 m
    (``hwbridge demo``'s driver)."""

    def __init__(self) -> None:
        self.turning_until = 0.0

    def command(self, now: float, sonar: Any) -> tuple[float, float]:
        near = sonar is not None and math.isfinite(sonar.range) and sonar.range < 0.5
        if near or (sonar is not None and sonar.range == -math.inf):
            self.turning_until = now + 0.8
        if now < self.turning_until:
            return 0.0, 1.2
        return 0.25, 0.3 * math.sin(now * 0.7)


class _Seen:
    def __init__(self, node: Any, topics: dict[str, str]) -> None:
        self.values: dict[str, Any] = dict.fromkeys(topics)
        self.counts: dict[str, int] = dict.fromkeys(topics, 0)
        for topic, type_name in topics.items():
            node.subscriber(topic, type_name, lambda m, t=topic: self._set(t, m))

    def _set(self, topic: str, message: Any) -> None:
        self.values[topic] = message
        self.counts[topic] += 1


def run_firmware_demo(
    *,
    duration: float = 30.0,
    seed: int = 0,
    endpoint: str | None = None,
    keep: bool = False,
    console: Console | None = None,
    plot: Path | None = None,
    reset_at: float | None = None,
    elf: Path | None = None,
) -> FirmwareDemoResult:
    """Run the demo on the firmware in simavr. ``reset_at`` (s) resets the AVR once mid-run
    (the bridge has to recover on its own); ``elf`` replaces the DiffDriveBase build."""
    out = console or Console(stderr=False)
    firmware = elf or build_example(SKETCH, "uno")
    robot = uno_robot(load_robot(ROBOT_FILE))
    namespace = robot.board(BOARD).namespace
    sim = SimAvr(firmware, mcu="atmega328p")
    graph: Graph | None = None
    runtime: RobotRuntime | None = None
    try:
        sim.start(hold=True)
        pins = PinWorld(sim, load_board(str(ROBOT_FILE), BOARD), seed=seed).attach()
        sim.go()
        graph = Graph(GraphConfig.embedded([endpoint] if endpoint else None))
        runtime = RobotRuntime(robot.with_links({BOARD: sim.url}), graph).start()
        view = graph.node("demo_driver", namespace=namespace)
        seen = _Seen(
            view,
            {"odom": "nav_msgs/Odometry", "range": "sensor_msgs/Range", "imu": "sensor_msgs/Imu"},
        )
        cmd_vel = view.publisher("cmd_vel", "geometry_msgs/Twist")
        out.print(
            f"[bold]hwbridge demo --firmware[/]: {SKETCH} for the ATmega328P "
            f"({firmware.name}) in simavr on {sim.path}; robot {robot.name} up with board "
            f"{BOARD}; graph on {graph.config.describe()}; topics under {namespace}"
        )
        if pins.skipped:
            out.print(f"no pins on the Uno for: {', '.join(pins.skipped)}")
        wait_connected(runtime, 30.0, "the firmware in simavr")
        world = pins.world.config
        path_plot = PathPlot(
            room=world.room,
            obstacles=world.obstacles,
            title=f"hwbridge demo --firmware: {robot.name}, odometry against ground truth",
        )
        driver = _Driver()
        started = time.monotonic()
        last_line = 0.0
        reset_done = reset_at is None
        try:
            while True:
                elapsed = time.monotonic() - started
                if elapsed >= duration:
                    break
                if not reset_done and reset_at is not None and elapsed >= reset_at:
                    reset_done = True
                    out.print(f"{elapsed:5.1f} s: resetting the AVR")
                    sim.reset()
                v, w = driver.command(elapsed, seen.values["range"])
                cmd_vel.publish({"linear": {"x": v}, "angular": {"z": w}})
                _sample(path_plot, pins, seen.values["odom"])
                if elapsed - last_line >= 5.0:
                    last_line = elapsed
                    out.print(_status(pins, seen, namespace, elapsed))
                time.sleep(0.1)
            cmd_vel.publish({})
            time.sleep(1.0)  # the robot stops; the last ticks arrive
            _sample(path_plot, pins, seen.values["odom"])
            if keep:
                out.print(
                    "The simulated board and the bridge keep running: try 'hwbridge topic "
                    "list' in another terminal. Ctrl-C ends."
                )
                while True:
                    time.sleep(1.0)
        except KeyboardInterrupt:
            out.print("interrupted")
        result = _result(pins, seen.values["odom"], sim)
        counts = ", ".join(f"{namespace}/{t}: {n}" for t, n in seen.counts.items())
        out.print(f"{sim.time:.1f} s of AVR time; messages {counts}; AVR resets {sim.resets}")
        print_ending(out, result, path_plot, plot, note="firmware in simavr; ")
        return result
    finally:
        if runtime is not None:
            runtime.stop()
        if graph is not None:
            graph.close()
        sim.close()


def _status(pins: PinWorld, seen: _Seen, namespace: str, elapsed: float) -> str:
    with pins.lock:
        truth = pins.world.pose
        sonar = pins.world.sonar_distance()
    odom, rng, imu = seen.values["odom"], seen.values["range"], seen.values["imu"]
    parts = [f"{elapsed:5.1f} s: truth {truth.x:+.2f}, {truth.y:+.2f} m"]
    if odom is not None:
        p = odom.pose.pose.position
        parts.append(f"{namespace}/odom {float(p.x):+.2f}, {float(p.y):+.2f} m")
    if rng is not None:
        shown = f"{sonar:.2f}" if sonar is not None else "-"
        parts.append(f"{namespace}/range {float(rng.range):.2f} m (truth {shown})")
    if imu is not None:
        parts.append(f"{namespace}/imu accel z {float(imu.linear_acceleration.z):.2f} m/s²")
    return "; ".join(parts)


def _sample(plot: PathPlot, pins: PinWorld, odom: Any) -> None:
    with pins.lock:
        truth = pins.world.pose
    position = odom.pose.pose.position if odom is not None else None
    plot.add(
        (float(position.x), float(position.y)) if position is not None else None,
        (truth.x, truth.y),
    )


def _result(pins: PinWorld, odom: Any, sim: SimAvr) -> FirmwareDemoResult:
    if odom is None:
        raise HwBridgeError("no odometry arrived: the firmware's ticks did not reach the host")
    with pins.lock:
        truth = pins.world.pose
        distance = pins.world.base.distance
    position = odom.pose.pose.position
    error = math.hypot(float(position.x) - truth.x, float(position.y) - truth.y)
    return FirmwareDemoResult(distance, error, sim.time, sim.resets)
