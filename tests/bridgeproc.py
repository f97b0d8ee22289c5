"""A bridge process for end-to-end tests."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

from tests.netutil import free_port, wait_until


def new_sessions(output: str, board: str | None = None) -> int:
    """How many new sessions a bridge's ``output`` shows (with ``board``: with the board of that
    name), resumed ones not counted: a busy machine may hold a simulated board silent past the
    link's 0.8 s timeout, and its session then resumes ('connected (native, session
    resumed)'); a board that came back after a reset but was taken for its old session resumed
    never adds one."""
    named = rf"board '{re.escape(board)}' " if board is not None else ""
    return len(re.findall(rf"{named}connected \([^,)]*\):", output))


class BridgeProcess:
    """``hwbridge connect PATH`` (a path or a link URL) in a subprocess, on its own endpoint and
    graph domain."""

    def __init__(self, path: Path | str, tmp: Path, domain: str, *extra: str) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.env = {**os.environ, "HWBRIDGE_ENDPOINT": self.endpoint, "HWBRIDGE_DOMAIN": domain}
        self.log = tmp / "bridge.log"
        self._log_file = self.log.open("w")
        self.process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "hwbridge",
                "-v",
                "connect",
                str(path),
                "--start-delay",
                "0.2",
                *extra,
            ],
            env=self.env,
            stdout=self._log_file,
            stderr=subprocess.STDOUT,
        )

    def wait_ready(self) -> None:
        """Wait for the line the bridge prints once its graph endpoint listens."""
        assert wait_until(lambda: "hwbridge: bridging" in self.output(), 60), self.output()

    def cli(self, *argv: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "hwbridge", *argv],
            env=self.env,
            capture_output=True,
            text=True,
            timeout=timeout,
            check=False,
        )

    def output(self) -> str:
        return self.log.read_text()

    def board_session(self) -> int | None:
        """The board's session id (its device session, PROTOCOL.md 2.10) while the bridge has
        the board connected, from ``hwbridge board info``; None while it has not (or when the
        question went unanswered)."""
        done = self.cli("board", "info", "--json")
        if done.returncode != 0:
            return None
        info = json.loads(done.stdout)
        device = (info.get("session") or {}).get("device_session")
        return int(device) if info.get("state") == "connected" and device else None

    def wait_session(self, timeout: float, *, other_than: int | None = None, since: int = 0) -> int:
        """Wait until the bridge has the board connected in a session other than
        ``other_than``, and return the board's session id: a board that came back after a
        reset is told from its old session resumed by that id, which log lines do not give.
        The bridge is asked (a CLI process each time) once its output past offset ``since``
        shows a connection. AssertionError, with the output, after ``timeout`` seconds."""
        found: list[int] = []

        def connected() -> bool:
            if "connected (" not in self.output()[since:]:
                return False
            session = self.board_session()
            if session is None or session == other_than:
                return False
            found.append(session)
            return True

        other = f" other than {other_than:#010x}" if other_than is not None else ""
        assert wait_until(connected, timeout), (
            f"no board session{other} in {timeout:g} s:\n{self.output()}"
        )
        return found[-1]

    def stop(self) -> int:
        self.process.send_signal(signal.SIGINT)
        try:
            return self.process.wait(15)
        finally:
            if self.process.poll() is None:
                self.process.kill()
            self._log_file.close()
