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

The robot file is the Uno's (``diffbot_uno.yaml``: the same body and room as ``diffbot.yaml``,
DiffDriveBase's Uno wiring, ``counts_per_rev`` for its x2 decoding, no pan servo); the devices'
pin models read their pins from it. With ``generated`` (``hwbridge demo --firmware
--generated``) the firmware is not DiffDriveBase but the sketch that ``hwbridge firmware
generate`` writes from that same file (:func:`hwbridge.sketchgen.generated_elf`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rich.console import Console

from hwbridge.emulator.board import ROBOTS_DIR, load_board
from hwbridge.emulator.demo import BOARD, BoardSide, Seen, Truth, drive
from hwbridge.emulator.pins import PinWorld
from hwbridge.emulator.world import WorldConfig
from hwbridge.firmware.sim import SimAvr
from hwbridge.firmware.sim.examples import build_example
from hwbridge.graph import Graph
from hwbridge.robot.config import load_robot
from hwbridge.robot.runtime import RobotRuntime

__all__ = ["UNO_ROBOT_FILE", "FirmwareDemoResult", "FirmwareSide", "run_firmware_demo"]

SKETCH = "DiffDriveBase"
UNO_ROBOT_FILE = ROBOTS_DIR / "diffbot_uno.yaml"
"""The demo robot wired to an Uno (the robot the firmware in simavr is)."""


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


class FirmwareSide(BoardSide[FirmwareDemoResult]):
    """The demo robot's board as the DiffDriveBase firmware (``generated``: the sketch generated
    from the robot file; or ``elf``) for an ATmega328P in simavr, its pins driven by the
    emulator's world; ``reset_at`` (s) resets the AVR once mid-run."""

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
        self,
        seed: int = 0,
        *,
        reset_at: float | None = None,
        elf: Path | None = None,
        generated: bool = False,
    ) -> None:
        self.seed = seed
        self.reset_at = reset_at
        self.sketch = f"the sketch generated from {UNO_ROBOT_FILE.name}" if generated else SKETCH
        if elf is None:
            if generated:
                from hwbridge.sketchgen import generated_elf

                elf = generated_elf(UNO_ROBOT_FILE, "uno", BOARD)
            else:
                elf = build_example(SKETCH, "uno")
        self.firmware = elf
        self.robot = load_robot(UNO_ROBOT_FILE)
        self.plot_title = (
            f"hwbridge demo --firmware: {self.robot.name}, odometry against ground truth"
        )
        self.sim = SimAvr(self.firmware, mcu="atmega328p")
        self.pins: PinWorld | None = None

    def open(self) -> str:
        self.sim.start(hold=True)
        board = load_board(str(UNO_ROBOT_FILE), BOARD)
        self.pins = PinWorld(self.sim, board, board="uno", seed=self.seed).attach()
        self.sim.go()
        return self.sim.url

    def _world(self) -> PinWorld:
        if self.pins is None:
            raise RuntimeError("the simulated board is not open")
        return self.pins

    def intro(self, graph: Graph, namespace: str) -> list[str]:
        lines = [
            f"[bold]hwbridge demo --firmware[/]: {self.sketch} for the ATmega328P "
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

    def clock(self) -> float:
        return self.sim.time

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
    generated: bool = False,
) -> FirmwareDemoResult:
    """Run the demo on the firmware in simavr. ``reset_at`` (s) resets the AVR once mid-run
    (the bridge has to recover on its own); ``elf`` replaces the DiffDriveBase build;
    ``generated`` runs the sketch generated from the robot file instead."""
    return drive(
        FirmwareSide(seed, reset_at=reset_at, elf=elf, generated=generated),
        duration=duration,
        endpoint=endpoint,
        keep=keep,
        console=console,
        plot=plot,
    )
