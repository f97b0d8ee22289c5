"""Build Arduino sketches for AVR boards the way the Arduino IDE does, and measure them.

``hwbridge firmware build SKETCH --board uno|mega|host`` compiles a sketch (a folder with
``NAME.ino``, or the ``.ino`` itself) with the HwBridge library (``firmware/HwBridge``) and the
Debian Arduino AVR core (``arduino-core-avr``), with the compiler flags of the core's
``platform.txt`` (``-Os``, LTO, sections garbage-collected): the sketch and the library are built
with ``-Wall -Wextra -Werror``; the Arduino core with the warnings it always has. The core is
compiled once per board and kept in a cache. ``hwbridge firmware size ELF`` reports flash and
SRAM as ``avr-size`` counts them, and the static RAM of the HwBridge library's own objects.

``--board stm32f405`` (a Cortex-M4F, as QEMU's ``netduinoplus2`` models it) and ``--board
microbit`` (the nRF51822's Cortex-M0, QEMU's ``microbit``) build it bare-metal with Debian's
``gcc-arm-none-eabi`` and newlib-nano: the start-up code, linker scripts and a minimal Arduino
stand-in of ``hwbridge/firmware/arm/core/`` (``setup()``/``loop()``, ``millis()``/``micros()``,
pins in memory, ``Serial`` on the board's UART) and the node on the board's UART class
(``hwbridge/hardware_stm32f4.h``, ``hwbridge/hardware_nrf51.h``), with ``-Wall -Wextra -Werror
-Wcast-align=strict -Wconversion`` on the sketch and the library. ``hwbridge firmware sim`` runs
the ELF in ``qemu-system-arm`` (``hwbridge.firmware.qemu``).

``--board host`` builds the sketch as a native program instead (``g++``, ``-Wall -Wextra
-Werror``): a small Arduino stand-in (``firmware/HwBridge/src/hwbridge/host/``: ``setup()`` and
``loop()``, the clock, pins in memory, serial ports and I2C that go nowhere) and the node on a
POSIX ``Hardware``. The program opens the link given as its first argument or in
``$HWBRIDGE_LINK`` (a pty or serial path, ``socket://HOST:PORT``, ``listen://PORT``), or else a new
pseudo-terminal, and prints the URL to connect to as its first line.

The Arduino core's own libraries (``Wire``, ``SoftwareSerial``, ``SPI``, ``EEPROM``) are added
when the sketch includes their header, as the IDE adds them.

A sketch is compiled as the IDE compiles one: ``#include <Arduino.h>`` is put before it; unlike
the IDE, no function prototypes are generated, so a sketch declares a function before it uses it.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from hwbridge.errors import HwBridgeError

__all__ = [
    "ARM_BOARDS",
    "BOARDS",
    "CORE_DIR",
    "ELF_MCUS",
    "LIBRARY_DIR",
    "MCU_FLASH",
    "ArmBoard",
    "Board",
    "FirmwareSize",
    "ToolchainMissingError",
    "arm_firmware_size",
    "build_arm_program",
    "build_arm_sketch",
    "build_host_sketch",
    "build_sketch",
    "elf_mcu",
    "firmware_size",
]

log = logging.getLogger("hwbridge.firmware")

CORE_DIR: Final = Path(
    os.environ.get("HWBRIDGE_ARDUINO_AVR", "/usr/share/arduino/hardware/arduino/avr")
)
"""Debian's Arduino AVR core (package arduino-core-avr)."""
LIBRARY_DIR: Final = Path(__file__).resolve().parents[2] / "firmware" / "HwBridge"
"""The HwBridge Arduino library in this checkout."""
ARDUINO_VERSION: Final = "10819"
_WARNINGS: Final = ("-Wall", "-Wextra", "-Werror")
_DEBIAN_PACKAGES: Final = "gcc-avr avr-libc binutils-avr arduino-core-avr"


class ToolchainMissingError(HwBridgeError):
    """The AVR compiler or the Arduino core is not installed."""


