"""Host side of a rosserial protocol v2 session, sans-I/O (what rosserial_python's node does).

:class:`RosserialHost` is a :class:`hwbridge.protocols.base.BoardSession`: feed what the link
read with :meth:`~RosserialHost.receive_data`, call :meth:`~RosserialHost.tick` at the latest at
:meth:`~RosserialHost.next_deadline`, write out :meth:`~RosserialHost.chunks_to_send` after every
call, and act on the returned events (the shared ones of :mod:`hwbridge.protocols.base`)::

    host = RosserialHost(registry, now=clock())
    while running:
        events = [*host.receive_data(link.read(), clock()), *host.tick(clock())]
        for chunk in host.chunks_to_send():
            link.write(chunk)
        ...
    host.close(clock())
    for chunk in host.chunks_to_send():  # TX_STOP
        link.write(chunk)

Times (``now``) are seconds on one monotonic clock; time replies use ``now + wall_offset`` (or
``wall_clock()`` when no offset is given). Channels are topic ids (see
:mod:`hwbridge.protocols.rosserial.table`).

Life cycle (details in :mod:`hwbridge.protocols.rosserial.negotiation`). The host sends "request
topics" at once and repeats it with backoff (0.1 s doubling up to 1 s) until the device answers,
so a running sketch answers within milliseconds and one that the opening of the port reset is
caught soon after its bootloader; ``start_delay`` (default 0) keeps it silent for that long first.
Each TopicInfo is checked against the host's type: a md5 mismatch is refused (an ``Error``
event), a type the host does not know passes through with the device's name and md5 (a warning
once per type). ``Connected`` follows once the line is quiet; lost sync (no time request for
``sync_timeout``) gives ``Disconnected`` and a new negotiation.

Services and parameters have no request ids on the wire; the host makes them up and keeps the
order (see :mod:`hwbridge.protocols.rosserial.services`). rosserial cannot fail a device's call,
nor push a parameter: ``respond_service(..., error=...)`` and ``push_param`` return False.

Sizes. The client library does not check the length of what it receives, so the host refuses
(with :class:`MessageTooLargeError`, before anything is sent) a payload larger than the device's
input buffer: the ``buffer_size`` of the subscriber the frame goes to; for parameter answers the
smallest subscriber buffer, else the smallest buffer announced, else ``fallback_input_buffer``.
Received frames may be as large as ``max_payload`` until the device announced its output buffer,
then as large as that buffer (the library never sends more), which bounds how long a corrupted
header claiming a long payload can hold back the frames behind it.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from typing import Any, Final

from hwbridge.protocols.base import (
    DebugOutput,
    Disconnected,
    Error,
    Event,
    Log,
    Message,
    ParamRequest,
    ServiceRequest,
    ServiceResponse,
    SessionStats,
)
from hwbridge.protocols.calling import BOOTLOADER_QUIET, check_bursts
from hwbridge.protocols.errors import (
    ProtocolError,
    ProtocolMismatchError,
    SerializationError,
)
from hwbridge.protocols.msgtypes import TypeRegistry
from hwbridge.protocols.rosserial.framing import (
    DEFAULT_MAX_PAYLOAD,
    BadFrame,
    NonFrameBytes,
    OldProtocol,
    RosFrame,
    RosserialFraming,
    encode_frame,
)
from hwbridge.protocols.rosserial.ids import (
    FIRST_USER_TOPIC,
    LOG_TYPE,
    PARAM_SERVICE,
    ReservedId,
)
from hwbridge.protocols.rosserial.negotiation import (
    REQUEST_MIN_INTERVAL,
    Negotiation,
    NegotiationMixin,
    State,
)
from hwbridge.protocols.rosserial.params import ParamValue, encode_param
from hwbridge.protocols.rosserial.services import (
    Call,
    HostCalls,
    MessageTooLargeError,
    PendingRequests,
    RequestIds,
    check_size,
)
from hwbridge.protocols.rosserial.stats import HostStats
from hwbridge.protocols.rosserial.table import (
    DEVICE_OUTPUT_KINDS,
    RX_CLIENT_REQUEST,
    RX_MESSAGE,
    TOPIC_INFO_IDS,
    BuiltTable,
    Info,
    Service,
    Topic,
    TopicTable,
)

__all__ = [
    "OLD_FIRMWARE_MESSAGE",
    "REQUEST_TOPICS",
    "TX_STOP",
    "HostStats",
    "MessageTooLargeError",
    "ParamValue",
    "RosserialHost",
    "Service",
    "Topic",
    "TopicTable",
]

_log = logging.getLogger("hwbridge.protocols.rosserial")

OLD_FIRMWARE_MESSAGE: Final = (
    "old rosserial firmware (protocol v1, pre-hydro): update rosserial_arduino (ros_lib) to "
    "0.5 or later and rebuild the sketch; hwbridge speaks rosserial protocol v2 only"
)
REQUEST_TOPICS: Final = encode_frame(ReservedId.PUBLISHER)
"""The "request topics" frame, ``FF FE 00 00 FF 00 00 FF``."""
TX_STOP: Final = encode_frame(ReservedId.TX_STOP)
"""The frame a host sends when it stops, ``FF FE 00 00 FF 0B 00 F4``."""
_PARAMS: Final = 0
"""The key of parameter requests among the pending requests."""


class RosserialHost(NegotiationMixin):
    """One rosserial v2 session with one device; see the module docstring.

    Args:
        registry: message and service types to check md5 sums against (a new one if None).
        now: the time the link was opened (seconds, same clock as later calls).
        framing: the framing to decode and encode with (a new :class:`RosserialFraming` if None);
            the host sets its ``max_payload``.
        wall_clock: time source for time replies (seconds since the epoch), used when
            ``wall_offset`` is None.
        wall_offset: wall-clock time minus the ``now`` clock, seconds: time replies are
            ``now + wall_offset``.
        start_delay: silence after opening before the first "request topics" (0: none).
        settle_time: quiet period that ends a negotiation (see the module docstring).
        sync_timeout: seconds without a time request before "lost sync", and between reports
            that nothing answers.
        request_retry: first interval between unanswered "request topics"; it doubles up to
            ``request_retry_max``.
        request_retry_max: the longest interval between unanswered "request topics".
        probe_after: seconds without a time request, while connected, after which "request
            topics" is sent (then every ``request_retry_max``) to catch a device that reset: the
            library asks for the time every ~2.5 s and says nothing after a reset until asked.
            A configured device answers it harmlessly (its table again). 0 turns it off.
        max_payload: largest payload the receive parser accepts until the device announced
            its buffers; then the largest output buffer it announced is the limit.
        fallback_input_buffer: input buffer assumed for parameter answers when the device
            announced no buffer at all (150 bytes, the smallest stock one: ATmega168).
        old_protocol_threshold: protocol v1 headers in a row (without a valid v2 frame between
            them) before the "old firmware" error; a single one is usually line noise.
        call_burst: seconds of unanswered "request topics" (and silence probes) after which the
            host leaves the device ``call_pause`` seconds of silence, and so on
            (:mod:`hwbridge.protocols.calling`; 0, the default: no pauses). The runtime's
            sessions use CALL_BURST: a Mega whose bootloader took a request goes on to the
            sketch in a pause.
        call_pause: the silence after each ``call_burst``.
    """

    def __init__(
        self,
        registry: TypeRegistry | None = None,
        *,
        now: float = 0.0,
        framing: RosserialFraming | None = None,
        wall_clock: Callable[[], float] = time.time,
        wall_offset: float | None = None,
        start_delay: float = 0.0,
        settle_time: float = 0.5,
        sync_timeout: float = 15.0,
        request_retry: float = 0.1,
        request_retry_max: float = 1.0,
        probe_after: float = 3.0,
        max_payload: int = DEFAULT_MAX_PAYLOAD,
        fallback_input_buffer: int = 150,
        old_protocol_threshold: int = 2,
        call_burst: float = 0.0,
        call_pause: float = BOOTLOADER_QUIET,
    ) -> None:
        if not 0 < request_retry <= request_retry_max:
            raise ValueError(
                f"need 0 < request_retry <= request_retry_max, not {request_retry}, "
                f"{request_retry_max}"
            )
        self.registry = registry if registry is not None else TypeRegistry()
        self._wall_clock = wall_clock
        self._wall_offset = wall_offset
        self._start_delay = start_delay
        self._settle_time = settle_time
        self._sync_timeout = sync_timeout
        self._retry = request_retry
        self._retry_max = request_retry_max
        self._probe_after = probe_after
        self._next_probe = 0.0
        check_bursts(call_burst, call_pause)
        self._call_burst = call_burst
        self._call_pause = call_pause
        self._max_payload = max_payload
        self._fallback_input_buffer = fallback_input_buffer
        self._old_threshold = max(1, old_protocol_threshold)
        self.framing = framing if framing is not None else RosserialFraming(max_payload)
        self.framing.max_payload = max_payload
        self.stats = HostStats(self.framing.stats)
        self._now = now
        self._opened_at = now
        self._state = State.WAITING
        self._tx: list[RosFrame] = []
        self._pending_events: list[Event] = []
        self._built: BuiltTable | None = None
        self._refused_ids: set[int] = set()
        self._accepted: dict[int, Info] = {}
        self._warned_types: set[str] = set()
        self._negotiation: Negotiation | None = None
        self._requested_at: float | None = None
        self._want_topics = False
        self._probed = False
        self._sync_ref = now
        self._ids = RequestIds()
        self._calls = HostCalls()
        self._requests = PendingRequests()
        """Requests of device service clients (by channel) and parameter requests."""
        self._old_streak = 0
        self._old_reported = False
        self._param_request = self.registry.service(PARAM_SERVICE).request.name
        if start_delay <= 0:
            self._request_topics(now)

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> str:
        """``waiting`` (start delay), ``negotiating``, ``connected`` or ``closed``."""
        return self._state.value

    @property
    def connected(self) -> bool:
        """True once a negotiation completed (also while a later one reopens it)."""
        return self._built is not None and self._state is not State.CLOSED

    @property
    def topics(self) -> TopicTable | None:
        """The current topic table, None before the first ``Connected``."""
        return self._built.table if self._built is not None else None

    @property
    def input_buffer(self) -> int:
        """Input buffer assumed for frames that go to no subscriber (parameter answers)."""
        if self._built is not None and self._built.input_buffer is not None:
            return self._built.input_buffer
        return self._fallback_input_buffer

    def counters(self) -> SessionStats:
        """The session's counters (the host's own ones in ``detail``)."""
        return self.stats.session_stats()

    def describe(self) -> dict[str, Any]:
        """Facts about the device and the session (JSON-able)."""
        built = self._built
        table = built.table if built is not None else TopicTable()
        return {
            "protocol": "rosserial",
            "state": self.state,
            "input_buffer": self.input_buffer,
            "max_rx_payload": self.framing.max_payload,
            "publishers": len(table.publishers),
            "subscribers": len(table.subscribers),
            "service_servers": len(table.service_servers),
            "service_clients": len(table.service_clients),
            "unknown_types": sorted(self._warned_types),
            "refused_topic_ids": sorted(self._refused_ids),
            "pending_calls": len(self._calls),
        }

    def next_deadline(self) -> float | None:
        """The latest time :meth:`tick` should next be called, or None if nothing is timed."""
        times: list[float] = []
        if self._state is State.CLOSED:
            return None
        if self._state is State.WAITING:
            times.append(self._opened_at + self._start_delay)
        neg = self._negotiation
        if self._state is State.NEGOTIATING and neg is not None:
            mark = neg.last_info_at if neg.last_info_at is not None else neg.answered_at
            if mark is not None:
                times.append(mark + self._settle_time)
            else:
                times.append(neg.retry_at)
                times.append(neg.reported_at + self._sync_timeout)
        if self._built is not None:
            times.append(self._sync_ref + self._sync_timeout)
        if self._state is State.CONNECTED and self._probe_after > 0:
            times.append(max(self._sync_ref + self._probe_after, self._next_probe))
        if self._state is State.CONNECTED and self._want_topics and self._requested_at is not None:
            times.append(self._requested_at + REQUEST_MIN_INTERVAL)
        call_deadline = self._calls.deadline()
        if call_deadline is not None:
            times.append(call_deadline)
        return min(times) if times else None

    def chunks_to_send(self) -> list[bytes]:
        """What to write to the link (one chunk, or none); empties the queue."""
        if not self._tx:
            return []
        frames = self._tx
        self._tx = []
        return self.framing.encode(frames, self._now)

    def data_to_send(self) -> bytes:
        """Bytes to write to the link, in order; empties the queue."""
        return b"".join(self.chunks_to_send())

    # ------------------------------------------------------------------ input
    def receive_data(self, data: bytes | bytearray | memoryview, now: float) -> list[Event]:
        """Consume bytes read from the link at time ``now``; return the resulting events."""
        events = self._take_pending()
        if self._state is State.CLOSED:
            return events
        self._now = now
        self._timers(now, events)
        for item in self.framing.decode(data):
            if isinstance(item, RosFrame):
                self._old_streak = 0
                self._on_frame(item, now, events)
            elif isinstance(item, NonFrameBytes):
                events.append(DebugOutput(item.data))
            elif isinstance(item, BadFrame):
                _log.debug("rosserial bad frame (%s): %s", item.reason.value, item.data.hex(" "))
            elif isinstance(item, OldProtocol):
                self._on_old_protocol(events)
        self._timers(now, events)
        return events

    def tick(self, now: float) -> list[Event]:
        """Advance timers to ``now``: start-up, negotiation, lost sync, service timeouts."""
        events = self._take_pending()
        if self._state is not State.CLOSED:
            self._now = now
            self._timers(now, events)
        return events

    # ------------------------------------------------------------------ actions
    def publish(self, channel: int, payload: bytes | bytearray | memoryview, /) -> bool:
        """Send ``payload`` (ROS 1 bytes) to the device subscriber on topic id ``channel``.

        Returns False when not connected (or closed).

        Raises:
            ProtocolError: the device has no subscriber on ``channel``.
            MessageTooLargeError: the payload exceeds the subscriber's buffer (nothing sent).
        """
        built = self._usable()
        if built is None:
            return False
        topic = built.subscribers.get(channel)
        if topic is None:
            raise ProtocolError(
                f"the device has no subscriber on topic id {channel}; it subscribes to "
                f"{_channels((t.topic_id, t.name) for t in built.subscribers.values())}"
            )
        data = bytes(payload)
        check_size(data, topic.buffer_size, "message for %r (%s)", topic.name, topic.type)
        self._send(topic.topic_id, data)
        self.stats.messages_out += 1
        return True

    def call_service(
        self,
        channel: int,
        request: bytes | bytearray | memoryview,
        *,
        timeout: float = 5.0,
        now: float,
    ) -> int:
        """Call the device's service server on ``channel``; returns the request id.

        rosserial carries no request ids, so calls to one service are queued and sent one at a
        time. Exactly one :class:`ServiceResponse` with the id follows: the answer, or an error
        (after ``timeout`` seconds from this call at the latest; at once when not connected).
        Without ids, a response that arrives after its call timed out is dropped while no call
        is in flight, but is taken for the next call's response if that one was already sent.

        Raises:
            ProtocolError: connected, but the device serves no service on ``channel``.
            MessageTooLargeError: the request exceeds the device's input buffer.
            ValueError: ``timeout`` is not positive.
        """
        if not timeout > 0:
            raise ValueError(f"timeout must be positive, not {timeout}")
        built = self._usable()
        if built is None:
            request_id = self._ids.new()
            why = "the session is closed" if self._state is State.CLOSED else "not connected"
            error = ProtocolError(f"service call on topic id {channel}: {why}")
            self._pending_events.append(ServiceResponse(channel, request_id, b"", error))
            return request_id
        service = built.servers.get(channel)
        if service is None:
            raise ProtocolError(
                f"the device serves no service on topic id {channel}; it serves "
                f"{_channels((s.request_topic_id, s.name) for s in built.servers.values())}"
            )
        data = bytes(request)
        check_size(data, service.input_buffer, "request for service %r", service.name)
        request_id = self._ids.new()
        call = Call(request_id, channel, service.name, data, timeout, now + timeout)
        self.stats.service_calls += 1
        if self._calls.add(call):
            self._send_call(call)
        return request_id

    def respond_service(
        self,
        channel: int,
        request_id: int,
        payload: bytes | bytearray | memoryview = b"",
        *,
        error: str | None = None,
    ) -> bool:
        """Answer the :class:`ServiceRequest` ``request_id`` of the device client ``channel``.

        Returns False (nothing sent) when the request is not pending (answered already, or
        forgotten when sync was lost), and with ``error``: rosserial cannot fail a device's
        call (its client keeps waiting), so the request is only forgotten.

        Raises:
            MessageTooLargeError: the response exceeds the device's input buffer (the request
                stays pending).
        """
        if error is not None:
            if self._requests.take(channel, request_id) is not None:
                _log.info(
                    "rosserial cannot fail the device's call %d on topic id %d (%s); "
                    "its client keeps waiting",
                    request_id,
                    channel,
                    error,
                )
            return False
        built = self._usable()
        if built is None or self._requests.peek(channel, request_id) is None:
            return False
        service = built.clients.get(channel)
        if service is None:  # pragma: no cover - requests are forgotten with their client
            return False
        data = bytes(payload)
        check_size(data, service.input_buffer, "response for service %r", service.name)
        self._requests.take(channel, request_id)
        self._send(service.response_topic_id, data)
        return True

    def answer_param(self, request_id: int, value: ParamValue, /) -> bool:
        """Answer the device's :class:`ParamRequest` ``request_id`` (see :mod:`.params`).

        ``value`` is a bool, int, float or str, or a list of them; None means the parameter does
        not exist. Returns False (nothing sent) when the request is not pending.

        Raises:
            SerializationError: the value has no rosserial form (dict, mixed strings and
                numbers, out of int32/float32 range); the request stays pending.
            MessageTooLargeError: the answer exceeds the device's input buffer.
        """
        name = self._requests.peek(_PARAMS, request_id)
        if name is None or self._state is State.CLOSED:
            return False
        payload = encode_param(name, value)
        check_size(payload, self.input_buffer, "value of parameter %r", name)
        self._requests.take(_PARAMS, request_id)
        self.stats.params_answered += 1
        self._send(ReservedId.PARAMETER_REQUEST, payload)
        return True

    def push_param(self, name: str, value: Any, /) -> bool:
        """rosserial cannot push parameters: always False."""
        return False

    @staticmethod
    def encode_param(name: str, value: ParamValue) -> bytes:
        """The ``RequestParam`` response bytes for ``value`` (see :meth:`answer_param`)."""
        return encode_param(name, value)

    def close(self, now: float | None = None, /) -> list[Event]:
        """Stop the session: TX_STOP goes to :meth:`chunks_to_send`; pending calls fail.

        Returns the last events (failed calls, then ``Disconnected`` if it was connected);
        after that the host does nothing more.
        """
        events = self._take_pending()
        if self._state is State.CLOSED:
            return events
        if now is not None:
            self._now = now
        error = ProtocolError("the host closed the session")
        events += self._calls.abandon(error)
        if self.connected:
            events.append(Disconnected("closed by the host", error))
        self._requests.clear()
        self._send(ReservedId.TX_STOP, b"")
        self._state = State.CLOSED
        return events

    # ------------------------------------------------------------------ timers
    def _timers(self, now: float, events: list[Event]) -> None:
        self._negotiation_timers(now, events)
        failed, resend = self._calls.expire(now)
        if failed:
            self.stats.service_timeouts += len(failed)
            events += failed
        for call in resend:
            self._send_call(call)

    # ------------------------------------------------------------------ frames in
    def _on_frame(self, frame: RosFrame, now: float, events: list[Event]) -> None:
        topic_id = frame.topic_id
        if topic_id >= FIRST_USER_TOPIC:
            self._on_data(frame, now, events)
        elif topic_id == ReservedId.TIME:
            self._on_time_request(now)
        elif topic_id in TOPIC_INFO_IDS:
            if topic_id == ReservedId.PUBLISHER and not frame.payload:
                self.stats.unknown_topic_frames += 1  # our own "request topics" echoed back
                return
            self._on_topic_info(topic_id, frame.payload, now, events)
        elif topic_id == ReservedId.PARAMETER_REQUEST:
            self._on_param_request(frame.payload, events)
        elif topic_id == ReservedId.LOG:
            self._on_log(frame.payload, events)
        else:
            self.stats.unknown_topic_frames += 1

    def _on_data(self, frame: RosFrame, now: float, events: list[Event]) -> None:
        topic_id = frame.topic_id
        neg = self._negotiation
        if (
            neg is not None
            and self._state is State.NEGOTIATING
            and topic_id in neg.infos
            and neg.infos[topic_id].kind in DEVICE_OUTPUT_KINDS
        ):
            self._finish_negotiation(now, events)  # the device publishes: it is configured
        built = self._built
        entry = built.rx.get(topic_id) if built is not None else None
        if entry is None:
            if topic_id in self._refused_ids:
                self.stats.refused_topic_frames += 1
                return
            self.stats.unknown_topic_frames += 1
            if self._state is State.CONNECTED and not self._want_topics:
                # the device knows a topic the host does not: ask again (the request goes out
                # at once, or a second after the previous one)
                _log.info("rosserial frame on unknown topic id %d: asking for topics", topic_id)
                self._want_topics = True
                self._timers(now, events)
            return
        kind, channel = entry
        if kind == RX_MESSAGE:
            self.stats.messages_in += 1
            events.append(Message(channel, frame.payload, 0))
        elif kind == RX_CLIENT_REQUEST:
            self.stats.device_service_requests += 1
            request_id = self._ids.new()
            self._requests.add(channel, request_id)
            events.append(ServiceRequest(channel, request_id, frame.payload))
        else:
            call, after = self._calls.answered(channel)
            if call is None:
                self.stats.late_service_responses += 1
                return
            self.stats.service_responses += 1
            events.append(ServiceResponse(channel, call.request_id, frame.payload))
            if after is not None:
                self._send_call(after)

    def _on_param_request(self, payload: bytes, events: list[Event]) -> None:
        try:
            request = self.registry.deserialize(payload, self._param_request)
        except SerializationError as exc:
            self.stats.undecodable += 1
            events.append(Error(ProtocolError(f"undecodable parameter request: {exc}")))
            return
        name = str(request.name)
        self.stats.params_requested += 1
        request_id = self._ids.new()
        self._requests.add(_PARAMS, request_id, name)
        events.append(ParamRequest(request_id, name))

    def _on_log(self, payload: bytes, events: list[Event]) -> None:
        try:
            record = self.registry.deserialize(payload, LOG_TYPE)
        except SerializationError as exc:
            self.stats.undecodable += 1
            events.append(Error(ProtocolError(f"undecodable Log frame: {exc}")))
            return
        self.stats.logs += 1
        events.append(Log(int(record.level), str(record.msg)))

    def _on_old_protocol(self, events: list[Event]) -> None:
        self._old_streak += 1
        if self._old_streak >= self._old_threshold and not self._old_reported:
            self._old_reported = True
            events.append(Error(ProtocolMismatchError(OLD_FIRMWARE_MESSAGE)))

    # ------------------------------------------------------------------ helpers
    def _take_pending(self) -> list[Event]:
        events = self._pending_events
        self._pending_events = []
        return events

    def _usable(self) -> BuiltTable | None:
        """The table, if the session is connected and not closed."""
        return self._built if self._state is not State.CLOSED else None

    def _send_call(self, call: Call) -> None:
        built = self._built
        service = built.servers.get(call.channel) if built is not None else None
        if service is None:  # pragma: no cover - calls are abandoned when a service goes away
            return
        call.sent = True
        self._send(service.request_topic_id, call.payload)


def _channels(items: Iterable[tuple[int, str]]) -> str:
    found = sorted(items)
    return ", ".join(f"{ch} ({name!r})" for ch, name in found) if found else "nothing"
