"""Refusing firmware built for another MCU before a simulator runs it or avrdude writes it:
the one check ``hwbridge firmware sim`` and ``hwbridge firmware upload`` share, each with its
own words (:class:`FirmwareTarget`: the option that picks another MCU, the error to raise).

An ELF says what it was built for (:func:`~hwbridge.firmware.build.elf_mcu`); an Intel HEX does
not, but its highest address must lie in the flash it is for: a Mega's HEX on an Uno reaches
past the Uno's 32 KiB (simavr crashed on it, and avrdude would refuse it only after resetting
the board).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from hwbridge.errors import HwBridgeError
from hwbridge.firmware.build import ELF_MCUS, elf_mcu
from hwbridge.firmware.sim.bootloader import HexError, read_hex

__all__ = ["FirmwareTarget", "check_elf", "check_hex"]


@dataclass(frozen=True)
class FirmwareTarget:
    """What firmware is checked against, and how a command words its refusal."""

    mcu: str
    """The MCU, as :func:`~hwbridge.firmware.build.elf_mcu` names it (``atmega328p``)."""
    name: str
    """The target in a message: ``the atmega328p``, ``the uno's atmega328p``."""
    verb: str
    """What the command would do with the file: ``refusing to VERB PATH: ...``."""
    option: str
    """The command's option that picks another target (``--mcu``, ``--board``)."""
    value: str
    """That option's value for this target."""
    choices: Mapping[str, str]
    """The option's value that targets each MCU (by :func:`elf_mcu`'s names)."""
    space: Mapping[str, int] | None = None
    """Bytes of flash an Intel HEX may fill, from address 0, for each value of the option (this
    target's too); None: no HEX is checked."""
    space_name: str = "of flash"
    """What this target's space is, after ``the N bytes``: ``of the atmega328p's flash``."""
    error: type[HwBridgeError] = HwBridgeError

    def refuse(self, path: Path, why: str) -> HwBridgeError:
        return self.error(f"refusing to {self.verb} {path}: {why}")


def check_elf(path: Path, target: FirmwareTarget) -> None:
    """Refuse an ELF built for another MCU than ``target``'s, naming the option value that
    targets the MCU it was built for (if the command has one); anything that is no ELF passes
    (a HEX: see :func:`check_hex`)."""
    built_for = elf_mcu(path)
    if built_for is None or built_for == target.mcu:
        return
    what = f"the {built_for}" if built_for in ELF_MCUS else built_for
    value = target.choices.get(built_for)
    hint = f": give {target.option} {value}" if value is not None else ""
    raise target.refuse(path, f"built for {what}, not {target.name}{hint}")


def check_hex(path: Path, target: FirmwareTarget) -> None:
    """Refuse an Intel HEX that is malformed (a bad record or checksum), or whose highest address
    lies past the flash ``target`` gives it: the message names the file, that address and the
    bytes up to it, the target's flash, and the option value that has room (if one has)."""
    try:
        memory = read_hex(path)
    except HexError as exc:
        raise target.error(f"refusing to {target.verb}: {exc}") from exc
    if target.space is None:
        return
    top = max(memory)
    room = target.space[target.value]
    if top < room:
        return
    roomier = [value for value, size in target.space.items() if size > top]
    hint = (
        f": give {target.option} {roomier[0]}"
        if roomier
        else f"; no {target.option} has that much flash"
    )
    raise target.refuse(
        path,
        f"it reaches address {top:#06x} ({top + 1} bytes), past the {room} bytes "
        f"{target.space_name}{hint}",
    )