MCU_FLASH: Final = {"atmega328p": 0x8000, "atmega2560": 0x40000}
"""Bytes of flash of each AVR of :data:`BOARDS` (32 KiB, 256 KiB): the one place of these sizes
(the simulator's bootloaders, :mod:`hwbridge.firmware.sim.bootloader`, take them from here)."""


@dataclass(frozen=True)
class Board:
    """An AVR board as ``boards.txt`` describes it."""

    name: str
    mcu: str
    f_cpu: str
    board_define: str
    variant: str
    boot_section: int
    """Bytes at the top of flash that are the bootloader's: the boot section the board's high
    fuse gives it (BOOTSZ of ``bootloader.high_fuses``)."""
    sram: int

    @property
    def flash(self) -> int:
        """Bytes of flash a sketch may use: the MCU's flash below the bootloader's section
        (``upload.maximum_size``), which is also the byte address the bootloader starts at."""
        return MCU_FLASH[self.mcu] - self.boot_section


BOARDS: Final = {
    "uno": Board("uno", "atmega328p", "16000000L", "AVR_UNO", "standard", 512, 2048),
    "nano": Board("nano", "atmega328p", "16000000L", "AVR_NANO", "eightanaloginputs", 2048, 2048),
    "mega": Board("mega", "atmega2560", "16000000L", "AVR_MEGA2560", "mega", 8192, 8192),
}


@dataclass(frozen=True)
class FirmwareSize:
    """What an ELF takes, as ``avr-size`` counts it."""

    flash: int
    """.text + .data (the data's initial values live in flash)."""
    sram: int
    """.data + .bss (static RAM; the stack and heap come on top)."""
    library_sram: int
    """Static RAM of objects from the HwBridge library (symbols in namespace hwbridge)."""
    core_sram: int = 0
    """Static RAM of the Arduino core's objects (``Serial``, the timer counters, ...)."""
    objects: tuple[tuple[str, int, str], ...] = ()
    """Every object in static RAM, largest first: (name, bytes, owner), owner ``core`` (the
    Arduino core and the C runtime), ``hwbridge`` (the library's own statics) or ``sketch``
    (the sketch's globals: its node handle, publishers and messages are the library's types)."""

    def as_dict(self) -> dict[str, Any]:
        return {
            "flash": self.flash,
            "sram": self.sram,
            "library_sram": self.library_sram,
            "core_sram": self.core_sram,
            "sketch_sram": self.sram - self.core_sram - self.library_sram,
            "objects": [list(item) for item in self.objects],
        }


def _tool(name: str) -> str:
    found = shutil.which(name)
    if found is None:
        raise ToolchainMissingError(
            f"{name} is not installed: install the Debian packages {_DEBIAN_PACKAGES} "
            "(sudo apt-get install ...)"
        )
    return found


def _run(command: list[str], what: str) -> None:
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise HwBridgeError(f"{what} failed:\n{done.stderr.strip() or done.stdout.strip()}")


def _flags(board: Board) -> list[str]:
    return [
        f"-mmcu={board.mcu}",
        f"-DF_CPU={board.f_cpu}",
        f"-DARDUINO={ARDUINO_VERSION}",
        f"-DARDUINO_{board.board_define}",
        "-DARDUINO_ARCH_AVR",
        "-DDECIMAL_DIG=__DECIMAL_DIG__",  # gcc-avr 5.4 lacks it; the core's WString needs it
        f"-I{CORE_DIR / 'cores' / 'arduino'}",
        f"-I{CORE_DIR / 'variants' / board.variant}",
    ]


_C_FLAGS: Final = ["-c", "-Os", "-std=gnu11", "-ffunction-sections", "-fdata-sections", "-flto"]
_CPP_FLAGS: Final = [
    "-c",
    "-Os",
    "-std=gnu++11",
    "-fno-exceptions",
    "-fno-rtti",
    "-ffunction-sections",
    "-fdata-sections",
    "-fno-threadsafe-statics",
    "-flto",
]
_S_FLAGS: Final = ["-c", "-x", "assembler-with-cpp", "-flto"]


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hwbridge" / "arduino-core"


Progress = Callable[[str], None]
"""Told one line per step of a build (``[3/9] compiling Wire.cpp``)."""


