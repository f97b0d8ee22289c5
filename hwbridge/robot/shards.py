"""A robot's boards shared out over bridge processes (``hwbridge up`` with many boards).

One bridge process carries a few dozen boards at most before the cost of each message grows
(``tools/bench/boards.py``: at 64 boards one process costs about twice per message what it costs
at one board, and falls behind; four processes of 16 carry the same load at below the one-board
cost). So ``hwbridge up`` starts its boards in child bridge processes, *shards*, of at most
``--boards-per-process`` boards (robot file: ``boards_per_process``, default
:data:`DEFAULT_BOARDS_PER_PROCESS`) when the robot has more than that, and keeps what is
robot-wide in itself: the Zenoh router every shard and client attaches to, the parameter
server, the host devices, the summary, viz and the ROS gateways (docs/design.md, "Sharded
``up``", says why).

Each shard is ``hwbridge up ROBOT.yaml --shard NAMES --link NAME=URL...`` (the parent's resolved
links), a Zenoh client of the parent's router on a private Unix socket; it prints ``ready`` on
its stdout once its boards are started (their links open, unless ``--wait``), and its stderr is
the parent's, so its log lines read as the parent's would. A shard stops when the parent tells
it (SIGTERM), when its stdin (a pipe from the parent) ends, or when the parent dies
(``PR_SET_PDEATHSIG``): it never outlives the parent. Shards run in sessions of their own, so
a terminal's Ctrl-C reaches the parent only, which passes it on once.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final

import yaml

from hwbridge.errors import HwBridgeError

if TYPE_CHECKING:
    from hwbridge.graph import GraphConfig

__all__ = [
    "DEFAULT_BOARDS_PER_PROCESS",
    "PARENT_ENV",
    "Shard",
    "Shards",
    "boards_per_process_key",
    "fail_with",
    "plan_shards",
]

DEFAULT_BOARDS_PER_PROCESS: Final = 16
"""Boards per bridge process when neither the option nor the robot file says."""

PARENT_ENV: Final = "HWBRIDGE_SHARD_PARENT"
"""Set in a shard's environment: the pid of the ``hwbridge up`` it belongs to."""

READY: Final = "ready"
"""What a shard prints on its stdout once its boards are started."""

START_TIMEOUT: Final = 180.0
"""Seconds a shard may take to start (an interpreter and Zenoh on a loaded machine, plus each
board link's first open)."""

STOP_WAIT: Final = 1.0
"""Seconds the parent gives its shards to stop on their own before killing them (the parent
itself is gone 1.5 s after a Ctrl-C: :data:`hwbridge.cli.stopping.GRACE`)."""

log = logging.getLogger("hwbridge.robot")


