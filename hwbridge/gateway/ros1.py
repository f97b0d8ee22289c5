"""The ROS 1 gateway: the hwbridge graph's topics and services in a ROS 1 master's graph.

Pass-through: the graph already carries ROS 1 bytes with their md5 and type name, which is what
TCPROS carries, so any type works without message classes (a board's own ``hwbridge_msgs`` too).
The gateway is one ROS 1 node (:mod:`hwbridge.gateway.tcpros`, no rospy needed):

- graph publishers -> ROS publications (``rostopic echo`` sees the board);
- graph subscribers (a board's ``cmd_vel``) -> ROS subscriptions (``rostopic pub`` drives it);
- graph services -> ROS services (``rosservice call``), ROS services chosen by pattern -> graph;
- ``/rosout``: board logs are published there, so ``rosout`` aggregates them;
- ``--param NAMESPACE``: the parameter server's values under it are copied to the graph's
  parameters (and so to boards), and followed.

The master is watched every second: when it is not running the gateway says so once and waits;
when it comes back (or restarts, a new pid) everything is registered again.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final

from hwbridge.errors import HwBridgeError
from hwbridge.gateway.common import (
    ANY,
    Announcer,
    GraphChange,
    GraphWatcher,
    MirrorOptions,
    Reporter,
    apply_change,
    claim_rosout,
    close_all,
    run_until_stopped,
)
from hwbridge.gateway.tcpros import (
    MasterDown,
    MasterProxy,
    SlaveServer,
    TcprosError,
    call_service,
    encode_header,
    local_host,
    probe_service,
    read_frame,
    read_header,
    xmlrpc_proxy,
)

if TYPE_CHECKING:
    from hwbridge.graph import DeferredReply, Graph, Node, Publisher, RawMessage

__all__ = ["Ros1Gateway", "Ros1Options", "run_ros1_gateway"]

log = logging.getLogger("hwbridge.gateway.ros1")

_CHECK_PERIOD: Final = 1.0
_CLOSE_JOIN: Final = 1.0
"""Longest wait on close for the gateway's thread to finish what it is doing."""
_UNREGISTER_BUDGET: Final = 0.5
"""Seconds on close for unregistering from the master, all calls together."""
_SEND_TIMEOUT: Final = 2.0
"""Seconds a ROS subscriber may keep a message waiting before it is disconnected."""


@dataclass
class Ros1Options(MirrorOptions):
    """What to mirror (:class:`~hwbridge.gateway.common.MirrorOptions`), the master to use and
    the parameters to copy to the graph."""

    master_uri: str = "http://127.0.0.1:11311"
    params: tuple[str, ...] = ()


class _Publication:
    """A ROS topic this node publishes: the TCPROS connections of its subscribers."""

    def __init__(self, topic: str, type_name: str, md5: str, definition: str) -> None:
        self.topic = topic
        self.type = type_name
        self.md5 = md5
        self.definition = definition
        self.connections: list[socket.socket] = []
        self.lock = threading.Lock()
        self.sent = 0

    def publish(self, data: bytes) -> None:
        frame = len(data).to_bytes(4, "little") + data
        with self.lock:
            connections = list(self.connections)
        for conn in connections:
            try:
                conn.sendall(frame)
            except OSError:
                with self.lock:
                    if conn in self.connections:
                        self.connections.remove(conn)
                with contextlib.suppress(OSError):
                    conn.close()
        self.sent += 1

    def close(self) -> None:
        with self.lock:
            connections, self.connections = self.connections, []
        for conn in connections:
            with contextlib.suppress(OSError):
                conn.close()