def _no_progress(_line: str) -> None:
    pass


def _core_archive(board: Board, progress: Progress = _no_progress) -> Path:
    """The Arduino core compiled for ``board``, built on first use and cached."""
    gcc, gpp, ar = _tool("avr-gcc"), _tool("avr-g++"), _tool("avr-gcc-ar")
    sources = sorted(
        p for p in (CORE_DIR / "cores" / "arduino").iterdir() if p.suffix in (".c", ".cpp", ".S")
    )
    if not sources:
        raise ToolchainMissingError(
            f"no Arduino AVR core at {CORE_DIR}: install the Debian package arduino-core-avr"
        )
    digest = hashlib.sha256(
        "\n".join([*_flags(board), *(f"{p}:{p.stat().st_mtime_ns}" for p in sources)]).encode()
    ).hexdigest()[:16]
    out = _cache_dir() / f"{board.name}-{digest}"
    archive = out / "core.a"
    if archive.exists():
        return archive
    out.mkdir(parents=True, exist_ok=True)
    log.info("compiling the Arduino core for %s (once; cached in %s)", board.name, out)
    # Objects and archive in a folder of this process: two first builds at once (two terminals,
    # parallel tests) each compile their own, and the first to finish puts its archive in place
    # (a hard link: atomic, and never over an archive that another build may be linking with;
    # the linker opens it more than once, and a replaced one no longer matches its index).
    work = Path(tempfile.mkdtemp(prefix="build.", dir=out))
    try:
        objects = []
        for number, source in enumerate(sources, 1):
            progress(
                f"[core {number}/{len(sources)}] compiling the Arduino core's {source.name} for "
                f"{board.name} (once; cached)"
            )
            obj = work / (source.name + ".o")
            if source.suffix == ".c":
                command = [gcc, *_C_FLAGS, *_flags(board)]
            elif source.suffix == ".cpp":
                command = [gpp, *_CPP_FLAGS, *_flags(board)]
            else:
                command = [gcc, *_S_FLAGS, *_flags(board)]
            _run([*command, str(source), "-o", str(obj)], f"compiling the core's {source.name}")
            objects.append(str(obj))
        partial = work / "core.a"
        _run([ar, "rcs", str(partial), *objects], "archiving the core")
        with contextlib.suppress(FileExistsError):  # another build's is there: use that one
            os.link(partial, archive)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return archive


def _sketch_source(sketch: Path) -> tuple[str, Path]:
    """(name, .ino file) of a sketch folder or file; a relative path (``.``, ``..``) is taken
    from the current folder, so a folder's name is its real one."""
    sketch = sketch.resolve()
    ino = sketch / f"{sketch.name}.ino" if sketch.is_dir() else sketch
    if ino.suffix != ".ino" or not ino.is_file():
        raise HwBridgeError(f"{sketch}: not a sketch (a NAME.ino file, or a folder NAME/NAME.ino)")
    return ino.stem, ino


_INCLUDE: Final = re.compile(r'^\s*#\s*include\s*[<"]([A-Za-z0-9_]+)\.h[>"]', re.M)


def _bundled_libraries(text: str) -> list[Path]:
    """The Arduino core's own libraries (Wire, SoftwareSerial, SPI, EEPROM...) whose main
    header the sketch includes, as the IDE adds them."""
    found: list[Path] = []
    for name in _INCLUDE.findall(text):
        folder = CORE_DIR / "libraries" / name
        if (folder / "src" / f"{name}.h").is_file() and folder not in found:
            found.append(folder)
    return found


@dataclass(frozen=True)
class ArmBoard:
    """A bare Cortex-M board built with arm-none-eabi-g++ and run in qemu-system-arm."""

    name: str
    cpu_flags: tuple[str, ...]
    board_define: str
    """The define that picks the node's hardware class (``hwbridge/node.h``)."""
    support: str
    """The board's C file and linker script in ``hwbridge/firmware/arm/core/`` (without suffix)."""
    linker_script: str
    qemu_machine: str
    flash: int
    sram: int
    description: str


