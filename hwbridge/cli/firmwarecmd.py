"""``hwbridge firmware``: build sketches for AVR boards, measure them, generate C++ headers and
sketches from robot files."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from hwbridge.cli.common import no_such_path
from hwbridge.cli.simcmd import sim
from hwbridge.cli.uploadcmd import upload

__all__ = ["firmware_app"]

firmware_app = typer.Typer(
    help="Firmware: build sketches, measure them, generate headers, run them in simavr, "
    "upload them.",
    no_args_is_help=True,
)


@firmware_app.command("build")
def build(
    sketch: Annotated[
        Path,
        typer.Argument(
            metavar="SKETCH", exists=True, help="A sketch folder (NAME/NAME.ino) or .ino file."
        ),
    ],
    board: Annotated[
        str,
        typer.Option(
            "--board",
            "-b",
            help="uno, nano, mega, stm32f405 or microbit (bare ARM, run in QEMU), or host (a "
            "native program).",
        ),
    ] = "uno",
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Build folder (default: SKETCH/build/BOARD)."),
    ] = None,
) -> None:
    """Build a sketch with the HwBridge library for an AVR board or a bare ARM board (prints the
    ELF and its size), or as a native program with --board host (prints its path; run it, then
    connect to the URL it prints first).

    An AVR build ends with the Intel HEX file to upload. SKETCH may be relative: '.' in the
    sketch's folder."""
    from hwbridge.cli.simcmd import ARM_MCUS
    from hwbridge.firmware.build import (
        ARM_BOARDS,
        BOARDS,
        HOST_BOARD,
        arm_firmware_size,
        build_sketch,
        firmware_size,
    )

    known = [*BOARDS, *ARM_BOARDS, HOST_BOARD]
    if board not in known:
        raise typer.BadParameter(
            f"unknown board {board!r}; use one of {', '.join(known)}", param_hint="--board"
        )

    def progress(line: str) -> None:
        sys.stderr.write(f"hwbridge: {line}\n")
        sys.stderr.flush()

    elf = build_sketch(sketch, board, out, progress=progress)
    if board == HOST_BOARD:
        sys.stdout.write(f"{elf}: a native program; it prints the URL to connect to\n")
        return
    if board in ARM_BOARDS:
        size = arm_firmware_size(elf)
        arm = ARM_BOARDS[board]
        mcu = next(name for name, of in ARM_MCUS.items() if of == board)
        sys.stdout.write(
            f"{elf}: flash {size.flash} B of {arm.flash} ({100 * size.flash / arm.flash:.1f}%), "
            f"RAM {size.sram} B of {arm.sram} ({100 * size.sram / arm.sram:.1f}%)\n"
            f"{elf.with_suffix('.bin')}: the raw image to flash; in QEMU: "
            f"hwbridge firmware sim {elf} --mcu {mcu}\n"
        )
        return
    size = firmware_size(elf)
    limits = BOARDS[board]
    sys.stdout.write(
        f"{elf}: flash {size.flash} B of {limits.flash} ({100 * size.flash / limits.flash:.0f}%), "
        f"SRAM {size.sram} B of {limits.sram} ({100 * size.sram / limits.sram:.0f}%)\n"
        f"{elf.with_suffix('.hex')}: the image to upload (avrdude -U flash:w:FILE:i)\n"
    )


@firmware_app.command("size")
def size(
    elf: Annotated[
        Path,
        typer.Argument(metavar="ELF", exists=True, dir_okay=False, help="A built AVR ELF file."),
    ],
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable JSON output.")] = False,
) -> None:
    """Flash and static RAM of an ELF, as avr-size (or arm-none-eabi-size) counts them, and the
    library's own RAM."""
    from hwbridge.firmware.build import arm_firmware_size, firmware_size

    arm = elf.is_file() and elf.read_bytes()[18:20] == b"\x28\x00"  # e_machine EM_ARM
    found = arm_firmware_size(elf) if arm else firmware_size(elf)
    if as_json:
        sys.stdout.write(json.dumps(found.as_dict()) + "\n")
        return
    sketch = found.sram - found.core_sram - found.library_sram
    sys.stdout.write(
        f"flash {found.flash} B, SRAM {found.sram} B (of which the HwBridge library's static "
        f"objects {found.library_sram} B, the sketch's objects {sketch} B, the Arduino core's "
        f"{found.core_sram} B)\n"
    )
    for name, size_of, owner in found.objects:
        sys.stdout.write(f"  {size_of:6} B  {owner:8}  {name}\n")


