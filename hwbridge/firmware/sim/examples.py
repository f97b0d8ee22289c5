"""The HwBridge library's example sketches built for simavr, kept in a cache.

:func:`build_example` builds ``firmware/HwBridge/examples/NAME`` with
:func:`hwbridge.firmware.build.build_sketch` for an Uno, a Nano or a Mega (which adds the core's own
libraries, such as ``Wire``, that a sketch includes), or for an ARM board run in QEMU. Builds
are cached under ``~/.cache/hwbridge/sim-examples/`` by a hash of the sketch, the library and
the board.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path
from typing import Final

from hwbridge.errors import HwBridgeError
from hwbridge.firmware import build

__all__ = ["EXAMPLES_DIR", "build_example", "build_sketch_for_sim", "cache_root"]

EXAMPLES_DIR: Final = build.LIBRARY_DIR / "examples"
MCU_OF_BOARD: Final = {"uno": "atmega328p", "nano": "atmega328p", "mega": "atmega2560"}


def cache_root() -> Path:
    """Where builds for the simulator are kept (``~/.cache/hwbridge/sim-examples``)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hwbridge" / "sim-examples"


def _digest(sketch: Path, board: str, defines: list[str]) -> str:
    digest = hashlib.sha256(f"{board}\0{' '.join(defines)}\0".encode())
    for folder in (sketch, build.LIBRARY_DIR / "src", build.ARM_CORE_DIR):
        for path in sorted(folder.rglob("*")):
            if path.is_file() and "build" not in path.relative_to(folder).parts:
                digest.update(str(path.relative_to(folder)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


def build_sketch_for_sim(
    sketch: Path, board: str = "uno", *, defines: list[str] | None = None
) -> Path:
    """The ELF of ``sketch`` (a folder with NAME.ino) for ``board``, built once and cached."""
    if board not in MCU_OF_BOARD and board not in build.ARM_BOARDS:
        known = ", ".join([*MCU_OF_BOARD, *build.ARM_BOARDS])
        raise HwBridgeError(f"unknown board {board!r}: {known}")
    sketch = sketch.resolve()
    flags = list(defines or [])
    out = cache_root() / f"{sketch.name}-{board}-{_digest(sketch, board, flags)}"
    elf = out / f"{sketch.name}.elf"
    if elf.exists():
        return elf
    partial = out.with_name(out.name + f".{os.getpid()}.tmp")
    built = build.build_sketch(sketch, board, partial, defines=flags)
    if out.exists():  # another process built it meanwhile
        shutil.rmtree(partial, ignore_errors=True)
    else:
        partial.rename(out)
    return out / built.name


def build_example(name: str, board: str = "uno", *, defines: list[str] | None = None) -> Path:
    """An example sketch of the HwBridge library (``HelloWorld``, ``DiffDriveBase``...) built
    for ``board``; its ELF."""
    sketch = EXAMPLES_DIR / name
    if not sketch.is_dir():
        known = ", ".join(sorted(p.name for p in EXAMPLES_DIR.iterdir() if p.is_dir()))
        raise HwBridgeError(f"no example sketch {name!r} (examples: {known})")
    return build_sketch_for_sim(sketch, board, defines=defines)
