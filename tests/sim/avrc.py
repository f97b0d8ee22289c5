"""Test helper: a C program built for the ATmega328P with avr-gcc, as the runner's tests need."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest


def build_avr_c(source: Path, elf: Path, *flags: str) -> Path:
    """``source`` built for an ATmega328P into ``elf`` (``-Os``, warnings as errors, ``flags``
    too); the test is skipped where avr-gcc is not installed."""
    compiler = shutil.which("avr-gcc")
    if compiler is None:
        pytest.skip("avr-gcc is not installed (apt-get install gcc-avr avr-libc)")
    options = ["-mmcu=atmega328p", *flags, "-Os", "-Wall", "-Wextra", "-Werror"]
    subprocess.run([compiler, *options, "-o", str(elf), str(source)], check=True)
    return elf
