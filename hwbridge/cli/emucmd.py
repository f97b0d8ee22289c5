"""``hwbridge emulate`` (a virtual board) and ``hwbridge demo`` (the whole path, emulated)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from hwbridge.cli.common import Context, robot_argument
from hwbridge.cli.stopping import wait_for_stop

__all__ = ["demo", "emulate"]


def emulate(
    board: Annotated[
        str,
        typer.Argument(
            metavar="ROBOT",
            help="A ready robot (diffbot), a robot file (ROBOT.yaml) or a Dynamixel bus "
            "(dxl-bus, dxl-bus-p1).",
        ),
    ],
    board_name: Annotated[
        str | None,
        typer.Option("--board", help="Which board of the robot file (default: the first)."),
    ] = None,
    pty: Annotated[
        bool, typer.Option("--pty", help="Serve on a new pseudo-terminal (the default).")
    ] = False,
    tcp: Annotated[
        int | None,
        typer.Option("--tcp", min=0, max=65535, help="Serve on this TCP port instead of a pty."),
    ] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the world and the devices.")] = 0,
    speed: Annotated[
        float, typer.Option("--speed", min=0.01, help="Simulated seconds per real second.")
    ] = 1.0,
) -> None:
    """Start a virtual board; the first line printed is the URL to connect to. Ctrl-C stops.

    A robot's board runs its devices' emulated models in a simulated world and speaks the native
    protocol (``hwbridge up ROBOT.yaml --link BOARD=URL``, or ``hwbridge connect URL``).
    Dynamixel buses answer raw Dynamixel packets, as servos behind a USB adapter do (try
    ``hwbridge dxl scan URL``).
    """
    from hwbridge.devices.dynamixel import EmulatedBusRunner, bus_configs, emulated_bus

    if pty and tcp is not None:
        raise typer.BadParameter("--pty and --tcp exclude each other")
    listen = "pty://" if tcp is None else f"tcp-listen://127.0.0.1:{tcp}"
    if board in bus_configs():
        runner = EmulatedBusRunner(emulated_bus(board), listen).start()
        url = _url_of(runner.link)
        _announce(url, f"emulated Dynamixel bus {board}; try: hwbridge dxl scan {url}")
        try:
            wait_for_stop()
        finally:
            runner.close()
        return

    from hwbridge.emulator import VirtualBoard, load_board
    from hwbridge.links import open_link

    config = load_board(robot_argument(board, "ROBOT"), board_name)
    virtual = VirtualBoard(config, seed=seed, speed=speed)
    link = open_link(listen)
    url = _url_of(link)
    _announce(url, f"virtual {config.name} (native protocol); connect with: hwbridge connect {url}")
    try:
        virtual.start(link)
        wait_for_stop()
    finally:
        virtual.stop()


def _url_of(link: object) -> str:
    """What a client opens to reach a link we serve: the pty's path or a socket URL."""
    slave = getattr(link, "slave_path", None)
    if slave is not None:
        return str(slave)
    host, port = link.bound_address  # type: ignore[attr-defined]
    return f"socket://{host}:{port}"


def _announce(url: str, what: str) -> None:
    sys.stdout.write(url + "\n")
    sys.stdout.flush()
    sys.stderr.write(what + "\n")


def demo(
    ctx: typer.Context,
    duration: Annotated[
        float, typer.Option("--duration", min=1.0, help="Seconds of driving.")
    ] = 30.0,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the world and the devices.")] = 0,
    keep: Annotated[
        bool,
        typer.Option("--keep", help="Keep board and bridge running afterwards for other tools."),
    ] = False,
    plot: Annotated[
        Path | None,
        typer.Option(
            "--plot",
            dir_okay=False,
            help="SVG file for the driven path against the ground truth (default: "
            "hwbridge-demo-SEED.svg in the temporary folder; the path is printed).",
        ),
    ] = None,
    no_plot: Annotated[bool, typer.Option("--no-plot", help="Write no path plot.")] = False,
    firmware: Annotated[
        bool,
        typer.Option(
            "--firmware",
            help="Run the real firmware (the DiffDriveBase sketch built for an ATmega328P) in "
            "simavr instead of the Python board; needs gcc-avr, arduino-core-avr and simavr.",
        ),
    ] = False,
    generated: Annotated[
        bool,
        typer.Option(
            "--generated",
            help="With --firmware: run the firmware generated from the robot file "
            "(diffbot_uno.yaml, as 'hwbridge firmware generate' writes it) instead of "
            "DiffDriveBase.",
        ),
    ] = False,
) -> None:
    """Drive an emulated diffbot through the real bridge and show what the graph sees."""
    options = ctx.find_root().obj
    endpoint = options.endpoint if isinstance(options, Context) else None
    if plot is None:
        import tempfile

        plot = Path(tempfile.gettempdir()) / f"hwbridge-demo-{seed}.svg"
    if generated and not firmware:
        raise typer.BadParameter("--generated goes with --firmware")
    if firmware:
        from hwbridge.emulator.firmware_demo import run_firmware_demo

        run_firmware_demo(
            duration=duration,
            seed=seed,
            endpoint=endpoint,
            keep=keep,
            plot=None if no_plot else plot,
            generated=generated,
        )
        return
    from hwbridge.emulator.demo import run_demo

    run_demo(
        duration=duration, seed=seed, endpoint=endpoint, keep=keep, plot=None if no_plot else plot
    )
