"""One shard of a sharded ``hwbridge up``: the child process side (see
:mod:`hwbridge.robot.shards`).

``hwbridge up ROBOT.yaml --shard NAMES`` runs the named boards of the robot and their devices'
host nodes, attached to the parent's graph as a Zenoh client, reading parameters from the
parent's server. It is started by ``hwbridge up`` itself, never by a user (the option is
hidden), and it never outlives that parent.
"""

from __future__ import annotations

import ctypes
import dataclasses
import os
import signal
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Final

from hwbridge.errors import HwBridgeError

if TYPE_CHECKING:
    import typer

__all__ = ["run_shard"]

_PR_SET_PDEATHSIG: Final = 1


def _follow_parent() -> None:
    """End this process when the parent ends, however it ends: SIGTERM from the kernel when it
    dies (``PR_SET_PDEATHSIG``), and SIGTERM to ourselves when our stdin (the parent's pipe)
    ends; both go through :mod:`hwbridge.cli.stopping` as a signal from a user would."""
    from hwbridge.robot.shards import PARENT_ENV

    parent = os.environ.get(PARENT_ENV)
    if parent is None or not parent.isdigit():
        raise HwBridgeError("--shard is for 'hwbridge up' itself: run 'hwbridge up ROBOT.yaml'")
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    if os.getppid() != int(parent):  # it died before the line above took effect
        os.kill(os.getpid(), signal.SIGTERM)

    def watch() -> None:
        try:
            while sys.stdin.buffer.read(4096):
                pass
        except OSError:
            pass
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="shard-parent", daemon=True).start()


def run_shard(
    ctx: typer.Context,
    robot_file: Path,
    links: dict[str, str],
    names: str,
    *,
    wait: bool,
) -> None:
    """Run the boards ``names`` (comma-separated) of the robot until stopped."""
    from hwbridge.bridge.remoteparams import RemoteParams
    from hwbridge.cli.bridgecmd import wait_for_signal
    from hwbridge.cli.common import get_registry, open_graph
    from hwbridge.robot.config import check_robot
    from hwbridge.robot.runtime import RobotRuntime
    from hwbridge.robot.shards import READY

    _follow_parent()
    robot, _notes = check_robot(robot_file, links)  # the parent showed the notes
    wanted = names.split(",")
    mine = tuple(b for b in robot.boards if b.name in wanted)
    if len(mine) != len(wanted):
        raise HwBridgeError(f"{robot_file}: --shard names boards the robot does not have")
    robot = dataclasses.replace(robot, boards=mine, host_devices=())
    graph = open_graph(ctx)
    try:
        graph.registry = get_registry(ctx)
        runtime = RobotRuntime(robot, graph, param_source=RemoteParams(graph), wait_for_boards=wait)
        runtime.start()
        try:
            sys.stdout.write(READY + "\n")
            sys.stdout.flush()
            wait_for_signal()
        finally:
            runtime.stop()
    finally:
        graph.close()
