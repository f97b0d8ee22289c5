"""``hwbridge firmware sim`` and ``upload`` given an ELF or an Intel HEX a user could mix up: one
built for another MCU (a HEX: one past the MCU's flash) is refused at once, naming the option
that runs it (a Mega's ELF or HEX on the default Uno crashed in simavr, an ARM ELF in simavr hung
after its crash, and an upload wrote a Mega's ELF to an Uno); an AVR that stops at once ends the
command with the reason; a simulator that dies ends it with an error instead of exit status 0."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import typing
from pathlib import Path

import pytest

from hwbridge.errors import HwBridgeError
from hwbridge.firmware.build import elf_mcu
from hwbridge.firmware.sim.bootloader import HEX_SUFFIXES
from hwbridge.firmware.sim.examples import EXAMPLES_DIR, build_example
from tests.cliutil import run_hwbridge
from tests.netutil import wait_until
from tests.sim.avrc import build_avr_c

_hwbridge = run_hwbridge


def _example(board: str) -> Path:
    try:
        return build_example("HelloWorld", board)
    except HwBridgeError as exc:
        pytest.skip(f"HelloWorld does not build for {board} here: {str(exc).splitlines()[0]}")


def test_elf_mcu_reads_the_target_from_the_header(tmp_path: Path) -> None:
    assert elf_mcu(_example("uno")) == "atmega328p"
    assert elf_mcu(_example("mega")) == "atmega2560"
    hex_file = tmp_path / "x.hex"
    hex_file.write_text(":00000001FF\n")
    assert elf_mcu(hex_file) is None
    assert elf_mcu(tmp_path) is None


def _elf_header(machine: int, entry: int, flags: int = 0) -> bytes:
    """The 52 bytes of a 32-bit little-endian ELF header that ``elf_mcu`` reads."""
    header = bytearray(52)
    header[:6] = b"\x7fELF\x01\x01"
    header[18:20] = machine.to_bytes(2, "little")
    header[24:28] = entry.to_bytes(4, "little")
    header[36:40] = flags.to_bytes(4, "little")
    return bytes(header)


@pytest.mark.parametrize(
    ("machine", "entry", "flags", "mcu"),
    [
        (40, 0x0800_0189, 0, "stm32f405"),
        (40, 0x0000_00C1, 0, "nrf51822"),
        (40, 0x2000_0100, 0, "another ARM chip"),  # an entry point in RAM
        (83, 0, 5, "atmega328p"),
        (83, 0, 0x80 | 6, "atmega2560"),  # bit 7: avr-gcc's linker-relaxation flag
        (83, 0, 2, "an AVR of architecture avr2"),
        (62, 0x40_1000, 0, "ELF machine 62"),  # x86-64 (a host build)
    ],
)
def test_elf_mcu_by_machine_entry_and_flags(
    tmp_path: Path, machine: int, entry: int, flags: int, mcu: str
) -> None:
    elf = tmp_path / "x.elf"
    elf.write_bytes(_elf_header(machine, entry, flags))
    assert elf_mcu(elf) == mcu


def test_elf_mcu_calls_a_64_bit_elf_a_host_program(tmp_path: Path) -> None:
    elf = tmp_path / "x.elf"
    elf.write_bytes(b"\x7fELF\x02\x01" + bytes(58))
    assert elf_mcu(elf) == "a 64-bit computer (a host build?)"


def test_sim_refuses_an_elf_built_for_another_mcu(runner: Path) -> None:
    del runner
    mega = _example("mega")
    done = _hwbridge("firmware", "sim", str(mega))  # --mcu atmega328p by default
    assert done.returncode == 1, done.stderr
    assert done.stdout == "", done.stdout  # no simulator started
    assert (
        f"error: refusing to run {mega}: built for the atmega2560, not the atmega328p: "
        "give --mcu atmega2560"
    ) in done.stderr, done.stderr
    uno = _example("uno")
    done = _hwbridge("firmware", "sim", str(uno), "--mcu", "stm32f405")
    assert done.returncode == 1, done.stderr
    assert "built for the atmega328p, not the stm32f405: give --mcu atmega328p" in done.stderr


_NOT_ELF = "it is not an ELF file, and QEMU runs only ELF files: give the .elf the build wrote"


@pytest.mark.parametrize(
    ("name", "mcu", "why"),
    [
        (
            "notes.bin",
            "atmega328p",
            "it is neither an ELF file nor named as an Intel HEX (.hex, .ihex, .ihx)",
        ),
        ("image.hex", "stm32f405", _NOT_ELF),
        ("image.bin", "microbit", _NOT_ELF),
    ],
)
def test_sim_refuses_a_file_it_cannot_run(tmp_path: Path, name: str, mcu: str, why: str) -> None:
    """A file that is no ELF (nor, for simavr, named as an Intel HEX) is refused before the
    simulator starts: the simavr runner said 'could not read ... Success', QEMU dumped its
    registers after a lockup."""
    path = tmp_path / name
    path.write_text(":10000000000102030405060708090A0B0C0D0E0F78\n:00000001FF\n")
    done = _hwbridge("firmware", "sim", str(path), "--mcu", mcu)
    assert done.returncode == 1, done.stderr
    assert done.stdout == ""
    assert done.stderr.splitlines() == [f"error: refusing to run {path}: {why}"]


def test_upload_refuses_an_elf_built_for_another_mcu(tmp_path: Path) -> None:
    mega = _example("mega")
    done = _hwbridge("firmware", "upload", str(mega), "--port", str(tmp_path / "ttyNONE"))
    assert done.returncode == 1, done.stderr
    assert (
        f"error: refusing to upload {mega}: built for the atmega2560, not the uno's atmega328p: "
        "give --board mega"
    ) in done.stderr, done.stderr


def _intel_hex(path: Path, chunks: dict[int, bytes]) -> Path:
    """An Intel HEX file of ``chunks`` (bytes by address): 16 bytes a record, an extended
    linear address record where the upper 16 bits of the addresses change."""

    def record(kind: int, address: int, data: bytes) -> str:
        body = bytes([len(data), address >> 8, address & 0xFF, kind]) + data
        return ":" + (body + bytes([-sum(body) & 0xFF])).hex().upper()

    lines: list[str] = []
    upper = 0
    for start, data in sorted(chunks.items()):
        for offset in range(0, len(data), 16):
            address = start + offset
            if address >> 16 != upper:
                upper = address >> 16
                lines.append(record(4, 0, upper.to_bytes(2, "big")))
            lines.append(record(0, address & 0xFFFF, data[offset : offset + 16]))
    lines.append(record(1, 0, b""))
    path.write_text("\n".join(lines) + "\n")
    return path


_LOOP = b"\xff\xcf"  # rjmp .-2


def test_sim_refuses_a_hex_past_the_mcus_flash(tmp_path: Path) -> None:
    """A Mega's HEX, code up to 0x9d61, is refused on the default Uno before the simulator
    starts (the runner crashed on it, or was killed by SIGSEGV), naming the --mcu that fits; with
    --bootloader, a HEX reaching into the Uno's bootloader section (from 0x7E00) likewise."""
    mega = _intel_hex(tmp_path / "mega.hex", {0: _LOOP, 0x9D60: _LOOP})
    done = _hwbridge("firmware", "sim", str(mega))
    assert (done.returncode, done.stdout) == (1, ""), done.stderr
    assert (
        f"error: refusing to run {mega}: it reaches address 0x9d61 (40290 bytes), past the "
        "32768 bytes of the atmega328p's flash: give --mcu atmega2560"
    ) in done.stderr, done.stderr
    full = _intel_hex(tmp_path / "full.hex", {0: _LOOP, 0x7E00: _LOOP})
    done = _hwbridge("firmware", "sim", str(full), "--bootloader")
    assert (done.returncode, done.stdout) == (1, ""), done.stderr
    assert (
        f"error: refusing to run {full}: it reaches address 0x7e01 (32258 bytes), past the "
        "32256 bytes of the atmega328p's flash below its bootloader (at 0x7e00): give --mcu "
        "atmega2560"
    ) in done.stderr, done.stderr