_TYPES_HELP = (
    "Message or service types (pkg/Type); default: hwbridge_msgs' types, std_msgs/String, Bool, "
    "Float64 and sensor_msgs/JointState."
)
MsgPathOpt = Annotated[
    list[Path] | None,
    typer.Option(
        "--msg-path",
        help="Directory of message packages (PKG/msg/*.msg, PKG/srv/*.srv); repeatable.",
        exists=True,
        file_okay=False,
    ),
]
_CAPACITY_HELP = (
    "Elements of a variable-length array or bytes of a string field (default 8 and 32); "
    "pkg/Type.field[]=N for each string of a string array. Repeatable."
)


@firmware_app.command("headers")
def headers(
    ctx: typer.Context,
    outdir: Annotated[Path, typer.Argument(metavar="OUTDIR", help="Folder to write into.")],
    types: Annotated[
        list[str] | None, typer.Argument(metavar="[TYPES]...", help=_TYPES_HELP)
    ] = None,
    msg_path: MsgPathOpt = None,
    capacity: Annotated[
        list[str] | None,
        typer.Option("--capacity", metavar="pkg/Type.field=N", help=_CAPACITY_HELP),
    ] = None,
) -> None:
    """Write C++ headers: hwbridge_control.h (control messages) with the parts it includes
    (hwbridge_control_base.h, _msgs.h, _board.h), one per message type, and the fixed
    hwbridge_msg.h and hwbridge_wire.h they include; hwbridge_msgdefs.h, the hash of their
    definitions that a board sends (PROTOCOL.md 2.6.1)."""
    _write_headers(ctx, outdir, types, msg_path, capacity)


def _write_headers(
    ctx: typer.Context,
    outdir: Path,
    types: list[str] | None,
    msg_path: list[Path] | None,
    capacity: list[str] | None,
) -> None:
    from hwbridge.cli.common import Context
    from hwbridge.firmware.gen_control import generate_control_files
    from hwbridge.firmware.gen_msgs import Capacities, MessageHeaders, parse_capacity
    from hwbridge.msg import registry

    root = ctx.find_root().obj  # hwbridge --msg-path DIR firmware headers ...
    reg = registry([*(msg_path or ()), *(root.msg_path if isinstance(root, Context) else ())])
    limits = Capacities()
    for text in capacity or ():
        type_name, field, n = parse_capacity(text)
        limits.fields[(type_name, field)] = n
    names = types or [
        *reg.message_names("hwbridge_msgs"),
        *reg.service_names("hwbridge_msgs"),
        "std_msgs/String",
        "std_msgs/Bool",
        "std_msgs/Float64",
        "sensor_msgs/JointState",
    ]
    files = {**generate_control_files(), **MessageHeaders(reg, limits).headers(names)}
    for rel, text in files.items():
        path = outdir / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    sys.stdout.write(f"{len(files)} headers written to {outdir}\n")


def _is_robot_file(path: Path) -> bool:
    return path.suffix in (".yaml", ".yml") or path.is_file()


