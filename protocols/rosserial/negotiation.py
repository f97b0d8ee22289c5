"""Start-up and topic negotiation of the rosserial host (a mixin of ``RosserialHost``).

Life cycle. The host sends "request topics" at once and repeats it with backoff (0.1, 0.2, 0.4,
0.8 s, then every 1 s) until the device answers: a sketch that is already running answers within
milliseconds, and one that the opening of the port reset (an Arduino bootloader waits about 1-2
s; it discards what it hears, or starts the sketch sooner) is caught soon after its sketch
starts. ``start_delay`` (default 0) keeps the host silent for that long first; time requests are
answered meanwhile. The device answers with a time request and one ``rosserial_msgs/TopicInfo``
per endpoint. Each TopicInfo is checked at once against the host's type of the same name (md5 of
the message, or of the request or response half of a service): a mismatch is reported as an
:class:`~hwbridge.protocols.base.Error` event and only that endpoint is left out; a type the host
does not know passes through (its bytes are carried unchecked, with the device's type name and
md5) and is logged once per type as a warning. Service endpoints arrive as two halves (a publisher
and a subscriber TopicInfo with the same name) and are joined by name.

When is the board configured? The device sends its TopicInfos back to back and then says
nothing that marks the end, so the host uses this rule:

- the negotiation has an answer once a time request or a TopicInfo arrived after the request;
- it is complete when ``settle_time`` (0.5 s) passed without a new TopicInfo since the last one
  (or since the time request, for a board without topics), or at once when a data frame arrives
  on a topic id announced in this negotiation (the library only publishes once configured, and
  it sends all its TopicInfos in one go before that);
- completion emits :class:`~hwbridge.protocols.base.Connected` with all accepted endpoints.

A TopicInfo arriving after that (a slow link) reopens the negotiation: it is merged into the table
and ``Connected`` is emitted again once the line is quiet. The answer to a silence probe (below) is
the device's whole table instead: it replaces the old one, so the topics of a board that reset into
another sketch leave (``Connected`` carries only the new table). If nothing answers the requests for
``sync_timeout`` (15 s), the host reports an ``Error`` (again every ``sync_timeout``) and keeps
asking. Once connected, the device asks for the time every ~2.5 s. After ``probe_after`` (3 s)
without a time request the host sends "request topics" (again every ``request_retry_max``): a device
that reset is silent until asked, and answers with its table, which replaces the old one, so its
traffic is back within about 4 s; a configured device just sends its table again (rosserial_python
waits the whole sync timeout). ``sync_timeout`` without a time request means "lost sync": the host
fails pending calls, emits :class:`~hwbridge.protocols.base.Disconnected`, drops the topic table
(not connected until the next ``Connected``) and asks for topics again. A data frame on a topic id
the host does not know also makes it ask again (at most once a second), as rosserial_python does;
meanwhile the current table stays in use.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Final

from hwbridge.protocols.base import Connected, Disconnected, Error, Event
from hwbridge.protocols.calling import may_call, next_call
from hwbridge.protocols.errors import (
    HwBridgeError,
    HwBridgeTimeoutError,
    ProtocolError,
    SerializationError,
)
from hwbridge.protocols.msgtypes import TypeRegistry
from hwbridge.protocols.rosserial.framing import (
    FRAME_OVERHEAD,
    MAX_PAYLOAD,
    RosFrame,
    RosserialFraming,
)
from hwbridge.protocols.rosserial.ids import TOPIC_INFO_TYPE, ReservedId
from hwbridge.protocols.rosserial.services import HostCalls, PendingRequests
from hwbridge.protocols.rosserial.stats import HostStats
from hwbridge.protocols.rosserial.table import BuiltTable, Info, build_table, check_info

__all__ = ["REQUEST_MIN_INTERVAL", "Negotiation", "NegotiationMixin", "State"]

REQUEST_MIN_INTERVAL: Final = 1.0
"""Least time between two "request topics" sent because of an unknown topic id."""
_TIME: Final = struct.Struct("<II")


class State(Enum):
    WAITING = "waiting"
    NEGOTIATING = "negotiating"
    CONNECTED = "connected"
    CLOSED = "closed"


@dataclass
class Negotiation:
    """One round of "request topics" and the TopicInfos it brought."""

    started: float
    infos: dict[int, Info] = field(default_factory=dict)
    answered_at: float | None = None
    last_info_at: float | None = None
    retry_gap: float = 0.0
    retry_at: float = math.inf
    reported_at: float = 0.0
    """When the host last said that nothing answers (the start, before that)."""


class NegotiationMixin:
    """The negotiation half of ``RosserialHost``: requests, TopicInfos, time, lost sync."""

    registry: TypeRegistry
    framing: RosserialFraming
    stats: HostStats
    _state: State
    _built: BuiltTable | None
    _negotiation: Negotiation | None
    _accepted: dict[int, Info]
    _refused_ids: set[int]
    _warned_types: set[str]
    _requested_at: float | None
    _want_topics: bool
    _probed: bool
    _sync_ref: float
    _sync_timeout: float
    _settle_time: float
    _retry: float
    _retry_max: float
    _probe_after: float
    _next_probe: float
    _call_burst: float
    _call_pause: float
    _max_payload: int
    _opened_at: float
    _start_delay: float
    _wall_clock: Callable[[], float]
    _wall_offset: float | None
    _calls: HostCalls
    _requests: PendingRequests
    _tx: list[RosFrame]

    def _negotiation_timers(self, now: float, events: list[Event]) -> None:
        state = self._state
        if state is State.WAITING:
            if now - self._opened_at >= self._start_delay:
                self._request_topics(now)
        elif self._built is not None and now - self._sync_ref >= self._sync_timeout:
            self._lose_sync(now, events)  # connected, or renegotiating with a table in use
        elif state is State.NEGOTIATING:
            self._check_negotiation(now, events)
        elif (
            state is State.CONNECTED
            and self._probe_after > 0
            and now - self._sync_ref >= self._probe_after
            and now >= self._next_probe
        ):
            # Silent for longer than the library's time-sync period: it may have reset (it then
            # waits to be asked). A configured device just sends its table again. Probes go in
            # bursts with pauses (hwbridge.protocols.calling): a Mega's bootloader that took one
            # goes on to the sketch in a pause.
            since = self._sync_ref + self._probe_after
            if may_call(now, since, self._call_burst, self._call_pause):
                self._send_request(now)
                self._probed = True
                self.stats.silence_probes += 1
                self._next_probe = now + self._retry_max
            else:
                self._next_probe = next_call(now, since, self._call_burst, self._call_pause)
        elif (
            state is State.CONNECTED
            and self._want_topics
            and (self._requested_at is None or now - self._requested_at >= REQUEST_MIN_INTERVAL)
        ):
            self._request_topics(now)

    def _lose_sync(self, now: float, events: list[Event]) -> None:
        silence = now - self._sync_ref
        self.stats.sync_lost += 1
        reason = f"no time request for {silence:.1f} s"
        events += self._calls.abandon(ProtocolError(f"lost sync with the device ({reason})"))
        events.append(
            Disconnected(
                reason,
                HwBridgeTimeoutError(
                    f"lost sync with the rosserial device: {reason} (it resets, stopped or "
                    "lost the link); asking for its topics again"
                ),
            )
        )
        self._requests.clear()
        self._built = None
        self._accepted = {}
        self._request_topics(now)

    def _check_negotiation(self, now: float, events: list[Event]) -> None:
        neg = self._negotiation
        if neg is None:  # pragma: no cover - NEGOTIATING always has one
            return
        mark = neg.last_info_at if neg.last_info_at is not None else neg.answered_at
        if mark is not None:
            if now - mark >= self._settle_time:
                self._finish_negotiation(now, events)
            return
        if now - neg.reported_at >= self._sync_timeout:
            neg.reported_at = now
            waited = now - neg.started
            events.append(
                Error(
                    HwBridgeTimeoutError(
                        f"no answer from the device to 'request topics' for {waited:.1f} s; "
                        "check the baud rate (rosserial's default is 57600), that the sketch "
                        "calls nh.initNode() and nh.spinOnce(), and that it is a rosserial "
                        "(hydro or later) sketch; still asking"
                    )
                )
            )
        if now >= neg.retry_at:
            if not may_call(now, neg.started, self._call_burst, self._call_pause):
                neg.retry_at = next_call(now, neg.started, self._call_burst, self._call_pause)
                return
            self._send_request(now)
            neg.retry_gap = min(neg.retry_gap * 2, self._retry_max)
            neg.retry_at = now + neg.retry_gap

    def _send_request(self, now: float) -> None:
        self._send(ReservedId.PUBLISHER, b"")
        self.stats.topic_requests += 1
        self._requested_at = now

    def _request_topics(self, now: float) -> None:
        self._want_topics = False
        self._probed = False
        self._send_request(now)
        self._negotiation = Negotiation(
            started=now, retry_gap=self._retry, retry_at=now + self._retry, reported_at=now
        )
        self.framing.max_payload = self._max_payload
        self._state = State.NEGOTIATING

    def _finish_negotiation(self, now: float, events: list[Event]) -> None:
        neg = self._negotiation
        assert neg is not None
        self._negotiation = None
        errors: list[HwBridgeError] = []
        built = build_table(self.registry, neg.infos.values(), errors)
        events += [Error(e) for e in errors]
        # The library never sends a frame larger than its output buffer: accepting no more
        # bounds how long a corrupted header that claims a long payload can hold frames back.
        out = built.output_buffer
        self.framing.max_payload = min(MAX_PAYLOAD, out) if out is not None else self._max_payload
        if self._built is None:
            self.stats.sessions += 1
        self._built = built
        self._accepted = dict(neg.infos)
        self._state = State.CONNECTED
        self._sync_ref = max(self._sync_ref, now)
        gone = [
            channel
            for channel, name in self._calls.channels()
            if channel not in built.servers or built.servers[channel].name != name
        ]
        if gone:
            events += self._calls.abandon(
                ProtocolError("the device no longer serves this service"), gone
            )
        events.append(Connected(built.endpoints))

    def _on_time_request(self, now: float) -> None:
        self._sync_ref = max(self._sync_ref, now)
        neg = self._negotiation
        if neg is not None and neg.answered_at is None:
            neg.answered_at = now
        wall = self._wall_clock() if self._wall_offset is None else now + self._wall_offset
        wall = max(0.0, wall)
        sec = math.floor(wall)
        nsec = round((wall - sec) * 1e9)
        if nsec >= 1_000_000_000:
            sec, nsec = sec + 1, nsec - 1_000_000_000
        self._send(ReservedId.TIME, _TIME.pack(sec & 0xFFFFFFFF, nsec))
        self.stats.time_syncs += 1

    def _on_topic_info(self, kind: int, payload: bytes, now: float, events: list[Event]) -> None:
        self.stats.topic_infos += 1
        try:
            msg = self.registry.deserialize(payload, TOPIC_INFO_TYPE)
        except SerializationError as exc:
            self.stats.undecodable += 1
            self.stats.topics_refused += 1
            events.append(Error(ProtocolError(f"undecodable TopicInfo on id {kind}: {exc}")))
            return
        info = Info(
            kind,
            int(msg.topic_id),
            str(msg.topic_name),
            str(msg.message_type),
            str(msg.md5sum),
            int(msg.buffer_size),
        )
        neg = self._negotiation
        if neg is None:
            neg = self._negotiation = Negotiation(started=now, retry_at=math.inf)
            if not self._probed:  # a late TopicInfo: reopen, keeping what was accepted
                neg.infos.update(self._accepted)
            # else the answer to a silence probe: the device sends its whole table, which
            # replaces the old one (a board that reset into another sketch drops old topics)
            self._probed = False
            if self._state is State.CONNECTED:
                self._state = State.NEGOTIATING
        if neg.answered_at is None:
            neg.answered_at = now
        neg.last_info_at = now
        checked = check_info(self.registry, info, self._warned_types)
        if isinstance(checked, HwBridgeError):
            self.stats.topics_refused += 1
            self._refused_ids.add(info.topic_id)
            neg.infos.pop(info.topic_id, None)
            events.append(Error(checked))
            return
        if not checked.known:
            self.stats.unknown_types += 1
        self._refused_ids.discard(info.topic_id)
        neg.infos[info.topic_id] = checked

    def _send(self, topic_id: int, payload: bytes) -> None:
        self._tx.append(RosFrame(topic_id, payload))
        self.stats.tx_frames += 1
        self.stats.tx_bytes += len(payload) + FRAME_OVERHEAD
