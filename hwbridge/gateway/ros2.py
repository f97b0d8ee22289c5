"""The ROS 2 gateway: the hwbridge graph's topics and services in a ROS 2 graph, through rclpy.

rclpy and the message packages come from PyPI wheels (the ``[ros2]`` extra); they need
``LD_LIBRARY_PATH`` and ``AMENT_PREFIX_PATH`` to point into the environment they are installed
in, which :func:`ros2_environment` works out and ``hwbridge ros2`` sets on itself before rclpy
loads. A sourced ROS 2 installation works as well (its paths are kept, ours go after them).

Bytes are converted, never decoded into Python objects: ROS 1 bytes from the graph become CDR
with rosbags (``header.seq`` dropped, time fields as ``builtin_interfaces/Time``) and are
published as serialized messages; ROS 2 subscriptions are raw and their CDR becomes ROS 1 bytes.
Board logs (``/rosout``, ``rosgraph_msgs/Log``) become ``rcl_interfaces/msg/Log`` on ``/rosout``.

QoS (:mod:`hwbridge.gateway.qos`): what the gateway publishes is reliable, so default-QoS and
sensor-data subscribers both receive it; what it subscribes to is best effort, so reliable and
best-effort publishers both reach the graph; :attr:`Ros2Options.qos` rules change it per topic.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from hwbridge.errors import HwBridgeError
from hwbridge.gateway.common import (
    ROSOUT,
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
from hwbridge.gateway.qos import ROSOUT_KIND, QosKind, QosRules
from hwbridge.gateway.types import CdrConverter, TypeMapError, ros1_type_name, ros2_type_name

if TYPE_CHECKING:
    from hwbridge.graph import DeferredReply, Graph, Node, Publisher

__all__ = [
    "ROS1_LOG_LEVELS",
    "Ros2Gateway",
    "Ros2Options",
    "load_rclpy",
    "qos_kind",
    "ros2_environment",
]

log = logging.getLogger("hwbridge.gateway.ros2")

ROS1_LOG_LEVELS: Final = {1: 10, 2: 20, 4: 30, 8: 40, 16: 50}
"""rosgraph_msgs/Log levels (DEBUG=1 ... FATAL=16) -> rcl_interfaces/msg/Log (10 ... 50)."""


def ros2_environment(
    prefix: str | None = None, env: dict[str, str] | None = None
) -> dict[str, str]:
    """The environment rclpy from wheels installed under ``prefix`` (default: this Python's
    ``sys.prefix``) needs: its ``lib`` (and the wheels' ``ros_*.libs``) on ``LD_LIBRARY_PATH``,
    ``prefix`` on ``AMENT_PREFIX_PATH``, Fast DDS unless an RMW is chosen. Existing entries are
    kept first.

    (The wheels also install ``ros_wheels_bootstrapper``, a ``.pth`` hook that re-executes
    every Python process of the environment with ``LD_LIBRARY_PATH`` set, unless
    ``_ROS_WHEELS_BOOTSTRAP_COMPLETE`` is set; ``hwbridge ros2`` does not rely on it.)"""
    base = dict(os.environ if env is None else env)
    root = prefix or sys.prefix
    lib = str(Path(root) / "lib")

    def add(name: str, value: str) -> None:
        parts = [p for p in base.get(name, "").split(os.pathsep) if p]
        if value not in parts:
            parts.append(value)
        base[name] = os.pathsep.join(parts)

    add("LD_LIBRARY_PATH", lib)
    site = Path(lib) / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"
    for vendored in sorted(site.glob("ros_*.libs")):  # libraries the wheels carry along
        add("LD_LIBRARY_PATH", str(vendored))
    add("AMENT_PREFIX_PATH", root)
    base.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    return base


def environment_ready(prefix: str | None = None) -> bool:
    """Whether this process already runs with :func:`ros2_environment`'s paths."""
    wanted = ros2_environment(prefix, {})
    for name in ("LD_LIBRARY_PATH", "AMENT_PREFIX_PATH"):
        have = os.environ.get(name, "").split(os.pathsep)
        if any(part not in have for part in wanted[name].split(os.pathsep)):
            return False
    return True


def load_rclpy() -> Any:
    """Import rclpy, or say how to install it."""
    try:
        return importlib.import_module("rclpy")
    except ImportError as exc:
        raise HwBridgeError(
            f"hwbridge ros2 needs rclpy ({exc}): install the ROS 2 wheels with "
            "pip install 'hwbridge[ros2]' (CPython 3.11, x86-64 Linux) or source a ROS 2 "
            "installation before running it"
        ) from exc


def qos_kind(topic: str, direction: str, rules: QosRules | None = None) -> QosKind:
    """The QoS a topic gets in ROS 2: the first of ``rules`` that matches it, else the
    default (:func:`hwbridge.gateway.qos.default_kind`): everything published into ROS 2
    reliable (a reliable publisher reaches default and sensor-data subscribers alike), ``/tf``
    as tf2 broadcasts it, ``/tf_static`` latched, subscriptions best effort (they take reliable
    and best-effort publishers alike), and ``/rosout`` as rclpy's own."""
    if topic == ROSOUT:
        return ROSOUT_KIND
    return (rules or QosRules()).kind(topic, direction)


def _qos(rclpy_qos: Any, kind: QosKind) -> Any:
    reliability = rclpy_qos.ReliabilityPolicy
    durability = rclpy_qos.DurabilityPolicy
    return rclpy_qos.QoSProfile(
        history=rclpy_qos.HistoryPolicy.KEEP_LAST,  # never blocks on a slow subscriber
        depth=kind.depth,
        reliability=reliability.RELIABLE if kind.reliable else reliability.BEST_EFFORT,
        durability=durability.TRANSIENT_LOCAL if kind.transient_local else durability.VOLATILE,
    )


@dataclass
class Ros2Options(MirrorOptions):
    """What to mirror (:class:`~hwbridge.gateway.common.MirrorOptions`), with QoS and how often
    ROS 2's services are looked for."""

    qos: QosRules = field(default_factory=QosRules)
    """Per-topic QoS rules (``--qos PATTERN=KIND``, the robot file's ``ros: {qos:}``), before
    the defaults of :func:`qos_kind`."""
    poll: float = 1.0


@dataclass
class _Counters:
    to_ros: int = 0
    from_ros: int = 0
    calls_to_graph: int = 0
    calls_to_ros: int = 0
    dropped: int = 0


class Ros2Gateway:
    """Mirrors a graph into ROS 2 until :meth:`close`. Needs rclpy importable."""

    def __init__(
        self,
        graph: Graph,
        options: Ros2Options | None = None,
        announce: Callable[[str], None] | None = None,
    ) -> None:
        self.graph = graph
        self._say = Announcer(announce, log)
        self.options = options or Ros2Options()
        self.report = Reporter()
        self.counters = _Counters()
        self.bridged: dict[str, str] = {}
        """Name -> what was set up (``to_ros TYPE``, ``from_ros TYPE``, ``service TYPE``)."""
        self._rclpy = load_rclpy()
        self._qos_mod = importlib.import_module("rclpy.qos")
        self._serialization = importlib.import_module("rclpy.serialization")
        executors = importlib.import_module("rclpy.executors")
        groups = importlib.import_module("rclpy.callback_groups")
        self.converter = CdrConverter(graph.registry)
        self._context = self._rclpy.Context()
        self._rclpy.init(context=self._context)
        self._closing = False
        self._lock = threading.Lock()
        self._keep: list[Any] = []
        try:
            self.node = self._rclpy.create_node(self.options.node_name, context=self._context)
            self._group = groups.ReentrantCallbackGroup()
            self._executor = executors.MultiThreadedExecutor(num_threads=4, context=self._context)
            self._executor.add_node(self.node)
        except Exception as exc:
            self._shutdown_context()
            raise HwBridgeError(f"cannot start the ROS 2 node: {exc}") from exc
        self.graph_node: Node = graph.node(self.options.node_name)
        self._served_in_ros: set[str] = set()
        self._served_on_graph: set[str] = set()
        self._watcher = GraphWatcher(graph, self.options.topics, self.options.services)
        self._spin = threading.Thread(target=self._spin_ros, name="ros2-executor", daemon=True)
        self._main = threading.Thread(target=self._run, name="ros2-gateway", daemon=True)
        self._stop = threading.Event()

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Ros2Gateway:
        claim_rosout(self.options.rosout, self.options.topics.exclude, self._watcher, self._apply)
        self._spin.start()
        self._watcher.start()
        self._main.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._watcher.stop()
        self._main.join(5)
        with self._lock:
            self._closing = True
        self._executor.shutdown(timeout_sec=2)
        self._spin.join(5)
        close_all(reversed(self._keep))
        with contextlib.suppress(Exception):
            self.node.destroy_node()
        self._shutdown_context()

    def _shutdown_context(self) -> None:
        with contextlib.suppress(Exception):
            self._rclpy.shutdown(context=self._context)

    def _spin_ros(self) -> None:
        with contextlib.suppress(Exception):  # the executor raises when shut down
            self._executor.spin()

    def _run(self) -> None:
        last_poll = 0.0
        while not self._stop.is_set():
            change = self._watcher.next_change(0.1)
            if change is not None:
                self._apply(change)
            if (
                self.options.ros_services.include
                and time.monotonic() - last_poll > self.options.poll
            ):
                last_poll = time.monotonic()
                self._poll_ros_services()

    def _apply(self, change: GraphChange) -> None:
        try:
            apply_change(
                change,
                self._to_ros,
                self._from_ros,
                self._serve_in_ros,
                self.report,
                passes=(TypeMapError,),
            )
        except TypeMapError as exc:
            self.report.once(
                f"type:{change.type}",
                f"{change.name}: {change.type} has no ROS 2 counterpart ({exc}); not mirrored "
                "(further topics of this type are skipped silently)",
            )

    # ------------------------------------------------------------------ types
    def _ros2_class(self, ros2_name: str) -> Any:
        package, kind, name = ros2_name.split("/")
        try:
            module = importlib.import_module(f"{package}.{kind}")
            return getattr(module, name)
        except (ImportError, AttributeError) as exc:
            raise TypeMapError(
                f"no ROS 2 package provides {ros2_name} here (install its wheel, "
                "or source a ROS 2 installation that has it)"
            ) from exc

    def _message_types(self, ros1: str) -> tuple[Any, str]:
        """(rclpy class, ROS 2 store name) for a ROS 1 message type, checked once."""
        ros2 = ros2_type_name(ros1)
        cls = self._ros2_class(ros2)
        try:
            store1 = self.graph.registry.message(ros1).store_name
        except HwBridgeError as exc:
            raise TypeMapError(f"{ros1} is not defined on this host") from exc
        self.converter.prepare(store1, ros2)
        added = self.converter.added_fields(ros2)
        if added:
            self.report.once(
                f"added:{ros2}",
                f"{ros2} has fields ROS 1's {ros1} lacks ({', '.join(added)}): "
                "they go to ROS 2 as zeros",
            )
        return cls, ros2

    def _qos_for(self, topic: str, direction: str) -> tuple[Any, str]:
        """The rclpy profile for a topic and the name of its kind (for the log)."""
        kind = qos_kind(topic, direction, self.options.qos)
        return _qos(self._qos_mod, kind), kind.name

    # ------------------------------------------------------------------ topics
    def _to_ros(self, topic: str, ros1: str) -> None:
        if topic == ROSOUT:
            if self.options.rosout:
                self._rosout()
            return
        cls, ros2 = self._message_types(ros1)
        profile, kind = self._qos_for(topic, "to_ros")
        publisher = self.node.create_publisher(cls, topic, profile)
        converter = self.converter
        counters = self.counters

        def forward(raw: Any) -> None:
            if raw.md5 and raw.type and raw.type != ros1:
                counters.dropped += 1
                return
            try:
                publisher.publish(converter.to_cdr(raw.data, ros2))
            except Exception as exc:  # noqa: BLE001 - bad bytes or a context shutting down
                counters.dropped += 1
                self.report.once(f"bytes:{topic}", f"{topic}: message not converted: {exc}")
                return
            counters.to_ros += 1

        self._keep.append(self.graph_node.subscriber(topic, ros1, forward, raw=True))
        self.bridged[topic] = f"to_ros {ros1}"
        self._say("%s: graph -> ROS 2 (%s, QoS %s)", topic, ros2, kind)

    def _rosout(self) -> None:
        from hwbridge import msg as msgmod

        log_cls = self._ros2_class("rcl_interfaces/msg/Log")
        publisher = self.node.create_publisher(log_cls, ROSOUT, _qos(self._qos_mod, ROSOUT_KIND))
        registry = self.graph.registry

        def forward(raw: Any) -> None:
            try:
                entry = msgmod.decode(raw.data, "rosgraph_msgs/Log", registry)
                out = log_cls()
                out.stamp.sec = int(entry.header.stamp.sec)
                out.stamp.nanosec = int(entry.header.stamp.nanosec)
                out.level = ROS1_LOG_LEVELS.get(int(entry.level), 20)
                out.name = str(entry.name)
                out.msg = str(entry.msg)
                out.file = str(entry.file)
                out.function = str(entry.function)
                out.line = int(entry.line)
                publisher.publish(out)
            except Exception as exc:  # noqa: BLE001 - anything wrong with one log line
                self.counters.dropped += 1
                self.report.once("rosout", f"{ROSOUT}: log line not converted: {exc}")
                return
            self.counters.to_ros += 1

        self._keep.append(
            self.graph_node.subscriber(ROSOUT, "rosgraph_msgs/Log", forward, raw=True)
        )
        self.bridged[ROSOUT] = "to_ros rosgraph_msgs/Log -> rcl_interfaces/msg/Log"
        self._say("%s: graph -> ROS 2 (rcl_interfaces/msg/Log)", ROSOUT)

    def _from_ros(self, topic: str, ros1: str) -> None:
        cls, ros2 = self._message_types(ros1)
        publisher: Publisher = self.graph_node.publisher(topic, ros1)
        self._keep.append(publisher)
        converter = self.converter

        def forward(data: bytes) -> None:
            try:
                publisher.publish_raw(converter.from_cdr(data, ros2))
            except Exception as exc:  # noqa: BLE001 - bad bytes or a graph closing
                self.counters.dropped += 1
                self.report.once(f"bytes:{topic}", f"{topic}: message not converted: {exc}")
                return
            self.counters.from_ros += 1

        profile, kind = self._qos_for(topic, "from_ros")
        self.node.create_subscription(
            cls, topic, forward, profile, callback_group=self._group, raw=True
        )
        self.bridged[topic] = f"from_ros {ros1}"
        self._say("%s: ROS 2 -> graph (%s, QoS %s)", topic, ros2, kind)

    # ------------------------------------------------------------------ services
    def _service_types(self, ros1: str) -> tuple[Any, str, str, str]:
        """(rclpy service class, ROS 2 request and response store names, ROS 1 md5)."""
        ros2 = ros2_type_name(ros1, "srv")
        cls = self._ros2_class(ros2)
        try:
            service = self.graph.registry.service(ros1)
        except HwBridgeError as exc:
            raise TypeMapError(f"{ros1} is not defined on this host") from exc
        request, response = f"{ros2}_Request", f"{ros2}_Response"
        self.converter.prepare(service.request.store_name, request)
        self.converter.prepare(service.response.store_name, response)
        return cls, request, response, service.md5

    def _serve_in_ros(self, name: str, ros1: str) -> None:
        if name in self._served_on_graph:
            return  # our own mirror of a ROS service
        cls, request_name, response_name, md5 = self._service_types(ros1)
        serialize = self._serialization.serialize_message
        deserialize = self._serialization.deserialize_message
        converter = self.converter
        timeout = self.options.service_timeout

        def handle(request: Any, response: Any) -> Any:
            data = converter.from_cdr(serialize(request), request_name)
            try:
                answer = self.graph_node.call_raw(name, ros1, data, timeout, md5=md5)
            except HwBridgeError as exc:
                # A ROS 2 service cannot fail a call: the client gets a default response.
                log.warning("%s: graph call failed: %s", name, exc)
                return response
            self.counters.calls_to_graph += 1
            return deserialize(converter.to_cdr(answer, response_name), cls.Response)

        self.node.create_service(cls, name, handle, callback_group=self._group)
        self._served_in_ros.add(name)
        self.bridged[name] = f"service {ros1}"
        self._say("%s: graph service in ROS 2 (%s)", name, ros1)

    def _poll_ros_services(self) -> None:
        try:
            found = self.node.get_service_names_and_types()
        except Exception:  # noqa: BLE001 - the context may be shutting down
            return
        for name, types in found:
            if (
                name in self._served_in_ros
                or name in self._served_on_graph
                or not self.options.ros_services(name)
                or not types
            ):
                continue
            self._served_on_graph.add(name)
            try:
                self._serve_on_graph(name, types[0])
            except HwBridgeError as exc:
                self.report.once(f"rossrv:{name}", f"{name} ({types[0]}): not mirrored: {exc}")

    def _serve_on_graph(self, name: str, ros2: str) -> None:
        ros1 = ros1_type_name(ros2)
        cls, request_name, response_name, _md5 = self._service_types(ros1)
        client = self.node.create_client(cls, name, callback_group=self._group)
        serialize = self._serialization.serialize_message
        deserialize = self._serialization.deserialize_message
        converter = self.converter

        def handle(data: bytes, reply: DeferredReply) -> None:
            try:
                request = deserialize(converter.to_cdr(data, request_name), cls.Request)
            except Exception as exc:  # noqa: BLE001 - bad request bytes
                reply.error(f"request not converted: {exc}")
                return
            future = client.call_async(request)

            def done(finished: Any) -> None:
                try:
                    result = finished.result()
                    reply.ok(converter.from_cdr(serialize(result), response_name))
                    self.counters.calls_to_ros += 1
                except Exception as exc:  # noqa: BLE001 - the call failed in ROS 2
                    reply.error(f"ROS 2 service {name} failed: {exc}")

            future.add_done_callback(done)

        self._keep.append(self.graph_node.deferred_service(name, ros1, handle))
        self.bridged[name] = f"ros_service {ros1}"
        self._say("%s: ROS 2 service on the graph (%s)", name, ros1)


def run_ros2_gateway(
    open_graph: Callable[[], Graph],
    options: Ros2Options,
    stop: threading.Event,
    retry: float = 1.0,
    announce: Callable[[str], None] | None = None,
) -> None:
    """Join the graph (retrying every ``retry`` s while it is not there), mirror until ``stop``."""

    def up_line(_gateway: Ros2Gateway, graph: Graph) -> str:
        domain = os.environ.get("ROS_DOMAIN_ID", "0")
        return (
            f"ROS 2 gateway up (node {options.node_name}, ROS_DOMAIN_ID {domain}, "
            f"graph {graph.config.describe()})"
        )

    run_until_stopped(
        open_graph,
        lambda graph: Ros2Gateway(graph, options, announce).start(),
        up_line,
        stop,
        retry,
        announce,
    )
