"""Start a gateway as a child process of the process that owns the graph (``hwbridge up
--ros2``/``--ros1``).

A child keeps rclpy (and the environment it needs) out of the bridge's process, and a gateway
that fails does not take the robot down with it.
"""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Final

if TYPE_CHECKING:
    from hwbridge.graph import GraphConfig

__all__ = ["GatewayProcess", "child_argv", "client_endpoint"]

_WILDCARDS: Final = {"0.0.0.0": "127.0.0.1", "[::]": "[::1]"}


def client_endpoint(listen: str) -> str:
    """The endpoint a local client connects to for a router listening on ``listen``."""
    for wildcard, local in _WILDCARDS.items():
        listen = listen.replace(f"/{wildcard}:", f"/{local}:")
    return listen


def child_argv(config: GraphConfig, msg_path: Sequence[str] = ()) -> list[str]:
    """``python -m hwbridge`` with the global options that attach a child process to the graph
    ``config`` describes (its endpoint, Zenoh config file and domain) and find the same message
    packages; the command and its arguments come after."""
    argv = [sys.executable, "-m", "hwbridge"]
    for path in msg_path:
        argv += ["--msg-path", path]
    if config.listen:
        argv += ["--endpoint", client_endpoint(config.listen[0])]
    if config.config_file is not None:
        argv += ["--zenoh-config", str(config.config_file)]
    return [*argv, "--domain", config.domain]


class GatewayProcess:
    """``hwbridge ros2|ros1 ...`` attached to the graph ``config`` describes, until :meth:`stop`."""

    def __init__(
        self,
        kind: str,
        config: GraphConfig,
        extra: Sequence[str] = (),
        msg_path: Sequence[str] = (),
    ) -> None:
        from hwbridge.msg import child_environment

        argv = [*child_argv(config, msg_path), kind, *extra]
        self.argv = argv
        self.kind = kind
        self.process = subprocess.Popen(argv, env=child_environment(), stdin=subprocess.DEVNULL)

    def running(self) -> bool:
        return self.process.poll() is None

    def stop(self, timeout: float = 10.0) -> int:
        """SIGINT, then SIGKILL after ``timeout``; the exit status."""
        if self.process.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)
        return int(self.process.returncode)
