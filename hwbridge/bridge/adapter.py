"""One board session mirrored onto the graph, whatever protocol the board speaks.

Every protocol gives the bridge the same events (:mod:`hwbridge.protocols.base`) and takes the
same actions by channel, so one adapter serves them all: it matches each event by its type (a
protocol's subclass of an event is handled as the event it extends) and turns it into calls on
:class:`~hwbridge.bridge.endpoints.BoardEndpoints`, which own what the board has on the graph.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any

from hwbridge.bridge.endpoints import BoardEndpoints
from hwbridge.bridge.port import BoardPort
from hwbridge.errors import HwBridgeError, LinkError
from hwbridge.graph import ParamError
from hwbridge.protocols import base

if TYPE_CHECKING:
    from hwbridge.protocols.registry import ProtocolSpec

__all__ = ["SessionAdapter"]

_Handler = Callable[[Any], None]

LOSS_REPORT_INTERVAL = 10.0
"""Least seconds between two warnings about the same kind of loss on one board."""
_LOSSES = {
    "bad_frames": "frames rejected (checksum, framing or size: see 'hwbridge board stats')",
    "dropped_messages": "messages on channels that are unknown, refused or not connected",
}
"""Counters of every protocol whose growth is reported, with what they mean; a protocol's own
counters named ``*oversize*``, ``*malformed*`` or ``*refused*`` are reported too."""
_LOSS_WORDS = ("oversize", "malformed", "refused")


def _call_on(channel: int) -> Callable[[base.BoardSession, bytes, float], int]:
    """How a graph call of the board's service on ``channel`` reaches the board (``timeout``:
    the bridge's service timeout, after which the session fails the call)."""
    return lambda session, request, timeout: session.call_service(
        channel, request, timeout=timeout, now=time.monotonic()
    )


