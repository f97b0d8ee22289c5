"""Firmware generated from a robot file against the hand-written DiffDriveBase sketch.

Two measurements, each against its peer in the same run:

* ``size`` (one line per board, ``uno`` and ``mega``): the flash and static RAM (``hwbridge
  firmware size``: avr-size's .text + .data and .data + .bss) of the sketch ``hwbridge firmware
  generate`` writes for the demo robot (``diffbot_uno.yaml`` for the Uno, ``diffbot.yaml``,
  with the Dynamixel pan servo, for the Mega) and of DiffDriveBase built for the same board,
  with ``flash_ratio`` and ``sram_ratio`` (generated / hand-written) and ``within_5pct``
  (both ratios at most 1.05: the generator costs no more than 5 % over the hand-written
  sketch; ``abs_within_5pct`` says whether they are also no more than 5 % under it). The
  hand-written sketch asks the host for its ``max_wheel_speed`` parameter at run time; the
  generated one compiles the robot file's value in, which is most of the difference.
* ``demo``: ``hwbridge demo --firmware`` (DiffDriveBase in simavr) and ``hwbridge demo
  --firmware --generated`` (the generated firmware in simavr) with the same world, seed and
  duration, each on a graph of its own: distance driven (ground truth) and final odometry
  error (% of the distance), ``within_0_5pct`` for the generated one.

Builds are cached (``~/.cache/hwbridge/sim-examples``). Needs gcc-avr, arduino-core-avr and the
simavr runner (as ``hwbridge demo --firmware``).

    .venv/bin/python tools/bench/generated_firmware.py [--duration 20] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
from pathlib import Path
from typing import Any

from rich.console import Console

from hwbridge.emulator.board import ROBOTS_DIR
from hwbridge.emulator.firmware_demo import UNO_ROBOT_FILE, run_firmware_demo
from hwbridge.firmware.build import firmware_size
from hwbridge.firmware.sim.examples import build_example
from hwbridge.sketchgen import generated_elf

ROBOT_FILES = {"uno": UNO_ROBOT_FILE, "mega": ROBOTS_DIR / "diffbot.yaml"}
LIMIT = 1.05


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


def _line(record: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps({"bench": "generated_firmware", **record}) + "\n")
    sys.stdout.flush()


def sizes() -> None:
    for board, robot_file in ROBOT_FILES.items():
        ours = firmware_size(generated_elf(Path(robot_file), board))
        theirs = firmware_size(build_example("DiffDriveBase", board))
        flash, sram = ours.flash / theirs.flash, ours.sram / theirs.sram
        _line(
            {
                "case": "size",
                "board": board,
                "robot_file": Path(robot_file).name,
                "generated_flash": ours.flash,
                "generated_sram": ours.sram,
                "peer": "DiffDriveBase",
                "peer_flash": theirs.flash,
                "peer_sram": theirs.sram,
                "flash_ratio": round(flash, 4),
                "sram_ratio": round(sram, 4),
                "within_5pct": flash <= LIMIT and sram <= LIMIT,
                "abs_within_5pct": abs(flash - 1) <= LIMIT - 1 and abs(sram - 1) <= LIMIT - 1,
            }
        )


def demo(duration: float, seed: int) -> None:
    quiet = Console(stderr=True)
    results = {}
    for label, generated in (("peer", False), ("generated", True)):
        results[label] = run_firmware_demo(
            duration=duration,
            seed=seed,
            endpoint=f"tcp/127.0.0.1:{_free_port()}",
            console=quiet,
            plot=None,
            generated=generated,
        )
    ours, theirs = results["generated"], results["peer"]
    _line(
        {
            "case": "demo",
            "board": "uno",
            "duration_s": duration,
            "seed": seed,
            "generated_distance_m": round(ours.distance, 3),
            "generated_error_pct": round(ours.error_percent, 3),
            "generated_sim_time_s": round(ours.sim_time, 2),
            "peer": "DiffDriveBase",
            "peer_distance_m": round(theirs.distance, 3),
            "peer_error_pct": round(theirs.error_percent, 3),
            "within_0_5pct": ours.error_percent <= 0.5,
        }
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0, help="demo seconds")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-demo", action="store_true", help="sizes only")
    args = parser.parse_args()
    sizes()
    if not args.no_demo:
        demo(args.duration, args.seed)


if __name__ == "__main__":
    main()