@firmware_app.command("generate")
def generate(
    ctx: typer.Context,
    target: Annotated[
        Path,
        typer.Argument(
            metavar="ROBOT.yaml|OUTDIR",
            help="A robot file: write (and build) its board's sketch. A folder: write the C++ "
            "message headers there, as 'firmware headers'.",
        ),
    ],
    types: Annotated[
        list[str] | None, typer.Argument(metavar="[TYPES]...", help=_TYPES_HELP)
    ] = None,
    board: Annotated[
        str | None,
        typer.Option(
            "--board",
            "-b",
            help="The MCU board: uno, nano or mega (default: the robot file's mcu, else uno).",
        ),
    ] = None,
    part: Annotated[
        str | None,
        typer.Option(
            "--for", metavar="NAME", help="The robot file's board (default: its only one)."
        ),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out", "-o", help="Folder of the sketch (default: ROBOTDIR/firmware/ROBOT_BOARD)."
        ),
    ] = None,
    no_build: Annotated[
        bool, typer.Option("--no-build", help="Write the sketch only; do not build it.")
    ] = False,
    msg_path: MsgPathOpt = None,
    capacity: Annotated[
        list[str] | None,
        typer.Option("--capacity", metavar="pkg/Type.field=N", help=_CAPACITY_HELP),
    ] = None,
) -> None:
    """Generate a board's firmware from a robot file: the sketch (printed path), then its build
    for the MCU board (the .elf and .hex with their sizes). The pins are checked first, each
    problem as FILE:LINE. Nobody writes C++: each device's plugin writes its part from the
    settings the host reads too.

    Given a folder instead, write the C++ message headers there ('firmware headers')."""
    if not _is_robot_file(target):
        if board or part or out or no_build:
            raise typer.BadParameter(
                f"{target} is no robot file (.yaml): --board, --for, --out and --no-build are "
                "for a robot file's sketch"
            )
        _write_headers(ctx, target, types, msg_path, capacity)
        return
    if not target.exists():  # a robot file to read (an OUTDIR is made)
        raise no_such_path(target, "ROBOT.yaml|OUTDIR")
    if types:
        raise typer.BadParameter("message types go with an OUTDIR, not with a robot file")
    from hwbridge.firmware.build import BOARDS, build_sketch, firmware_size
    from hwbridge.robot.config import load_robot
    from hwbridge.sketchgen import (
        DEFAULT_MCU,
        default_out_dir,
        generate_sketch,
        pick_board,
        write_sketch,
    )

    robot = load_robot(target)
    chosen = pick_board(robot, part)
    mcu = board or chosen.mcu
    if mcu is None:
        mcu = DEFAULT_MCU
        sys.stderr.write(
            f"hwbridge: {robot.path}: board {chosen.name} names no mcu: generating for "
            f"{DEFAULT_MCU} (say 'mcu: uno|nano|mega' in the file, or --board)\n"
        )
    sketch = generate_sketch(robot, target.read_bytes(), chosen, mcu)
    if sketch.left_out:
        sys.stderr.write(
            f"hwbridge: left out on the {sketch.mcu} (only_on): {', '.join(sketch.left_out)}\n"
        )
    ino = write_sketch(sketch, out if out is not None else default_out_dir(robot, sketch))
    sys.stdout.write(f"{ino}\n")
    sys.stdout.flush()
    if no_build:
        return

    def progress(line: str) -> None:
        sys.stderr.write(f"hwbridge: {line}\n")
        sys.stderr.flush()

    elf = build_sketch(ino, sketch.mcu, ino.parent / "build" / sketch.mcu, progress=progress)
    size = firmware_size(elf)
    limits = BOARDS[sketch.mcu]
    sys.stdout.write(
        f"{elf}: flash {size.flash} B of {limits.flash} ({100 * size.flash / limits.flash:.0f}%), "
        f"SRAM {size.sram} B of {limits.sram} ({100 * size.sram / limits.sram:.0f}%)\n"
        f"{elf.with_suffix('.hex')}: the image to upload (hwbridge firmware upload, or avrdude)\n"
    )


@firmware_app.command("library")
def library(
    zip_it: Annotated[
        bool,
        typer.Option(
            "--zip", help="Write the library as a zip for the Arduino IDE's Add .ZIP Library."
        ),
    ] = False,
    out: Annotated[
        Path | None,
        typer.Argument(
            metavar="[OUT]", help="The zip to write, with --zip (default: HwBridge.zip here)."
        ),
    ] = None,
) -> None:
    """Where the HwBridge Arduino library is, or with --zip a zip of it for the Arduino IDE.

    In the IDE: Sketch > Include Library > Add .ZIP Library..., then pick the zip; its
    examples show under File > Examples > HwBridge."""
    from hwbridge.firmware.build import LIBRARY_DIR

    if not zip_it:
        if out is not None:
            raise typer.BadParameter("OUT is the zip to write: add --zip", param_hint="OUT")
        sys.stdout.write(f"{LIBRARY_DIR}\n")
        return
    from hwbridge.firmware.libzip import write_library_zip

    target = out if out is not None else Path("HwBridge.zip")
    if target.is_dir():
        target = target / "HwBridge.zip"
    names = write_library_zip(target)
    examples = sum(1 for name in names if name.endswith(".ino"))
    sys.stdout.write(
        f"{target}: the HwBridge library, {len(names)} files, {examples} examples; in the "
        "Arduino IDE: Sketch > Include Library > Add .ZIP Library...\n"
    )


firmware_app.command("sim")(sim)
firmware_app.command("upload")(upload)
