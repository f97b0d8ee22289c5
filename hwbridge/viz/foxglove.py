"""The graph served to Foxglove-protocol viewers over WebSocket (``hwbridge viz``, and
``hwbridge up --viz`` through :func:`start_viz`).

Topics: each topic published on the graph becomes a channel as soon as its first message
arrives: message encoding ``ros1`` (the bytes the graph carries, unchanged) and schema encoding
``ros1msg`` with the full ROS 1 definition of its type (the type's own text, then each type it
uses after a line of ``=`` and ``MSG: pkg/Type``, as rosbag and MCAP's ROS 1 profile write it),
so panels decode odometry, Range, Imu, JointState and ``/tf`` themselves. A type this host has no
definition of (or another definition of: another md5) is left out with one warning naming it;
``--msg-path`` adds definitions.

What a viewer may do besides watching (the ``capabilities`` of ``serverInfo``):

* ``clientPublish``: a client advertises a topic with a ROS 1 type name (a Teleop panel's
  ``geometry_msgs/Twist`` on ``/diffbot/cmd_vel``) and sends messages in ``ros1`` bytes or
  ``json``; they are published on the graph under that type and its md5. A type this host does
  not know, or one that differs from the type the topic already has on the graph, is refused
  with a status message to the client and a log line.
* ``services``: the graph's services are advertised (request and response as ``ros1msg``
  schemas) and a call is forwarded to the graph; the answer goes back, or a failure with the
  reason (no server, timeout, the server's error).
* ``time``: the server's wall clock, twenty times a second (:data:`TIME_PERIOD`).

Why a server of our own on ``websockets`` and not foxglove-sdk's: the SDK's server answers only
clients that offer ``foxglove.sdk.v1`` and refuses with HTTP 400 those that offer the spec's
``foxglove.websocket.v1`` (``@foxglove/ws-protocol``, Lichtblick), it can refuse a subscription
sent right after a new channel's advertisement ("Unknown channel ID"), and a shim in front of it
would add a second hop per message. The protocol is small; ``tools/bench/viz.py`` measures this
server against the SDK's in one run (fed from the same graph, one viewer process): at a busy
robot's 500 messages/s both deliver everything with a p50 latency under a millisecond; in a
flood the SDK's Rust server moves about twice as many (roughly 9,500 against 5,000 messages/s on
the development machine), which is ten times what such a robot sends.

Threads: the WebSocket side runs an asyncio loop in a thread of its own; graph callbacks hand
their work to it (``call_soon_threadsafe``), so all protocol state lives on that one thread.
Each client has a bounded queue: when a slow client lets it fill, new message data for it is
dropped and counted (control messages are never dropped), with one log line per client.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final, TypeGuard

from hwbridge.errors import HwBridgeError
from hwbridge.graph import ANY_TYPE, Graph, GraphEntity, RawMessage
from hwbridge.viz import wsprotocol as wsp

if TYPE_CHECKING:
    from websockets.asyncio.server import Server, ServerConnection

    from hwbridge.graph.core import Publisher, Subscriber

__all__ = [
    "DEFAULT_PORT",
    "MESSAGE_ENCODING",
    "SCHEMA_ENCODING",
    "SUPPORTED_ENCODINGS",
    "VizServer",
    "start_viz",
]

log = logging.getLogger("hwbridge.viz")

DEFAULT_PORT: Final = 8765
"""Foxglove's usual WebSocket port."""
MESSAGE_ENCODING: Final = "ros1"
SCHEMA_ENCODING: Final = "ros1msg"
SUPPORTED_ENCODINGS: Final = ("ros1", "json")
"""What clients may publish and call services with (Teleop panels publish with one of these)."""
CAPABILITIES: Final = ("clientPublish", "services", "time")
TIME_PERIOD: Final = 0.05
_CLIENT_CLOSE_TIMEOUT: Final = 0.5
"""Seconds a viewer gets to answer the closing handshake when the server stops."""
_STOP_WAIT: Final = 1.0
"""Longest wait on close for the server's thread (Ctrl-C's promise is 2 s for everything)."""
"""Seconds between time broadcasts (viewers stamp what they receive with the latest one)."""
SERVICE_TIMEOUT: Final = 10.0
"""Seconds a forwarded service call may take."""
QUEUE_LIMIT: Final = 1024
"""Frames queued for one client before its new message data is dropped."""
_TEXT_LIMIT: Final = 200
"""Characters of an error shown in a status message."""