_SLEEP = b"\xf8\x94\x88\x95"  # cli; sleep: simavr stops the AVR ("done")


@pytest.mark.parametrize("suffix", HEX_SUFFIXES)
def test_sim_runs_an_intel_hex_by_any_of_its_names(
    runner: Path, tmp_path: Path, suffix: str
) -> None:
    """``firmware sim`` takes the Intel HEX names ``firmware upload`` takes: the runner is told
    that the file is a HEX (it read a ``.ihx`` as an ELF, and failed), loads it, and the AVR
    runs it (here: into a sleep with interrupts off, which stops it)."""
    del runner
    image = _intel_hex(tmp_path / f"sleeper{suffix.upper()}", {0: _SLEEP})
    done = _hwbridge("firmware", "sim", str(image), timeout=60)
    assert (done.returncode, done.stdout.startswith("serial:///dev/pts/")) == (1, True), (
        done.stdout + done.stderr
    )
    assert "error: the AVR stopped (done)" in done.stderr, done.stderr


def test_sim_and_upload_say_they_take_every_hex_name() -> None:
    """The commands' help (written out: the CLI imports lazily) names each of HEX_SUFFIXES."""
    from hwbridge.cli.simcmd import sim
    from hwbridge.cli.uploadcmd import upload

    for command, parameter in ((sim, "firmware"), (upload, "target")):
        argument = typing.get_type_hints(command, include_extras=True)[parameter].__metadata__[0]
        assert all(suffix in argument.help for suffix in HEX_SUFFIXES), argument.help


