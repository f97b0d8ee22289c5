"""Firmware from a robot file: ``hwbridge firmware generate ROBOT.yaml --board NAME``.

One robot file describes both sides of the wire. The host reads it at ``hwbridge up``; this
module writes the board's sketch from it: each device's plugin renders its own part
(:meth:`~hwbridge.robot.plugin.DevicePlugin.sketch`, a
:class:`~hwbridge.robot.plugin.SketchPart` kept in the device's folder) from the same settings
the host node reads (topics, rates, frames, pins, calibration such as the motors' full-PWM
speed), and :func:`generate_sketch` puts the parts together around one
``hwbridge::NodeHandle``: the includes (each once), the globals, ``setup()`` (the node, the shared
bus set-up such as ``Wire.begin()``, each device's set-up), and ``loop()`` (the devices'
disconnect code while no host is connected, their connect code once per connection, their loop
code, then ``spinOnce``). Settings are compiled in: no parameter is asked of the host, so the two
cannot disagree.

Before anything is written the board's wiring is checked against the MCU board's pins
(:func:`hwbridge.robot.wiring.check_wiring`). Devices whose ``only_on`` leaves the MCU board out
are left out of its sketch (named in the sketch's head and in the command's output).

The sketch defines ``HWBRIDGE_FIRMWARE_NAME`` (``ROBOT/BOARD``, BOARD the robot file's board
name) and ``HWBRIDGE_BUILD_TAG`` (``ROBOT/BOARD@`` and the first 12 hex digits of the robot
file's SHA-256, :func:`build_tag`) before it includes ``HwBridge.h``, so that a board says which
robot file it was built from and ``hwbridge up`` can compare it with the file it brings up.
"""

from __future__ import annotations

import hashlib
import re
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

from hwbridge.errors import HwBridgeError
from hwbridge.firmware.boards import mcu_board
from hwbridge.robot import identity
from hwbridge.robot.model import Robot, RobotBoardConfig
from hwbridge.robot.plugin import SketchContext, SketchPart, Wiring
from hwbridge.robot.registry import get_device
from hwbridge.robot.wiring import check_wiring, device_wiring, on_board

__all__ = [
    "DEFAULT_MCU",
    "GeneratedSketch",
    "build_tag",
    "c_identifier",
    "default_out_dir",
    "generate_sketch",
    "generated_elf",
    "pick_board",
    "write_sketch",
]

DEFAULT_MCU = "uno"
"""The MCU board of a robot file that names none (and no ``--board``)."""
DEFAULT_BAUD = 115200


def build_tag(robot_name: str, board_name: str, robot_file_bytes: bytes) -> str:
    """``ROBOT/BOARD@`` and the first 12 hex digits of the SHA-256 of the robot file's bytes:
    the one formula of :func:`hwbridge.robot.identity.build_tag`, which ``hwbridge up`` compares
    the board's tag with (BOARD is the robot file's board name, ``base``)."""
    return identity.build_tag(robot_name, board_name, robot_file_bytes)


def c_identifier(name: str) -> str:
    """``front-sonar`` -> ``front_sonar``: a name as a C++ identifier."""
    text = re.sub(r"[^A-Za-z0-9_]", "_", name)
    return text if text and not text[0].isdigit() else f"d_{text}"


@dataclass(frozen=True)
class GeneratedSketch:
    """A sketch generated from a robot file's board."""

    name: str
    """The sketch's name (its folder's and its ``.ino``'s): ``ROBOT_BOARD``."""
    mcu: str
    """The MCU board it is for (``uno``, ``nano``, ``mega``)."""
    text: str
    devices: tuple[str, ...]
    """The devices in it, by name."""
    left_out: tuple[str, ...] = field(default=())
    """Devices of the board that ``only_on`` keeps off this MCU board."""


def pick_board(robot: Robot, name: str | None) -> RobotBoardConfig:
    """The robot's board ``name``, or its only board."""
    if name is not None:
        return robot.board(name)
    if len(robot.boards) == 1:
        return robot.boards[0]
    if not robot.boards:
        raise HwBridgeError(f"{robot.path}: the robot has no boards: no firmware to generate")
    names = ", ".join(b.name for b in robot.boards)
    raise HwBridgeError(f"{robot.path}: the robot has boards {names}: say which with --for NAME")


def _block(code: str, indent: int) -> str:
    return textwrap.indent(code.rstrip("\n") + "\n", " " * indent) if code.strip() else ""


