"""``hwbridge firmware sim``: an AVR firmware in simavr, UART0 on a pty, the robot on its pins;
or an ARM firmware (``--mcu stm32f405`` or ``--mcu nrf51822``) in qemu-system-arm, its UART on a
pty."""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Annotated

import typer

from hwbridge.cli.common import no_such_path, robot_argument
from hwbridge.cli.shell import UsageError

__all__ = ["ARM_MCUS", "AVR_MCUS", "sim"]

ARM_MCUS = {"stm32f405": "stm32f405", "nrf51822": "microbit", "microbit": "microbit"}
"""--mcu values run in QEMU, and the build board of each."""
AVR_MCUS = ("atmega328p", "atmega2560")
"""--mcu values run in simavr."""


def _sim_arm(
    firmware: str | None,
    mcu: str,
    *,
    symlink: Path | None,
    robot: str | None,
    bootloader: bool,
) -> None:
    """An ARM firmware in QEMU until Ctrl-C (QEMU stopped on the way out)."""
    from hwbridge.errors import HwBridgeError
    from hwbridge.firmware.qemu import QemuBoard

    given = [
        name for name, on in (("--robot", robot is not None), ("--bootloader", bootloader)) if on
    ]
    if given:
        raise UsageError(
            f"{' and '.join(given)} {'is' if len(given) == 1 else 'are'} for the AVR boards in "
            f"simavr only, not --mcu {mcu}"
        )
    if firmware is None:
        raise UsageError("give the firmware to run (an ELF, a sketch, an example's name)")
    board = ARM_MCUS[mcu]
    path = _firmware(firmware, board)
    _check_firmware(path, mcu)
    with QemuBoard(path, board) as machine:
        url = machine.link_url
        if symlink is not None:
            with contextlib.suppress(FileNotFoundError):
                symlink.unlink()
            symlink.symlink_to(machine.pty or "")
            url = f"serial://{symlink}"
        sys.stdout.write(url + "\n")
        sys.stdout.flush()
        try:
            while machine.running:
                time.sleep(0.2)
        except KeyboardInterrupt:
            return
        finally:
            if symlink is not None:
                with contextlib.suppress(FileNotFoundError):
                    symlink.unlink()
        raise HwBridgeError(f"QEMU stopped (exit code {machine.exit_code})")


def sim(
    firmware: Annotated[
        str | None,
        typer.Argument(
            metavar="[ELF]",
            help="An AVR ELF or Intel HEX (.hex, .ihex, .ihx), a sketch folder, or the name of "
            "a HwBridge example (HelloWorld); with --bootloader also nothing (blank flash).",
        ),
    ] = None,
    mcu: Annotated[
        str,
        typer.Option(
            "--mcu",
            help="atmega328p (Uno) or atmega2560 (Mega) in simavr; stm32f405 (QEMU's "
            "netduinoplus2) or nrf51822 (QEMU's microbit) in qemu-system-arm.",
        ),
    ] = "atmega328p",
    robot: Annotated[
        str | None,
        typer.Option(
            "--robot",
            metavar="ROBOT.yaml",
            help="Put this robot file's world on the pins (a path, or diffbot).",
        ),
    ] = None,
    board: Annotated[
        str | None, typer.Option("--board", help="The robot file's board (default: the first).")
    ] = None,
    speed: Annotated[
        float, typer.Option("--speed", help="Simulated seconds per second (0: flat out).")
    ] = 1.0,
    frequency: Annotated[int, typer.Option("--frequency", help="Clock (Hz).")] = 16_000_000,
    seed: Annotated[int, typer.Option("--seed", help="The world's seed.")] = 0,
    bootloader: Annotated[
        bool,
        typer.Option(
            "--bootloader",
            help="Run the board's bootloader (an Uno's Optiboot; with --mcu atmega2560 the "
            "Mega's stk500v2): the AVR resets into it whenever the pty is opened, so "
            "'hwbridge firmware upload SKETCH --port PTY' (avrdude) uploads to it.",
        ),
    ] = False,
    symlink: Annotated[
        Path | None,
        typer.Option(
            "--symlink",
            metavar="PATH",
            help="Also make PATH point at the UART's pty (the URL printed is then PATH's).",
        ),
    ] = None,
) -> None:
    """Run an AVR firmware in simavr, or an ARM one in QEMU (--mcu stm32f405 or nrf51822),
    until Ctrl-C. The first line printed is the URL of its UART (serial:///dev/pts/N): give it
    to 'hwbridge connect' or a robot file's --link.

    With --bootloader the simulated Uno has Optiboot at 0x7E00 (the Mega, --mcu atmega2560, its
    stk500v2 bootloader at 0x3E000) and starts there; opening the pty resets it into the
    bootloader (as the boards' DTR auto-reset does), which takes an upload for a moment before
    it starts the application in flash. Uploaded flash lasts until the simulator stops."""
    from hwbridge.emulator.board import load_board
    from hwbridge.emulator.pins import PinWorld
    from hwbridge.errors import HwBridgeError
    from hwbridge.firmware.sim import SimAvr
    from hwbridge.firmware.sim.bootloader import bootloader_hex

    if mcu not in AVR_MCUS and mcu not in ARM_MCUS:
        raise typer.BadParameter(
            f"unknown MCU {mcu!r}; use one of {', '.join([*AVR_MCUS, *ARM_MCUS])}",
            param_hint="--mcu",
        )
    if mcu in ARM_MCUS:
        _sim_arm(firmware, mcu, symlink=symlink, robot=robot, bootloader=bootloader)
        return
    board_name = "mega" if mcu == "atmega2560" else "uno"
    if firmware is None and not bootloader:
        raise UsageError("give the firmware to run (an ELF, a sketch, an example's name)")
    if robot is not None:
        robot = robot_argument(robot, "--robot")
    path: Path | None = None
    if firmware is not None:
        path = _firmware(firmware, board_name)
        _check_firmware(path, mcu, bootloader=bootloader)
    boot = bootloader_hex(mcu) if bootloader else None
    simulation = SimAvr(
        path, bootloader=boot, mcu=mcu, frequency=frequency, speed=speed, symlink=symlink
    )
    stopped = threading.Event()
    # set before the AVR runs, so that one that stops at once is not missed
    simulation.on_exit.append(lambda state: stopped.set())
    try:
        simulation.start(hold=True)
        if robot is not None:
            # each device's pins: its settings in the robot file (its defaults for the board)
            PinWorld(simulation, load_board(robot, board), seed=seed).attach()
        simulation.go()
        sys.stdout.write(simulation.link_url + "\n")
        sys.stdout.flush()
        try:
            while simulation.exited is None and simulation.running:
                stopped.wait(0.5)
        except KeyboardInterrupt:
            return
        if simulation.exited is not None:
            raise HwBridgeError(f"the AVR stopped ({simulation.exited})")
        raise HwBridgeError(f"the simulator stopped ({_status(simulation.exit_code)})")
    finally:
        simulation.close()


