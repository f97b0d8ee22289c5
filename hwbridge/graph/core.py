"""The host graph on Eclipse Zenoh: nodes, topics, services and discovery.

A rospy user should feel at home::

    from hwbridge.graph import Graph

    with Graph.attached() as graph:                 # a bridge is running on this machine
        node = graph.node("listener")
        node.subscriber("/chatter", "std_msgs/String", lambda m: print(m.data))
        odom = node.wait_for_message("/odom", "nav_msgs/Odometry", timeout=2.0)
        reply = node.call("/board/reset", "std_srvs/Trigger", {}, timeout=1.0)

Topics carry ROS 1 serialized bytes with the type's md5 and name in the Zenoh attachment; a
subscriber that expects another md5 gets an error naming both types and never sees the bytes.
Raw publishers and subscribers (used by the bridge) move bytes without decoding them; a raw
publisher needs no definition of its type (a board may publish a type this host does not know).

Importing this module imports neither Zenoh nor the message registry: Zenoh is imported when a
graph opens, the registry (``hwbridge.msg``, rosbags) when something first needs a type.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import logging
import threading
import time
import weakref
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final

from hwbridge import errors
from hwbridge.errors import HwBridgeError, HwBridgeTimeoutError, ProtocolMismatchError
from hwbridge.graph.config import GraphConfig, open_error
from hwbridge.graph.guard import call_guarded
from hwbridge.graph.header import with_seq
from hwbridge.graph.names import decode_segment, encode_segment, resolve_name
from hwbridge.graph.params import ParamClient
from hwbridge.graph.snapshot import GraphEntity, GraphSnapshot
from hwbridge.graph.wire import attachment as _attachment
from hwbridge.graph.wire import parse_attachment as _parse_attachment

if TYPE_CHECKING:
    import zenoh

    from hwbridge.msg import MessageType, TypeRegistry

__all__ = [
    "ANY_TYPE",
    "DeferredReply",
    "Graph",
    "GraphEntity",
    "GraphSnapshot",
    "Node",
    "Publisher",
    "RawMessage",
    "ServiceError",
    "ServiceServer",
    "Subscriber",
]

log = logging.getLogger("hwbridge.graph")

ANY_TYPE: Final = "*"
"""Type given to a subscriber that takes whatever type the publishers send."""
_ZENOH_TIMEOUT: Final = "Timeout"
"""The error reply Zenoh gives a query whose time limit passed while a server was on it."""


class ServiceError(HwBridgeError):
    """A service server answered with an error, or refused the request."""


@dataclass(frozen=True, slots=True)
class RawMessage:
    """Bytes received on a topic, with the type the publisher declared."""

    topic: str
    type: str
    md5: str
    data: bytes


class Graph:
    """One Zenoh session and everything declared on it. Always close it (or use ``with``)."""

    def __init__(self, config: GraphConfig | None = None) -> None:
        import zenoh

        self.config = config or GraphConfig.attached()
        self.prefix = f"hwbridge/{encode_segment(self.config.domain)}"
        try:
            self.session: zenoh.Session = zenoh.open(self.config.to_zenoh())
        except zenoh.ZError as exc:
            raise open_error(self.config, exc) from exc
        self.zid = str(self.session.zid())
        self._lock = threading.Lock()
        self._closeables: list[Any] = []
        self._closed = False
        self._params: ParamClient | None = None
        self._alive: dict[str, GraphEntity] = {}
        self._discovery_started = False
        self._last_discovery_event = 0.0
        self._registry: TypeRegistry | None = None
        _OPEN_GRAPHS.add(self)
        log.debug("joined the graph as %s: %s", self.zid, self.config.describe())

    @classmethod
    def embedded(cls, listen: list[str] | None = None, domain: str | None = None) -> Graph:
        """Own the graph: a router on the loopback endpoint (see GraphConfig.embedded)."""
        return cls(GraphConfig.embedded(listen, domain))

    @classmethod
    def attached(cls, connect: list[str] | None = None, domain: str | None = None) -> Graph:
        """Join a running bridge's graph (see GraphConfig.attached)."""
        return cls(GraphConfig.attached(connect, domain))

    @property
    def registry(self) -> TypeRegistry:
        """Message types this graph encodes and decodes with (``hwbridge.msg.registry()``
        unless set); built on first use, so tools that only move bytes never load it."""
        if self._registry is None:
            from hwbridge import msg

            self._registry = msg.registry()
        return self._registry

    @registry.setter
    def registry(self, value: TypeRegistry) -> None:
        self._registry = value

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> Graph:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        """Undeclare everything and close the session (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            closeables, self._closeables = self._closeables, []
        for item in reversed(closeables):
            with contextlib.suppress(Exception):  # the session may already be gone
                item.undeclare()
        with contextlib.suppress(Exception):
            self.session.close()  # type: ignore[no-untyped-call]
        _OPEN_GRAPHS.discard(self)

    def keep(self, declaration: Any) -> Any:
        """Own ``declaration`` (anything with ``undeclare()`` made on :attr:`session`: a Zenoh
        publisher, subscriber, queryable, querier or liveliness token): it is undeclared when
        the graph closes, or at once (HwBridgeError) if the graph is already closed. Returns
        it, so ``pub = graph.keep(graph.session.declare_publisher(key))`` reads naturally.
        For code that uses the session directly next to the graph's own API."""
        with self._lock:
            if self._closed:
                with contextlib.suppress(Exception):
                    declaration.undeclare()
                raise HwBridgeError("the graph is closed")
            self._closeables.append(declaration)
        return declaration

    def forget(self, declaration: Any) -> None:
        """Undeclare something given to :meth:`keep` now, and stop owning it."""
        with self._lock:
            if declaration in self._closeables:
                self._closeables.remove(declaration)
        with contextlib.suppress(Exception):
            declaration.undeclare()

    _keep = keep
    """Old name of :meth:`keep`, kept for callers not yet moved (use ``keep``)."""
    _forget = forget
    """Old name of :meth:`forget`, kept for callers not yet moved (use ``forget``)."""

    # ------------------------------------------------------------------ keys
    def topic_key(self, topic: str) -> str:
        return f"{self.prefix}/t{topic}"

    def service_key(self, service: str) -> str:
        return f"{self.prefix}/s{service}"

    def announce(self, kind: str, node: str, name: str = "", type_name: str = "") -> Any:
        """Declare a liveliness token saying this entity is alive; returns it (undeclare it)."""
        parts = [kind, encode_segment(node)]
        if name or type_name:
            parts += [encode_segment(name), encode_segment(type_name)]
        key = f"{self.prefix}/@/{self.zid}/" + "/".join(parts)
        return self.keep(self.session.liveliness().declare_token(key))

    # ------------------------------------------------------------------ API
    def node(self, name: str, namespace: str = "/") -> Node:
        """A node: the owner of publishers, subscribers and services."""
        return Node(self, resolve_name(name, namespace), namespace)

    @property
    def params(self) -> ParamClient:
        """Client of the parameter server (hosted by the bridge)."""
        if self._params is None:
            self._params = ParamClient(self)
        return self._params

    def snapshot(self, timeout: float = 1.0, settle: float = 0.15) -> GraphSnapshot:
        """Everything alive on the graph now.

        Two sources are merged: a liveliness query, and a liveliness subscriber (with history)
        that this graph keeps from its first snapshot on. A liveliness query from a client has
        been seen to return nothing at all now and then, so the subscriber is the reliable part;
        on first use it waits until its history is quiet for ``settle`` s (at most ``timeout``).
        """
        self._start_discovery(timeout, settle)
        found: dict[str, GraphEntity] = {}
        replies = self.session.liveliness().get(f"{self.prefix}/@/**", timeout=timeout)
        for reply in replies:
            if reply.ok is not None:
                key = str(reply.ok.key_expr)
                entity = self._parse_entity(key)
                if entity is not None:
                    found[key] = entity
        with self._lock:
            found.update(self._alive)
        return GraphSnapshot(list(found.values()))

    def _start_discovery(self, timeout: float, settle: float) -> None:
        with self._lock:
            if self._discovery_started:
                return
            self._discovery_started = True

        def track(key: str, entity: GraphEntity, alive: bool) -> None:
            with self._lock:
                self._last_discovery_event = time.monotonic()
                if alive:
                    self._alive[key] = entity
                else:
                    self._alive.pop(key, None)

        self._watch_keys(track)
        started = time.monotonic()
        while time.monotonic() - started < timeout:
            time.sleep(settle / 3)
            if time.monotonic() - max(started, self._last_discovery_event) >= settle:
                break

    def watch(self, callback: Callable[[GraphEntity, bool], None]) -> Any:
        """Call ``callback(entity, alive)`` as entities appear and disappear (history included)."""
        return self._watch_keys(lambda _key, entity, alive: callback(entity, alive))

    def _watch_keys(self, callback: Callable[[str, GraphEntity, bool], None]) -> Any:
        import zenoh

        def on_sample(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            entity = self._parse_entity(key)
            if entity is not None and not self._closed:
                alive, closed = sample.kind == zenoh.SampleKind.PUT, lambda: self._closed
                call_guarded(callback, key, entity, alive, closed=closed)

        return self.keep(
            self.session.liveliness().declare_subscriber(
                f"{self.prefix}/@/**", on_sample, history=True
            )
        )

    def _parse_entity(self, key: str) -> GraphEntity | None:
        rest = key[len(self.prefix) + len("/@/") :].split("/")
        if len(rest) not in (3, 5):
            return None
        session, kind, node = rest[0], rest[1], decode_segment(rest[2])
        name = decode_segment(rest[3]) if len(rest) == 5 else ""
        type_name = decode_segment(rest[4]) if len(rest) == 5 else ""
        return GraphEntity(kind, node, name, type_name, session)


_OPEN_GRAPHS: weakref.WeakSet[Graph] = weakref.WeakSet()


def _close_open_graphs() -> None:
    """Close every graph still open when the interpreter exits.

    Zenoh runs callbacks on a non-daemon Python thread, which the interpreter joins before it
    runs ``atexit`` handlers: an open session with callback subscribers would hang exit. So the
    hook goes into ``threading``'s own exit list, which runs before that join (as
    ``concurrent.futures`` does), with plain ``atexit`` as a fallback.
    """
    for graph in list(_OPEN_GRAPHS):
        graph.close()


_register_exit = getattr(threading, "_register_atexit", None)
if callable(_register_exit):
    _register_exit(_close_open_graphs)
else:  # pragma: no cover - other interpreters
    atexit.register(_close_open_graphs)


class Node:
    """A named participant; topic and service names resolve in its namespace."""

    max_queriers: int = 64
    """Queriers kept declared for calls, one per service, type and timeout; then one-off gets."""

    def __init__(self, graph: Graph, name: str, namespace: str = "/") -> None:
        self.graph = graph
        self.name = name
        self.namespace = namespace
        self._token = graph.announce("node", name)
        self._call_targets: dict[
            tuple[str, str, str | None, float], tuple[str, Callable[..., Any], bytes]
        ] = {}
        """(name, type, md5, timeout) -> (resolved name, querier's get, attachment)."""
        self._lock = threading.Lock()

    def resolve(self, name: str) -> str:
        return resolve_name(name, self.namespace, self.name.rsplit("/", 1)[-1])

    def _message_type(self, type_name: str) -> MessageType:
        return self.graph.registry.message(type_name)

    # ------------------------------------------------------------------ topics
    def publisher(
        self, topic: str, type_name: str, *, drop_when_congested: bool = False
    ) -> Publisher:
        """Publish messages of ``type_name`` on ``topic``."""
        mtype = self._message_type(type_name)
        return Publisher(self, self.resolve(topic), mtype, drop_when_congested)

    def raw_publisher(self, topic: str, type_name: str, md5: str) -> Publisher:
        """Publish bytes that are already serialized (the bridge's path): type and md5 as given.

        The type needs no definition here: subscribers see ``type_name`` and ``md5`` as given
        (``hwbridge topic echo`` shows the bytes of a type it cannot decode)."""
        from hwbridge.msg import MessageType

        mtype = MessageType(name=type_name, md5=md5, source="raw", store_name="")
        return Publisher(self, self.resolve(topic), mtype, False)

    def subscriber(
        self,
        topic: str,
        type_name: str,
        callback: Callable[[Any], None],
        *,
        raw: bool = False,
        on_error: Callable[[HwBridgeError], None] | None = None,
    ) -> Subscriber:
        """Call ``callback`` for each message on ``topic``.

        ``type_name`` may be ``ANY_TYPE`` to take whatever is published. With ``raw=True`` the
        callback gets a :class:`RawMessage` (no decoding); otherwise a message object.
        """
        expected = None if type_name == ANY_TYPE else self._message_type(type_name)
        return Subscriber(self, self.resolve(topic), expected, callback, raw, on_error)

    def wait_for_message(self, topic: str, type_name: str, timeout: float = 5.0) -> Any:
        """Block until one message arrives on ``topic``; HwBridgeTimeoutError after ``timeout``."""
        arrived = threading.Event()
        box: list[Any] = []
        errors: list[HwBridgeError] = []

        def take(message: Any) -> None:
            if not arrived.is_set():
                box.append(message)
                arrived.set()

        def fail(error: HwBridgeError) -> None:
            errors.append(error)
            arrived.set()

        sub = self.subscriber(topic, type_name, take, on_error=fail)
        try:
            if not arrived.wait(timeout):
                raise HwBridgeTimeoutError(
                    f"no message on {self.resolve(topic)} within {timeout:g} s"
                )
        finally:
            sub.close()
        if box:
            return box[0]
        raise errors[0]

    # ------------------------------------------------------------------ services
    def service(
        self,
        name: str,
        srv_type: str,
        handler: Callable[[Any], Any],
        *,
        raw: bool = False,
    ) -> ServiceServer:
        """Serve ``name``: ``handler(request) -> response`` (bytes in and out with ``raw``)."""
        return ServiceServer(self, self.resolve(name), srv_type, handler, raw)

    def deferred_service(
        self, name: str, srv_type: str, handler: Callable[[bytes, DeferredReply], None]
    ) -> ServiceServer:
        """Serve ``name`` with raw bytes, answering later: ``handler(request, reply)`` returns
        at once and ``reply.ok(bytes)`` or ``reply.error(text)`` is called from any thread.
        (The bridge uses this so a board's answer goes out from the thread that reads it.)"""
        return ServiceServer(self, self.resolve(name), srv_type, handler, True, deferred=True)

    def call(self, name: str, srv_type: str, request: Any, timeout: float = 5.0) -> Any:
        """Call a service and return the decoded response. ``request`` is a message object or a
        dict; errors: ServiceError (the server refused or failed), HwBridgeTimeoutError (no
        answer in time), its subclass NoServerError (no server took the request)."""
        from hwbridge import msg as msgmod

        service = self.graph.registry.service(srv_type)
        if isinstance(request, Mapping):
            request = msgmod.from_dict(service.request.name, request, self.graph.registry)
        data = msgmod.encode(request, service.request.name, self.graph.registry)
        reply = self.call_raw(name, srv_type, data, timeout, md5=service.md5)
        return msgmod.decode(reply, service.response.name, self.graph.registry)

    def call_raw(
        self, name: str, srv_type: str, data: bytes, timeout: float = 5.0, md5: str | None = None
    ) -> bytes:
        """Call a service with serialized request bytes; returns the response bytes."""
        found = self._call_targets.get((name, srv_type, md5, timeout))
        resolved, get, attachment = found or self._call_target(name, srv_type, md5, timeout)
        started = time.monotonic()
        for reply in get(payload=data, attachment=attachment):
            if reply.ok is not None:
                return bytes(reply.ok.payload.to_bytes())
            if reply.err is not None:
                text = reply.err.payload.to_string()
                if text == _ZENOH_TIMEOUT:
                    raise HwBridgeTimeoutError(
                        f"no answer from service {resolved} within {timeout:g} s: its server "
                        "is still at work or stuck (give a longer timeout if it is slow)"
                    )
                raise ServiceError(f"{resolved}: {text}")
        early = time.monotonic() - started < 0.9 * timeout  # no server took the query
        what = "no server answered" if early else f"no answer within {timeout:g} s from"
        raise (errors.NoServerError if early else HwBridgeTimeoutError)(
            f"{what} service {resolved} (is its server running? see 'hwbridge service list')"
        )

    def _call_target(
        self, name: str, srv_type: str, md5: str | None, timeout: float
    ) -> tuple[str, Callable[..., Any], bytes]:
        """What a call needs, worked out once per (service, type, md5, timeout): the resolved
        name, a Zenoh querier (declared once: ~10 us a call less than a ``get``), the attachment."""
        import zenoh

        resolved = self.resolve(name)
        attachment = _attachment(md5 or self.graph.registry.service(srv_type).md5, srv_type)
        key = self.graph.service_key(resolved)
        # Express: a query that waits for Zenoh's batching can wait its whole time limit (1 ms).
        # Unconsolidated: Zenoh's default holds a reply until the server lets the query go.
        options: dict[str, Any] = {
            "target": zenoh.QueryTarget.BEST_MATCHING,
            "consolidation": zenoh.ConsolidationMode.NONE,
            "timeout": timeout,
            "express": True,
        }
        session = self.graph.session
        with self._lock:
            found = self._call_targets.get((name, srv_type, md5, timeout))
            if found is not None:
                return found
            if len(self._call_targets) >= self.max_queriers:
                # Many distinct timeouts (computed ones, say): plain gets, nothing declared.
                return resolved, functools.partial(session.get, key, **options), attachment
            querier = self.graph.keep(session.declare_querier(key, **options))
            target = (resolved, querier.get, attachment)
            self._call_targets[name, srv_type, md5, timeout] = target
        return target


class Publisher:
    """Publishes on one topic. ``publish`` takes a message or dict; ``publish_raw`` bytes."""

    def __init__(
        self, node: Node, topic: str, mtype: MessageType, drop_when_congested: bool
    ) -> None:
        import zenoh

        self.node = node
        self.topic = topic
        self.type = mtype
        self.sent = 0
        self.dropped_after_close = 0
        """Publishes that came after :meth:`close` (or the graph's close) and were dropped: a
        callback still running while its node shuts down."""
        self._closed = False
        graph = node.graph
        congestion = (
            zenoh.CongestionControl.DROP if drop_when_congested else zenoh.CongestionControl.BLOCK
        )
        self._publisher = graph.keep(
            graph.session.declare_publisher(graph.topic_key(topic), congestion_control=congestion)
        )
        self._attachment = _attachment(mtype.md5, mtype.name)
        self._token = graph.announce("pub", node.name, topic, mtype.name)

    def publish(self, message: Any) -> None:
        """Serialize and publish a message object (or a dict of its fields); a header's seq
        of 0 becomes the publisher's count (1, 2, ...), as rospy does."""
        from hwbridge import msg as msgmod

        registry = self.node.graph.registry
        if isinstance(message, Mapping):
            message = msgmod.from_dict(self.type.name, message, registry)
        data = msgmod.encode(message, self.type.name, registry)
        self.publish_raw(with_seq(registry, self.type.name, data, self.sent + 1))

    def publish_raw(self, data: bytes | bytearray | memoryview) -> None:
        """Publish bytes already in ROS 1 serialization of this publisher's type. After a
        close (of it or its graph) they are dropped and counted in :attr:`dropped_after_close`:
        a callback still running while its node shuts down is not an error."""
        import zenoh

        if self.closed:
            self._drop_after_close()
            return
        try:
            self._publisher.put(
                data if type(data) is bytes else bytes(data), attachment=self._attachment
            )
        except zenoh.ZError:
            if not (self._closed or self.node.graph.closed):  # not closed while putting
                raise
            self._drop_after_close()
            return
        self.sent += 1

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` (or the graph's close) has run (read afresh: a close races a
        put)."""
        return self._closed or self.node.graph.closed

    def _drop_after_close(self) -> None:
        self.dropped_after_close += 1
        log.debug("%s: dropped a message published after close", self.topic)

    @property
    def has_subscribers(self) -> bool:
        """Whether any subscriber on the graph matches this topic now."""
        return bool(self._publisher.matching_status.matching)

    def wait_for_subscribers(self, timeout: float, stop: threading.Event | None = None) -> bool:
        """Wait until a subscriber matches (declarations travel asynchronously); False after
        ``timeout`` or as soon as ``stop`` (if given) is set."""
        deadline = time.monotonic() + timeout
        pause = stop if stop is not None else threading.Event()
        while not self.has_subscribers:
            if time.monotonic() >= deadline or pause.is_set():
                return False
            pause.wait(0.01)
        return True

    def close(self) -> None:
        self._closed = True
        self.node.graph.forget(self._publisher)
        self.node.graph.forget(self._token)


class Subscriber:
    """Receives one topic; counts what it could not deliver."""

    def __init__(
        self,
        node: Node,
        topic: str,
        expected: MessageType | None,
        callback: Callable[[Any], None],
        raw: bool,
        on_error: Callable[[HwBridgeError], None] | None,
    ) -> None:
        self.node = node
        self.topic = topic
        self.expected = expected
        self.received = 0
        self.type_mismatches = 0
        self.decode_errors = 0
        self._callback = callback
        self._raw = raw
        self._on_error = on_error
        self._reported: set[str] = set()
        graph = node.graph
        self._subscriber = graph.keep(
            graph.session.declare_subscriber(graph.topic_key(topic), self._on_sample)
        )
        type_label = expected.name if expected else ANY_TYPE
        self._token = graph.announce("sub", node.name, topic, type_label)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        md5, type_name = _parse_attachment(
            sample.attachment.to_bytes() if sample.attachment is not None else None
        )
        expected = self.expected
        if expected is not None and md5 != expected.md5:
            self.type_mismatches += 1
            self._fail(
                md5,
                ProtocolMismatchError(
                    f"topic {self.topic}: publisher sends {type_name or '?'} (md5 {md5 or '?'}), "
                    f"this subscriber expects {expected.name} (md5 {expected.md5})"
                ),
            )
            return
        data = sample.payload.to_bytes()
        self.received += 1
        if self._raw:
            call_guarded(self._callback, RawMessage(self.topic, type_name, md5, data))
            return
        from hwbridge import msg as msgmod

        try:
            message = msgmod.decode(
                data, expected.name if expected else type_name, self.node.graph.registry
            )
        except HwBridgeError as exc:
            self.decode_errors += 1
            self._fail(f"decode:{type_name}", exc)
            return
        call_guarded(self._callback, message)

    def _fail(self, key: str, error: HwBridgeError) -> None:
        if self._on_error is not None:
            call_guarded(self._on_error, error)
        elif key not in self._reported:
            self._reported.add(key)
            log.error("%s (further errors of this kind are counted, not logged)", error)

    def close(self) -> None:
        self.node.graph.forget(self._subscriber)
        self.node.graph.forget(self._token)


class ServiceServer:
    """Answers one service; handler exceptions become error replies, never silence."""

    def __init__(
        self,
        node: Node,
        name: str,
        srv_type: str,
        handler: Callable[..., Any],
        raw: bool,
        deferred: bool = False,
    ) -> None:
        self.node = node
        self.name = name
        self.service = node.graph.registry.service(srv_type)
        self.calls = 0
        self.failures = 0
        self._handler = handler
        self._raw = raw
        self._deferred = deferred
        import zenoh

        graph = node.graph
        self.key = zenoh.KeyExpr(graph.service_key(name))
        """The service's key, built once: replies carry it (a queryable of one concrete key is
        asked on that key only)."""
        self._queryable = graph.keep(graph.session.declare_queryable(self.key, self._on_query))
        self._token = graph.announce("srv", node.name, name, srv_type)

    def _on_query(self, query: zenoh.Query) -> None:
        attachment = query.attachment  # each access builds a new object: read once
        md5, type_name = _parse_attachment(
            attachment.to_bytes() if attachment is not None else None
        )
        service = self.service
        if md5 != service.md5:
            self.failures += 1
            query.reply_err(
                f"type mismatch: caller uses {type_name or '?'} (md5 {md5 or '?'}), "
                f"server {self.name} serves {service.name} (md5 {service.md5})"
            )
            return
        payload = query.payload
        data = payload.to_bytes() if payload is not None else b""
        self.calls += 1
        if self._deferred:
            reply = DeferredReply(query, self)
            try:
                self._handler(data, reply)
            except Exception as exc:  # noqa: BLE001 - any handler failure goes back to the caller
                reply.error(f"{type(exc).__name__}: {exc}")
            return
        try:
            if self._raw:
                answer = bytes(self._handler(data))
            else:
                from hwbridge import msg as msgmod

                registry = self.node.graph.registry
                request = msgmod.decode(data, service.request.name, registry)
                response = self._handler(request)
                if isinstance(response, Mapping) or response is None:
                    response = msgmod.from_dict(service.response.name, response or {}, registry)
                answer = msgmod.encode(response, service.response.name, registry)
        except Exception as exc:  # noqa: BLE001 - any handler failure goes back to the caller
            self.failures += 1
            log.warning("service %s failed: %s", self.name, exc)
            query.reply_err(f"{type(exc).__name__}: {exc}")
            return
        query.reply(self.key, answer, express=True)  # a caller waits: no batching delay

    def close(self) -> None:
        self.node.graph.forget(self._queryable)
        self.node.graph.forget(self._token)


class DeferredReply:
    """The answer to one call of a deferred service, given later from any thread (once)."""

    __slots__ = ("_query", "_server")

    def __init__(self, query: zenoh.Query, server: ServiceServer) -> None:
        self._query = [query]  # list.pop hands it to one answer, from any thread, lock-free
        self._server = server

    def _finish(self) -> zenoh.Query | None:
        # (try, not contextlib.suppress: 0.16 against 1.08 us, once per answer a board gives)
        try:
            return self._query.pop()
        except IndexError:  # answered already
            return None

    def ok(self, payload: bytes) -> None:
        """Send the response bytes (ignored if an answer was already given)."""
        query = self._finish()
        if query is not None:
            query.reply(self._server.key, payload, express=True)
            query.drop()  # type: ignore[no-untyped-call]

    def error(self, text: str) -> None:
        """Fail the call with ``text`` (ignored if an answer was already given)."""
        query = self._finish()
        if query is not None:
            self._server.failures += 1
            log.warning("service %s failed: %s", self._server.name, text)
            query.reply_err(text)
            query.drop()  # type: ignore[no-untyped-call]
