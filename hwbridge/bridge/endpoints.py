"""What one connected board puts on the graph, and how it is taken off again.

The session adapter (:mod:`hwbridge.bridge.adapter`) turns session events into calls on
:class:`BoardEndpoints`; it owns every publisher, subscriber and service it declares for the
board, so a lost link removes exactly those from the graph (discovery sees them go).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

from hwbridge.errors import HwBridgeError, HwBridgeTimeoutError
from hwbridge.graph import DeferredReply, Node, Publisher, RawMessage, ServiceServer, Subscriber

if TYPE_CHECKING:
    from hwbridge.bridge.port import SessionCall
    from hwbridge.protocols.base import BoardSession

__all__ = ["BOARD_LOG", "ROSOUT_LEVELS", "BoardEndpoints", "PendingCalls"]

BOARD_LOG = "hwbridge.board_log"
"""The logger of the boards' own log lines (``nh.logInfo``), one child per board: apart from the
bridge's messages, so that ``connect`` and ``up`` can show them by default."""

# rosgraph_msgs/Log levels for DEBUG, INFO, WARN, ERROR, FATAL (0..4 on the board).
ROSOUT_LEVELS = (1, 2, 4, 8, 16)
_PYTHON_LEVELS = (logging.DEBUG, logging.INFO, logging.WARNING, logging.ERROR, logging.CRITICAL)
_TIMEOUT_HINT = (
    "(the bridge's service timeout; raise it with 'hwbridge connect --service-timeout SECONDS')"
)
"""Ends the error of a service call through the bridge that ran out of time, either way."""


class PendingCalls:
    """Graph callers waiting for a board's answer, by the session's request id.

    Each entry leaves exactly once: the board's answer, the session's error (the bridge's
    service timeout among them: the sessions report every call they time out), or
    :meth:`fail_all` when the board's session ends. A graph caller that gave up earlier (its own
    timeout) does not remove its entry; the late outcome then goes nowhere.
    """

    def __init__(self, board_name: str, service_timeout: float) -> None:
        self._calls: dict[int, DeferredReply] = {}
        self._lock = threading.Lock()
        self._timed_out = (
            f"board {board_name} did not answer within {service_timeout:g} s {_TIMEOUT_HINT}"
        )

    def __len__(self) -> int:
        with self._lock:
            return len(self._calls)

    def add(self, request_id: int, reply: DeferredReply) -> None:
        """Register before the board can answer (call under the pump's lock)."""
        with self._lock:
            self._calls[request_id] = reply

    def resolve(self, request_id: int, payload: bytes | None, error: HwBridgeError | None) -> None:
        with self._lock:
            reply = self._calls.pop(request_id, None)
        if reply is None:
            return
        if isinstance(error, HwBridgeTimeoutError):
            # The session's own text names the board-side name and a request id; the caller
            # needs the timeout and what sets it (the graph prefixes the service's name).
            reply.error(self._timed_out)
        elif error is not None or payload is None:
            reply.error(str(error) if error is not None else "no answer from the board")
        else:
            reply.ok(payload)

    def fail_all(self, error: HwBridgeError) -> None:
        with self._lock:
            calls, self._calls = self._calls, {}
        for reply in calls.values():
            reply.error(str(error))