def _firmware(firmware: str, board: str) -> Path:
    """The ELF to run: ``firmware`` itself, or the build for ``board`` of the sketch folder or
    HwBridge example it names; a usage error if it is none of them."""
    from hwbridge.firmware.sim.examples import EXAMPLES_DIR, build_sketch_for_sim

    path = Path(firmware)
    if path.is_dir():
        return build_sketch_for_sim(path, board)
    if path.exists():
        return path
    if (EXAMPLES_DIR / firmware).is_dir():
        return build_sketch_for_sim(EXAMPLES_DIR / firmware, board)
    raise no_such_path(firmware, "[ELF]", "a HwBridge example's name, e.g. HelloWorld")


def _status(code: int | None) -> str:
    """A process's exit status in words: ``exit code 3``, ``killed by SIGSEGV``."""
    if code is not None and code < 0:
        with contextlib.suppress(ValueError):
            return f"killed by {signal.Signals(-code).name}"
    return f"exit code {code}"


def _check_firmware(path: Path, mcu: str, *, bootloader: bool = False) -> None:
    """Refuse firmware built for another MCU than ``mcu`` (an --mcu value): in the simulator it
    crashes at once. An ELF by the MCU it names; an AVR's Intel HEX by its highest address,
    against the MCU's flash (with ``bootloader``: the flash below the bootloader's section)."""
    import dataclasses

    from hwbridge.firmware.build import ELF_MCUS, elf_mcu
    from hwbridge.firmware.checks import FirmwareTarget, check_elf, check_hex
    from hwbridge.firmware.sim.bootloader import HEX_SUFFIXES, flash_layout, is_intel_hex

    name = "nrf51822" if mcu == "microbit" else mcu  # elf_mcu's names
    target = FirmwareTarget(
        mcu=name,
        name=f"the {name}",
        verb="run",
        option="--mcu",
        value=mcu,
        choices={each: each for each in ELF_MCUS},  # each one an --mcu value
    )
    if not path.is_file():
        # /dev/null, a pipe (<(...)), a FIFO: they exist, so no usage error; not read here (a
        # FIFO's open waits for a writer): SimAvr or QEMU says there is no firmware
        return
    if mcu not in AVR_MCUS or not is_intel_hex(path):  # (as SimAvr tells the runner)
        if elf_mcu(path) is None:  # (the runner said "cannot read", QEMU dumped registers)
            raise target.refuse(
                path,
                f"it is neither an ELF file nor named as an Intel HEX ({', '.join(HEX_SUFFIXES)})"
                if mcu in AVR_MCUS
                else "it is not an ELF file, and QEMU runs only ELF files: give the .elf the build "
                "wrote",
            )
        check_elf(path, target)
        return
    # (boot section start, flash size) of each AVR
    layouts = {each: flash_layout(each) for each in AVR_MCUS}
    room = 0 if bootloader else 1
    below = f" below its bootloader (at {layouts[mcu][0]:#x})" if bootloader else ""
    check_hex(
        path,
        dataclasses.replace(
            target,
            space={each: layout[room] for each, layout in layouts.items()},
            space_name=f"of the {mcu}'s flash{below}",
        ),
    )