@dataclass
class _Topic:
    subscriber: Subscriber | None = None
    channel: dict[str, Any] | None = None
    """The advertised channel (as sent), or None while there is none."""
    key: tuple[str, str] | None = None
    """(type, md5) the channel was made for."""
    messages: int = 0


@dataclass
class _Service:
    id: int
    name: str
    type: str
    providers: set[tuple[str, str]] = field(default_factory=set)
    """(node, session) of each server seen."""
    advertised: bool = False
    md5: str = ""


@dataclass
class _ClientChannel:
    channel: wsp.ClientChannel
    type: str
    publisher: Publisher


class _Client:
    """One connected viewer: its subscriptions, its channels and its outgoing queue."""

    def __init__(self, ws: ServerConnection) -> None:
        self.ws = ws
        self.name = "{}:{}".format(*ws.remote_address[:2]) if ws.remote_address else "?"
        self.subscriptions: dict[int, int] = {}
        """subscription id -> channel id."""
        self.by_channel: dict[int, list[int]] = {}
        """channel id -> subscription ids."""
        self.channels: dict[int, _ClientChannel] = {}
        self.queue: deque[str | bytes] = deque()
        self.wake = asyncio.Event()
        self.dropped = 0
        self.told: set[str] = set()
        """Problems already sent as status messages (each is sent once)."""

    def send(self, frame: str | bytes) -> None:
        self.queue.append(frame)
        self.wake.set()

    def send_data(self, frame: bytes) -> None:
        if len(self.queue) >= QUEUE_LIMIT:
            if self.dropped == 0:
                log.warning(
                    "Foxglove client %s is not keeping up: dropping its message data "
                    "(%d frames queued)",
                    self.name,
                    len(self.queue),
                )
            self.dropped += 1
            return
        self.send(frame)

    def problem(self, text: str, level: int = wsp.STATUS_ERROR) -> None:
        """Tell the client (once per distinct text) and log it."""
        if text in self.told:
            return
        self.told.add(text)
        log.warning("Foxglove client %s: %s", self.name, text)
        self.send(wsp.status(level, text[:_TEXT_LIMIT]))

    async def write(self) -> None:
        from websockets.exceptions import ConnectionClosed

        try:
            while True:
                await self.wake.wait()
                self.wake.clear()
                while self.queue:
                    await self.ws.send(self.queue.popleft())
        except ConnectionClosed:
            return


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
            import websockets.asyncio.server  # noqa: F401
        except ImportError as exc:
            raise HwBridgeError(
                "the Foxglove view needs websockets: pip install 'hwbridge[viz]'"
            ) from exc
        self.graph = graph
        self.name = name
        self.host = host
        self.only = frozenset(topics) if topics else None
        self.session_id = uuid.uuid4().hex
        self._closed = False
        self._topics: dict[str, _Topic] = {}
        self._services: dict[str, _Service] = {}
        self._topic_types: dict[str, dict[tuple[str, str, str], str]] = {}
        """topic -> {(kind, node, session): type} of what the graph has on it."""
        self._clients: set[_Client] = set()
        self._warned: set[tuple[str, str]] = set()
        self._next_id = 0
        self._loop = _new_loop()
        self._stop = asyncio.Event()  # bound to the loop at its first use, in the loop
        self._ready = threading.Event()
        self._failures: list[BaseException] = []
        """Why the server could not start (set by its thread)."""
        self.port = port
        self._thread = threading.Thread(
            target=self._run, args=(host, port), name="hwbridge-viz", daemon=True
        )
        self._thread.start()
        try:
            self._ready.wait()
            if self._failures:
                self._thread.join()
                self._loop.close()
                failure = self._failures[0]
                raise HwBridgeError(
                    f"cannot serve Foxglove on {host}:{port}: {failure}"
                ) from failure
            self._node = graph.node("hwbridge_viz")
            self._zid = str(graph.zid)
            self._watch = graph.watch(self._on_entity)
        except KeyboardInterrupt:  # Ctrl-C in start-up: stop the server thread on the way out
            self._stop_loop()
            raise

    @property
    def url(self) -> str:
        """The address to open in Foxglove or Lichtblick (Open connection, Foxglove WebSocket)."""
        host = "127.0.0.1" if self.host in ("", "0.0.0.0") else self.host
        return f"ws://{host}:{self.port}"

    @property
    def closed(self) -> bool:
        return self._closed

    def stats(self) -> dict[str, int]:
        """Messages forwarded per topic (topics with a channel only)."""
        return {t: s.messages for t, s in list(self._topics.items()) if s.channel is not None}

    # ------------------------------------------------------------------ the loop's thread
    def _run(self, host: str, port: int) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._main(host, port))
        except BaseException as exc:  # noqa: BLE001 - handed to the constructor or logged
            if not self._ready.is_set():
                self._failures.append(exc)
            else:
                log.error("the Foxglove server stopped: %s", exc)
        finally:
            self._ready.set()

    async def _main(self, host: str, port: int) -> None:
        from websockets.asyncio.server import serve

        server: Server
        async with serve(
            self._serve_client,
            host,
            port,
            subprotocols=[wsp.SUBPROTOCOLS[0], wsp.SUBPROTOCOLS[1]],  # type: ignore[list-item]
            select_subprotocol=_select_subprotocol,
            compression=None,
            max_size=64 * 1024 * 1024,
            close_timeout=_CLIENT_CLOSE_TIMEOUT,
        ) as server:
            self.port = int(server.sockets[0].getsockname()[1])
            self._ready.set()
            ticker = asyncio.create_task(self._broadcast_time())
            await self._stop.wait()
            ticker.cancel()

    async def _broadcast_time(self) -> None:
        while True:
            frame = wsp.time_frame(time.time_ns())
            for client in self._clients:
                client.send_data(frame)
            await asyncio.sleep(TIME_PERIOD)

    async def _serve_client(self, ws: ServerConnection) -> None:
        client = _Client(ws)
        log.info("Foxglove client %s connected (%s)", client.name, ws.subprotocol)
        self._clients.add(client)
        client.send(
            wsp.server_info(
                self.name, CAPABILITIES, SUPPORTED_ENCODINGS, self.session_id, {"hwbridge": "1"}
            )
        )
        channels = [s.channel for s in self._topics.values() if s.channel is not None]
        if channels:
            client.send(wsp.advertise(channels))
        services = [_service_json(s, self.graph) for s in self._services.values() if s.advertised]
        if services:
            client.send(wsp.advertise_services(services))
        writer = asyncio.create_task(client.write())
        try:
            async for frame in ws:
                try:
                    if isinstance(frame, str):
                        self._on_text(client, frame)
                    else:
                        self._on_binary(client, frame)
                except wsp.ProtocolError as exc:
                    client.problem(str(exc))
        except Exception as exc:  # noqa: BLE001 - a broken connection ends that client only
            from websockets.exceptions import ConnectionClosed

            if not isinstance(exc, ConnectionClosed):
                log.warning("Foxglove client %s: %s", client.name, exc)
        finally:
            self._clients.discard(client)
            writer.cancel()
            for own in client.channels.values():
                own.publisher.close()
            dropped = f"; {client.dropped} messages dropped" if client.dropped else ""
            log.info("Foxglove client %s left%s", client.name, dropped)

    # ------------------------------------------------------------------ client messages
    def _on_text(self, client: _Client, frame: str) -> None:
        message = wsp.parse_text(frame)
        op = message["op"]
        if op == "subscribe":
            for item in wsp.objects(message, "subscriptions"):
                self._subscribe(client, item)
        elif op == "unsubscribe":
            for subscription in wsp.ints(message, "subscriptionIds"):
                channel_id = client.subscriptions.pop(subscription, None)
                if channel_id is not None:
                    ids = client.by_channel.get(channel_id, [])
                    if subscription in ids:
                        ids.remove(subscription)
        elif op == "advertise":
            for item in wsp.objects(message, "channels"):
                self._client_advertise(client, wsp.client_channel(item))
        elif op == "unadvertise":
            for channel_id in wsp.ints(message, "channelIds"):
                own = client.channels.pop(channel_id, None)
                if own is not None:
                    own.publisher.close()
        else:
            client.problem(f"operation '{op}' is not supported by this server", wsp.STATUS_WARNING)

    def _subscribe(self, client: _Client, item: Mapping[str, Any]) -> None:
        subscription, channel_id = item.get("id"), item.get("channelId")
        if not (_uint32(subscription) and _uint32(channel_id)):
            raise wsp.ProtocolError(
                "subscribe: each subscription needs 'id' and 'channelId' (uint32 numbers)"
            )
        if not any(
            s.channel is not None and s.channel["id"] == channel_id for s in self._topics.values()
        ):
            client.problem(f"subscribe: no channel {channel_id} (it may have been replaced)")
            return
        if subscription in client.subscriptions:
            client.problem(f"subscribe: subscription id {subscription} is already in use")
            return
        client.subscriptions[subscription] = channel_id
        client.by_channel.setdefault(channel_id, []).append(subscription)

    def _client_advertise(self, client: _Client, channel: wsp.ClientChannel) -> None:
        where = f"cannot publish {channel.topic} (channel {channel.id})"
        if channel.id in client.channels:
            client.problem(f"{where}: channel id {channel.id} is already advertised")
            return
        if channel.encoding not in SUPPORTED_ENCODINGS:
            client.problem(
                f"{where}: encoding '{channel.encoding}' is not one of "
                f"{', '.join(SUPPORTED_ENCODINGS)}"
            )
            return
        type_name = _ros1_type(channel.schema_name)
        try:
            self.graph.registry.message(type_name)
        except HwBridgeError:
            client.problem(
                f"{where}: this host has no definition of type '{channel.schema_name}' "
                "(add its package with --msg-path)"
            )
            return
        live = sorted(
            set(self._topic_types.get(channel.topic, {}).values()) - {type_name, ANY_TYPE, ""}
        )
        if live:
            client.problem(
                f"{where}: type {type_name}, but the topic has type {', '.join(live)} on the graph"
            )
            return
        try:
            publisher = self._node.publisher(channel.topic, type_name)
        except HwBridgeError as exc:
            client.problem(f"{where}: {exc}")
            return
        client.channels[channel.id] = _ClientChannel(channel, type_name, publisher)
        log.info("Foxglove client %s publishes %s (%s)", client.name, channel.topic, type_name)

    def _on_binary(self, client: _Client, frame: bytes) -> None:
        message = wsp.parse_binary(frame)
        if isinstance(message, wsp.ServiceCall):
            self._call(client, message)
            return
        own = client.channels.get(message.channel_id)
        if own is None:
            client.problem(f"message on channel {message.channel_id}, which it did not advertise")
            return
        try:
            data = _to_ros1(self.graph, own.type, own.channel.encoding, message.payload)
        except (HwBridgeError, ValueError) as exc:
            client.problem(f"not published on {own.channel.topic}: {_short(exc)}")
            return
        own.publisher.publish_raw(data)

    def _call(self, client: _Client, call: wsp.ServiceCall) -> None:
        service = next((s for s in self._services.values() if s.id == call.service_id), None)

        def fail(reason: str) -> None:
            log.warning("Foxglove client %s: service call failed: %s", client.name, reason)
            client.send(wsp.service_call_failure(call.service_id, call.call_id, reason))

        if service is None or not service.advertised:
            fail(f"no service with id {call.service_id}")
            return
        if call.encoding not in SUPPORTED_ENCODINGS:
            fail(f"{service.name}: encoding '{call.encoding}' is not ros1 or json")
            return
        asyncio.get_running_loop().create_task(self._forward_call(client, service, call, fail))

    async def _forward_call(
        self,
        client: _Client,
        service: _Service,
        call: wsp.ServiceCall,
        fail: Callable[[str], None],
    ) -> None:
        graph = self.graph
        try:
            srv = graph.registry.service(service.type)
            request = _to_ros1(graph, srv.request.name, call.encoding, call.payload)
            reply = await asyncio.get_running_loop().run_in_executor(
                None,
                lambda: self._node.call_raw(
                    service.name, service.type, request, SERVICE_TIMEOUT, md5=srv.md5
                ),
            )
            payload = _from_ros1(graph, srv.response.name, call.encoding, reply)
        except (HwBridgeError, ValueError) as exc:
            fail(f"{service.name}: {_short(exc)}")
            return
        client.send(
            wsp.service_call_response(call.service_id, call.call_id, call.encoding, payload)
        )

    # ------------------------------------------------------------------ graph side
    def _post(self, callback: Any, *args: Any) -> None:
        """Run ``callback(*args)`` on the loop's thread (nothing once closed)."""
        if self._closed:
            return
        try:
            self._loop.call_soon_threadsafe(callback, *args)
        except RuntimeError:  # the loop closed meanwhile
            return

    def _on_entity(self, entity: GraphEntity, alive: bool) -> None:
        if entity.name and entity.kind in ("pub", "sub", "srv"):
            self._post(self._entity, entity, alive)

    def _entity(self, entity: GraphEntity, alive: bool) -> None:
        if entity.node == self._node.name and entity.session == self._zid:
            return  # our own: the clients' publishers
        if entity.kind == "srv":
            self._track_service(entity, alive)
            return
        self._track_topic(entity, alive)
        topic = entity.name
        if not alive or entity.kind != "pub" or topic in self._topics:
            return
        if self.only is not None and topic not in self.only:
            return
        state = self._topics[topic] = _Topic()
        try:
            state.subscriber = self._node.subscriber(topic, ANY_TYPE, self._on_message, raw=True)
        except HwBridgeError as exc:
            log.warning("cannot show %s in Foxglove: %s", topic, exc)

    def _track_topic(self, entity: GraphEntity, alive: bool) -> None:
        seen = self._topic_types.setdefault(entity.name, {})
        key = (entity.kind, entity.node, entity.session)
        if alive:
            seen[key] = entity.type
        else:
            seen.pop(key, None)

    def _track_service(self, entity: GraphEntity, alive: bool) -> None:
        service = self._services.get(entity.name)
        if service is None:
            if not alive:
                return
            self._next_id += 1
            service = self._services[entity.name] = _Service(
                self._next_id, entity.name, entity.type
            )
        provider = (entity.node, entity.session)
        if alive:
            service.providers.add(provider)
        else:
            service.providers.discard(provider)
        if service.providers and not service.advertised:
            try:
                service.md5 = self.graph.registry.service(service.type).md5
            except HwBridgeError:
                if (service.name, service.type) not in self._warned:
                    self._warned.add((service.name, service.type))
                    log.warning(
                        "not offering service %s in Foxglove: this host has no definition of "
                        "type %s (add its package with --msg-path)",
                        service.name,
                        service.type or "?",
                    )
                return
            service.advertised = True
            self._broadcast(wsp.advertise_services([_service_json(service, self.graph)]))
        elif not service.providers and service.advertised:
            service.advertised = False
            self._broadcast(wsp.unadvertise_services([service.id]))
            del self._services[service.name]

    def _on_message(self, message: RawMessage) -> None:
        self._post(self._deliver, message, time.time_ns())

    def _deliver(self, message: RawMessage, received: int) -> None:
        state = self._topics.get(message.topic)
        if state is None:
            return
        key = (message.type, message.md5)
        if state.key != key:
            if state.channel is not None:  # the publisher changed its type: a new channel
                old = state.channel["id"]
                self._broadcast(wsp.unadvertise([old]))
                for client in self._clients:
                    for subscription in client.by_channel.pop(old, []):
                        client.subscriptions.pop(subscription, None)
            state.key = key
            state.channel = self._channel(message)
            if state.channel is not None:
                self._broadcast(wsp.advertise([state.channel]))
        channel = state.channel
        if channel is None:
            return
        state.messages += 1
        channel_id = channel["id"]
        for client in self._clients:
            for subscription in client.by_channel.get(channel_id, ()):
                client.send_data(wsp.message_data(subscription, received, message.data))

    def _broadcast(self, frame: str) -> None:
        for client in self._clients:
            client.send(frame)

    def _channel(self, message: RawMessage) -> dict[str, Any] | None:
        definition = self._definition(message)
        if definition is None:
            return None
        self._next_id += 1
        return {
            "id": self._next_id,
            "topic": message.topic,
            "encoding": MESSAGE_ENCODING,
            "schemaName": message.type,
            "schema": definition,
            "schemaEncoding": SCHEMA_ENCODING,
        }

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
        if self._closed:
            return
        self._closed = True
        self.graph.forget(self._watch)
        token = getattr(self._node, "_token", None)  # the node's liveliness: gone with us
        if token is not None:
            self.graph.forget(token)
        if not self._stop_loop():
            log.warning("the Foxglove server did not stop within %g s", _STOP_WAIT)
            return
        for state in self._topics.values():  # the loop's thread has ended: no one else here
            if state.subscriber is not None:
                state.subscriber.close()
        self._loop.close()

    def _stop_loop(self) -> bool:
        """Ask the server's loop to end and wait (at most :data:`_STOP_WAIT` s) for its thread;
        whether it ended."""
        with contextlib.suppress(RuntimeError):  # the loop already ended
            self._loop.call_soon_threadsafe(self._stop.set)  # runs first if _main has not begun
        self._thread.join(_STOP_WAIT)
        return not self._thread.is_alive()

    def __enter__(self) -> VizServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _new_loop() -> asyncio.AbstractEventLoop:
    """A new event loop, made on a thread of its own: a Ctrl-C (KeyboardInterrupt in the main
    thread) in the middle of making one would leave a half-made loop whose clean-up fails."""
    made: list[asyncio.AbstractEventLoop] = []
    maker = threading.Thread(target=lambda: made.append(asyncio.new_event_loop()))
    maker.start()
    maker.join()
    return made[0]