class BoardEndpoints:
    """Publishers, subscribers and services of one board session on the graph.

    ``service_timeout`` (seconds) bounds every service call through the bridge, both ways:
    the adapters' ``send`` gets it for graph calls of board services, and board calls of graph
    services (:meth:`call_graph_service`) use it as the graph call's timeout.
    """

    def __init__(
        self, node: Node, board_name: str, logger: logging.Logger, service_timeout: float
    ) -> None:
        self.node = node
        self.board_name = board_name
        self.log = logger
        self.service_timeout = service_timeout
        self.publishers: dict[str, Publisher] = {}
        self.subscribers: dict[str, Subscriber] = {}
        self.servers: dict[str, ServiceServer] = {}
        self.pending = PendingCalls(board_name, service_timeout)
        self._workers = ThreadPoolExecutor(max_workers=4, thread_name_prefix=f"{board_name}-svc")
        self._rosout: Publisher | None = None
        self._closed = False

    # ------------------------------------------------------------------ board -> graph
    def advertise(self, topic: str, type_name: str, md5: str) -> Publisher:
        """A topic the board publishes (declared once per name); the adapters hand the board's
        bytes to the returned publisher's ``publish_raw`` unchanged."""
        found = self.publishers.get(topic)
        if found is None or found.type.md5 != md5:
            if found is not None:
                found.close()
            found = self.node.raw_publisher(topic, type_name, md5)
            self.publishers[topic] = found
        return found

    def subscribe(self, topic: str, type_name: str, deliver: Callable[[bytes], None]) -> None:
        """A topic the board subscribes to: graph messages go to ``deliver(payload)``."""
        if topic in self.subscribers:
            return

        def on_message(message: RawMessage) -> None:
            try:
                deliver(message.data)
            except HwBridgeError as exc:
                self.log.error(
                    "%s: cannot deliver %s to the board: %s", self.board_name, topic, exc
                )

        self.subscribers[topic] = self.node.subscriber(topic, type_name, on_message, raw=True)

    def serve(
        self,
        name: str,
        srv_type: str,
        call: SessionCall,
        send: Callable[[BoardSession, bytes, float], int],
    ) -> None:
        """A service the board serves. Each graph call runs ``send(session, request, timeout)``
        through ``call``, under the session's pump lock: it sends the request, to be answered
        within ``timeout`` seconds (the bridge's service timeout), and returns the session's
        request id, under which the caller's reply is registered before the lock is let go, so
        the board's answer (read by the pump thread, which resolves the reply) always finds it."""
        if name in self.servers:
            return
        pending, timeout = self.pending, self.service_timeout

        def start(request: bytes, reply: DeferredReply) -> None:
            call(lambda session: pending.add(send(session, request, timeout), reply))

        self.servers[name] = self.node.deferred_service(name, srv_type, start)

    def call_graph_service(
        self,
        name: str,
        srv_type: str,
        payload: bytes,
        answer: Callable[[bytes], None],
        refuse: Callable[[str], None] | None = None,
    ) -> None:
        """The board calls a graph service; ``answer(response)`` runs when it returns within
        the service timeout, ``refuse(reason)`` (where the protocol can tell the board) when
        the call fails."""
        timeout = self.service_timeout

        def work() -> None:
            started = time.monotonic()
            try:
                response = self.node.call_raw(name, srv_type, payload, timeout)
            except HwBridgeError as exc:
                reason = str(exc)
                if time.monotonic() - started >= timeout:  # a server that took too long
                    reason = f"no answer from {name} within {timeout:g} s {_TIMEOUT_HINT}"
                self.log.error(
                    "%s: service call %s for the board failed: %s", self.board_name, name, reason
                )
                if refuse is not None:
                    self._tell_board(refuse, reason, name)
                return
            failed = self._tell_board(answer, response, name)
            if failed is not None and refuse is not None:
                # Refused (too large for the board, say): the call is still open, so it fails
                # now with the reason, not at the board's timeout.
                self._tell_board(refuse, str(failed), name)

        self._workers.submit(work)

    def _tell_board(
        self, action: Callable[[Any], None], outcome: Any, name: str
    ) -> HwBridgeError | None:
        """Run ``action(outcome)``; the error that kept it from the board (logged), or None."""
        try:
            action(outcome)
        except HwBridgeError as exc:
            self.log.error(
                "%s: the answer of %s did not reach the board: %s", self.board_name, name, exc
            )
            return exc
        return None

    def log_line(self, level: int, text: str) -> None:
        """A board log line: Python logging and /rosout (rosgraph_msgs/Log)."""
        level = min(max(level, 0), 4)
        logging.getLogger(f"{BOARD_LOG}.{self.board_name}").log(
            _PYTHON_LEVELS[level], "[%s] %s", self.board_name, text
        )
        if self._rosout is None:
            self._rosout = self.node.publisher("/rosout", "rosgraph_msgs/Log")
        now = time.time()
        self._rosout.publish(
            {
                "header": {"stamp": now},
                "level": ROSOUT_LEVELS[level],
                "name": self.node.name,
                "msg": text,
            }
        )

    def withdraw_all_but(self, keep: set[str]) -> list[str]:
        """Take off the graph every publisher, subscriber and service not named in ``keep``;
        their names, sorted."""
        gone: list[Publisher | Subscriber | ServiceServer] = []
        names: list[str] = []
        for table in (self.publishers, self.subscribers, self.servers):
            for name in [n for n in table if n not in keep]:
                gone.append(table.pop(name))
                names.append(name)
        for item in gone:
            item.close()
        return sorted(names)

    # ------------------------------------------------------------------ teardown
    def close(self, reason: HwBridgeError) -> None:
        """Take everything off the graph and fail the calls still waiting."""
        if self._closed:
            return
        self._closed = True
        self.pending.fail_all(reason)
        items: list[Publisher | Subscriber | ServiceServer] = [
            *self.publishers.values(),
            *self.subscribers.values(),
            *self.servers.values(),
        ]
        for item in items:
            item.close()
        if self._rosout is not None:
            self._rosout.close()
        self.publishers.clear()
        self.subscribers.clear()
        self.servers.clear()
        self._workers.shutdown(wait=False, cancel_futures=True)

    def names(self) -> dict[str, Any]:
        return {
            "publishes": sorted(self.publishers),
            "subscribes": sorted(self.subscribers),
            "serves": sorted(self.servers),
        }
