"""``hwbridge demo --firmware``: the demo with the real firmware instead of the Python board.

The DiffDriveBase example sketch is built for an ATmega328P (an Uno) and run in simavr
(:class:`~hwbridge.firmware.sim.SimAvr`); the emulator's world drives its pins
(:class:`~hwbridge.emulator.pins.PinWorld`: encoder edges, motor PWM read back, the sonar's
echo, the MPU-6050 on I2C). The run is ``hwbridge demo``'s
(:func:`hwbridge.emulator.demo.drive`) with this module's board side (:class:`FirmwareSide`):
the robot file is brought up as ``hwbridge up`` brings it up with its board's link on the
simulator's pty, so the same host nodes make ``odom``, ``range`` and ``imu`` from what the
firmware publishes, the same driver steers, and the run ends with the same line: ``odometry
error: E% of D m``. Its screen is a status line every 5 s.

An Uno decodes its encoders x2 (one interrupt pin per wheel), so the host's ``counts_per_rev``
is halved for this run, as the sketch's comment asks of a robot file for an Uno.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console

from hwbridge.emulator.board import load_board
from hwbridge.emulator.demo import BOARD, ROBOT_FILE, BoardSide, Seen, Truth, drive
from hwbridge.emulator.pins import PinWorld
from hwbridge.emulator.world import WorldConfig
from hwbridge.firmware.sim import SimAvr
from hwbridge.firmware.sim.examples import build_example
from hwbridge.graph import Graph
from hwbridge.robot.config import load_robot
from hwbridge.robot.model import Robot
from hwbridge.robot.runtime import RobotRuntime

__all__ = ["FirmwareDemoResult", "FirmwareSide", "run_firmware_demo", "uno_robot"]

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


class FirmwareSide(BoardSide[FirmwareDemoResult]):
    """The demo robot's board as the DiffDriveBase firmware (or ``elf``) for an ATmega328P in
    simavr, its pins driven by the emulator's world; ``reset_at`` (s) resets the AVR once
    mid-run."""

    label = "the firmware in simavr"
    connect_timeout = 30.0
    settle = 1.0
    ticks_of = "the firmware's"
    plot_note = "firmware in simavr; "
    keep_note = (
        "The simulated board and the bridge keep running: try 'hwbridge topic list' in another "
        "terminal. Ctrl-C ends."
    )

    def __init__(
        self, seed: int = 0, *, reset_at: float | None = None, elf: Path | None = None
    ) -> None:
        self.seed = seed
        self.reset_at = reset_at
        self.firmware = elf or build_example(SKETCH, "uno")
        self.robot = uno_robot(load_robot(ROBOT_FILE))
        self.plot_title = (
            f"hwbridge demo --firmware: {self.robot.name}, odometry against ground truth"
        )
        self.sim = SimAvr(self.firmware, mcu="atmega328p")
        self.pins: PinWorld | None = None

    def open(self) -> str:
        self.sim.start(hold=True)
        self.pins = PinWorld(self.sim, load_board(str(ROBOT_FILE), BOARD), seed=self.seed).attach()
        self.sim.go()
        return self.sim.url

    def _world(self) -> PinWorld:
        if self.pins is None:
            raise RuntimeError("the simulated board is not open")
        return self.pins

    def intro(self, graph: Graph, namespace: str) -> list[str]:
        lines = [
            f"[bold]hwbridge demo --firmware[/]: {SKETCH} for the ATmega328P "
            f"({self.firmware.name}) in simavr on {self.sim.path}; robot {self.robot.name} up "
            f"with board {BOARD}; graph on {graph.config.describe()}; topics under {namespace}"
        ]
        skipped = self._world().skipped
        if skipped:
            lines.append(f"no pins on the Uno for: {', '.join(skipped)}")
        return lines

    @property
    def world(self) -> WorldConfig:
        return self._world().world.config

    def truth(self) -> Truth:
        pins = self._world()
        with pins.lock:
            pose = pins.world.pose
            return Truth(pose.x, pose.y, pins.world.base.distance, pins.world.sonar_distance())

    def during(self, elapsed: float, out: Console) -> None:
        if self.reset_at is not None and elapsed >= self.reset_at:
            self.reset_at = None
            out.print(f"{elapsed:5.1f} s: resetting the AVR")
            self.sim.reset()

    def result(self, distance: float, error: float) -> FirmwareDemoResult:
        return FirmwareDemoResult(distance, error, self.sim.time, self.sim.resets)

    def summary(self, runtime: RobotRuntime, seen: Seen, namespace: str) -> str:
        counts = ", ".join(f"{namespace}/{t}: {n}" for t, n in seen.counts.items())
        return f"{self.sim.time:.1f} s of AVR time; messages {counts}; AVR resets {self.sim.resets}"

    def close(self) -> None:
        self.sim.close()


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
    return drive(
        FirmwareSide(seed, reset_at=reset_at, elf=elf),
        duration=duration,
        endpoint=endpoint,
        keep=keep,
        console=console,
        plot=plot,
    )