def _select_subprotocol(connection: Any, offered: Any) -> Any:
    """The first subprotocol the client offered that this server speaks (both are one
    protocol); HTTP 400 naming the accepted ones when there is none."""
    from websockets.exceptions import NegotiationError

    for name in offered:
        if name in wsp.SUBPROTOCOLS:
            return name
    raise NegotiationError(
        f"offered {', '.join(offered) or 'no subprotocol'}; this Foxglove WebSocket server "
        f"accepts {' or '.join(wsp.SUBPROTOCOLS)}"
    )


def _ros1_type(schema_name: str) -> str:
    """``pkg/msg/Type`` (ROS 2 style, as some clients write it) as ``pkg/Type``."""
    parts = schema_name.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        return f"{parts[0]}/{parts[2]}"
    return schema_name


def _to_ros1(graph: Graph, type_name: str, encoding: str, payload: bytes) -> bytes:
    """A client's payload as checked ROS 1 bytes of ``type_name``."""
    from hwbridge import msg as msgmod

    registry = graph.registry
    if encoding == "json":
        try:
            fields = json.loads(payload) if payload.strip() else {}
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"not JSON: {exc}") from None
        if not isinstance(fields, dict):
            raise ValueError(f"a JSON {type_name} must be an object")
        return msgmod.encode(msgmod.from_dict(type_name, fields, registry), type_name, registry)
    msgmod.decode(payload, type_name, registry)  # refuses bytes that are not a whole message
    return payload