class _Subscription:
    """A ROS topic this node subscribes to: one reader thread per publisher."""

    def __init__(
        self,
        topic: str,
        type_name: str,
        md5: str,
        caller_id: str,
        deliver: Callable[[bytes, dict[str, str]], None],
        refused: Callable[[str], None],
    ) -> None:
        self.refused = refused
        self.topic = topic
        self.type = type_name
        self.md5 = md5
        self.caller_id = caller_id
        self.deliver = deliver
        self.readers: dict[str, socket.socket | None] = {}
        self.lock = threading.Lock()
        self.closed = False

    def update(self, publishers: list[str]) -> None:
        with self.lock:
            wanted = set(publishers)
            gone = [uri for uri in self.readers if uri not in wanted]
            for uri in gone:
                sock = self.readers.pop(uri)
                if sock is not None:
                    with contextlib.suppress(OSError):
                        sock.shutdown(socket.SHUT_RDWR)
            new = [uri for uri in publishers if uri not in self.readers]
            for uri in new:
                self.readers[uri] = None
        for uri in new:
            threading.Thread(target=self._read, args=(uri,), name="ros1-sub", daemon=True).start()

    def _read(self, uri: str) -> None:
        try:
            proxy = xmlrpc_proxy(uri)
            answer: Any = proxy.requestTopic(self.caller_id, self.topic, [["TCPROS"]])
            code, text, protocol = answer
            if code != 1 or not protocol or protocol[0] != "TCPROS":
                raise TcprosError(f"{uri} refused {self.topic}: {text}")
            sock = socket.create_connection((protocol[1], int(protocol[2])), timeout=5)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self.lock:
                if self.closed or uri not in self.readers:
                    sock.close()
                    return
                self.readers[uri] = sock
            sock.sendall(
                encode_header(
                    {
                        "callerid": self.caller_id,
                        "topic": self.topic,
                        "md5sum": self.md5,
                        "type": self.type,
                        "tcp_nodelay": "1",
                    }
                )
            )
            header = read_header(sock)
            if "error" in header:
                self.refused(f"{self.topic}: the ROS publisher at {uri} refused: {header['error']}")
                raise TcprosError(header["error"])
            sock.settimeout(None)
            while True:
                self.deliver(read_frame(sock), header)
        except (OSError, HwBridgeError) as exc:
            log.debug("%s: reader of %s ends: %s", self.topic, uri, exc)
        finally:
            with self.lock:
                sock_now = self.readers.pop(uri, None)
            if sock_now is not None:
                with contextlib.suppress(OSError):
                    sock_now.close()

    def close(self) -> None:
        with self.lock:
            self.closed = True
            readers, self.readers = self.readers, {}
        for sock in readers.values():
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)


@dataclass
class _Service:
    name: str
    type: str
    md5: str
    handler: Callable[[bytes, str], bytes]
    """``handler(request, caller's md5) -> response``; raises to fail the call."""


