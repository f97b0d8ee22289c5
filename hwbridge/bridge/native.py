"""Bridge adapter for boards speaking the native hwbridge protocol."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from hwbridge.bridge.endpoints import BoardEndpoints, EventDispatch
from hwbridge.errors import HwBridgeError, LinkError
from hwbridge.graph import ParamError
from hwbridge.protocols.native import session as ns
from hwbridge.protocols.native.control import EntryKind

if TYPE_CHECKING:
    from hwbridge.bridge.board import BoardConnection

__all__ = ["NativeAdapter"]


def _call_on(channel: int) -> Callable[[ns.HostSession, bytes, float], int]:
    """How a graph call of the board's service on ``channel`` reaches the board (``timeout``:
    the bridge's service timeout, after which the session fails the call)."""
    return lambda session, request, timeout: session.call_service(
        channel, request, timeout=timeout, now=time.monotonic()
    )


class NativeAdapter(EventDispatch):
    """Maps :class:`HostSession` events onto the graph for one board connection."""

    protocol = "native"
    session_per_peer = False
    """One session across the peers of a listening link: a board that comes back resumes it
    or negotiates anew through HELLOs."""

    def __init__(self, board: BoardConnection) -> None:
        super().__init__()
        self.board = board
        self.log = logging.getLogger(f"hwbridge.board.{board.name}")
        config = ns.HostConfig(epoch_offset=time.time() - time.monotonic())
        self.session = ns.HostSession(config, type_check=self._expected_type)
        self.endpoints = BoardEndpoints.for_board(self.board, self.log)
        self.channels: dict[int, str] = {}  # board channel -> graph name
        self._forward: dict[int, Callable[[bytes], None]] = {}
        """Board publisher channel -> its graph publisher's ``publish_raw`` (per message)."""
        self.param_names: dict[str, str] = {}  # graph parameter name -> the board's name
        board.bridge.params.on_update(self._on_param_changed)

    # ------------------------------------------------------------------ info
    def topics(self) -> dict[str, Any]:
        return self.endpoints.names()

    def stats(self) -> dict[str, Any]:
        stats: dict[str, Any] = dict(self.session.stats.as_dict())
        board = self.session.board
        if board is not None:
            stats["board"] = {
                "name": board.name,
                "unique_id": board.unique_id.hex(),
                "firmware": board.firmware_version,
            }
        return stats

    # ------------------------------------------------------------------ types
    def _expected_type(self, entry: ns.TopicEntry) -> ns.ExpectedType | None:
        registry = self.board.bridge.registry
        try:
            if entry.is_service:
                md5 = registry.service(entry.type_name).md5
            else:
                md5 = registry.message(entry.type_name).md5
        except HwBridgeError:
            self.log.warning(
                "%s: %s has type %s, unknown here: bytes are forwarded, nothing can decode them "
                "(add its .msg with --msg-path)",
                self.board.name,
                entry.name,
                entry.type_name,
            )
            return None
        return ns.ExpectedType(entry.type_name, md5)

    # ------------------------------------------------------------------ events
    def _on_Connected(self, event: ns.Connected) -> None:
        for entry in event.topics:
            self._declare(entry)
        self.board.set_state(
            "connected",
            board=event.board.name,
            resumed=event.resumed,
            mtu=event.link.mtu,
            window=event.link.window,
        )
        self.log.info(
            "%s: board %r connected (native%s): %s",
            self.board.name,
            event.board.name,
            ", session resumed" if event.resumed else "",
            self.endpoints.names(),
        )

    def _on_TopicAnnounced(self, event: ns.TopicAnnounced) -> None:
        if self.session.connected:
            self._declare(event.entry)

    def _declare(self, entry: ns.TopicEntry) -> None:
        name = self.board.resolve(entry.name)
        self.channels[entry.channel] = name
        if entry.kind == EntryKind.PUBLISHER:
            publisher = self.endpoints.advertise(name, entry.type_name, entry.md5)
            for channel, topic in self.channels.items():  # a re-declared type replaces it
                if topic == name and (channel in self._forward or channel == entry.channel):
                    self._forward[channel] = publisher.publish_raw
        elif entry.kind == EntryKind.SUBSCRIBER:
            self.endpoints.subscribe(name, entry.type_name, self._deliver(entry.channel))
        elif entry.kind == EntryKind.SERVICE_SERVER:
            self.endpoints.serve(name, entry.type_name, self.board, _call_on(entry.channel))
        # SERVICE_CLIENT entries need nothing until the board calls (ServiceRequest).

    def _deliver(self, channel: int) -> Callable[[bytes], None]:
        def deliver(data: bytes) -> None:
            sent = self.board.pump.call(lambda s: s.publish(channel, data))
            if not sent:
                self.log.warning("%s: message to channel %d not sent", self.board.name, channel)

        return deliver

    def _on_Message(self, event: ns.Message) -> None:
        forward = self._forward.get(event.channel)
        if forward is not None:
            forward(event.payload)

    def _on_ServiceResponse(self, event: ns.ServiceResponse) -> None:
        self.endpoints.pending.resolve(
            event.request_id, None if event.error else event.payload, event.error
        )

    def _on_ServiceRequest(self, event: ns.ServiceRequest) -> None:
        entry = self.session.topics.get(event.channel)
        if entry is None:
            return
        channel, request_id = event.channel, event.request_id

        def answer(response: bytes) -> None:
            self.board.pump.call(lambda s: s.respond_service(channel, request_id, response))

        def refuse(reason: str) -> None:  # the board's call fails now, not at its own timeout
            self.board.pump.call(lambda s: s.respond_service(channel, request_id, error=reason))

        self.endpoints.call_graph_service(
            self.board.resolve(entry.name), entry.type_name, event.payload, answer, refuse
        )

    def _on_ParamRequest(self, event: ns.ParamRequest) -> None:
        name = self.board.resolve(event.name)
        if event.subscribe:
            self.param_names[name] = event.name
        try:
            value = self.board.bridge.get_param(name)
        except ParamError:
            self.log.warning("%s: board asked for missing parameter %s", self.board.name, name)
            value = None
        self.board.pump.call(lambda s: s.answer_param(event.request_id, value))

    def _on_param_changed(self, name: str, value: Any) -> None:
        board_name = self.param_names.get(name)
        if board_name is None or value is None or self.board.adapter is not self:
            return
        try:
            self.board.pump.call(lambda s: s.push_param(board_name, value))
        except HwBridgeError as exc:
            self.log.error("%s: cannot push parameter %s: %s", self.board.name, name, exc)

    def _on_Log(self, event: ns.Log) -> None:
        self.endpoints.log_line(int(event.level), event.text)

    def _on_DebugOutput(self, event: ns.DebugOutput) -> None:
        self.log.info("%s: board printed %r", self.board.name, event.data)

    def _on_Error(self, event: ns.Error) -> None:
        self.log.error("%s: %s", self.board.name, event.error)

    def _on_TimeSynced(self, event: ns.TimeSynced) -> None:
        self.log.debug(
            "%s: time offset %.6f s, rtt %.3f ms", self.board.name, event.offset, event.rtt * 1e3
        )

    def _on_Disconnected(self, event: ns.Disconnected) -> None:
        self.log.warning("%s: session ended (%s); negotiating again", self.board.name, event.reason)
        self.endpoints.close(event.error)
        self.endpoints = BoardEndpoints.for_board(self.board, self.log)
        self.channels.clear()
        self._forward.clear()
        self.board.set_state("negotiating")

    def close(self, reason: HwBridgeError) -> bytes:
        """Take the board's endpoints off the graph; returns a goodbye if the link lives."""
        self.endpoints.close(reason)
        if isinstance(reason, LinkError):
            return b""
        self.session.close(time.monotonic())
        return self.session.data_to_send()
