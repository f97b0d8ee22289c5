"""Fixtures for the ARM tests: the examples built for each QEMU board (cached), skipped with one
line when gcc-arm-none-eabi, newlib or qemu-system-arm is missing."""

from __future__ import annotations

import shutil

import pytest

from hwbridge.firmware.build import ARM_BOARDS

BOARDS = tuple(ARM_BOARDS)
"""stm32f405 (QEMU netduinoplus2, Cortex-M4F) and microbit (QEMU microbit, nRF51 Cortex-M0)."""


def need_arm_tools(*, qemu: bool = True) -> None:
    """Skips the test when the ARM toolchain (or QEMU) is missing."""
    for tool in ("arm-none-eabi-g++", "arm-none-eabi-gcc", *(("qemu-system-arm",) if qemu else ())):
        if shutil.which(tool) is None:
            pytest.skip(
                f"{tool} is not installed (apt-get install gcc-arm-none-eabi "
                "libnewlib-arm-none-eabi qemu-system-arm)"
            )


@pytest.fixture(params=BOARDS)
def arm_board(request: pytest.FixtureRequest) -> str:
    need_arm_tools()
    board: str = request.param
    return board