class Ros1Gateway:
    """Mirrors a graph into a ROS 1 master's graph until :meth:`close`."""

    def __init__(
        self,
        graph: Graph,
        options: Ros1Options | None = None,
        announce: Callable[[str], None] | None = None,
    ) -> None:
        self.graph = graph
        self._say = Announcer(announce, log)
        self.options = options or Ros1Options()
        self.caller_id = "/" + self.options.node_name.strip("/")
        self.report = Reporter()
        self.master = MasterProxy(self.options.master_uri, self.caller_id)
        self.graph_node: Node = graph.node(self.options.node_name)
        self._publications: dict[str, _Publication] = {}
        self._subscriptions: dict[str, _Subscription] = {}
        self._services: dict[str, _Service] = {}
        self._ros_services: set[str] = set()
        self._keep: list[Any] = []
        self._lock = threading.Lock()
        self._master_pid: int | None = None
        self.master_up = threading.Event()
        self.registrations = 0
        """How many times everything was registered with a master (1 + restarts seen)."""
        self.slave = SlaveServer(
            local_host(self.options.master_uri),
            self.options.master_uri,
            self._publication_list,
            self._subscription_list,
            self._on_publisher_update,
            self._on_param_update,
            self._on_tcpros,
        )
        self._watcher = GraphWatcher(graph, self.options.topics, self.options.services)
        self._stop = threading.Event()
        self._main = threading.Thread(target=self._run, name="ros1-gateway", daemon=True)
        self.bridged: dict[str, str] = {}

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Ros1Gateway:
        claim_rosout(self.options.rosout, self.options.topics.exclude, self._watcher, self._apply)
        self.slave.start()
        self._watcher.start()
        self._main.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._watcher.stop()
        self._main.join(_CLOSE_JOIN)  # it waits 0.1 s at a time; a master call may take longer
        if self.master_up.is_set():
            self._unregister_all()
        close_all(reversed(self._keep))
        for publication in list(self._publications.values()):
            publication.close()
        for subscription in list(self._subscriptions.values()):
            subscription.close()
        self.slave.close()

    def _run(self) -> None:
        next_check = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= next_check:
                next_check = time.monotonic() + _CHECK_PERIOD
                self._check_master()
                if self.master_up.is_set() and self.options.ros_services.include:
                    self._poll_ros_services()
            change = self._watcher.next_change(0.1)
            if change is not None:
                self._apply(change)

    # ------------------------------------------------------------------ the master
    def _check_master(self) -> None:
        try:
            pid = int(self.master.call("getPid"))
        except MasterDown as exc:
            if self.master_up.is_set():
                log.warning("ROS master %s went away; waiting for it", self.options.master_uri)
            self.master_up.clear()
            self.report.once(
                "master",
                f"ROS master {self.options.master_uri} is not running ({exc}); "
                "retrying every second (start roscore, or give --master / ROS_MASTER_URI)",
            )
            return
        except HwBridgeError:
            return
        if self.master_up.is_set() and pid == self._master_pid:
            return
        restarted = self._master_pid is not None
        self._master_pid = pid
        try:
            self._register_all()
        except MasterDown:
            return
        self.master_up.set()
        self.report.forget("master")
        self.registrations += 1
        log.warning(
            "ROS master %s %s: registered %d topics and %d services",
            self.options.master_uri,
            "restarted" if restarted else "found",
            len(self._publications) + len(self._subscriptions),
            len(self._services),
        )

    def _register_all(self) -> None:
        with self._lock:
            publications = list(self._publications.values())
            subscriptions = list(self._subscriptions.values())
            services = list(self._services.values())
        for publication in publications:
            self._register_publication(publication)
        for subscription in subscriptions:
            self._register_subscription(subscription)
        for service in services:
            self._register_service(service)
        for prefix in self.options.params:
            self._follow_params(prefix)

    def _unregister_all(self) -> None:
        """Tell the master we are gone, within :data:`_UNREGISTER_BUDGET` seconds in all (a
        stopping gateway must not hang on a slow master; one left behind is dropped by the
        master when a caller finds our slave API gone)."""
        master = MasterProxy(self.master.uri, self.caller_id, timeout=_UNREGISTER_BUDGET)
        deadline = time.monotonic() + _UNREGISTER_BUDGET
        calls = [
            *(("unregisterPublisher", t, self.slave.uri) for t in list(self._publications)),
            *(("unregisterSubscriber", t, self.slave.uri) for t in list(self._subscriptions)),
            *(("unregisterService", n, self._service_uri) for n in list(self._services)),
            *(("unsubscribeParam", self.slave.uri, p) for p in self.options.params),
        ]
        with contextlib.suppress(HwBridgeError):
            for method, *args in calls:
                left = deadline - time.monotonic()
                if left <= 0:
                    log.debug("not unregistering the rest from the master: out of time")
                    return
                master.timeout = left
                master.call(method, *args)

    @property
    def _service_uri(self) -> str:
        return f"rosrpc://{self.slave.host}:{self.slave.tcpros_port}"

    def _register_publication(self, publication: _Publication) -> None:
        self.master.call("registerPublisher", publication.topic, publication.type, self.slave.uri)

    def _register_subscription(self, subscription: _Subscription) -> None:
        publishers = self.master.call(
            "registerSubscriber", subscription.topic, subscription.type, self.slave.uri
        )
        subscription.update([uri for uri in publishers if uri != self.slave.uri])

    def _register_service(self, service: _Service) -> None:
        self.master.call("registerService", service.name, self._service_uri, self.slave.uri)

    def _when_up(self, action: Callable[[], None]) -> None:
        """Register now if the master is up (else the next (re)connection does it)."""
        if not self.master_up.is_set():
            return
        try:
            action()
        except MasterDown:
            self.master_up.clear()

    # ------------------------------------------------------------------ slave callbacks
    def _publication_list(self) -> list[list[str]]:
        with self._lock:
            return [[p.topic, p.type] for p in self._publications.values()]

    def _subscription_list(self) -> list[list[str]]:
        with self._lock:
            return [[s.topic, s.type] for s in self._subscriptions.values()]

    def _on_publisher_update(self, topic: str, publishers: list[str]) -> None:
        subscription = self._subscriptions.get(topic)
        if subscription is not None:
            subscription.update([uri for uri in publishers if uri != self.slave.uri])

    def _on_tcpros(self, conn: socket.socket, header: dict[str, str]) -> None:
        if "service" in header:
            self._serve_service_connection(conn, header)
            return
        topic = header.get("topic", "")
        publication = self._publications.get(topic)
        if publication is None:
            conn.sendall(encode_header({"error": f"{self.caller_id} does not publish {topic}"}))
            conn.close()
            return
        wanted = header.get("md5sum", ANY)
        if wanted not in (ANY, publication.md5):
            self.report.once(
                f"refused:{topic}:{wanted}",
                f"{topic}: {header.get('callerid', '?')} subscribes with "
                f"{header.get('type', '?')} (md5 {wanted}), the graph publishes "
                f"{publication.type} (md5 {publication.md5}): refused",
            )
            conn.sendall(
                encode_header(
                    {
                        "error": f"{topic}: md5 {wanted} asked for, {publication.type} has "
                        f"md5 {publication.md5}"
                    }
                )
            )
            conn.close()
            return
        conn.sendall(
            encode_header(
                {
                    "callerid": self.caller_id,
                    "topic": topic,
                    "type": publication.type,
                    "md5sum": publication.md5,
                    "message_definition": publication.definition,
                    "latching": "0",
                }
            )
        )
        conn.settimeout(_SEND_TIMEOUT)  # a subscriber that stops reading is dropped
        with publication.lock:
            publication.connections.append(conn)

    def _serve_service_connection(self, conn: socket.socket, header: dict[str, str]) -> None:
        name = header["service"]
        service = self._services.get(name)
        with conn:
            if service is None:
                conn.sendall(encode_header({"error": f"{self.caller_id} does not serve {name}"}))
                return
            md5 = header.get("md5sum", ANY)
            if md5 not in (ANY, service.md5) and service.md5 != ANY:
                conn.sendall(
                    encode_header(
                        {"error": f"{name}: md5 {md5} asked for, {service.type} has {service.md5}"}
                    )
                )
                return
            conn.sendall(
                encode_header(
                    {
                        "callerid": self.caller_id,
                        "type": service.type,
                        "md5sum": service.md5 if service.md5 != ANY else md5,
                        "request_type": service.type + "Request",
                        "response_type": service.type + "Response",
                    }
                )
            )
            if header.get("probe") == "1":
                return
            while True:
                try:
                    request = read_frame(conn)
                except (OSError, HwBridgeError):
                    return
                try:
                    response = service.handler(request, md5)
                except Exception as exc:  # noqa: BLE001 - the failure goes back to the caller
                    text = str(exc).encode()
                    conn.sendall(b"\x00" + len(text).to_bytes(4, "little") + text)
                else:
                    conn.sendall(b"\x01" + len(response).to_bytes(4, "little") + response)
                if header.get("persistent") != "1":
                    return

    # ------------------------------------------------------------------ graph changes
    def _apply(self, change: GraphChange) -> None:
        apply_change(change, self._to_ros, self._from_ros, self._serve_in_ros, self.report)

    def _known(self, type_name: str) -> tuple[str, str] | None:
        """(md5, definition) of a message type known here, else None."""
        registry = self.graph.registry
        try:
            return registry.message(type_name).md5, registry.definition(type_name)
        except HwBridgeError:
            return None

    def _add_publication(self, topic: str, type_name: str, md5: str, definition: str) -> None:
        publication = _Publication(topic, type_name, md5, definition)
        with self._lock:
            if topic in self._publications:
                return
            self._publications[topic] = publication
        self.bridged[topic] = f"to_ros {type_name}"
        self._when_up(lambda: self._register_publication(publication))
        self._say("%s: graph -> ROS 1 (%s)", topic, type_name)

    def _to_ros(self, topic: str, type_name: str) -> None:
        known = self._known(type_name)
        if known is not None:
            self._add_publication(topic, type_name, *known)

        def forward(raw: RawMessage) -> None:
            publication = self._publications.get(topic)
            if publication is None:
                if not raw.md5 or not raw.type:
                    return
                # A type this host does not define: the publisher's md5 and name are enough.
                self._add_publication(topic, raw.type, raw.md5, "")
                publication = self._publications[topic]
            elif raw.md5 and raw.md5 != publication.md5:
                self.report.once(
                    f"md5:{topic}",
                    f"{topic}: a graph publisher sends {raw.type} (md5 {raw.md5}), the ROS "
                    f"topic has {publication.type} (md5 {publication.md5}); those are dropped",
                )
                return
            publication.publish(raw.data)

        self._keep.append(self.graph_node.subscriber(topic, ANY, forward, raw=True))

    def _from_ros(self, topic: str, type_name: str) -> None:
        known = self._known(type_name)
        md5 = known[0] if known is not None else ANY
        publishers: dict[str, Publisher] = {}
        node = self.graph_node

        def deliver(data: bytes, header: dict[str, str]) -> None:
            sent_md5 = header.get("md5sum", md5)
            publisher = publishers.get(sent_md5)
            if publisher is None:
                publisher = node.raw_publisher(topic, header.get("type", type_name), sent_md5)
                publishers[sent_md5] = publisher
                self._keep.append(publisher)
            publisher.publish_raw(data)

        def refused(text: str) -> None:
            self.report.once(f"refused:{topic}", f"{text} (a type that does not map)")

        subscription = _Subscription(topic, type_name, md5, self.caller_id, deliver, refused)
        with self._lock:
            if topic in self._subscriptions:
                return
            self._subscriptions[topic] = subscription
        self.bridged[topic] = f"from_ros {type_name}"
        self._when_up(lambda: self._register_subscription(subscription))
        self._say("%s: ROS 1 -> graph (%s)", topic, type_name)

    def _serve_in_ros(self, name: str, type_name: str) -> None:
        if name in self._ros_services:
            return  # our own mirror of a ROS service
        try:
            md5 = self.graph.registry.service(type_name).md5
        except HwBridgeError:
            md5 = ANY  # unknown here: the caller's md5 is passed on and checked by the board
        timeout = self.options.service_timeout
        node = self.graph_node

        def handle(request: bytes, caller_md5: str) -> bytes:
            return node.call_raw(
                name, type_name, request, timeout, md5=md5 if md5 != ANY else caller_md5
            )

        service = _Service(name, type_name, md5, handle)
        with self._lock:
            if name in self._services:
                return
            self._services[name] = service
        self.bridged[name] = f"service {type_name}"
        self._when_up(lambda: self._register_service(service))
        self._say("%s: graph service in ROS 1 (%s)", name, type_name)

    # ------------------------------------------------------------------ ROS services -> graph
    def _poll_ros_services(self) -> None:
        try:
            _pubs, _subs, services = self.master.call("getSystemState")
        except HwBridgeError:
            return
        for name, providers in services:
            if (
                name in self._services
                or name in self._ros_services
                or self.caller_id in providers
                or not self.options.ros_services(name)
            ):
                continue
            self._ros_services.add(name)
            try:
                self._serve_on_graph(name)
            except HwBridgeError as exc:
                self.report.once(f"rossrv:{name}", f"{name}: not mirrored: {exc}")

    def _serve_on_graph(self, name: str) -> None:
        uri = str(self.master.call("lookupService", name))
        header = probe_service(uri, name, self.caller_id)
        type_name, md5 = header.get("type", ""), header.get("md5sum", "")
        self.graph.registry.service(type_name)  # the graph's servers need the type defined
        timeout = self.options.service_timeout

        def handle(request: bytes, reply: DeferredReply) -> None:
            def work() -> None:
                try:
                    where = str(self.master.call("lookupService", name))
                    reply.ok(call_service(where, name, md5, request, self.caller_id, timeout))
                except (OSError, HwBridgeError) as exc:
                    reply.error(f"ROS 1 service {name}: {exc}")

            threading.Thread(target=work, name="ros1-call", daemon=True).start()

        self._keep.append(self.graph_node.deferred_service(name, type_name, handle))
        self.bridged[name] = f"ros_service {type_name}"
        self._say("%s: ROS 1 service on the graph (%s)", name, type_name)

    # ------------------------------------------------------------------ parameters
    def _follow_params(self, prefix: str) -> None:
        key = "/" + prefix.strip("/")
        try:
            value = self.master.call("subscribeParam", self.slave.uri, key)
        except MasterDown:
            raise
        except HwBridgeError as exc:
            self.report.once(f"param:{key}", f"parameters under {key}: {exc}")
            return
        self._copy_param(key, value)

    def _on_param_update(self, key: str, value: Any) -> None:
        threading.Thread(
            target=self._copy_param, args=(key.rstrip("/") or "/", value), daemon=True
        ).start()

    def _copy_param(self, key: str, value: Any) -> None:
        from hwbridge.graph.params import flatten

        if value == {}:
            return  # nothing set there (or deleted): the graph keeps what it has
        try:
            for name, leaf in flatten(key, value).items():
                self.graph.params.set(name, leaf)
        except HwBridgeError as exc:
            self.report.once(f"paramset:{key}", f"parameter {key} not copied to the graph: {exc}")


def run_ros1_gateway(
    open_graph: Callable[[], Graph],
    options: Ros1Options,
    stop: threading.Event,
    retry: float = 1.0,
    announce: Callable[[str], None] | None = None,
) -> None:
    """Join the graph (retrying while it is not there), mirror into ROS 1 until ``stop``."""

    def up_line(gateway: Ros1Gateway, graph: Graph) -> str:
        return (
            f"ROS 1 gateway up (node {gateway.caller_id}, master {options.master_uri}, "
            f"graph {graph.config.describe()})"
        )

    run_until_stopped(
        open_graph,
        lambda graph: Ros1Gateway(graph, options, announce).start(),
        up_line,
        stop,
        retry,
        announce,
    )
