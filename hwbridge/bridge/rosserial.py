"""Bridge adapter for boards running the rosserial client library (protocol v2)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from hwbridge.bridge.endpoints import BoardEndpoints, EventDispatch
from hwbridge.errors import HwBridgeError, LinkError, ProtocolError
from hwbridge.graph import ParamError
from hwbridge.protocols.rosserial import RosserialHost
from hwbridge.protocols.rosserial import host as rs

if TYPE_CHECKING:
    from hwbridge.bridge.board import BoardConnection

__all__ = ["RosserialAdapter"]


def _call(name: str) -> Callable[[RosserialHost, bytes, float], int]:
    """How a graph call of the board's service ``name`` reaches the board (``timeout``: the
    bridge's service timeout, after which the session fails the call)."""
    return lambda session, request, timeout: session.call_service(
        name, request, time.monotonic(), timeout=timeout
    )


class RosserialAdapter(EventDispatch):
    """Maps :class:`RosserialHost` events onto the graph for one board connection."""

    protocol = "rosserial"
    session_per_peer = True
    """A new session for each peer of a listening link: a new client says nothing until asked
    for its topics (rosserial_python also serves each connection apart)."""

    def __init__(self, board: BoardConnection, *, start_delay: float) -> None:
        super().__init__()
        self.board = board
        self.log = logging.getLogger(f"hwbridge.board.{board.name}")
        self.session = RosserialHost(
            board.bridge.registry, now=time.monotonic(), start_delay=start_delay
        )
        self.endpoints = BoardEndpoints.for_board(self.board, self.log)
        self.connected = False
        self._forward: dict[str, Callable[[bytes], None]] = {}
        """Board topic -> its graph publisher's ``publish_raw`` (looked up once per table)."""

    def topics(self) -> dict[str, Any]:
        return self.endpoints.names()

    def stats(self) -> dict[str, Any]:
        return dict(self.session.stats.as_dict())

    def _on_Connected(self, event: rs.Connected) -> None:
        table = event.topics
        self._forward.clear()
        for topic in table.publishers.values():
            self.endpoints.advertise(self.board.resolve(topic.name), topic.type, topic.md5)
        for topic in table.subscribers.values():
            self.endpoints.subscribe(
                self.board.resolve(topic.name), topic.type, self._deliver(topic.name)
            )
        for service in table.service_servers.values():
            self.endpoints.serve(
                self.board.resolve(service.name), service.type, self.board, _call(service.name)
            )
        first = not self.connected
        self.connected = True
        self.board.set_state("connected", table_size=len(table.publishers) + len(table.subscribers))
        if first:
            self.log.info(
                "%s: rosserial board connected: %s", self.board.name, self.endpoints.names()
            )

    def _deliver(self, name: str) -> Callable[[bytes], None]:
        def deliver(data: bytes) -> None:
            self.board.pump.call(lambda s: s.publish(name, data))

        return deliver

    def _on_Message(self, event: rs.Message) -> None:
        forward = self._forward.get(event.topic)
        if forward is None:
            publisher = self.endpoints.publishers.get(self.board.resolve(event.topic))
            if publisher is None:
                return
            forward = self._forward[event.topic] = publisher.publish_raw
        forward(event.payload)

    def _on_ServiceResponse(self, event: rs.ServiceResponse) -> None:
        self.endpoints.pending.resolve(event.request_id, bytes(event.payload), None)

    def _on_ServiceFailed(self, event: rs.ServiceFailed) -> None:
        self.endpoints.pending.resolve(event.request_id, None, event.error)

    def _on_ServiceRequest(self, event: rs.ServiceRequest) -> None:
        name = event.name
        self.endpoints.call_graph_service(
            self.board.resolve(name),
            event.type,
            bytes(event.payload),
            lambda response: self.board.pump.call(lambda s: s.respond(name, response)),
            # rosserial has no way to fail a board's call: its client waits on (logged here).
        )

    def _on_ParamRequest(self, event: rs.ParamRequest) -> None:
        name = self.board.resolve(event.name)
        try:
            value = self.board.bridge.get_param(name)
        except ParamError:
            self.log.warning("%s: board asked for missing parameter %s", self.board.name, name)
            value = None
        try:
            self.board.pump.call(lambda s: s.answer_param(event.name, value))
        except HwBridgeError as exc:
            self.log.error("%s: cannot answer parameter %s: %s", self.board.name, name, exc)

    def _on_Log(self, event: rs.Log) -> None:
        self.endpoints.log_line(event.level, event.text)

    def _on_DeviceOutput(self, event: rs.DeviceOutput) -> None:
        self.log.info("%s: board printed %r", self.board.name, bytes(event.data))

    def _on_Error(self, event: rs.Error) -> None:
        self.log.error("%s: %s", self.board.name, event.error)

    def _on_SyncLost(self, event: rs.SyncLost) -> None:
        self.log.warning(
            "%s: no time request for %.1f s: board lost or reset, negotiating again",
            self.board.name,
            event.silence,
        )
        self.endpoints.close(ProtocolError("the board lost sync"))
        self.endpoints = BoardEndpoints.for_board(self.board, self.log)
        self._forward.clear()
        self.connected = False
        self.board.set_state("negotiating")

    def close(self, reason: HwBridgeError) -> bytes:
        """Take the board's endpoints off the graph; returns TX_STOP to send if the link lives."""
        self.endpoints.close(reason)
        if isinstance(reason, LinkError):
            return b""
        return self.session.close()
