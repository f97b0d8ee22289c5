"""``hwbridge firmware upload``: a sketch, ELF or HEX into a board through its bootloader."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Annotated

import typer

__all__ = ["upload"]


def upload(
    target: Annotated[
        Path,
        typer.Argument(
            metavar="SKETCH|ELF|HEX",
            help="A sketch folder (built first), an AVR ELF, or an Intel HEX file.",
        ),
    ],
    port: Annotated[
        str,
        typer.Option(
            "--port", "-p", help="The board's serial port (/dev/ttyACM0, or a simulator's pty)."
        ),
    ],
    board: Annotated[str, typer.Option("--board", "-b", help="uno or mega.")] = "uno",
) -> None:
    """Upload firmware through the board's serial bootloader with avrdude (reset, write,
    verify). The port must be free: stop a bridge that has it open first."""
    from hwbridge.cli.stopping import STOP, on_signal
    from hwbridge.firmware.upload import Upload, check_port, prepare_image

    def progress(line: str) -> None:
        sys.stderr.write(f"hwbridge: {line}\n")
        sys.stderr.flush()

    with tempfile.TemporaryDirectory(prefix="hwbridge-upload-") as work:
        if not target.is_dir() and target.suffix.lower() != ".ino":
            progress(f"build: not needed ({target.name})")
        image = prepare_image(target, board, Path(work), progress=progress)
        path = check_port(port)
        job = Upload(image, path, board, progress=progress)
        with on_signal(job.stop):
            job.run()
        if job.stopped or STOP.is_set():
            raise KeyboardInterrupt
