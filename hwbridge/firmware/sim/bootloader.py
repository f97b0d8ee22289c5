"""The boards' bootloaders for the simulator, from Debian's ``arduino-core-avr``: the Uno's
Optiboot, and the Mega 2560's stk500v2 bootloader (:func:`stk500v2_hex`, used as Debian ships it:
it lies in the Mega's 8 KiB boot section).

:func:`optiboot_hex` gives the Intel HEX the runner loads at the top of the ATmega328P's flash
(``hwbridge firmware sim --bootloader``). Debian's ``optiboot_atmega328.hex`` is used as it is
when it fits the 512 bytes the Uno's fuses give the bootloader (0x7E00..0x7FFF). The one Debian
ships today does not: rebuilt with a newer avr-gcc, which lacks the ``-mshort-calls`` its
Makefile asks for, it is 532 bytes, so its last instructions would lie past the end of flash (a
real Uno could not hold it either). Then the same source (``optiboot.c`` next to the HEX, with
its Makefile's ``atmega328`` settings: 16 MHz, 115200 baud, three LED flashes) is built with
size options that fit, once, and cached under ``~/.cache/hwbridge/optiboot/``.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
from pathlib import Path
from typing import Final

from hwbridge.errors import HwBridgeError
from hwbridge.firmware.build import BOARDS, MCU_FLASH

__all__ = [
    "HEX_SUFFIXES",
    "MEGA_BOOT_START",
    "OPTIBOOT_DIR",
    "STK500V2_HEX",
    "HexError",
    "bootloader_hex",
    "flash_layout",
    "is_intel_hex",
    "optiboot_hex",
    "read_hex",
]

OPTIBOOT_DIR: Final = Path("/usr/share/arduino/hardware/arduino/avr/bootloaders/optiboot")
STK500V2_HEX: Final = OPTIBOOT_DIR.parent / "stk500v2" / "stk500boot_v2_mega2560.hex"
"""The Mega 2560's bootloader (stk500v2, as boards.txt names it), Debian's build."""
_BOOT_BOARDS: Final = {"atmega328p": BOARDS["uno"], "atmega2560": BOARDS["mega"]}
"""The board whose bootloader the simulator runs on each AVR: the Uno's Optiboot, the Mega's
stk500v2 (:data:`~hwbridge.firmware.build.BOARDS` has their boot sections, ``MCU_FLASH`` the
flash sizes: these are not repeated here)."""
_FLASH: Final = {mcu: (board.flash, MCU_FLASH[mcu]) for mcu, board in _BOOT_BOARDS.items()}
"""Each AVR's flash: where the boot section its board's fuses give the bootloader starts, and
the flash's end (its size), in bytes."""
MEGA_BOOT_START: Final = _FLASH["atmega2560"][0]
"""Byte address of the Mega 2560's boot section (0x3E000): its fuses (high 0xD8) give it 4 K
words."""
MEGA_FLASH_END: Final = _FLASH["atmega2560"][1]  # ATmega2560: 256 KiB
BOOT_START: Final = _FLASH["atmega328p"][0]  # the Uno's Optiboot: 0x7E00
FLASH_END: Final = _FLASH["atmega328p"][1]  # ATmega328P: 32 KiB
_SETTINGS: Final = (
    "-mmcu=atmega328p",
    "-DF_CPU=16000000L",
    "-DLED_START_FLASHES=3",
    "-DBAUD_RATE=115200",
)
_SIZE_OPTIONS: Final = (
    "-Os",
    "-fno-inline-small-functions",
    "-fno-split-wide-types",
    "-mrelax",
    "-fno-caller-saves",
    "-fno-tree-loop-optimize",
    "-fno-move-loop-invariants",
    "-mstrict-X",
    "-fwhole-program",
)
_LINK: Final = (
    f"-Wl,--section-start=.text={BOOT_START:#x}",
    f"-Wl,--section-start=.version={FLASH_END - 2:#x}",
    "-Wl,--relax",
    "-Wl,--gc-sections",
    "-nostartfiles",
    "-nostdlib",
)


def flash_layout(mcu: str) -> tuple[int, int]:
    """The flash of ``mcu`` (``atmega328p``, ``atmega2560``): where its boot section starts
    (the bootloader's, as the board's fuses set it) and its size, in bytes."""
    layout = _FLASH.get(mcu)
    if layout is None:
        raise HwBridgeError(f"no flash layout for {mcu} ({' or '.join(_FLASH)})")
    return layout


HEX_SUFFIXES: Final = (".hex", ".ihex", ".ihx")
"""The names of Intel HEX files (any case), for every command that takes one: ``hwbridge
firmware sim`` (which tells the runner that it has a HEX) and ``upload``."""


def is_intel_hex(path: Path) -> bool:
    """Whether ``path`` is named as an Intel HEX file (:data:`HEX_SUFFIXES`)."""
    return path.suffix.lower() in HEX_SUFFIXES


class HexError(HwBridgeError):
    """An Intel HEX file that cannot be used."""


