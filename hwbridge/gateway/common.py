"""What the ROS 2 and ROS 1 gateways share: choosing names, watching the graph, reporting once.

A gateway mirrors what lives on the hwbridge graph (boards' topics and services, host nodes'
topics) into ROS, and what ROS offers to the graph's subscribers back:

- a topic with a publisher on the graph (not the gateway's own) goes **graph -> ROS**;
- a topic with only subscribers on the graph (a board's ``cmd_vel``) goes **ROS -> graph**;
- a service served on the graph is served in ROS too (ROS clients call the board);
- ROS services named by ``--ros-service`` patterns are served on the graph (boards and graph
  nodes call ROS).

Names are chosen with shell patterns (``/diffbot/*``; ``*`` matches across ``/``), with
exclusions winning.
"""

from __future__ import annotations

import contextlib
import fnmatch
import logging
import queue
import threading
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Final, Protocol, TypeVar

from hwbridge.errors import HwBridgeError

if TYPE_CHECKING:
    from hwbridge.graph import Graph, GraphEntity

__all__ = [
    "ROSOUT",
    "Announcer",
    "GraphChange",
    "GraphWatcher",
    "MirrorOptions",
    "Reporter",
    "Selection",
    "apply_change",
    "close_all",
    "open_graph_with_retry",
    "run_until_stopped",
]

log = logging.getLogger("hwbridge.gateway")

ANY: Final = "*"
ROSOUT: Final = "/rosout"
GATEWAY_NODE: Final = "hwbridge_gateway"
"""Graph nodes whose names start with this are gateways: their entities are never mirrored, so
two gateways on one graph do not feed each other's mirrors back."""


@dataclass(frozen=True)
class Selection:
    """Shell patterns: a name is chosen if it matches an include and no exclude."""

    include: tuple[str, ...] = (ANY,)
    exclude: tuple[str, ...] = ()

    @classmethod
    def of(cls, include: Sequence[str] | None, exclude: Sequence[str] | None) -> Selection:
        return cls(tuple(include) if include else (ANY,), tuple(exclude or ()))

    def __call__(self, name: str) -> bool:
        if any(fnmatch.fnmatchcase(name, pattern) for pattern in self.exclude):
            return False
        return any(fnmatch.fnmatchcase(name, pattern) for pattern in self.include)


@dataclass
class MirrorOptions:
    """What a gateway mirrors, whatever the ROS. Patterns are shell patterns on graph/ROS
    names."""

    topics: Selection = field(default_factory=Selection)
    services: Selection = field(default_factory=Selection)
    ros_services: Selection = field(default_factory=lambda: Selection(()))
    """ROS services served on the graph (none unless named)."""
    node_name: str = GATEWAY_NODE
    service_timeout: float = 5.0
    rosout: bool = True
    """Board logs (the graph's ``/rosout``) to ROS's ``/rosout``, whatever ``topics`` says."""


class Reporter:
    """Logs each distinct problem once (a type that does not map, a ROS side that is down)."""

    def __init__(self) -> None:
        self._seen: set[str] = set()
        self._lock = threading.Lock()
        self.problems: list[str] = []

    def once(self, key: str, text: str, level: int = logging.WARNING) -> bool:
        with self._lock:
            if key in self._seen:
                return False
            self._seen.add(key)
            self.problems.append(text)
        log.log(level, "%s", text)
        return True

    def forget(self, key: str) -> None:
        """Let ``key`` be reported again (the problem went away)."""
        with self._lock:
            self._seen.discard(key)


@dataclass(frozen=True)
class GraphChange:
    """A topic or service the gateway should mirror, in the direction it says."""

    kind: str  # "to_ros" (graph publishes), "from_ros" (graph subscribes), "service"
    name: str
    type: str


@dataclass
class _Names:
    pubs: dict[str, dict[str, str]] = field(default_factory=dict)  # topic -> key -> type
    subs: dict[str, dict[str, str]] = field(default_factory=dict)
    services: dict[str, dict[str, str]] = field(default_factory=dict)