def plan_shards(names: Sequence[str], per_process: int) -> list[tuple[str, ...]]:
    """The boards (by name, in file order) of each shard: as few shards as hold at most
    ``per_process`` boards each, the boards shared out evenly (17 boards, 16 a process: 9 and
    8). Empty when one process runs them all (``per_process`` 0, or no more boards than it)."""
    if per_process <= 0 or len(names) <= per_process:
        return []
    count = -(-len(names) // per_process)
    return [
        tuple(names[k * len(names) // count : (k + 1) * len(names) // count]) for k in range(count)
    ]


def boards_per_process_key(
    top: dict[str, tuple[yaml.Node, yaml.Node]], report: Callable[[yaml.Node, str], None]
) -> dict[str, int]:
    """The robot file's ``boards_per_process: N`` (as :class:`~hwbridge.robot.model.Robot`'s
    keyword), or nothing; a value that is not a whole number from 0 is reported at its line."""
    if "boards_per_process" not in top:
        return {}
    node = top["boards_per_process"][1]
    value: object = None
    if isinstance(node, yaml.ScalarNode) and node.tag == "tag:yaml.org,2002:int":
        value = yaml.SafeLoader("").construct_object(node)
    if not isinstance(value, int) or value < 0:
        report(
            node,
            f"boards_per_process must be a whole number from 0 (0: every board in one "
            f"process), not {node.value if isinstance(node, yaml.ScalarNode) else 'that'!r}",
        )
        return {}
    return {"boards_per_process": value}


def _verbosity() -> list[str]:
    """The ``-v`` options that give a child the log level this process has."""
    level = logging.getLogger().getEffectiveLevel()
    count = max(0, min(2, (logging.WARNING - level) // 10))
    return ["-v"] * count


@dataclass
class Shard:
    """One bridge process of a sharded robot."""

    index: int
    boards: tuple[str, ...]
    process: subprocess.Popen[bytes]
    ready: threading.Event
    ended: threading.Event
    told: bool = False
    """The stop signal has been sent (once: a second would end it without its goodbyes)."""

    def describe(self) -> str:
        return (
            f"bridge process {self.index + 1} (pid {self.process.pid}; "
            f"board{'s' if len(self.boards) > 1 else ''} {', '.join(self.boards)})"
        )

    def status(self) -> str:
        code = self.process.poll()
        if code is None:
            return "still running"
        if code < 0:
            with contextlib.suppress(ValueError):
                return f"killed by {signal.Signals(-code).name}"
        return f"exit status {code}"


class Shards:
    """The shards of one ``hwbridge up``: started together, watched, stopped together."""

    def __init__(self, groups: Sequence[tuple[str, ...]]) -> None:
        self.groups = list(groups)
        self.shards: list[Shard] = []
        self._folder = tempfile.TemporaryDirectory(prefix="hwbridge-up-")
        self.endpoint = f"unixsock-stream/{Path(self._folder.name) / 'graph.sock'}"
        """The private endpoint the parent's router listens on for its shards."""
        self._stopping = threading.Event()

    def parent_config(self, config: GraphConfig) -> GraphConfig:
        """``config`` (the parent's router) also listening on :attr:`endpoint`; unchanged when a
        Zenoh config file gives the endpoints (its listen list is the file's: the shards attach
        the way the file says, as the gateways do)."""
        import dataclasses

        if config.config_file is not None and not config.listen:
            return config
        return dataclasses.replace(config, listen=(*config.listen, self.endpoint))

    def start(
        self,
        config: GraphConfig,
        msg_path: Sequence[str],
        robot_file: Path,
        links: dict[str, str],
        options: Sequence[str],
    ) -> None:
        """Start every shard and wait until each says it is ready. One that ends first (or
        takes longer than :data:`START_TIMEOUT`) is an error naming its boards; every shard
        is stopped before it is raised."""
        import dataclasses

        from hwbridge.gateway.launch import child_argv
        from hwbridge.msg import child_environment

        if config.config_file is None or config.listen:
            config = dataclasses.replace(config, listen=(self.endpoint,))
        base = [*child_argv(config, msg_path), *_verbosity(), "up", str(robot_file)]
        env = {**child_environment(), PARENT_ENV: str(os.getpid())}
        try:
            for index, boards in enumerate(self.groups):
                argv = [*base, "--shard", ",".join(boards), *options]
                for name in boards:
                    argv += ["--link", f"{name}={links[name]}"]
                process = subprocess.Popen(
                    argv,
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    env=env,
                    start_new_session=True,  # Ctrl-C at a terminal reaches the parent only
                )
                shard = Shard(index, boards, process, threading.Event(), threading.Event())
                threading.Thread(
                    target=self._read, args=(shard,), name=f"shard-{index + 1}", daemon=True
                ).start()
                self.shards.append(shard)
            self._wait_ready()
        except BaseException:
            self.stop()
            raise

    def _read(self, shard: Shard) -> None:
        """The shard's stdout: ``ready``, then nothing until it ends."""
        assert shard.process.stdout is not None
        for line in shard.process.stdout:
            if line.strip() == READY.encode():
                shard.ready.set()
        shard.process.wait()
        shard.ended.set()

    def _wait_ready(self) -> None:
        deadline = time.monotonic() + START_TIMEOUT
        waiting = list(self.shards)
        while waiting:
            shard = waiting[0]
            shard.ready.wait(0.1)
            if shard.ready.is_set():
                waiting.pop(0)
                continue
            ended = next((s for s in waiting if s.ended.is_set() and not s.ready.is_set()), None)
            if ended is not None:
                raise HwBridgeError(
                    f"{ended.describe()} did not start ({ended.status()}; its error is above)"
                )
            if time.monotonic() > deadline:
                raise HwBridgeError(f"{shard.describe()} did not start within {START_TIMEOUT:g} s")

    def failed(self) -> Shard | None:
        """The first shard that ended while the robot runs (None: all run)."""
        if self._stopping.is_set():
            return None
        return next((s for s in self.shards if s.ended.is_set()), None)

    def interrupt(self) -> None:
        """Tell every shard to stop, without waiting; the first Ctrl-C does this at once, while
        the parent's own shutdown goes on. SIGTERM, which a shard handles as Ctrl-C: SIGINT
        may be ignored in it (started from a shell's background job, as the parent was)."""
        self._stopping.set()
        for shard in self.shards:
            if shard.process.poll() is None and not shard.told:
                shard.told = True
                with contextlib.suppress(ProcessLookupError):
                    shard.process.send_signal(signal.SIGTERM)

    def stop(self) -> None:
        """Stop every shard: SIGTERM, :data:`STOP_WAIT` seconds to go, then SIGKILL."""
        self.interrupt()
        deadline = time.monotonic() + STOP_WAIT
        for shard in self.shards:
            with contextlib.suppress(subprocess.TimeoutExpired):
                shard.process.wait(max(0.0, deadline - time.monotonic()))
        for shard in self.shards:
            if shard.process.poll() is None:
                log.warning("%s did not stop within %g s: killed", shard.describe(), STOP_WAIT)
                shard.process.kill()
                shard.process.wait(5)
            if shard.process.stdin is not None:
                with contextlib.suppress(OSError):
                    shard.process.stdin.close()
        with contextlib.suppress(OSError):
            self._folder.cleanup()

    def describe(self) -> str:
        """One line for the start-up message."""
        pids = ", ".join(str(s.process.pid) for s in self.shards)
        return (
            f"hwbridge: {sum(len(g) for g in self.groups)} boards in {len(self.shards)} bridge "
            f"processes (pids {pids}; --boards-per-process 0 runs them in this one)"
        )


def fail_with(shard: Shard) -> HwBridgeError:
    """The error ``up`` ends with when a shard ended under it."""
    return HwBridgeError(
        f"{shard.describe()} ended ({shard.status()}); the robot was stopped "
        "(its other bridge processes with it)"
    )
