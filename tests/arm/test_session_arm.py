"""The golden session transcript of PROTOCOL.md 2.12 replayed byte for byte on the ARM boards:
``firmware/tests/test_session.cpp`` (the host-native replay and session checks) built for the
STM32F405 and the micro:bit's nRF51822 with the transcript compiled in, run in QEMU with its
output and exit code through semihosting. On the Cortex-M0 every access of the library is
checked for alignment by the core (a fault stops the program; the UART says where)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from hwbridge.firmware.build import LIBRARY_DIR, build_arm_program
from hwbridge.firmware.qemu import run_semihosted
from tests.arm.conftest import need_arm_tools

TESTS = LIBRARY_DIR.parents[1] / "firmware" / "tests"


def _transcript() -> str:
    spec = importlib.util.spec_from_file_location("session_vectors", TESTS / "session_vectors.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    lines: list[str] = module.lines()
    return "".join(line + "\n" for line in lines)


_compiled: dict[str, Path] = {}


def _replay(board: str, tmp_path: Path, transcript: str) -> tuple[int, str, str]:
    need_arm_tools()
    obj = _compiled.get(board)
    if obj is None or not obj.exists():  # test_session.cpp compiled once per board and run
        obj = build_arm_program(
            [TESTS / "test_session.cpp"],
            board,
            tmp_path / f"test_session-{board}.elf",
            includes=[LIBRARY_DIR / "src", TESTS],
            defines=["HWBRIDGE_EMBEDDED_TRANSCRIPT"],
            cxx_flags=["-Wall", "-Wextra", "-Werror"],
            compile_only=True,
        )
        _compiled[board] = obj
    source = tmp_path / "transcript.c"
    source.write_text(f"const char hwbridge_transcript[] = {json.dumps(transcript)};\n")
    elf = build_arm_program(
        [obj, source],
        board,
        tmp_path / f"replay-{board}.elf",
        defines=["HWBRIDGE_EMBEDDED_TRANSCRIPT"],
    )
    uart = tmp_path / "uart.txt"
    done = run_semihosted(elf, board, timeout=180, serial_file=uart)
    fault = uart.read_text(errors="replace") if uart.exists() else ""
    return done.returncode, done.stdout + done.stderr, fault


@pytest.mark.parametrize("board", ["microbit", "stm32f405"])
def test_golden_transcript_on_arm(board: str, tmp_path: Path) -> None:
    code, output, fault = _replay(board, tmp_path, _transcript())
    assert code == 0, output + fault
    assert "golden transcript: 42 frames" in output
    assert "checks passed" in output


def test_a_wrong_transcript_byte_fails_on_arm(tmp_path: Path) -> None:
    """The replay can fail in QEMU too: one byte of the board's BOARD_INFO changed."""
    lines = _transcript().splitlines(keepends=True)
    at = next(i for i, line in enumerate(lines) if line.startswith("T board_info d "))
    good = lines[at].rstrip("\n")
    lines[at] = good[:-1] + ("6" if good[-1] != "6" else "7") + "\n"
    code, output, _ = _replay("microbit", tmp_path, "".join(lines))
    assert code == 1, output
    assert "board_info: the board wrote" in output