ARM_BOARDS: Final = {
    "stm32f405": ArmBoard(
        "stm32f405",
        (
            "-mcpu=cortex-m4",
            "-mthumb",
            "-mfloat-abi=hard",
            "-mfpu=fpv4-sp-d16",
            # UNALIGN_TRP is on (start-up): no unaligned loads of our own making either
            "-mno-unaligned-access",
        ),
        "HWBRIDGE_BOARD_STM32F4",
        "stm32f405",
        "stm32f405",
        "netduinoplus2",
        1024 * 1024,
        128 * 1024,
        "STM32F405 (Cortex-M4F, 168 MHz), USART1; QEMU netduinoplus2",
    ),
    "microbit": ArmBoard(
        "microbit",
        ("-mcpu=cortex-m0", "-mthumb", "-mfloat-abi=soft"),
        "HWBRIDGE_BOARD_NRF51",
        "nrf51",
        "nrf51822",
        "microbit",
        256 * 1024,
        16 * 1024,
        "BBC micro:bit v1, nRF51822 (Cortex-M0, 16 MHz), UART0; QEMU microbit",
    ),
}
ARM_CORE_DIR: Final = Path(__file__).resolve().parent / "arm" / "core"
"""Start-up code, linker scripts and the Arduino stand-in of the ARM boards."""
ARM_WARNINGS: Final = (*_WARNINGS, "-Wcast-align=strict", "-Wconversion")
_ARM_PACKAGES: Final = "gcc-arm-none-eabi libnewlib-arm-none-eabi"


def _arm_tool(name: str) -> str:
    found = shutil.which(name)
    if found is None:
        raise ToolchainMissingError(
            f"{name} is not installed: install the Debian packages {_ARM_PACKAGES} "
            "(sudo apt-get install ...)"
        )
    return found


def arm_flags(board: ArmBoard) -> list[str]:
    """Compiler flags of every C and C++ file built for ``board``."""
    return [
        *board.cpu_flags,
        "-Os",
        "-g",
        "-ffunction-sections",
        "-fdata-sections",
        f"-D{board.board_define}",
        "-DHWBRIDGE_ARM_CORE",
    ]


def arm_link_flags(board: ArmBoard, *, semihosting: bool = False) -> list[str]:
    """Linker flags for ``board``: our start-up and linker script, newlib-nano, and system
    calls that fail (``nosys``) or, for test programs, go to QEMU's semihosting (``rdimon``)."""
    return [
        *board.cpu_flags,
        "-nostartfiles",
        "--specs=nano.specs",
        "--specs=rdimon.specs" if semihosting else "--specs=nosys.specs",
        f"-T{ARM_CORE_DIR / (board.linker_script + '.ld')}",
        "-Wl,--gc-sections",
    ]


def arm_core_sources(board: ArmBoard) -> list[Path]:
    """The start-up and board support C files of ``board``."""
    return [ARM_CORE_DIR / "startup.c", ARM_CORE_DIR / f"{board.support}.c"]