def read_hex(path: Path) -> dict[int, int]:
    """The bytes of an Intel HEX file by address; raises :class:`HexError` naming the line of
    a malformed record or a bad checksum."""
    memory: dict[int, int] = {}
    base = 0
    try:
        lines = path.read_text(encoding="ascii").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise HexError(f"cannot read {path}: {exc}") from exc
    ended = False
    for number, line in enumerate(lines, 1):
        text = line.strip()
        if not text:
            continue
        if ended:
            raise HexError(f"{path}, line {number}: a record after the end-of-file record")
        try:
            if not text.startswith(":") or len(text) % 2 == 0:
                raise ValueError
            record = bytes.fromhex(text[1:])
        except ValueError:
            raise HexError(f"{path}, line {number}: not an Intel HEX record") from None
        if len(record) < 5 or len(record) != record[0] + 5:
            raise HexError(f"{path}, line {number}: the record's length is wrong")
        if sum(record) & 0xFF:
            expected = (-sum(record[:-1])) & 0xFF
            raise HexError(
                f"{path}, line {number}: bad checksum {record[-1]:02X} (the record's bytes "
                f"give {expected:02X}): the file is corrupted"
            )
        count, address, kind, data = (
            record[0],
            (record[1] << 8) | record[2],
            record[3],
            record[4:-1],
        )
        if kind == 0:
            for i in range(count):
                memory[base + address + i] = data[i]
        elif kind == 1:
            ended = True
        elif kind == 2:
            base = int.from_bytes(data, "big") << 4
        elif kind == 4:
            base = int.from_bytes(data, "big") << 16
        # 3 and 5 (start addresses) mean nothing to an AVR's flash
    if not memory:
        raise HexError(f"{path}: no data records")
    return memory


def _fits(path: Path) -> bool:
    try:
        memory = read_hex(path)
    except HexError:
        return False
    return min(memory) >= BOOT_START and max(memory) < FLASH_END


def _cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hwbridge" / "optiboot"


def optiboot_hex(*, cache: Path | None = None) -> Path:
    """Optiboot for an Uno (ATmega328P, 16 MHz, 115200 baud) as an Intel HEX that fits the
    bootloader section: Debian's file, or one built from Debian's source (see the module)."""
    shipped = OPTIBOOT_DIR / "optiboot_atmega328.hex"
    if _fits(shipped):
        return shipped
    source = OPTIBOOT_DIR / "optiboot.c"
    if not source.is_file():
        raise HwBridgeError(
            f"no Optiboot for the simulated Uno: {shipped} and {source} are missing "
            "(apt-get install arduino-core-avr)"
        )
    key = hashlib.sha256(
        source.read_bytes() + " ".join((*_SETTINGS, *_SIZE_OPTIONS, *_LINK)).encode()
    ).hexdigest()[:16]
    folder = (cache or _cache_root()) / key
    built = folder / "optiboot_atmega328.hex"
    if built.exists():
        return built
    gcc, objcopy = shutil.which("avr-gcc"), shutil.which("avr-objcopy")
    if gcc is None or objcopy is None:
        raise HwBridgeError(
            f"{shipped} does not fit the Uno's bootloader section, and building Optiboot from "
            "its source needs avr-gcc (apt-get install gcc-avr avr-libc)"
        )
    folder.mkdir(parents=True, exist_ok=True)
    elf = folder / f"optiboot.{os.getpid()}.elf"
    partial = folder / f"optiboot.{os.getpid()}.hex"
    steps = (
        [gcc, *_SIZE_OPTIONS, *_SETTINGS, "-I", str(OPTIBOOT_DIR), *_LINK, "-o", str(elf),
         str(source)],
        [objcopy, "-O", "ihex", "-j", ".text", "-j", ".version", "--set-section-flags",
         ".version=alloc,load", str(elf), str(partial)],
    )  # fmt: skip
    for command in steps:
        done = subprocess.run(command, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise HwBridgeError(f"building Optiboot failed:\n{done.stderr.strip()}")
    elf.unlink(missing_ok=True)
    if not _fits(partial):
        raise HwBridgeError(
            f"Optiboot built from {source} does not fit {BOOT_START:#x}..{FLASH_END - 1:#x} either"
        )
    partial.replace(built)
    return built


def stk500v2_hex() -> Path:
    """The Mega 2560's stk500v2 bootloader from Debian's ``arduino-core-avr``, checked to lie in
    the boot section (0x3E000..0x3FFFF)."""
    if not STK500V2_HEX.is_file():
        raise HwBridgeError(
            f"no stk500v2 bootloader for the simulated Mega: {STK500V2_HEX} is missing "
            "(apt-get install arduino-core-avr)"
        )
    memory = read_hex(STK500V2_HEX)
    if min(memory) < MEGA_BOOT_START or max(memory) >= MEGA_FLASH_END:
        raise HwBridgeError(
            f"{STK500V2_HEX} does not lie in the Mega's boot section "
            f"({MEGA_BOOT_START:#x}..{MEGA_FLASH_END - 1:#x})"
        )
    return STK500V2_HEX


def bootloader_hex(mcu: str) -> Path:
    """The bootloader ``hwbridge firmware sim --bootloader`` runs on ``mcu``: Optiboot on the
    ATmega328P (Uno), stk500v2 on the ATmega2560 (Mega)."""
    if mcu == "atmega328p":
        return optiboot_hex()
    if mcu == "atmega2560":
        return stk500v2_hex()
    raise HwBridgeError(f"--bootloader: no bootloader for {mcu} (atmega328p or atmega2560)")
