"""Unaligned accesses fault where the claim says so: on the micro:bit's Cortex-M0 always (ARMv6-M
has no unaligned access, and QEMU's model enforces it), on the STM32F405's Cortex-M4 when the
start-up sets CCR.UNALIGN_TRP (HWBRIDGE_UNALIGN_TRAP=1); without it the M4 loads the word."""

from __future__ import annotations

from pathlib import Path

import pytest

from hwbridge.firmware.build import build_arm_program
from hwbridge.firmware.qemu import run_semihosted
from tests.arm.conftest import need_arm_tools

PROGRAM = Path(__file__).with_name("programs") / "unaligned.c"


def _run(board: str, tmp_path: Path, *defines: str) -> tuple[str, str]:
    need_arm_tools()
    elf = build_arm_program(
        [PROGRAM], board, tmp_path / f"unaligned-{board}.elf", defines=[*defines]
    )
    uart = tmp_path / "uart.txt"
    done = run_semihosted(elf, board, timeout=60, serial_file=uart, run_for=3.0)
    return done.stdout, uart.read_text(errors="replace") if uart.exists() else ""


@pytest.mark.parametrize(
    ("board", "defines"), [("microbit", ()), ("stm32f405", ("HWBRIDGE_UNALIGN_TRAP=1",))]
)
def test_unaligned_load_faults(board: str, defines: tuple[str, ...], tmp_path: Path) -> None:
    stdout, uart = _run(board, tmp_path, *defines)
    assert "before" in stdout
    assert "after" not in stdout
    assert "HARDFAULT" in uart, uart
    if board == "stm32f405":  # the UsageFault's UNALIGNED bit (CFSR bit 24), escalated
        cfsr = int(uart.split("cfsr=")[1][:8], 16)
        assert cfsr & (1 << 24), uart


def test_m4_without_the_trap_loads_the_word(tmp_path: Path) -> None:
    """The same program on the M4 without UNALIGN_TRP: the test above can fail."""
    stdout, uart = _run("stm32f405", tmp_path)
    assert "after: 05040302" in stdout
    assert "HARDFAULT" not in uart
