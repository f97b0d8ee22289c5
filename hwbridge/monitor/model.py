"""What ``hwbridge monitor`` shows, gathered from the running graph as any client would:

* **boards**: the bridge's board announcements (``hwbridge board list``) and each board's info
  (``hwbridge board info/stats``): link state, protocol, frames, bytes, CRC errors, drops,
  retransmissions and round-trip time; byte rates from the change between two polls;
* **topics**: every topic with a publisher, subscribed raw (nothing decoded): messages per second
  and bytes per second over the last :data:`WINDOW` seconds, publishers and subscribers;
* **log**: the last lines on ``/rosout`` (board logs, node logs) and the diagnostics that are not
  OK on ``/diagnostics``.

:meth:`Monitor.poll` makes a :class:`Snapshot`; :mod:`hwbridge.monitor.view` draws it.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import json
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Final

from hwbridge.errors import HwBridgeError
from hwbridge.graph import ANY_TYPE, Graph, GraphEntity, RawMessage

__all__ = ["WINDOW", "BoardRow", "LogLine", "Monitor", "Snapshot", "TopicRow"]

WINDOW: Final = 3.0
"""Seconds over which topic rates are measured."""
_LOG_LEVELS: Final = {1: "DEBUG", 2: "INFO", 4: "WARN", 8: "ERROR", 16: "FATAL"}
_DIAGNOSTIC_LEVELS: Final = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}


@dataclass(frozen=True)
class BoardRow:
    name: str
    url: str
    protocol: str
    state: str
    stats: dict[str, Any]
    link: dict[str, Any]
    rx_rate: float | None = None
    """Bytes per second received over about the last WINDOW seconds of polls (None on the
    first poll)."""
    tx_rate: float | None = None
    error: str = ""

    @property
    def drops(self) -> int:
        """Everything the session counted as lost or dropped."""
        return sum(
            int(value)
            for key, value in self.stats.items()
            if isinstance(value, int) and ("lost" in key or "dropped" in key)
        )


@dataclass(frozen=True)
class TopicRow:
    name: str
    type: str
    rate: float
    """Messages per second over the window."""
    bandwidth: float
    """Bytes per second over the window."""
    messages: int
    publishers: int
    subscribers: int


@dataclass(frozen=True)
class LogLine:
    stamp: float
    level: str
    source: str
    text: str


@dataclass(frozen=True)
class Snapshot:
    time: float
    endpoint: str
    boards: list[BoardRow] = field(default_factory=list)
    topics: list[TopicRow] = field(default_factory=list)
    log: list[LogLine] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """The snapshot as JSON data (``hwbridge monitor --json``): rates in messages or bytes
        per second (``null`` before there are two polls), times in seconds since the epoch."""
        boards = [{**dataclasses.asdict(board), "drops": board.drops} for board in self.boards]
        return {
            "time": self.time,
            "endpoint": self.endpoint,
            "boards": boards,
            "topics": [dataclasses.asdict(topic) for topic in self.topics],
            "log": [dataclasses.asdict(line) for line in self.log],
        }


class _TopicCounter:
    def __init__(self) -> None:
        self.type = ""
        self.messages = 0
        self.recent: collections.deque[tuple[float, int]] = collections.deque()


class Monitor:
    """Watches ``graph`` (an attached client); call :meth:`poll` for each frame, then
    :meth:`close`."""

    def __init__(self, graph: Graph, *, log_lines: int = 8, board_timeout: float = 1.0) -> None:
        self.graph = graph
        self.board_timeout = board_timeout
        self._lock = threading.Lock()
        self._node = graph.node("hwbridge_monitor")
        self._entities: dict[tuple[str, str, str, str], int] = {}
        self._topics: dict[str, _TopicCounter] = {}
        self._subscribers: dict[str, Any] = {}
        self._log: collections.deque[LogLine] = collections.deque(maxlen=max(1, log_lines))
        self._history: dict[str, collections.deque[tuple[float, int, int]]] = {}
        """Board name -> (time, bytes received, bytes sent) over about the last WINDOW."""
        self._closed = False
        self._own = {"/rosout", "/diagnostics"}
        self._subscribers["/rosout"] = self._node.subscriber(
            "/rosout", "rosgraph_msgs/Log", self._on_log
        )
        self._subscribers["/diagnostics"] = self._node.subscriber(
            "/diagnostics", "diagnostic_msgs/DiagnosticArray", self._on_diagnostics
        )
        self._watch = graph.watch(self._on_entity)

    # ------------------------------------------------------------------ graph threads
    def _on_entity(self, entity: GraphEntity, alive: bool) -> None:
        if entity.node == self._node.name:
            return
        key = (entity.kind, entity.node, entity.name, entity.type)
        with self._lock:
            count = self._entities.get(key, 0) + (1 if alive else -1)
            if count > 0:
                self._entities[key] = count
            else:
                self._entities.pop(key, None)
            wanted = alive and entity.kind == "pub" and entity.name not in self._topics
            if wanted:
                self._topics[entity.name] = _TopicCounter()
        if wanted:
            self._subscribe(entity.name)

    def _subscribe(self, topic: str) -> None:
        try:
            subscriber = self._node.subscriber(
                topic, ANY_TYPE, functools.partial(self._on_message, topic), raw=True
            )
        except HwBridgeError:
            return
        with self._lock:
            if self._closed:
                keep = False
            else:
                keep = True
                self._subscribers.setdefault(topic, subscriber)
        if not keep:
            subscriber.close()

    def _on_message(self, topic: str, message: RawMessage) -> None:
        now = time.monotonic()
        with self._lock:
            counter = self._topics.get(topic)
            if counter is None:
                return
            counter.type = message.type or counter.type
            counter.messages += 1
            counter.recent.append((now, len(message.data)))
            while counter.recent and counter.recent[0][0] < now - WINDOW:
                counter.recent.popleft()

    def _on_log(self, message: Any) -> None:
        line = LogLine(
            _seconds(message.header.stamp),
            _LOG_LEVELS.get(int(message.level), str(message.level)),
            str(message.name),
            str(message.msg),
        )
        with self._lock:
            self._log.append(line)

    def _on_diagnostics(self, message: Any) -> None:
        stamp = _seconds(message.header.stamp)
        with self._lock:
            for status in message.status:
                if int(status.level) != 0:
                    level = _DIAGNOSTIC_LEVELS.get(int(status.level), str(status.level))
                    self._log.append(LogLine(stamp, level, str(status.name), str(status.message)))

    # ------------------------------------------------------------------ frames
    def poll(self) -> Snapshot:
        """A snapshot now: asks each board for its info (up to ``board_timeout`` each)."""
        now = time.monotonic()
        with self._lock:
            entities = list(self._entities)
            topics = {name: counter for name, counter in self._topics.items()}
            rows = []
            for name, counter in sorted(topics.items()):
                recent = [(t, n) for t, n in counter.recent if t >= now - WINDOW]
                span = WINDOW if counter.messages > len(recent) else _span(recent, now)
                publishers = sum(1 for e in entities if e[0] == "pub" and e[2] == name)
                subscribers = sum(1 for e in entities if e[0] == "sub" and e[2] == name)
                types = {e[3] for e in entities if e[0] == "pub" and e[2] == name}
                rows.append(
                    TopicRow(
                        name,
                        counter.type or ", ".join(sorted(types)),
                        len(recent) / span if span > 0 else 0.0,
                        sum(n for _, n in recent) / span if span > 0 else 0.0,
                        counter.messages,
                        publishers,
                        subscribers,
                    )
                )
            log = list(self._log)
        boards = sorted({(e[1], e[2], e[3]) for e in entities if e[0] == "board"})
        return Snapshot(
            time=time.time(),
            endpoint=self.graph.config.describe(),
            boards=[self._board(name, url, protocol) for name, url, protocol in boards],
            topics=rows,
            log=log,
        )

    def _board(self, name: str, url: str, protocol: str) -> BoardRow:
        try:
            info = self._board_info(name)
        except HwBridgeError as exc:
            return BoardRow(name, url, protocol, "?", {}, {}, error=str(exc))
        stats = dict(info.get("stats") or {})
        link = dict(info.get("link") or {})
        rx = int(stats.get("bytes_received", link.get("bytes_read", 0)) or 0)
        tx = int(stats.get("bytes_sent", link.get("bytes_written", 0)) or 0)
        now = time.monotonic()
        history = self._history.setdefault(name, collections.deque())
        if history and (rx < history[-1][1] or tx < history[-1][2]):
            history.clear()  # counters restarted (a new session)
        history.append((now, rx, tx))
        while len(history) > 2 and history[1][0] <= now - WINDOW:
            history.popleft()  # keep one sample at least WINDOW old, when there is one
        rx_rate = tx_rate = None
        first = history[0]
        if now - first[0] > 0.05:
            rx_rate = (rx - first[1]) / (now - first[0])
            tx_rate = (tx - first[2]) / (now - first[0])
        return BoardRow(
            name,
            str(info.get("url", url)),
            str(info.get("protocol") or protocol),
            str(info.get("state", "?")),
            stats,
            link,
            rx_rate,
            tx_rate,
        )

    def _board_info(self, name: str) -> dict[str, Any]:
        from hwbridge.bridge.board import board_key

        replies = self.graph.session.get(
            board_key(self.graph.prefix, name), timeout=self.board_timeout
        )
        for reply in replies:
            if reply.ok is not None:
                info: dict[str, Any] = json.loads(bytes(reply.ok.payload.to_bytes()))
                return info
            if reply.err is not None:
                raise HwBridgeError(reply.err.payload.to_string())
        raise HwBridgeError("no answer")

    def close(self) -> None:
        with self._lock:
            self._closed = True
            subscribers = list(self._subscribers.values())
        self.graph.forget(self._watch)
        for subscriber in subscribers:
            subscriber.close()
        token = getattr(self._node, "_token", None)
        if token is not None:
            self.graph.forget(token)

    def __enter__(self) -> Monitor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _span(recent: list[tuple[float, int]], now: float) -> float:
    """Seconds the rate is measured over while the topic is younger than the window."""
    if len(recent) < 2:
        return WINDOW
    return max(now - recent[0][0], 1e-3)


def _seconds(stamp: Any) -> float:
    sec = getattr(stamp, "sec", None)
    if sec is None:
        return float(stamp)
    return float(sec) + float(getattr(stamp, "nanosec", 0)) * 1e-9