def _from_ros1(graph: Graph, type_name: str, encoding: str, data: bytes) -> bytes:
    from hwbridge import msg as msgmod

    if encoding != "json":
        return data
    value = msgmod.to_dict(msgmod.decode(data, type_name, graph.registry))
    return json.dumps(value, default=str).encode()


def _service_json(service: _Service, graph: Graph) -> dict[str, Any]:
    registry = graph.registry
    srv = registry.service(service.type)
    halves: dict[str, Any] = {}
    for side, mtype in (("request", srv.request), ("response", srv.response)):
        definition = registry.definition(mtype.name)
        halves[side] = {
            "encoding": MESSAGE_ENCODING,
            "schemaName": mtype.name,
            "schemaEncoding": SCHEMA_ENCODING,
            "schema": definition,
        }
        halves[f"{side}Schema"] = definition  # what clients before the request/response fields read
    return {"id": service.id, "name": service.name, "type": service.type, **halves}


def _short(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return text if len(text) <= _TEXT_LIMIT else text[: _TEXT_LIMIT - 3] + "..."


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
    """Serve ``graph``'s topics (all, or only ``topics``) and services to Foxglove-protocol
    viewers on ``host:port`` (0: a free port; see ``.port``/``.url``). Call ``.close()`` before
    closing the graph."""
    return VizServer(graph, host=host, port=port, topics=topics)


def _uint32(value: Any) -> TypeGuard[int]:
    """Whether a JSON value is an id the protocol's binary frames can carry (not a bool)."""
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value < 1 << 32
