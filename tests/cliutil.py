"""Test helper: the ``hwbridge`` command run as a user runs it, in a process of its own."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path


def run_hwbridge(
    *argv: str,
    timeout: float = 120,
    env: Mapping[str, str] | None = None,
    cwd: Path | None = None,
) -> subprocess.CompletedProcess[str]:
    """``python -m hwbridge ARGV`` with its output captured as text (in ``env``, else this
    process's environment; in ``cwd``); its status is the caller's to check."""
    return subprocess.run(
        [sys.executable, "-m", "hwbridge", *argv],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
        env=env,
        cwd=cwd,
    )