def build_arm_sketch(
    sketch: Path,
    board_name: str,
    out_dir: Path | None = None,
    *,
    libraries: list[Path] | None = None,
    defines: list[str] | None = None,
    progress: Progress = _no_progress,
) -> Path:
    """Compile and link ``sketch`` for an ARM board of ``ARM_BOARDS``; returns the ELF (a raw
    ``.bin`` is written next to it)."""
    board = ARM_BOARDS[board_name]
    gcc, gpp = _arm_tool("arm-none-eabi-gcc"), _arm_tool("arm-none-eabi-g++")
    objcopy = _arm_tool("arm-none-eabi-objcopy")
    name, ino = _sketch_source(sketch)
    out = out_dir or (ino.parent / "build" / board.name)
    out.mkdir(parents=True, exist_ok=True)
    libs = libraries if libraries is not None else [LIBRARY_DIR]
    includes = [f"-I{ARM_CORE_DIR}", *(f"-I{lib / 'src'}" for lib in libs), f"-I{ino.parent}"]
    extra = [f"-D{d}" for d in defines or []]
    cpp = out / f"{name}.ino.cpp"
    cpp.write_text(f'#include <Arduino.h>\n#line 1 "{ino}"\n' + ino.read_text(encoding="utf-8"))
    cpp_sources = [
        cpp,
        ARM_CORE_DIR / "arduino_arm.cpp",
        *(src for lib in libs for src in sorted((lib / "src").rglob("*.cpp"))),
    ]
    c_sources = arm_core_sources(board)
    total = len(cpp_sources) + len(c_sources) + 1
    objects: list[Path] = []
    compile_cpp = [
        gpp,
        "-c",
        "-std=gnu++11",
        "-fno-exceptions",
        "-fno-rtti",
        "-fno-threadsafe-statics",
        *ARM_WARNINGS,
        *arm_flags(board),
        *includes,
        *extra,
    ]
    compile_c = [gcc, "-c", "-std=gnu11", *ARM_WARNINGS, *arm_flags(board), *extra]
    for number, source in enumerate([*cpp_sources, *c_sources], 1):
        progress(f"[{number}/{total}] compiling {source.name} for {board.name}")
        obj = out / f"{source.name}.o"
        command = compile_cpp if source.suffix == ".cpp" else compile_c
        _run([*command, str(source), "-o", str(obj)], f"compiling {source}")
        objects.append(obj)
    elf = out / f"{name}.elf"
    progress(f"[{total}/{total}] linking {elf.name}")
    _run(
        [gpp, *arm_link_flags(board), "-o", str(elf), *map(str, objects), "-lm"],
        f"linking {name}",
    )
    _run([objcopy, "-O", "binary", str(elf), str(elf.with_suffix(".bin"))], "bin")
    return elf


def build_arm_program(
    sources: list[Path],
    board_name: str,
    out: Path,
    *,
    includes: list[Path] | None = None,
    defines: list[str] | None = None,
    semihosting: bool = True,
    cxx_flags: list[str] | None = None,
    compile_only: bool = False,
) -> Path:
    """A plain C/C++ program (its own ``main``, no sketch) for an ARM board: the start-up code
    and board support added, stdio through QEMU's semihosting unless ``semihosting`` is false.
    Test programs use it (tests/arm); returns ``out``. A source may be an object file; with
    ``compile_only`` nothing is linked and the first source's object is returned."""
    board = ARM_BOARDS[board_name]
    gcc, gpp = _arm_tool("arm-none-eabi-gcc"), _arm_tool("arm-none-eabi-g++")
    out.parent.mkdir(parents=True, exist_ok=True)
    flags = [
        *arm_flags(board),
        *(["-DHWBRIDGE_SEMIHOSTED"] if semihosting else []),
        *(f"-D{d}" for d in defines or []),
        *(f"-I{folder}" for folder in includes or []),
    ]
    objects: list[str] = []
    for source in [*sources, *arm_core_sources(board)]:
        obj = out.parent / f"{out.stem}-{source.name}.o"
        if source.suffix == ".o":  # compiled already (by compile_only)
            objects.append(str(source))
            continue
        if source.suffix == ".c":
            command = [gcc, "-c", "-std=gnu11", *ARM_WARNINGS, *flags]
        else:
            command = [gpp, "-c", "-std=gnu++11", "-fno-exceptions", "-fno-rtti", *flags]
            command += cxx_flags or []
        _run([*command, str(source), "-o", str(obj)], f"compiling {source} for {board.name}")
        objects.append(str(obj))
    if compile_only:
        return out.parent / f"{out.stem}-{sources[0].name}.o"
    link = [gpp, *arm_link_flags(board, semihosting=semihosting), "-o", str(out), *objects, "-lm"]
    _run(link, f"linking {out.name}")
    return out