def test_upload_refuses_a_hex_past_the_boards_flash(tmp_path: Path) -> None:
    """Before avrdude resets the board: a Mega's HEX on the default Uno names --board mega; one
    past the Mega's room too names no board."""
    port = str(tmp_path / "ttyNONE")
    mega = _intel_hex(tmp_path / "mega.hex", {0: _LOOP, 0x9D60: _LOOP})
    done = _hwbridge("firmware", "upload", str(mega), "--port", port)
    assert done.returncode == 1, done.stderr
    assert (
        f"error: refusing to upload {mega}: it reaches address 0x9d61 (40290 bytes), past the "
        "32256 bytes of flash the uno's bootloader leaves: give --board mega"
    ) in done.stderr, done.stderr
    huge = _intel_hex(tmp_path / "huge.hex", {0: _LOOP, 0x3E000: _LOOP})
    done = _hwbridge("firmware", "upload", str(huge), "--port", port, "--board", "mega")
    assert done.returncode == 1, done.stderr
    assert (
        f"error: refusing to upload {huge}: it reaches address 0x3e001 (253954 bytes), past the "
        "253952 bytes of flash the mega's bootloader leaves; no --board has that much flash"
    ) in done.stderr, done.stderr


def _sleeper(tmp_path: Path) -> Path:
    """An ATmega328P program that sleeps with interrupts off at once: simavr stops it ("done")."""
    source = tmp_path / "sleeper.c"
    source.write_text(
        'int main(void) {\n  __asm__ volatile("cli\\n\\tsleep");\n  for (;;) {\n  }\n}\n'
    )
    return build_avr_c(source, tmp_path / "sleeper.elf")


def test_an_avr_that_stops_at_once_ends_the_command(runner: Path, tmp_path: Path) -> None:
    """The AVR stopping is listened for before it runs (a stop reported before the command
    listened for it was missed, and the command waited forever)."""
    del runner
    elf = _sleeper(tmp_path)
    for _ in range(3):  # the report races the command's start: each run is a new chance
        done = _hwbridge("firmware", "sim", str(elf), timeout=60)
        assert done.returncode == 1, done.stderr
        assert "error: the AVR stopped (done)" in done.stderr, done.stderr


def test_a_simulator_that_dies_is_an_error(runner: Path) -> None:
    del runner
    _example("uno")  # built before the clock
    process = subprocess.Popen(
        [sys.executable, "-m", "hwbridge", "firmware", "sim", "HelloWorld"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout is not None and process.stderr is not None
        first = process.stdout.readline().strip()
        assert first.startswith("serial:///dev/pts/"), first + process.stderr.read()
        children: list[int] = []

        def runner_found() -> bool:
            found = subprocess.run(
                ["pgrep", "-P", str(process.pid)], capture_output=True, text=True, check=False
            )
            children[:] = [int(pid) for pid in found.stdout.split()]
            return len(children) == 1

        assert wait_until(runner_found, 10), children
        os.kill(children[0], signal.SIGSEGV)
        assert process.wait(30) == 1
        assert "error: the simulator stopped (killed by SIGSEGV)" in process.stderr.read()
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
            process.wait(30)


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (
            ("firmware", "build", str(EXAMPLES_DIR / "HelloWorld"), "--board", "due"),
            "unknown board 'due'; use one of uno, nano, mega, stm32f405, microbit, host",
        ),
        (
            (
                "firmware",
                "upload",
                str(EXAMPLES_DIR / "HelloWorld"),
                "--port",
                "/nonexistent",
                "--board",
                "due",
            ),
            "unknown board 'due'; use uno or mega",
        ),
        (
            ("firmware", "sim", "HelloWorld", "--mcu", "atmega32u4"),
            "unknown MCU 'atmega32u4'; use one of atmega328p, atmega2560, stm32f405, nrf51822",
        ),
        (
            ("firmware", "sim", "HelloWorld", "--mcu", "stm32f405", "--bootloader"),
            "error: --bootloader is for the AVR boards in simavr only, not --mcu stm32f405",
        ),
    ],
)
def test_an_unknown_board_or_mcu_is_a_usage_error(argv: tuple[str, ...], said: str) -> None:
    """Status 2, as for any usage error, before anything is built or started."""
    done = _hwbridge(*argv, timeout=60)
    assert done.returncode == 2, done.stderr
    assert said in done.stderr, done.stderr
    assert "Traceback" not in done.stderr
