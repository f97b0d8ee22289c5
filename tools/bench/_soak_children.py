"""The child processes of a soak stage: the board processes (host builds of the SoakBoard
sketch, or Python emulators) and the client, each answering one line per command on stdin."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

from _common import child_line
from _soak_board import board_name

SCRIPT = Path(__file__).resolve().with_name("soak.py")
"""The bench's script, which the emulator and client processes run in another role."""


class Child:
    """A child process (soak.py in another role, or a board program) that answers one
    line per command; ``preamble`` lines it prints before ``ready`` are skipped."""

    def __init__(
        self,
        name: str,
        command: list[str],
        env: dict[str, str] | None = None,
        preamble: int = 0,
    ) -> None:
        self.process = subprocess.Popen(
            command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env
        )
        self.name = name
        for _ in range(preamble):
            self.line()
        self.expect("ready")

    @classmethod
    def script(cls, *args: str) -> Child:
        """The bench's script with ``args`` (``--emulator ...`` or ``--client ...``)."""
        return cls(args[0], [sys.executable, str(SCRIPT), *args])

    def line(self, timeout: float = 60.0) -> str:
        return child_line(self.process, self.name, timeout)

    def expect(self, word: str) -> None:
        line = self.line()
        if line != word:
            raise RuntimeError(f"{self.name}: expected {word!r}, got {line!r}")

    def ask(self, command: str, timeout: float = 60.0) -> str:
        stdin = self.process.stdin
        assert stdin is not None
        stdin.write(command + "\n")
        stdin.flush()
        return self.line(timeout)

    def close(self) -> None:
        if self.process.poll() is None:
            try:
                assert self.process.stdin is not None
                self.process.stdin.write("quit\n")
                self.process.stdin.flush()
                self.process.wait(10)
            except (OSError, subprocess.TimeoutExpired):
                self.process.kill()
                self.process.wait()


def start_boards(args: argparse.Namespace, ports: list[int], into: list[Child]) -> None:
    """Starts the board processes into ``into`` (so that the caller stops those started if a
    later one fails): one firmware program per board (``--boards-kind firmware``), or Python
    emulators of ``--per-emulator`` boards each."""
    if args.boards_kind == "firmware":
        assert args.board_program is not None
        for index, port in enumerate(ports):
            into.append(
                Child(
                    board_name(index),
                    [str(args.board_program), f"listen://127.0.0.1:{port}"],
                    env=dict(
                        os.environ,
                        SOAK_INDEX=str(index),
                        SOAK_TOPICS=str(args.topics),
                        SOAK_RELIABLE=str(args.reliable),
                        SOAK_RATE=str(args.rate),
                    ),
                    preamble=1,  # the link it serves
                )
            )
        return
    per = max(1, args.per_emulator)
    for first in range(0, len(ports), per):
        into.append(
            Child.script(
                "--emulator",
                str(first),
                ",".join(map(str, ports[first : first + per])),
                str(args.topics),
                str(args.rate),
                str(args.reliable),
            )
        )
