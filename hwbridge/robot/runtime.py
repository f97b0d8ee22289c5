"""A whole robot up: the bridge with every board of a robot file, and every host node its
devices need (``hwbridge up ROBOT.yaml``; the demo runs through here too).

::

    from hwbridge.robot.config import load_robot
    from hwbridge.robot.runtime import RobotRuntime

    robot = load_robot("examples/robots/diffbot.yaml").with_links({"base": "/dev/ttyACM0"})
    with RobotRuntime(robot) as running:      # embedded graph on tcp/127.0.0.1:7447
        running.wait()                         # until stop() or Ctrl-C

Nothing here names a device type: each device's plugin (:mod:`hwbridge.robot.registry`) starts
its own host node. A board device's node sits in its board's namespace next to the board's raw
topics; a host device (a servo bus on the host's adapter) gets its link and namespace from its
own entry.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hwbridge.bridge import BoardSpec, Bridge
from hwbridge.errors import HwBridgeError
from hwbridge.graph import Graph, GraphConfig
from hwbridge.robot.identity import build_tag
from hwbridge.robot.model import DeviceConfig, Robot, RobotFileError
from hwbridge.robot.plugin import Closeable, HostContext
from hwbridge.robot.registry import get_device

if TYPE_CHECKING:
    from hwbridge.bridge.remoteparams import ParamSource
    from hwbridge.links.discovery import SerialPort

__all__ = ["RobotRuntime", "RunningDevice"]

log = logging.getLogger("hwbridge.robot")

FIRST_OPEN_WAIT = 5.0
"""Seconds to wait for each board link's first open before saying it does not open."""


@dataclass
class RunningDevice:
    """A device whose host node runs."""

    device: DeviceConfig
    namespace: str
    node: Closeable | None