class GraphWatcher:
    """Follows the graph's discovery and queues :class:`GraphChange` items, one per name.

    The gateway's own entities (its Zenoh session) and those of any gateway node
    (:data:`GATEWAY_NODE`) are ignored. A topic is handed out once, in
    the first direction it qualifies for after a short settling time (so that a topic with both
    a publisher and subscribers on the graph goes graph -> ROS only, and nothing loops).
    """

    def __init__(
        self,
        graph: Graph,
        topics: Selection,
        services: Selection,
        settle: float = 0.3,
    ) -> None:
        self.graph = graph
        self.topics = topics
        self.services = services
        self.settle = settle
        self.changes: queue.Queue[GraphChange] = queue.Queue()
        self._names = _Names()
        self._handed: set[tuple[str, str]] = set()
        self._lock = threading.Lock()
        self._dirty = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="gateway-watch", daemon=True)

    def next_change(self, timeout: float) -> GraphChange | None:
        """The next change, waiting up to ``timeout`` s for one (None: none came)."""
        try:
            return self.changes.get(timeout=timeout)
        except queue.Empty:
            return None

    def claim(self, name: str, kind: str = "topic") -> None:
        """Take ``name`` out of the watch: the gateway handles it from the start (``/rosout``,
        whose graph publisher appears only with a board's first log line)."""
        with self._lock:
            self._handed.add((kind, name))

    def start(self) -> GraphWatcher:
        self.graph.watch(self._on_entity)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._dirty.set()
        self._thread.join(2)

    def _on_entity(self, entity: GraphEntity, alive: bool) -> None:
        if (
            entity.session == self.graph.zid
            or entity.kind not in ("pub", "sub", "srv")
            or entity.node.rsplit("/", 1)[-1].startswith(GATEWAY_NODE)
        ):
            return
        table = {
            "pub": self._names.pubs,
            "sub": self._names.subs,
            "srv": self._names.services,
        }[entity.kind]
        key = f"{entity.session}/{entity.node}"
        with self._lock:
            if alive:
                table.setdefault(entity.name, {})[key] = entity.type
            else:
                table.get(entity.name, {}).pop(key, None)
        self._dirty.set()

    def _run(self) -> None:
        while not self._stop.is_set():
            self._dirty.wait()
            if self._stop.wait(self.settle):
                return
            self._dirty.clear()
            for change in self._decide():
                self.changes.put(change)

    def _decide(self) -> list[GraphChange]:
        out: list[GraphChange] = []
        with self._lock:
            for topic, publishers in self._names.pubs.items():
                types = sorted(set(publishers.values()) - {ANY})
                if types and ("topic", topic) not in self._handed and self.topics(topic):
                    self._handed.add(("topic", topic))
                    out.append(GraphChange("to_ros", topic, types[0]))
            for topic, subscribers in self._names.subs.items():
                types = sorted(set(subscribers.values()) - {ANY})
                if (
                    types
                    and ("topic", topic) not in self._handed
                    and not self._names.pubs.get(topic)
                    and self.topics(topic)
                ):
                    self._handed.add(("topic", topic))
                    out.append(GraphChange("from_ros", topic, types[0]))
            for name, servers in self._names.services.items():
                types = sorted(set(servers.values()))
                if types and ("srv", name) not in self._handed and self.services(name):
                    self._handed.add(("srv", name))
                    out.append(GraphChange("service", name, types[0]))
        return out


def open_graph_with_retry(
    open_graph: Callable[[], Graph],
    stop: threading.Event,
    retry: float,
    announce: Callable[[str], None] | None,
) -> Graph | None:
    """Open the graph, retrying every ``retry`` s (saying so once) until it opens or ``stop``."""
    told = False
    while not stop.is_set():
        try:
            return open_graph()
        except HwBridgeError as exc:
            if not told and announce is not None:
                announce(f"hwbridge: waiting for the hwbridge graph: {exc}; retrying")
                told = True
            stop.wait(retry)
    return None


class Announcer:
    """Says what a gateway mirrors, one line each: to ``announce`` (the command's stderr) or,
    without one, to the log at INFO."""

    def __init__(self, announce: Callable[[str], None] | None, logger: logging.Logger) -> None:
        self._announce = announce
        self._log = logger

    def __call__(self, text: str, *args: object) -> None:
        line = text % args
        if self._announce is not None:
            self._announce(f"hwbridge: {line}")
        else:
            self._log.info("%s", line)


def claim_rosout(
    rosout: bool,
    exclude: Sequence[str],
    watcher: GraphWatcher,
    apply: Callable[[GraphChange], None],
) -> None:
    """Mirror the board logs to ``/rosout`` from the start (unless turned off or excluded), so
    the watcher never mirrors that topic the other way."""
    if rosout and Selection(exclude=tuple(exclude))(ROSOUT):
        watcher.claim(ROSOUT)
        apply(GraphChange("to_ros", ROSOUT, "rosgraph_msgs/Log"))


def apply_change(
    change: GraphChange,
    to_ros: Callable[[str, str], None],
    from_ros: Callable[[str, str], None],
    serve_in_ros: Callable[[str, str], None],
    report: Reporter,
    passes: tuple[type[HwBridgeError], ...] = (),
) -> None:
    """Hand ``change`` to the gateway's handler for its kind, each called with (name, type); a
    handler's error is reported once per name ('NAME: not mirrored: ...') and the name is left
    alone, except errors of the types in ``passes``: those are the caller's to report."""
    handler = {"to_ros": to_ros, "from_ros": from_ros}.get(change.kind, serve_in_ros)
    try:
        handler(change.name, change.type)
    except passes:
        raise
    except HwBridgeError as exc:
        report.once(f"name:{change.name}", f"{change.name}: not mirrored: {exc}")


def close_all(items: Iterable[object]) -> None:
    """Close each of ``items`` that has ``close()`` (a gateway's graph subscribers, services,
    publishers), ignoring their errors: the gateway is going away anyway."""
    for item in items:
        close = getattr(item, "close", None)
        if close is not None:
            with contextlib.suppress(Exception):
                close()


class _Gateway(Protocol):
    def close(self) -> None: ...


_G = TypeVar("_G", bound=_Gateway)


def run_until_stopped(
    open_graph: Callable[[], Graph],
    start: Callable[[Graph], _G],
    up_line: Callable[[_G, Graph], str],
    stop: threading.Event,
    retry: float,
    announce: Callable[[str], None] | None,
) -> None:
    """A gateway's life: join the graph (retrying while it is not there), ``start(graph)``,
    announce ``up_line``, mirror until ``stop``, then close the gateway and the graph."""
    graph = open_graph_with_retry(open_graph, stop, retry, announce)
    if graph is None:
        return
    try:
        gateway = start(graph)
        try:
            if announce is not None:
                announce(f"hwbridge: {up_line(gateway, graph)}; Ctrl-C stops")
            stop.wait()
        finally:
            gateway.close()
    finally:
        graph.close()
