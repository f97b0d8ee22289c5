"""The graph's topics served to Foxglove over its WebSocket protocol (``hwbridge viz``, and
``hwbridge up --viz`` through :func:`start_viz`).

Each topic published on the graph becomes a Foxglove channel as soon as its first message
arrives: message encoding ``ros1`` (the bytes the graph carries, unchanged) and schema encoding
``ros1msg`` with the full ROS 1 definition of its type (the type's own text, then each type it
uses after a line of ``=`` and ``MSG: pkg/Type``, as rosbag and MCAP's ROS 1 profile write
it). So Foxglove's panels decode odometry, Range, Imu, JointState and ``/tf`` themselves. A type
this host has no definition of (or a different definition of: another md5) is left out, with
one warning naming it; ``--msg-path`` adds definitions.

Nothing is decoded here; topics nobody watches in Foxglove cost one Zenoh subscription each.
Needs the ``[viz]`` extra (``foxglove-sdk``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Final

from hwbridge.errors import HwBridgeError
from hwbridge.graph import ANY_TYPE, Graph, GraphEntity, RawMessage

__all__ = ["DEFAULT_PORT", "MESSAGE_ENCODING", "SCHEMA_ENCODING", "VizServer", "start_viz"]

log = logging.getLogger("hwbridge.viz")

DEFAULT_PORT: Final = 8765
"""Foxglove's usual WebSocket port."""
MESSAGE_ENCODING: Final = "ros1"
SCHEMA_ENCODING: Final = "ros1msg"


@dataclass
class _Topic:
    subscriber: Any
    channel: Any = None
    key: tuple[str, str] | None = None
    """(type, md5) the channel was made for."""
    messages: int = 0


class VizServer:
    """A running Foxglove WebSocket server fed from a graph. Use :func:`start_viz`."""

    def __init__(
        self,
        graph: Graph,
        *,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        topics: Iterable[str] | None = None,
        name: str = "hwbridge",
    ) -> None:
        try:
            import foxglove
        except ImportError as exc:
            raise HwBridgeError(
                "the Foxglove view needs foxglove-sdk: pip install 'hwbridge[viz]'"
            ) from exc
        self.graph = graph
        self.only = frozenset(topics) if topics else None
        self._foxglove = foxglove
        self._context = foxglove.Context()
        self._lock = threading.Lock()
        self._topics: dict[str, _Topic] = {}
        self._warned: set[tuple[str, str]] = set()
        self._closed = False
        try:
            self._server = foxglove.start_server(
                name=name, host=host, port=port, context=self._context
            )
        except Exception as exc:
            raise HwBridgeError(f"cannot serve Foxglove on {host}:{port}: {exc}") from exc
        self.host = host
        self.port: int = int(self._server.port)
        self._node = graph.node("hwbridge_viz")
        self._watch = graph.watch(self._on_entity)

    @property
    def url(self) -> str:
        """The address to open in Foxglove (Open connection, Foxglove WebSocket)."""
        host = "127.0.0.1" if self.host in ("", "0.0.0.0") else self.host
        return f"ws://{host}:{self.port}"

    def stats(self) -> dict[str, int]:
        """Messages forwarded per topic (topics with a channel only)."""
        with self._lock:
            return {t: s.messages for t, s in self._topics.items() if s.channel is not None}

    # ------------------------------------------------------------------ graph side
    def _on_entity(self, entity: GraphEntity, alive: bool) -> None:
        topic = entity.name
        if not alive or entity.kind != "pub" or not topic:
            return
        if self.only is not None and topic not in self.only:
            return
        with self._lock:
            if self._closed or topic in self._topics:
                return
            self._topics[topic] = _Topic(subscriber=None)
        try:
            subscriber = self._node.subscriber(topic, ANY_TYPE, self._on_message, raw=True)
        except HwBridgeError as exc:
            log.warning("cannot show %s in Foxglove: %s", topic, exc)
            return
        with self._lock:
            keep = not self.closed  # closed while subscribing: let go at once
            if keep:
                self._topics[topic].subscriber = subscriber
        if not keep:
            subscriber.close()

    @property
    def closed(self) -> bool:
        return self._closed

    def _on_message(self, message: RawMessage) -> None:
        received = time.time_ns()
        with self._lock:
            state = self._topics.get(message.topic)
            if state is None or self._closed:
                return
            key = (message.type, message.md5)
            if state.key != key:
                if state.channel is not None:
                    state.channel.close()  # the publisher changed its type: a new channel
                state.channel = self._channel(message)
                state.key = key
            channel = state.channel
            if channel is None:
                return
            state.messages += 1
        channel.log(message.data, log_time=received)

    def _channel(self, message: RawMessage) -> Any:
        definition = self._definition(message)
        if definition is None:
            return None
        foxglove = self._foxglove
        schema = foxglove.Schema(
            name=message.type, encoding=SCHEMA_ENCODING, data=definition.encode()
        )
        return foxglove.Channel(
            message.topic,
            schema=schema,
            message_encoding=MESSAGE_ENCODING,
            context=self._context,
            metadata={"md5sum": message.md5},
        )

    def _definition(self, message: RawMessage) -> str | None:
        registry = self.graph.registry
        problem = ""
        try:
            known = registry.message(message.type)
        except HwBridgeError:
            problem = "which this host has no definition of"
            mavlink = _mavlink_definition(message)
            if mavlink is not None:
                return mavlink
        else:
            if known.md5 == message.md5:
                return str(registry.definition(message.type))
            problem = f"with md5 {message.md5}, not this host's {known.md5}"
        if (message.type, message.md5) not in self._warned:
            self._warned.add((message.type, message.md5))
            log.warning(
                "not showing %s in Foxglove: type %s %s (add its package with --msg-path)",
                message.topic,
                message.type or "?",
                problem,
            )
        return None

    # ------------------------------------------------------------------ life
    def close(self) -> None:
        """Stop serving and leave the graph (the graph itself stays open)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            topics = list(self._topics.values())
        self.graph.forget(self._watch)
        token = getattr(self._node, "_token", None)  # the node's liveliness: gone with us
        if token is not None:
            self.graph.forget(token)
        for state in topics:
            if state.subscriber is not None:
                state.subscriber.close()
        self._server.stop()
        for state in topics:
            if state.channel is not None:
                state.channel.close()

    def __enter__(self) -> VizServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _mavlink_definition(message: RawMessage) -> str | None:
    """The definition of a raw MAVLink message type (``mavlink/Attitude``, published by the
    ``mavlink_vehicle`` device) when pymavlink is here and the md5 matches."""
    try:
        from hwbridge.mavlink.msgdefs import find_type
    except ImportError:
        return None
    found = find_type(message.type)
    return found.definition if found is not None and found.md5 == message.md5 else None


def start_viz(
    graph: Graph,
    *,
    host: str = "127.0.0.1",
    port: int = DEFAULT_PORT,
    topics: Iterable[str] | None = None,
) -> VizServer:
    """Serve ``graph``'s topics (all, or only ``topics``) to Foxglove on ``host:port`` (0: a free
    port; see ``.port``/``.url``). Call ``.close()`` before closing the graph."""
    return VizServer(graph, host=host, port=port, topics=topics)