def build_sketch(
    sketch: Path,
    board_name: str = "uno",
    out_dir: Path | None = None,
    *,
    libraries: list[Path] | None = None,
    defines: list[str] | None = None,
    progress: Progress = _no_progress,
) -> Path:
    """Compile and link ``sketch`` for ``board_name``; returns the ELF (an Intel HEX is written
    next to it). ``libraries`` are folders of Arduino libraries (their ``src/`` is on the include
    path, and their ``.cpp`` files are compiled); default: the HwBridge library. ``progress``
    is told each step as it starts."""
    sketch = sketch.resolve()  # 'hwbridge firmware build .' in the sketch's folder
    if board_name == HOST_BOARD:
        progress(f"[1/1] compiling {sketch.name} as a native program (g++)")
        return build_host_sketch(sketch, out_dir, libraries=libraries, defines=defines)
    if board_name in ARM_BOARDS:
        return build_arm_sketch(
            sketch, board_name, out_dir, libraries=libraries, defines=defines, progress=progress
        )
    board = BOARDS.get(board_name)
    if board is None:
        raise HwBridgeError(
            f"unknown board {board_name!r}; use one of "
            f"{', '.join([*BOARDS, *ARM_BOARDS, HOST_BOARD])}"
        )
    name, ino = _sketch_source(sketch)
    gpp, gcc, objcopy = _tool("avr-g++"), _tool("avr-gcc"), _tool("avr-objcopy")
    core = _core_archive(board, progress)
    out = out_dir or (ino.parent / "build" / board.name)
    out.mkdir(parents=True, exist_ok=True)
    libs = libraries if libraries is not None else [LIBRARY_DIR]
    bundled = _bundled_libraries(ino.read_text(encoding="utf-8"))
    includes = [f"-I{lib / 'src'}" for lib in [*libs, *bundled]] + [f"-I{ino.parent}"]
    extra = [f"-D{d}" for d in defines or []]
    cpp = out / f"{name}.ino.cpp"
    cpp.write_text(f'#include <Arduino.h>\n#line 1 "{ino}"\n' + ino.read_text(encoding="utf-8"))
    objects = [out / f"{name}.ino.cpp.o"]
    compile_cpp = [gpp, *_CPP_FLAGS, *_WARNINGS, *_flags(board), *includes, *extra]
    own = [(lib, src) for lib in libs for src in sorted((lib / "src").rglob("*.cpp"))]
    theirs = [
        (lib, src)
        for lib in bundled
        for src in sorted((lib / "src").rglob("*.c*"))
        if src.suffix in (".c", ".cpp")
    ]
    total = len(own) + len(theirs) + 2
    progress(f"[1/{total}] compiling {ino.name} for {board.name}")
    _run([*compile_cpp, str(cpp), "-o", str(objects[0])], f"compiling {ino}")
    for number, (lib, source) in enumerate(own, 2):
        progress(f"[{number}/{total}] compiling {lib.name}/{source.name}")
        obj = out / f"{lib.name}-{source.name}.o"
        _run([*compile_cpp, str(source), "-o", str(obj)], f"compiling {source}")
        objects.append(obj)
    # the core's libraries: compiled with the core's flags (their own warnings are not ours)
    for number, (lib, source) in enumerate(theirs, 2 + len(own)):
        progress(f"[{number}/{total}] compiling {lib.name}/{source.name} (the core's library)")
        obj = out / f"{lib.name}-{source.name}.o"
        flags = _C_FLAGS if source.suffix == ".c" else _CPP_FLAGS
        tool = gcc if source.suffix == ".c" else gpp
        command = [tool, *flags, *_flags(board), *includes, *extra, str(source), "-o", str(obj)]
        _run(command, f"compiling {source}")
        objects.append(obj)
    elf = out / f"{name}.elf"
    progress(f"[{total}/{total}] linking {elf.name} (LTO)")
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
            str(core),
            "-lm",
        ],
        f"linking {name}",
    )
    _run([objcopy, "-O", "ihex", "-R", ".eeprom", str(elf), str(elf.with_suffix(".hex"))], "hex")
    return elf


HOST_BOARD: Final = "host"
"""The board name of native builds (``build_host_sketch``)."""
_HOST_SHIM: Final = LIBRARY_DIR / "src" / "hwbridge" / "host"


