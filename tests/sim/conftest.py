"""Fixtures for the simavr tests: the runner (built once into a cache of the session's own) and
the test programs under ``avr/`` compiled with avr-gcc; skipped with one line when the tools are
missing."""

from __future__ import annotations

import os
import select
import termios
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest

from hwbridge.firmware.sim import SimToolchainMissingError, runner_binary
from tests.sim.avrc import build_avr_c

AVR_DIR = Path(__file__).with_name("avr")


@pytest.fixture(scope="session")
def runner() -> Path:
    try:
        return runner_binary()
    except SimToolchainMissingError as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="session")
def probe_elf(tmp_path_factory: pytest.TempPathFactory, runner: Path) -> Path:
    """tests/sim/avr/probe.c built for an ATmega328P at 16 MHz."""
    elf = tmp_path_factory.mktemp("avr") / "probe.elf"
    return build_avr_c(AVR_DIR / "probe.c", elf, "-DF_CPU=16000000UL")


class Terminal:
    """The host end of the runner's UART, raw."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd, termios.TCSANOW)  # not TCSAFLUSH: keep what came
        self.buffer = b""

    def write(self, data: bytes) -> None:
        os.write(self.fd, data)

    def read_until(self, end: bytes, timeout: float = 10.0) -> bytes:
        """Bytes up to and with ``end``; fails after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while end not in self.buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"no {end!r} from the AVR; got {self.buffer!r}")
            ready, _, _ = select.select([self.fd], [], [], min(left, 0.1))
            if ready:
                self.buffer += os.read(self.fd, 4096)
        index = self.buffer.index(end) + len(end)
        found, self.buffer = self.buffer[:index], self.buffer[index:]
        return found

    def close(self) -> None:
        os.close(self.fd)


@pytest.fixture
def terminal_factory() -> Iterator[type[Terminal]]:
    opened: list[Terminal] = []

    class _Tracked(Terminal):
        def __init__(self, path: str) -> None:
            super().__init__(path)
            opened.append(self)

    yield _Tracked
    for terminal in opened:
        terminal.close()