def generate_sketch(
    robot: Robot, robot_file_bytes: bytes, board: RobotBoardConfig, mcu: str
) -> GeneratedSketch:
    """The sketch of ``board`` for MCU board ``mcu``; RobotFileError if its wiring does not fit,
    HwBridgeError if a device's plugin cannot generate firmware."""
    table = mcu_board(mcu)
    check_wiring(robot, board.name, table.name)
    parts: list[tuple[str, SketchPart]] = []
    left_out: list[str] = []
    used: set[str] = set()
    for device in board.devices:
        if not on_board(device, table.name):
            left_out.append(device.name)
            continue
        identifier = c_identifier(device.name)
        if identifier in used:
            raise HwBridgeError(f"{device.source}: {device.name}: its C++ name is taken")
        used.add(identifier)
        plugin = get_device(device.type)
        wiring = device_wiring(device, table)
        context = SketchContext(identifier, table, wiring or Wiring())
        part = plugin.sketch(device.settings, context)
        if part is None:
            raise HwBridgeError(
                f"{device.source}: {device.name}: the {device.type} plugin cannot generate "
                "firmware (it has no sketch part); write that board's sketch by hand"
            )
        parts.append((device.name, part))
    name = c_identifier(f"{robot.name}_{table.name}")
    text = _assemble(robot, robot_file_bytes, board, table.name, parts, left_out)
    return GeneratedSketch(name, table.name, text, tuple(n for n, _ in parts), tuple(left_out))


def _assemble(
    robot: Robot,
    robot_file_bytes: bytes,
    board: RobotBoardConfig,
    mcu: str,
    parts: list[tuple[str, SketchPart]],
    left_out: list[str],
) -> str:
    includes: list[str] = []
    prelude: list[str] = []
    for _name, part in parts:
        includes += [i for i in part.includes if i not in includes]
        prelude += [line for line in part.prelude if line not in prelude]
    system = [i for i in includes if "/" not in i]
    library = sorted(i for i in includes if "/" in i)
    loops = "".join(part.loop for _n, part in parts)
    uses_now = re.search(r"\bnow\s*-", loops) is not None
    out = [
        f"// {robot.name}/{board.name} for the {mcu}: generated by 'hwbridge firmware generate' "
        f"from {robot.path.name}.",
        "// Do not edit: change the robot file and generate again. Devices: "
        + (", ".join(n for n, _ in parts) or "none")
        + (f"; left out on the {mcu} (only_on): {', '.join(left_out)}" if left_out else "")
        + ".",
        f'#define HWBRIDGE_FIRMWARE_NAME "{robot.name}/{board.name}"',
        f'#define HWBRIDGE_BUILD_TAG "{build_tag(robot.name, board.name, robot_file_bytes)}"',
        "#include <HwBridge.h>",
        *(f"#include <{i}>" for i in system),
        *(f"#include <{i}>" for i in library),
        "",
        "using namespace hwbridge::drivers;",
        "",
        "hwbridge::NodeHandle nh;",
        "",
    ]
    for _name, part in parts:
        if part.globals.strip():
            out.append(part.globals.rstrip("\n"))
            out.append("")
    out += [
        "bool announced = false;",
        "",
        "void setup() {",
        f'  nh.initNode({board.baud or DEFAULT_BAUD}, "{board.name}");',
    ]
    text = "\n".join(out) + "\n"
    text += "".join(f"  {line}\n" for line in prelude)
    text += "".join(_block(part.setup, 2) for _n, part in parts)
    text += "}\n\nvoid loop() {\n"
    text += "  unsigned long now = millis();\n" if uses_now else ""
    text += "  if (!nh.connected()) {\n"
    text += "".join(_block(part.disconnect, 4) for _n, part in parts)
    text += "    announced = false;\n  } else if (!announced) {\n    announced = true;\n"
    for _n, part in parts:
        if part.connect.strip():
            text += "    {\n" + _block(part.connect, 6) + "    }\n"
    text += "  }\n"
    for _n, part in parts:
        if part.loop.strip():
            text += "  {\n" + _block(part.loop, 4) + "  }\n"
    text += "  nh.spinOnce();\n}\n"
    return text


def write_sketch(sketch: GeneratedSketch, out_dir: Path) -> Path:
    """Write ``out_dir/NAME.ino`` (the folder made if need be); its path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    ino = out_dir / f"{sketch.name}.ino"
    ino.write_text(sketch.text, encoding="utf-8")
    return ino


def default_out_dir(robot: Robot, sketch: GeneratedSketch) -> Path:
    """``ROBOTDIR/firmware/NAME``: where ``hwbridge firmware generate`` writes by default."""
    return robot.path.resolve().parent / "firmware" / sketch.name


def generated_elf(robot_file: Path, mcu: str, board: str | None = None) -> Path:
    """The ELF of the sketch generated from ``robot_file`` (its board ``board``, default its
    only one) for MCU board ``mcu``, written and built once into the simulator's build cache
    (:func:`hwbridge.firmware.sim.examples.build_sketch_for_sim`, keyed by the sketch's text and
    the library's)."""
    from hwbridge.firmware.sim.examples import build_sketch_for_sim, cache_root
    from hwbridge.robot.config import load_robot

    robot = load_robot(robot_file)
    sketch = generate_sketch(robot, Path(robot_file).read_bytes(), pick_board(robot, board), mcu)
    digest = hashlib.sha256(sketch.text.encode()).hexdigest()[:16]
    folder = cache_root() / "generated" / digest / sketch.name
    if not (folder / f"{sketch.name}.ino").exists():
        write_sketch(sketch, folder)
    return build_sketch_for_sim(folder, sketch.mcu)
