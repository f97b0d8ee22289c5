"""The HwBridge library's example sketches built for simavr, kept in a cache.

:func:`build_example` builds ``firmware/HwBridge/examples/NAME`` with
:func:`hwbridge.firmware.build.build_sketch` for an Uno or a Mega, adding the Arduino core's
``Wire`` library when the sketch includes ``<Wire.h>``. ``build_sketch`` compiles a library's
C++ files only; Wire's TWI layer is C (``utility/twi.c``), so when the link misses it, that one
file is compiled with the core's flags and the sketch linked again with it. Builds are cached
under ``~/.cache/hwbridge/sim-examples/`` by a hash of the sketch, the library and the board.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
from pathlib import Path
from typing import Final

from hwbridge.errors import HwBridgeError
from hwbridge.firmware import build

__all__ = ["EXAMPLES_DIR", "build_example", "build_sketch_for_sim"]

EXAMPLES_DIR: Final = build.LIBRARY_DIR / "examples"
WIRE_DIR: Final = build.CORE_DIR / "libraries" / "Wire"
MCU_OF_BOARD: Final = {"uno": "atmega328p", "mega": "atmega2560"}


def _cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hwbridge" / "sim-examples"


def _digest(sketch: Path, board: str, defines: list[str]) -> str:
    digest = hashlib.sha256(f"{board}\0{' '.join(defines)}\0".encode())
    for folder in (sketch, build.LIBRARY_DIR / "src"):
        for path in sorted(folder.rglob("*")):
            if path.is_file() and "build" not in path.relative_to(folder).parts:
                digest.update(str(path.relative_to(folder)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


def build_sketch_for_sim(
    sketch: Path, board: str = "uno", *, defines: list[str] | None = None
) -> Path:
    """The ELF of ``sketch`` (a folder with NAME.ino) for ``board``, built once and cached."""
    if board not in MCU_OF_BOARD:
        raise HwBridgeError(f"unknown board {board!r}: uno or mega")
    sketch = sketch.resolve()
    flags = list(defines or [])
    out = _cache_root() / f"{sketch.name}-{board}-{_digest(sketch, board, flags)}"
    elf = out / f"{sketch.name}.elf"
    if elf.exists():
        return elf
    ino = sketch / f"{sketch.name}.ino"
    uses_wire = ino.exists() and "<Wire.h>" in ino.read_text(encoding="utf-8")
    libraries = [build.LIBRARY_DIR, *([WIRE_DIR] if uses_wire else [])]
    partial = out.with_name(out.name + f".{os.getpid()}.tmp")
    try:
        built = build.build_sketch(sketch, board, partial, libraries=libraries, defines=flags)
    except HwBridgeError as exc:
        if not uses_wire or "twi_" not in str(exc):
            raise
        built = _link_with_twi(sketch.name, board, partial)
    if out.exists():  # another process built it meanwhile
        shutil.rmtree(partial, ignore_errors=True)
    else:
        partial.rename(out)
    return out / built.name


def _link_with_twi(name: str, board_name: str, out: Path) -> Path:
    """Link the objects build_sketch left in ``out`` again, with Wire's twi.c compiled."""
    board = build.BOARDS[board_name]
    twi = WIRE_DIR / "src" / "utility" / "twi.c"
    gcc = build._tool("avr-gcc")
    objects = sorted(out.glob("*.o"))
    twi_object = out / "Wire-twi.c.o"
    command = [gcc, *build._C_FLAGS, *build._flags(board), str(twi), "-o", str(twi_object)]
    _run(command, "compiling Wire's twi.c")
    elf = out / f"{name}.elf"
    core = build._core_archive(board)
    _run(
        [
            gcc,
            "-Os",
            "-flto",
            "-fuse-linker-plugin",
            "-Wl,--gc-sections",
            f"-mmcu={board.mcu}",
            "-o",
            str(elf),
            *map(str, objects),
            str(twi_object),
            str(core),
            "-lm",
        ],
        f"linking {name} with Wire",
    )
    return elf


def _run(command: list[str], what: str) -> None:
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise HwBridgeError(f"{what} failed:\n{done.stderr.strip() or done.stdout.strip()}")


def build_example(name: str, board: str = "uno", *, defines: list[str] | None = None) -> Path:
    """An example sketch of the HwBridge library (``HelloWorld``, ``DiffDriveBase``...) built
    for ``board``; its ELF."""
    sketch = EXAMPLES_DIR / name
    if not sketch.is_dir():
        known = ", ".join(sorted(p.name for p in EXAMPLES_DIR.iterdir() if p.is_dir()))
        raise HwBridgeError(f"no example sketch {name!r} (examples: {known})")
    return build_sketch_for_sim(sketch, board, defines=defines)
