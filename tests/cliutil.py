"""Test helper: the ``hwbridge`` command run as a user runs it, in a process of its own."""

from __future__ import annotations

import subprocess
import sys


def run_hwbridge(*argv: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """``python -m hwbridge ARGV`` with its output captured as text; its status is the caller's
    to check."""
    return subprocess.run(
        [sys.executable, "-m", "hwbridge", *argv],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )
