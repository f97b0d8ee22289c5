"""``hwbridge firmware``: build sketches for AVR boards, measure them, generate C++ headers."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

__all__ = ["firmware_app"]

firmware_app = typer.Typer(
    help="Firmware: build sketches, measure them, generate headers.", no_args_is_help=True
)


@firmware_app.command("build")
def build(
    sketch: Annotated[
        Path, typer.Argument(metavar="SKETCH", help="A sketch folder (NAME/NAME.ino) or .ino file.")
    ],
    board: Annotated[str, typer.Option("--board", "-b", help="uno or mega.")] = "uno",
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Build folder (default: SKETCH/build/BOARD)."),
    ] = None,
) -> None:
    """Build a sketch with the HwBridge library for an AVR board; prints the ELF and its size."""
    from hwbridge.firmware.build import BOARDS, build_sketch, firmware_size

    elf = build_sketch(sketch, board, out)
    size = firmware_size(elf)
    limits = BOARDS[board]
    sys.stdout.write(
        f"{elf}: flash {size.flash} B of {limits.flash} ({100 * size.flash / limits.flash:.0f}%), "
        f"SRAM {size.sram} B of {limits.sram} ({100 * size.sram / limits.sram:.0f}%)\n"
    )


@firmware_app.command("size")
def size(
    elf: Annotated[Path, typer.Argument(metavar="ELF", help="A built AVR ELF file.")],
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable JSON output.")] = False,
) -> None:
    """Flash and static RAM of an ELF, as avr-size counts them, and the library's own RAM."""
    from hwbridge.firmware.build import firmware_size

    found = firmware_size(elf)
    if as_json:
        sys.stdout.write(json.dumps(found.as_dict()) + "\n")
        return
    sys.stdout.write(
        f"flash {found.flash} B, SRAM {found.sram} B (of which the HwBridge library's static "
        f"objects {found.library_sram} B)\n"
    )