def build_host_sketch(
    sketch: Path,
    out_dir: Path | None = None,
    *,
    libraries: list[Path] | None = None,
    defines: list[str] | None = None,
    sanitize: bool = False,
) -> Path:
    """Compile ``sketch`` as a native program (see the module docstring); returns it.
    ``sanitize`` adds ASan and UBSan."""
    gpp = shutil.which("g++")
    if gpp is None:
        raise ToolchainMissingError("g++ is not installed: install the Debian package g++")
    name, ino = _sketch_source(sketch)
    out = out_dir or (ino.parent / "build" / HOST_BOARD)
    out.mkdir(parents=True, exist_ok=True)
    libs = libraries if libraries is not None else [LIBRARY_DIR]
    cpp = out / f"{name}.ino.cpp"
    cpp.write_text(f'#include <Arduino.h>\n#line 1 "{ino}"\n' + ino.read_text(encoding="utf-8"))
    shim = out / "arduino_host.cpp"
    shim.write_text("#include <hwbridge/host/arduino_host_impl.h>\n")
    sources = [cpp, shim] + [s for lib in libs for s in sorted((lib / "src").rglob("*.cpp"))]
    exe = out / name
    command = [
        gpp,
        "-std=gnu++11",
        "-O1",
        "-g",
        *_WARNINGS,
        "-DHWBRIDGE_HOST_BUILD",
        *(["-fsanitize=address,undefined", "-fno-sanitize-recover=all"] if sanitize else []),
        f"-I{_HOST_SHIM}",
        *(f"-I{lib / 'src'}" for lib in libs),
        f"-I{ino.parent}",
        *(f"-D{d}" for d in defines or []),
        *map(str, sources),
        "-o",
        str(exe),
    ]
    _run(command, f"compiling {ino} for the host")
    return exe


_SECTION: Final = re.compile(r"^\.(text|data|bss|noinit)\s+(\d+)", re.M)


