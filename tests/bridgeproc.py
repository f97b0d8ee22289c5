"""A bridge process for end-to-end tests."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from tests.netutil import free_port, wait_until


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

    def stop(self) -> int:
        self.process.send_signal(signal.SIGINT)
        try:
            return self.process.wait(15)
        finally:
            if self.process.poll() is None:
                self.process.kill()
            self._log_file.close()
