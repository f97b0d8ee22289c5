"""``python -m hwbridge.firmware.sim ELF [--mcu ...] [--robot ...]``: ``firmware sim``."""

from __future__ import annotations

import typer

from hwbridge.cli.simcmd import sim

if __name__ == "__main__":
    typer.run(sim)
