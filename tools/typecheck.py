#!/usr/bin/env python3
"""Run mypy over the installed shape of ``hwbridge`` (protocols and devices included).

The build backend maps ``protocols/`` and ``devices/`` into the ``hwbridge`` package; mypy cannot
follow that mapping (it ignores import hooks), so this script lays out a tree of symlinks under
``build/typecheck`` with the installed shape, runs mypy there and prints paths as they are in the
repository. Extra arguments go to mypy.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TREE = ROOT / "build" / "typecheck"
MAPPED = {"protocols": "protocols", "devices": "devices"}


def build_tree() -> None:
    if TREE.exists():
        shutil.rmtree(TREE)
    package = TREE / "hwbridge"
    package.mkdir(parents=True)
    for entry in (ROOT / "hwbridge").iterdir():
        if entry.name != "__pycache__":
            (package / entry.name).symlink_to(entry)
    for name, folder in MAPPED.items():
        (package / name).symlink_to(ROOT / folder)


def main() -> int:
    build_tree()
    command = [
        sys.executable,
        "-m",
        "mypy",
        "--config-file",
        str(ROOT / "pyproject.toml"),
        "--cache-dir",
        str(ROOT / "build" / "mypy-cache"),
        "-p",
        "hwbridge",
        *sys.argv[1:],
    ]
    result = subprocess.run(command, cwd=TREE, capture_output=True, text=True, check=False)
    output = result.stdout + result.stderr
    for name, folder in MAPPED.items():
        output = output.replace(f"hwbridge{os.sep}{name}{os.sep}", f"{folder}{os.sep}")
    sys.stdout.write(output)
    return result.returncode


if __name__ == "__main__":
    sys.exit(main())
