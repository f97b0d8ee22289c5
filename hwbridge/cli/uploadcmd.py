"""``hwbridge firmware upload``: a sketch, ELF or HEX into a board through its bootloader."""

from __future__ import annotations

import contextlib
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from hwbridge.errors import HwBridgeError

if TYPE_CHECKING:
    from hwbridge.firmware.upload import PortBusyError
    from hwbridge.graph import Graph

__all__ = ["upload"]


def upload(
    ctx: typer.Context,
    target: Annotated[
        Path,
        typer.Argument(
            metavar="SKETCH|ELF|HEX",
            exists=True,
            help="A sketch folder (built first), an AVR ELF, or an Intel HEX file (.hex, .ihex, "
            ".ihx).",
        ),
    ],
    port: Annotated[
        str,
        typer.Option(
            "--port", "-p", help="The board's serial port (/dev/ttyACM0, or a simulator's pty)."
        ),
    ],
    board: Annotated[str, typer.Option("--board", "-b", help="uno or mega.")] = "uno",
    pause_bridge: Annotated[
        bool,
        typer.Option(
            "--pause-bridge",
            help="If a running bridge (hwbridge connect/up) has the port, pause it for the "
            "upload without asking; it reopens the port afterwards.",
        ),
    ] = False,
) -> None:
    """Upload firmware through the board's serial bootloader with avrdude (reset, write,
    verify). The port must be free: a running hwbridge bridge that has it is paused for the
    upload (asked on a terminal, or --pause-bridge) and takes the board back afterwards; any
    other program that has it is named."""
    from hwbridge.cli.stopping import STOP, on_signal
    from hwbridge.firmware.upload import (
        PROGRAMMERS,
        PortBusyError,
        Upload,
        check_port,
        prepare_image,
    )

    if board not in PROGRAMMERS:
        raise typer.BadParameter(
            f"unknown board {board!r}; use {' or '.join(PROGRAMMERS)}", param_hint="--board"
        )

    def progress(line: str) -> None:
        sys.stderr.write(f"hwbridge: {line}\n")
        sys.stderr.flush()

    with tempfile.TemporaryDirectory(prefix="hwbridge-upload-") as work:
        if not target.is_dir() and target.suffix.lower() != ".ino":
            progress(f"build: not needed ({target.name})")
        image = prepare_image(target, board, Path(work), progress=progress)
        with contextlib.ExitStack() as stack:
            try:
                path = check_port(port)
            except PortBusyError as busy:
                _pause_bridge(ctx, stack, busy, pause_bridge, progress)
                path = _free_port(port)
            job = Upload(image, path, board, progress=progress)
            with on_signal(job.stop):
                job.run()
        if job.stopped or STOP.is_set():
            raise KeyboardInterrupt


def _free_port(port: str) -> Path:
    """The port once a paused bridge's close of it shows (the lock goes with the close)."""
    from hwbridge.firmware.upload import PortBusyError, check_port

    deadline = time.monotonic() + 10.0
    while True:
        try:
            return check_port(port)
        except PortBusyError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def _pause_bridge(
    ctx: typer.Context,
    stack: contextlib.ExitStack,
    busy: PortBusyError,
    pause_bridge: bool,
    progress: Callable[[str], None],
) -> None:
    """Pause the hwbridge bridge that holds the port (the lock holder, found on the graph),
    resumed when ``stack`` closes; ``busy`` again when the holder is no bridge on the graph or
    the user does not want it paused."""
    from hwbridge.bridge.control import BridgePause, find_holding_board
    from hwbridge.cli.common import open_graph
    from hwbridge.firmware.upload import UploadError

    if busy.pid is None:
        raise busy
    graph: Graph | None = None
    held = None
    try:
        graph = stack.enter_context(open_graph(ctx))
        held = find_holding_board(graph, str(busy.path), busy.pid)
    except HwBridgeError:
        pass  # no graph here: no bridge to pause
    if graph is None or held is None:
        if "hwbridge" in busy.holder:
            raise UploadError(
                f"{busy}; it looks like a hwbridge bridge, but no bridge on the graph this "
                "command reaches has the port: give the bridge's graph (hwbridge --endpoint "
                "ENDPOINT --domain DOMAIN firmware upload ...) to have it paused"
            ) from None
        raise busy
    what = f"board {held.name} of a running hwbridge bridge (pid {busy.pid})"
    if not pause_bridge:
        if not sys.stdin.isatty():
            raise UploadError(
                f"port {busy.path} is busy: board {held.name} of a running hwbridge bridge has "
                f"it ({busy.holder or f'pid {busy.pid}'}); give --pause-bridge to pause the "
                "bridge for the upload (it takes the board back afterwards), or stop it"
            ) from None
        if not typer.confirm(
            f"hwbridge: port {busy.path} is held by {what}: pause it for the upload?",
            default=False,
            err=True,
        ):
            raise busy
    pause = BridgePause(graph, held)
    progress(f"pause: asking {what} to release {busy.path}")

    def resume() -> None:
        try:
            pause.resume()
        except HwBridgeError as exc:
            progress(f"error: the bridge was not told to resume: {exc}; restart it")
            return
        progress(f"resume: {what} reopens {busy.path}")

    stack.callback(resume)  # also after a pause that failed half-way
    pause.pause()
    progress(f"pause: the bridge released {busy.path}")