def _measure(elf: Path, size: str, nm: str, owner_of: Callable[[str, str], str]) -> FirmwareSize:
    """Flash (.text + .data) and static RAM (.data + .bss + .noinit, the RAM a reset leaves as
    it was) of ``elf`` by ``size -A``, and its
    data symbols by ``nm``, each given an owner ("hwbridge", "core" or "sketch") by
    ``owner_of(name, nm_type)``."""
    if not elf.is_file():
        raise HwBridgeError(f"{elf}: no such ELF file")
    done = subprocess.run([size, "-A", str(elf)], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise HwBridgeError(f"{elf}: {Path(size).name} failed: {done.stderr.strip()}")
    sections = {name: int(value) for name, value in _SECTION.findall(done.stdout)}
    text, data, bss, noinit = (sections.get(k, 0) for k in ("text", "data", "bss", "noinit"))
    listed = subprocess.run(
        [nm, "-C", "--size-sort", "-S", str(elf)], capture_output=True, text=True, check=False
    ).stdout
    objects: list[tuple[str, int, str]] = []
    for line in listed.splitlines():
        parts = line.split(None, 3)
        if len(parts) == 4 and parts[2] in "bBdD":
            name = parts[3]
            owner = "hwbridge" if "hwbridge::" in name else owner_of(name, parts[2])
            objects.append((name, int(parts[1], 16), owner))
    objects.sort(key=lambda item: (-item[1], item[0]))
    return FirmwareSize(
        flash=text + data,
        sram=data + bss + noinit,
        library_sram=sum(n for _, n, owner in objects if owner == "hwbridge"),
        core_sram=sum(n for _, n, owner in objects if owner == "core"),
        objects=tuple(objects),
    )


def firmware_size(elf: Path) -> FirmwareSize:
    """Flash and static RAM of an ELF (``avr-size -A``), and the library's share of the RAM."""
    size, nm = _tool("avr-size"), _tool("avr-nm")
    if not elf.is_file():
        raise HwBridgeError(f"{elf}: no such ELF file")
    core_names = _core_symbols(shutil.which("avr-gcc-nm") or nm)
    core_statics = _core_statics()

    def owner_of(name: str, kind: str) -> str:
        if (
            name in core_names
            or name.startswith("__")
            or "HardwareSerial" in name
            or (kind in "bd" and name in core_statics)
        ):
            return "core"
        return "sketch"

    return _measure(elf, size, nm, owner_of)


def arm_firmware_size(elf: Path) -> FirmwareSize:
    """Flash and static RAM of an ELF built for an ARM board (``arm-none-eabi-size -A``): flash =
    .text + .data (the vector table, code, constants, initial values), RAM = .data + .bss +
    .noinit (the stack comes on top); the library's share from the symbols in namespace
    hwbridge."""

    def owner_of(name: str, kind: str) -> str:
        del kind
        if name.startswith(("_", "(anonymous namespace)::")) or name in ("Serial", "errno"):
            return "core"  # the C library, start-up and the Arduino stand-in
        return "sketch"

    return _measure(elf, _arm_tool("arm-none-eabi-size"), _arm_tool("arm-none-eabi-nm"), owner_of)


ELF_MCUS: Final = ("atmega328p", "atmega2560", "stm32f405", "nrf51822")
"""The MCUs :func:`elf_mcu` names (anything else it describes in words)."""
_AVR_ARCHITECTURES: Final = {5: "atmega328p", 6: "atmega2560"}
"""avr-gcc's architecture (``e_flags``: avr5, avr6) of the MCUs of :data:`BOARDS`."""
_STM32_FLASH: Final = 0x0800_0000
"""Where the STM32F405's flash begins (``stm32f405.ld``; the nRF51822's is at 0)."""
_STM32_FLASH_SIZE: Final = 0x10_0000
_NRF51_FLASH_SIZE: Final = 0x4_0000
"""The two boards' flash sizes (1 MB, 256 KB): an entry point outside both is another ARM."""


def elf_mcu(path: Path) -> str | None:
    """The MCU an ELF was built for, read from its header: ``atmega328p`` or ``atmega2560`` (the
    AVR architecture avr-gcc records: avr5, avr6), ``stm32f405`` or ``nrf51822`` (an ARM ELF, by
    the flash its entry point lies in: from 0x08000000 or from 0), or what else it is (``an AVR of
    architecture avrN``, ``another ARM chip``, ``ELF machine N``, a 64-bit computer); None when the
    file is no ELF (an Intel HEX, a folder)."""
    try:
        with path.open("rb") as file:
            header = file.read(52)
    except OSError:
        return None
    if len(header) < 52 or header[:4] != b"\x7fELF":
        return None
    if header[4] != 1:  # not ELFCLASS32
        return "a 64-bit computer (a host build?)"
    machine = int.from_bytes(header[18:20], "little")
    entry = int.from_bytes(header[24:28], "little")
    flags = int.from_bytes(header[36:40], "little")
    if machine == 83:  # EM_AVR
        return _AVR_ARCHITECTURES.get(flags & 0x7F, f"an AVR of architecture avr{flags & 0x7F}")
    if machine == 40:  # EM_ARM
        if _STM32_FLASH <= entry < _STM32_FLASH + _STM32_FLASH_SIZE:
            return "stm32f405"
        if entry < _NRF51_FLASH_SIZE:
            return "nrf51822"
        return "another ARM chip"
    return f"ELF machine {machine}"


def _core_statics() -> frozenset[str]:
    """Names the Arduino core declares ``static`` at file scope (``timer0_fract``): an LTO
    archive does not list them, so they are read from the core's sources."""
    names: set[str] = set()
    declared = re.compile(
        r"^static\s+(?:volatile\s+)?[\w\s\*]*?\b(\w+)\s*(?:\[[^\]]*\])?\s*(?:=|;)", re.M
    )
    for source in sorted((CORE_DIR / "cores" / "arduino").glob("*.c*")):
        names.update(declared.findall(source.read_text(errors="replace")))
    return frozenset(names)


def _core_symbols(nm: str) -> frozenset[str]:
    """Names the Arduino core defines, from the core archives this machine has built (LTO
    objects: ``nm`` is gcc's wrapper with the LTO plugin)."""
    names: set[str] = set()
    for archive in sorted(_cache_dir().glob("*/core.a")):
        listed = subprocess.run(
            [nm, "-C", "--defined-only", str(archive)], capture_output=True, text=True, check=False
        ).stdout
        for line in listed.splitlines():
            parts = line.split(None, 2)
            if len(parts) == 3:
                names.add(parts[2])
    return frozenset(names)