class SessionAdapter:
    """Maps the events of one board's session onto the graph, and graph traffic onto it.

    All it uses of the board is ``port`` (built by the board's connection for this session).
    """

    def __init__(self, port: BoardPort, spec: ProtocolSpec, session: base.BoardSession) -> None:
        self.port = port
        self.protocol = spec.name
        self.session_per_peer = spec.session_per_peer
        """A listening link gives each peer a new session (rosserial) rather than one session
        across peers (native boards resume theirs through HELLOs)."""
        self.session = session
        self.log = port.log
        self.endpoints = self._new_endpoints()
        self.channels: dict[int, base.Endpoint] = {}
        """The board's endpoints by channel (as last announced)."""
        self._forward: dict[int, Callable[[bytes], None]] = {}
        """Board publisher channel -> its graph publisher's ``publish_raw`` (per message)."""
        self.param_names: dict[str, str] = {}
        """Graph parameter name -> the board's name of it, for parameters it subscribed to."""
        self._announced = False
        self._loss_seen: dict[str, int] = {}
        self._loss_said: dict[str, float] = {}
        self._handlers: dict[type, _Handler] = {
            base.Message: self._on_message,
            base.Connected: self._on_connected,
            base.TopicAnnounced: self._on_topic_announced,
            base.ServiceResponse: self._on_service_response,
            base.ServiceRequest: self._on_service_request,
            base.ParamRequest: self._on_param_request,
            base.Log: self._on_log,
            base.DebugOutput: self._on_debug_output,
            base.Error: self._on_error,
            base.TimeSynced: self._on_time_synced,
            base.Disconnected: self._on_disconnected,
        }
        port.listen_params(self._on_param_changed)

    def _new_endpoints(self) -> BoardEndpoints:
        port = self.port
        return BoardEndpoints(port.node, port.name, self.log, port.service_timeout)

    # ------------------------------------------------------------------ info
    def topics(self) -> dict[str, Any]:
        return self.endpoints.names()

    def stats(self) -> dict[str, Any]:
        return self.session.counters().as_dict()

    def describe(self) -> dict[str, Any]:
        return self.session.describe()

    def report_losses(self, now: float) -> None:
        """Warn (once per kind of loss and :data:`LOSS_REPORT_INTERVAL`) about data the session
        counted as dropped since the last report, so a user whose messages vanish sees why."""
        counters = self.port.call(lambda s: s.counters().as_dict())
        for key, value in counters.items():
            if not isinstance(value, int) or (
                key not in _LOSSES and not any(word in key for word in _LOSS_WORDS)
            ):
                continue
            before = self._loss_seen.get(key, 0)
            if value <= before or now - self._loss_said.get(key, -1e9) < LOSS_REPORT_INTERVAL:
                continue
            self._loss_seen[key], self._loss_said[key] = value, now
            self.log.warning(
                "%s: %d more %s (%d in all): %s",
                self.port.name,
                value - before,
                key,
                value,
                _LOSSES.get(key, "dropped; 'hwbridge board stats' has every counter"),
            )

    # ------------------------------------------------------------------ dispatch
    def on_event(self, event: Any) -> None:
        """Handle one session event (runs on the pump thread, per message)."""
        handler = self._handlers.get(type(event))
        if handler is None:
            handler = self._handler_of(type(event))
        handler(event)

    def _handler_of(self, kind: type) -> _Handler:
        """The handler of a protocol's own event class: that of the base event it extends, or
        one that ignores it (an event the bridge has no use for)."""
        for parent in kind.__mro__[1:]:
            found = self._handlers.get(parent)
            if found is not None:
                break
        else:
            found = _ignore
        self._handlers[kind] = found
        return found

    # ------------------------------------------------------------------ endpoints
    def _on_connected(self, event: base.Connected) -> None:
        self.channels.clear()
        self._forward.clear()
        before = self.endpoints.names()
        for endpoint in event.endpoints:
            self._declare(endpoint)
        self._withdraw_others(event.endpoints, before)
        self._wire_publishers()
        self.port.set_state("connected", board=event.board_name or None, resumed=event.resumed)
        self.port.on_firmware(event.firmware)
        if not self._announced:
            self._announced = True
            self.log.info(
                "%s: board %sconnected (%s%s): %s",
                self.port.name,
                f"{event.board_name!r} " if event.board_name else "",
                self.protocol,
                ", session resumed" if event.resumed else "",
                self.endpoints.names(),
            )

    def _withdraw_others(
        self, endpoints: Iterable[base.Endpoint], before: dict[str, list[str]]
    ) -> None:
        """A session that negotiates again without ending (a rosserial board that reset and
        answered the next "request topics" with another table): what the board no longer has
        leaves the graph, and the log says what changed."""
        keep = {self.port.resolve(e.name) for e in endpoints}
        gone = self.endpoints.withdraw_all_but(keep)
        if not self._announced or not gone:
            return
        after = self.endpoints.names()
        added = sorted(
            {n for names in after.values() for n in names}.difference(
                n for names in before.values() for n in names
            )
        )
        self.log.warning(
            "%s: the board negotiated again with another table (it reset or was flashed): "
            "gone %s%s",
            self.port.name,
            ", ".join(gone),
            f"; new {', '.join(added)}" if added else "",
        )

    def _on_topic_announced(self, event: base.TopicAnnounced) -> None:
        if self.session.connected:
            self._declare(event.endpoint)
            self._wire_publishers()

    def _declare(self, endpoint: base.Endpoint) -> None:
        name = self.port.resolve(endpoint.name)
        self.channels[endpoint.channel] = endpoint
        kind = endpoint.kind
        if kind == base.EntryKind.PUBLISHER:
            self.endpoints.advertise(name, endpoint.type_name, endpoint.md5)
        elif kind == base.EntryKind.SUBSCRIBER:
            self.endpoints.subscribe(name, endpoint.type_name, self._deliver(endpoint.channel))
        elif kind == base.EntryKind.SERVICE_SERVER:
            self.endpoints.serve(
                name, endpoint.type_name, self.port.call, _call_on(endpoint.channel)
            )
        # SERVICE_CLIENT endpoints need nothing until the board calls (ServiceRequest).

    def _wire_publishers(self) -> None:
        """Point every publisher channel at its graph publisher (a re-declared type replaces the
        publisher of every channel with that name)."""
        publishers = self.endpoints.publishers
        for channel, endpoint in self.channels.items():
            if endpoint.kind == base.EntryKind.PUBLISHER:
                publisher = publishers.get(self.port.resolve(endpoint.name))
                if publisher is not None:
                    self._forward[channel] = publisher.publish_raw

    def _deliver(self, channel: int) -> Callable[[bytes], None]:
        def deliver(data: bytes) -> None:
            if not self.port.call(lambda s: s.publish(channel, data)):
                self.log.warning("%s: message to channel %d not sent", self.port.name, channel)

        return deliver

    # ------------------------------------------------------------------ traffic
    def _on_message(self, event: base.Message) -> None:
        forward = self._forward.get(event.channel)
        if forward is not None:
            forward(event.payload)

    def _on_service_response(self, event: base.ServiceResponse) -> None:
        self.endpoints.pending.resolve(
            event.request_id, None if event.error else event.payload, event.error
        )

    def _on_service_request(self, event: base.ServiceRequest) -> None:
        endpoint = self.channels.get(event.channel)
        if endpoint is None:
            self.log.warning(
                "%s: board called a service on unknown channel %d", self.port.name, event.channel
            )
            return
        channel, request_id, call = event.channel, event.request_id, self.port.call

        def answer(response: bytes) -> None:
            call(lambda s: s.respond_service(channel, request_id, response))

        def refuse(reason: str) -> None:  # the board's call fails now, where it can be told
            call(lambda s: s.respond_service(channel, request_id, error=reason))

        self.endpoints.call_graph_service(
            self.port.resolve(endpoint.name), endpoint.type_name, event.payload, answer, refuse
        )

    def _on_param_request(self, event: base.ParamRequest) -> None:
        name = self.port.resolve(event.name)
        if event.subscribe:
            self.param_names[name] = event.name
        try:
            value = self.port.get_param(name)
        except ParamError:
            self.log.warning("%s: board asked for missing parameter %s", self.port.name, name)
            value = None
        try:
            self.port.call(lambda s: s.answer_param(event.request_id, value))
        except HwBridgeError as exc:
            self.log.error("%s: cannot answer parameter %s: %s", self.port.name, name, exc)

    def _on_param_changed(self, name: str, value: Any) -> None:
        board_name = self.param_names.get(name)
        if board_name is None or value is None:  # (the port calls no listener once closed)
            return
        try:
            self.port.call(lambda s: s.push_param(board_name, value))
        except HwBridgeError as exc:
            self.log.error("%s: cannot push parameter %s: %s", self.port.name, name, exc)

    # ------------------------------------------------------------------ reports
    def _on_log(self, event: base.Log) -> None:
        self.endpoints.log_line(int(event.level), event.text)

    def _on_debug_output(self, event: base.DebugOutput) -> None:
        self.log.info("%s: board printed %r", self.port.name, bytes(event.data))

    def _on_error(self, event: base.Error) -> None:
        self.log.error("%s: %s", self.port.name, event.error)

    def _on_time_synced(self, event: base.TimeSynced) -> None:
        self.log.debug(
            "%s: time offset %.6f s, rtt %.3f ms", self.port.name, event.offset, event.rtt * 1e3
        )

    def _on_disconnected(self, event: base.Disconnected) -> None:
        self.log.warning("%s: session ended (%s); negotiating again", self.port.name, event.reason)
        self.endpoints.close(event.error)
        self.endpoints = self._new_endpoints()
        self.channels.clear()
        self._forward.clear()
        self._announced = False
        self.port.set_state("negotiating")

    # ------------------------------------------------------------------ end
    def close(self, reason: HwBridgeError) -> list[bytes]:
        """Take the board's endpoints off the graph; returns a goodbye to write if the link
        lives (one item per write). The session's parameter listeners go with the port (the
        board's connection closes it too, should this never run)."""
        self.port.close()
        self.endpoints.close(reason)
        if isinstance(reason, LinkError):
            return []
        self.session.close(time.monotonic())
        return self.session.chunks_to_send()


def _ignore(_event: Any) -> None:
    """Events the bridge has no use for."""