class RobotRuntime:
    """Runs one robot: a bridge for its boards and the host nodes of its devices."""

    def __init__(
        self,
        robot: Robot,
        graph: Graph | None = None,
        *,
        config: GraphConfig | None = None,
        params: dict[str, Any] | None = None,
        wait_for_boards: bool = False,
        list_ports: Callable[[], Sequence[SerialPort]] | None = None,
        param_source: ParamSource | None = None,
        run_boards: bool = True,
    ) -> None:
        """``list_ports`` lists the serial ports that ``usb:`` and ``auto`` links are resolved
        against when the robot starts (default: :func:`hwbridge.links.discovery.
        list_serial_ports`). ``param_source``: where the boards read parameters (default: the
        server this runtime's bridge hosts, with ``params`` in it). ``run_boards`` False: the
        boards and their devices' host nodes run elsewhere (shards of ``hwbridge up``, see
        :mod:`hwbridge.robot.shards`); their links are still resolved here."""
        self.robot = robot
        self._list_ports = list_ports
        self._own_graph = graph is None
        self.graph = graph if graph is not None else Graph(config or GraphConfig.embedded())
        self.bridge = Bridge(self.graph, params=params, param_source=param_source)
        self._run_boards = run_boards
        self.devices: list[RunningDevice] = []
        self._wait_for_boards = wait_for_boards
        self._stopped = threading.Event()

    def __enter__(self) -> RobotRuntime:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ life
    def start(self) -> RobotRuntime:
        """Start every board and host node; a problem that a user must fix (a link that does
        not open, a device that cannot start) stops what started and raises
        :class:`~hwbridge.robot.model.RobotFileError` naming the file and line."""
        try:
            self._resolve_links()
            self._start_boards()
            self._start_devices()
        except BaseException:
            self.stop()
            raise
        return self

    def _resolve_links(self) -> None:
        """Replace the ``usb:VID:PID`` and ``auto`` links with the ports they name now; a link
        that matches no port or several, or two links that name one port, is a RobotFileError
        naming the file and line."""
        from hwbridge.links.discovery import resolve_links

        linked = [(b.name, b.link, b.source, f"board {b.name}") for b in self.robot.boards]
        linked += [
            (h.device.name, h.link, h.source, f"host device {h.device.name}")
            for h in self.robot.host_devices
        ]
        results = resolve_links([(what, url) for _n, url, _s, what in linked], self._list_ports)
        problems: list[str] = []
        links: dict[str, str] = {}
        for name, url, source, what in linked:
            result = results.get(what)
            if result is None:
                continue
            where = source or str(self.robot.path)
            if result.problem is not None or result.resolved is None:
                hint = "" if result.shared else f" (--link {name}=URL gives another)"
                problems.append(f"{where}: {what}: {result.problem}{hint}")
                continue
            links[name] = result.resolved
            port = result.port
            log.info("%s: link %s is %s", what, url, port.describe() if port else result.resolved)
        if problems:
            raise RobotFileError(problems)
        self.robot = self.robot.with_links(links)

    def _robot_file_bytes(self) -> bytes | None:
        """The robot file's bytes, for the build tags of its boards' generated firmware (None:
        the robot was not read from a file)."""
        try:
            return self.robot.path.read_bytes() if self.robot.path.is_file() else None
        except OSError as exc:
            log.debug("%s: no build tags: %s", self.robot.path, exc)
            return None

    def _start_boards(self) -> None:
        if not self._run_boards:
            return
        problems: list[str] = []
        robot_bytes = self._robot_file_bytes()
        for board in self.robot.boards:
            spec = BoardSpec(
                board.link,
                protocol=board.protocol,
                baud=board.baud,
                namespace=board.namespace,
                name=board.name,
                start_delay=board.start_delay,
                service_timeout=board.service_timeout,
                build_tag=(
                    build_tag(self.robot.name, board.name, robot_bytes)
                    if robot_bytes is not None
                    else None
                ),
                robot_file=str(self.robot.path),
            )
            self.bridge.add_board(spec)
        if self._wait_for_boards:
            return
        for board in self.robot.boards:
            problem = self.bridge.boards[board.name].wait_first_open(FIRST_OPEN_WAIT)
            if problem is not None:
                problems.append(
                    f"{board.source or self.robot.path}: board {board.name}: link {board.link} "
                    f"does not open: {problem} (--link {board.name}=URL gives another; "
                    "--wait keeps waiting for it)"
                )
        if problems:
            raise RobotFileError(problems)

    def _start_devices(self) -> None:
        from hwbridge.robot.wiring import on_board

        for board in self.robot.boards if self._run_boards else ():
            for device in board.devices:
                if board.mcu is not None and not on_board(device, board.mcu):
                    continue  # only_on leaves it off this board's MCU board: not in its firmware
                self._start(device, board.namespace, board.name, None, None)
        for host in self.robot.host_devices:
            self._start(host.device, host.namespace, None, host.link, host.baud)

    def _start(
        self,
        device: DeviceConfig,
        namespace: str,
        board: str | None,
        link: str | None,
        baud: int | None,
    ) -> None:
        plugin = get_device(device.type)
        node_name = f"{board}_{device.name}" if board else device.name
        context = HostContext(
            graph=self.graph,
            node=self.graph.node(node_name, namespace=namespace),
            namespace=namespace,
            board=board,
            link=link,
            baud=baud,
            source=device.source,
        )
        try:
            started = plugin.host_node(device.settings, context)
        except HwBridgeError as exc:
            where = device.source or str(self.robot.path)
            raise RobotFileError([f"{where}: {device.type} {device.name}: {exc}"]) from exc
        self.devices.append(RunningDevice(device, namespace, started))
        if started is not None:
            log.info("%s: %s node in %s", device.name, device.type, namespace)

    def wait(self, timeout: float | None = None) -> bool:
        """Block until :meth:`stop` (True) or ``timeout`` (False)."""
        return self._stopped.wait(timeout)

    def stop(self) -> None:
        """Stop the host nodes, then the boards, then the graph if this runtime made it."""
        if self._stopped.is_set():
            return
        self._stopped.set()
        for running in reversed(self.devices):
            if running.node is not None:
                try:
                    running.node.close()
                except HwBridgeError as exc:
                    log.warning("%s: stopping its node failed: %s", running.device.name, exc)
        self.bridge.stop()
        if self._own_graph:
            self.graph.close()

    # ------------------------------------------------------------------ info
    def summary(self) -> str:
        """One line per board and host device, for the start-up message."""
        lines = [
            f"board {b.name} on {b.link} ({b.protocol}) in {b.namespace}: "
            + (", ".join(f"{d.name} ({d.type})" for d in b.devices) or "no devices")
            for b in self.robot.boards
        ]
        lines += [
            f"host device {h.device.name} ({h.device.type}) on {h.link} in {h.namespace}"
            for h in self.robot.host_devices
        ]
        return "\n".join(lines)
