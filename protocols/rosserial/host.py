"""Host side of a rosserial protocol v2 session, sans-I/O (what rosserial_python's node does).

Drive it like h11: feed received bytes with :meth:`RosserialHost.receive_data`, call
:meth:`RosserialHost.tick` regularly (at the latest at :meth:`RosserialHost.next_deadline`),
write out :meth:`RosserialHost.data_to_send` after every call, and act on the returned events::

    host = RosserialHost(registry, now=clock())
    while running:
        events = host.receive_data(link.read(), clock()) + host.tick(clock())
        link.write(host.data_to_send())
        ...
    link.write(host.close())

Times (``now``) are seconds on any monotonic clock; only time replies use ``wall_clock``.

Life cycle. Opening a serial port resets most Arduinos, so the host stays silent for
``start_delay`` seconds (the bootloader; time requests heard meanwhile go unanswered), then
sends "request topics". The device answers with a
time request and one ``rosserial_msgs/TopicInfo`` per endpoint. Each TopicInfo is checked at
once against the host's type of the same name (md5 of the message, or of the request or
response half of a service); a mismatch or an unknown type is reported as an :class:`Error`
event and only that endpoint is left out. Service endpoints arrive as two halves (a publisher
and a subscriber TopicInfo with the same name) and are joined by name.

When is the board configured? The device sends its TopicInfos back to back and then says
nothing that marks the end, so the host uses this rule:

- the negotiation has an answer once a time request or a TopicInfo arrived after the request;
- it is complete when ``settle_time`` (0.5 s) passed without a new TopicInfo since the last one
  (or since the time request, for a board without topics), or at once when a data frame arrives
  on a topic id announced in this negotiation (the library only publishes once configured, and
  it sends all its TopicInfos in one go before that);
- completion emits :class:`Connected` with the whole topic table.

A TopicInfo arriving after that (a slow link) reopens the negotiation: it is merged into the
table and :class:`Connected` is emitted again once the line is quiet. If nothing answers a
request for ``sync_timeout`` (15 s), the host sends it again and reports an :class:`Error`.
Once connected, the device asks for the time every ~2.5 s; ``sync_timeout`` without a time
request means "lost sync": the host emits :class:`SyncLost`, abandons pending calls, drops the
topic table (not connected until the next :class:`Connected`) and asks for topics again. A data
frame on a topic id the host does not know also makes it ask again (at most once a second), as
rosserial_python does; meanwhile the current table stays in use.

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
import math
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, fields
from enum import Enum
from typing import Any, Final, TypeAlias

import numpy as np

from hwbridge.protocols.errors import (
    FramingError,
    HwBridgeError,
    HwBridgeTimeoutError,
    MessageTypeError,
    ProtocolError,
    ProtocolMismatchError,
    SerializationError,
    UnknownTypeError,
)
from hwbridge.protocols.msgtypes import INT_RANGES, TypeRegistry
from hwbridge.protocols.rosserial.framing import (
    DEFAULT_MAX_PAYLOAD,
    MAX_PAYLOAD,
    BadFrame,
    FrameParser,
    NonFrameBytes,
    OldProtocol,
    ParserStats,
    RosFrame,
    encode_frame,
)
from hwbridge.protocols.rosserial.ids import (
    FIRST_USER_TOPIC,
    LOG_TYPE,
    PARAM_SERVICE,
    TIME_TYPE,
    TOPIC_INFO_TYPE,
    ReservedId,
)

__all__ = [
    "OLD_FIRMWARE_MESSAGE",
    "REQUEST_TOPICS",
    "TX_STOP",
    "Connected",
    "DeviceOutput",
    "Error",
    "HostEvent",
    "HostStats",
    "Log",
    "Message",
    "MessageTooLargeError",
    "ParamRequest",
    "ParamValue",
    "RosserialHost",
    "Service",
    "ServiceFailed",
    "ServiceRequest",
    "ServiceResponse",
    "SyncLost",
    "Topic",
    "TopicTable",
]

_log = logging.getLogger(__name__)

OLD_FIRMWARE_MESSAGE: Final = (
    "old rosserial firmware (protocol v1, pre-hydro): update rosserial_arduino (ros_lib) to "
    "0.5 or later and rebuild the sketch; hwbridge speaks rosserial protocol v2 only"
)
REQUEST_TOPICS: Final = encode_frame(ReservedId.PUBLISHER)
"""The "request topics" frame, ``FF FE 00 00 FF 00 00 FF``."""
TX_STOP: Final = encode_frame(ReservedId.TX_STOP)
"""The frame a host sends when it stops, ``FF FE 00 00 FF 0B 00 F4``."""
_REQUEST_MIN_INTERVAL: Final = 1.0
"""Least time between two "request topics" sent because of an unknown topic id."""
_MAX_PENDING_PARAMS: Final = 64
"""Parameter requests remembered per name before the oldest are forgotten."""

ParamValue: TypeAlias = bool | int | float | str | Sequence[bool | int | float | str] | None
"""What :meth:`RosserialHost.answer_param` accepts; None answers "missing" (empty arrays)."""


class MessageTooLargeError(FramingError):
    """A payload does not fit the device's input buffer; nothing was sent."""


# ---------------------------------------------------------------------------------- topic table
@dataclass(frozen=True)
class Topic:
    """One device publisher or subscriber, as the device announced it (md5 checked)."""

    name: str
    type: str
    md5: str
    topic_id: int
    buffer_size: int
    """Device output buffer (publishers) or input buffer (subscribers), in bytes."""


@dataclass(frozen=True)
class Service:
    """A device service server or client, joined from its two announced halves."""

    name: str
    type: str
    request_topic_id: int
    """Topic id the Request travels on (host -> device for servers, device -> host for clients)."""
    response_topic_id: int
    """Topic id the Response travels on."""
    request_md5: str
    response_md5: str
    input_buffer: int
    """The device's input buffer for what the host sends to this service."""


@dataclass(frozen=True)
class TopicTable:
    """Everything a device announced and the host accepted, by name."""

    publishers: dict[str, Topic] = field(default_factory=dict)
    """Topics the device publishes (the host receives them as :class:`Message`)."""
    subscribers: dict[str, Topic] = field(default_factory=dict)
    """Topics the device subscribes to (the host sends with :meth:`RosserialHost.publish`)."""
    service_servers: dict[str, Service] = field(default_factory=dict)
    """Services the device serves (called with :meth:`RosserialHost.call_service`)."""
    service_clients: dict[str, Service] = field(default_factory=dict)
    """Services the device calls (answered with :meth:`RosserialHost.respond`)."""


# ---------------------------------------------------------------------------------- events
@dataclass(frozen=True)
class Connected:
    """A negotiation completed; ``topics`` is the whole table (emitted again after each one)."""

    topics: TopicTable


@dataclass(frozen=True)
class SyncLost:
    """No time request for ``silence`` seconds: the device is gone or reset; topics requested."""

    silence: float


@dataclass(frozen=True)
class Message:
    """A device publication; ``payload`` is the ROS 1 serialized message, untouched."""

    topic: str
    type: str
    payload: bytes


@dataclass(frozen=True)
class ServiceRequest:
    """A device service client calls ``name``; answer with :meth:`RosserialHost.respond`."""

    name: str
    payload: bytes
    type: str = ""


@dataclass(frozen=True)
class ServiceResponse:
    """The device service server answered call ``request_id``."""

    request_id: int
    payload: bytes
    name: str = ""


@dataclass(frozen=True)
class ServiceFailed:
    """Call ``request_id`` will never be answered (timeout, lost sync, host closed)."""

    request_id: int
    error: HwBridgeError
    name: str = ""


@dataclass(frozen=True)
class ParamRequest:
    """The device asks for parameter ``name``; answer with :meth:`RosserialHost.answer_param`."""

    name: str


@dataclass(frozen=True)
class Log:
    """A log line from the device; ``level`` is DEBUG 0, INFO 1, WARN 2, ERROR 3, FATAL 4."""

    level: int
    text: str


@dataclass(frozen=True)
class DeviceOutput:
    """Bytes outside frames (debug prints, bootloader noise)."""

    data: bytes


@dataclass(frozen=True)
class Error:
    """Something the user should hear about; the session goes on (e.g. one topic refused)."""

    error: HwBridgeError


HostEvent: TypeAlias = (
    Connected
    | SyncLost
    | Message
    | ServiceRequest
    | ServiceResponse
    | ServiceFailed
    | ParamRequest
    | Log
    | DeviceOutput
    | Error
)


@dataclass(slots=True)
class HostStats:
    """Counters of a :class:`RosserialHost`; ``framing`` holds the receive parser's counters."""

    framing: ParserStats
    tx_frames: int = 0
    tx_bytes: int = 0
    time_syncs: int = 0
    """Time requests answered."""
    topic_requests: int = 0
    """"Request topics" frames sent."""
    topic_infos: int = 0
    topics_refused: int = 0
    """TopicInfos refused (md5 mismatch, unknown type, undecodable)."""
    messages_in: int = 0
    messages_out: int = 0
    service_calls: int = 0
    service_responses: int = 0
    service_timeouts: int = 0
    late_service_responses: int = 0
    """Responses that arrived when no call was in flight (after a timeout), dropped."""
    device_service_requests: int = 0
    params_requested: int = 0
    params_answered: int = 0
    logs: int = 0
    unknown_topic_frames: int = 0
    refused_topic_frames: int = 0
    """Frames on the id of a refused topic, dropped."""
    undecodable: int = 0
    """Control frames (TopicInfo, Log, parameter request) that did not decode."""
    sync_lost: int = 0

    def as_dict(self) -> dict[str, int]:
        """All counters, the parser's prefixed with ``rx_``."""
        out = {f"rx_{k}": v for k, v in self.framing.as_dict().items()}
        out.update({f.name: getattr(self, f.name) for f in fields(self) if f.name != "framing"})
        return out


# ---------------------------------------------------------------------------------- internals
class _State(Enum):
    WAITING = "waiting"
    NEGOTIATING = "negotiating"
    CONNECTED = "connected"
    CLOSED = "closed"


@dataclass(frozen=True)
class _Info:
    """One accepted TopicInfo: the reserved id it came on and its fields."""

    kind: int
    topic_id: int
    name: str
    type: str
    md5: str
    buffer_size: int


@dataclass
class _Negotiation:
    started: float
    infos: dict[int, _Info] = field(default_factory=dict)
    answered_at: float | None = None
    last_info_at: float | None = None


@dataclass
class _Call:
    request_id: int
    name: str
    payload: bytes
    timeout: float
    deadline: float
    sent: bool = False


_ROLE: Final = {
    ReservedId.PUBLISHER: "publisher",
    ReservedId.SUBSCRIBER: "subscriber",
    ReservedId.SERVICE_SERVER: "service server (response half)",
    ReservedId.SERVICE_SERVER + 1: "service server (request half)",
    ReservedId.SERVICE_CLIENT: "service client (request half)",
    ReservedId.SERVICE_CLIENT + 1: "service client (response half)",
}
_TOPIC_INFO_IDS: Final = frozenset(range(ReservedId.PUBLISHER, ReservedId.SERVICE_CLIENT + 2))
_DEVICE_OUTPUT_KINDS: Final = frozenset(
    {ReservedId.PUBLISHER, ReservedId.SERVICE_SERVER, ReservedId.SERVICE_CLIENT}
)
"""TopicInfo ids whose endpoint the device writes to (their buffer_size is its output buffer)."""
_DEVICE_INPUT_KINDS: Final = frozenset(
    {ReservedId.SUBSCRIBER, ReservedId.SERVICE_SERVER + 1, ReservedId.SERVICE_CLIENT + 1}
)

_RX_MESSAGE: Final = "message"
_RX_SERVER_RESPONSE: Final = "server_response"
_RX_CLIENT_REQUEST: Final = "client_request"


class RosserialHost:
    """One rosserial v2 session with one device; see the module docstring.

    Args:
        registry: message and service types to check md5 sums against (a new one if None).
        now: the time the link was opened (seconds, same clock as later calls).
        wall_clock: time source for time replies (seconds since the epoch).
        start_delay: silence after opening, for the bootloader (0 for links that do not reset).
        settle_time: quiet period that ends a negotiation (see the module docstring).
        sync_timeout: seconds without a time request before "lost sync", and between
            unanswered topic requests.
        max_payload: largest payload the receive parser accepts until the device announced
            its buffers; then the largest output buffer it announced is the limit.
        fallback_input_buffer: input buffer assumed for parameter answers when the device
            announced no buffer at all (150 bytes, the smallest stock one: ATmega168).
        old_protocol_threshold: protocol v1 headers in a row (without a valid v2 frame between
            them) before the "old firmware" error; a single one is usually line noise.
    """

    def __init__(
        self,
        registry: TypeRegistry | None = None,
        *,
        now: float = 0.0,
        wall_clock: Callable[[], float] = time.time,
        start_delay: float = 2.0,
        settle_time: float = 0.5,
        sync_timeout: float = 15.0,
        max_payload: int = DEFAULT_MAX_PAYLOAD,
        fallback_input_buffer: int = 150,
        old_protocol_threshold: int = 2,
    ) -> None:
        self.registry = registry if registry is not None else TypeRegistry()
        self._wall_clock = wall_clock
        self._start_delay = start_delay
        self._settle_time = settle_time
        self._sync_timeout = sync_timeout
        self._max_payload = max_payload
        self._fallback_input_buffer = fallback_input_buffer
        self._old_threshold = max(1, old_protocol_threshold)
        self._parser = FrameParser(max_payload)
        self.stats = HostStats(self._parser.stats)
        self._opened_at = now
        self._state = _State.WAITING
        self._tx = bytearray()
        self._pending_events: list[HostEvent] = []
        self._table: TopicTable | None = None
        self._rx: dict[int, tuple[str, str, str]] = {}  # topic id -> (kind, name, type)
        self._refused_ids: set[int] = set()
        self._accepted: dict[int, _Info] = {}
        self._input_buffer: int | None = None
        self._negotiation: _Negotiation | None = None
        self._requested_at: float | None = None
        self._want_topics = False
        self._sync_ref = now
        self._calls: dict[str, deque[_Call]] = {}
        self._next_request_id = 1
        self._client_pending: Counter[str] = Counter()
        self._params_pending: Counter[str] = Counter()
        self._old_streak = 0
        self._old_reported = False
        self._time_msg = self.registry.message_class(TIME_TYPE)
        self._time_field = self.registry.message_class("builtin_interfaces/msg/Time")
        self._param_response = self.registry.service(PARAM_SERVICE).response.name
        self._param_response_cls = self.registry.message_class(self._param_response)
        self._param_request = self.registry.service(PARAM_SERVICE).request.name

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> str:
        """``waiting`` (start delay), ``negotiating``, ``connected`` or ``closed``."""
        return self._state.value

    @property
    def connected(self) -> bool:
        """True once a negotiation completed (also while a later one reopens it)."""
        return self._table is not None and self._state is not _State.CLOSED

    @property
    def topics(self) -> TopicTable | None:
        """The current topic table, None before the first :class:`Connected`."""
        return self._table

    @property
    def input_buffer(self) -> int:
        """Input buffer assumed for frames that go to no subscriber (parameter answers)."""
        if self._input_buffer is not None:
            return self._input_buffer
        return self._fallback_input_buffer

    def next_deadline(self) -> float | None:
        """The latest time :meth:`tick` should next be called, or None if nothing is timed."""
        times: list[float] = []
        if self._state is _State.CLOSED:
            return None
        if self._state is _State.WAITING:
            times.append(self._opened_at + self._start_delay)
        neg = self._negotiation
        if self._state is _State.NEGOTIATING and neg is not None:
            mark = neg.last_info_at if neg.last_info_at is not None else neg.answered_at
            if mark is not None:
                times.append(mark + self._settle_time)
            if self._requested_at is not None:
                times.append(self._requested_at + self._sync_timeout)
        if self._table is not None:
            times.append(self._sync_ref + self._sync_timeout)
        if self._state is _State.CONNECTED and self._want_topics and self._requested_at is not None:
            times.append(self._requested_at + _REQUEST_MIN_INTERVAL)
        times.extend(queue[0].deadline for queue in self._calls.values() if queue)
        return min(times) if times else None

    def data_to_send(self) -> bytes:
        """Bytes to write to the link, in order; empties the queue."""
        out = bytes(self._tx)
        self._tx.clear()
        return out

    # ------------------------------------------------------------------ input
    def receive_data(self, data: bytes | bytearray | memoryview, now: float) -> list[HostEvent]:
        """Consume bytes read from the link at time ``now``; return the resulting events."""
        events = self._take_pending()
        if self._state is _State.CLOSED:
            return events
        self._timers(now, events)
        for item in self._parser.feed(data):
            if isinstance(item, RosFrame):
                self._old_streak = 0
                self._on_frame(item, now, events)
            elif isinstance(item, NonFrameBytes):
                events.append(DeviceOutput(item.data))
            elif isinstance(item, BadFrame):
                _log.debug("rosserial bad frame (%s): %s", item.reason.value, item.data.hex(" "))
            elif isinstance(item, OldProtocol):
                self._on_old_protocol(events)
        self._timers(now, events)
        return events

    def tick(self, now: float) -> list[HostEvent]:
        """Advance timers to ``now``: start-up, negotiation, lost sync, service timeouts."""
        events = self._take_pending()
        if self._state is not _State.CLOSED:
            self._timers(now, events)
        return events

    # ------------------------------------------------------------------ output API
    def publish(self, topic: str, payload: bytes | bytearray | memoryview) -> None:
        """Send ``payload`` (ROS 1 bytes) to the device's subscriber ``topic``.

        Raises:
            ProtocolError: not connected, or the device does not subscribe to ``topic``.
            MessageTooLargeError: the payload exceeds the subscriber's buffer (nothing sent).
        """
        table = self._require_table("publish on %r", topic)
        found = table.subscribers.get(topic)
        if found is None:
            raise ProtocolError(
                f"the device does not subscribe to {topic!r}; it subscribes to "
                f"{_names(table.subscribers)}"
            )
        data = bytes(payload)
        self._check_size(data, found.buffer_size, "message for %r (%s)", topic, found.type)
        self._send(found.topic_id, data)
        self.stats.messages_out += 1

    def call_service(
        self,
        name: str,
        request: bytes | bytearray | memoryview,
        now: float,
        timeout: float = 5.0,
    ) -> int:
        """Call the device's service server ``name``; returns the request id.

        rosserial carries no request ids, so calls to one service are queued and sent one at a
        time. The outcome arrives as :class:`ServiceResponse` or :class:`ServiceFailed` (after
        ``timeout`` seconds from this call at the latest). Without ids, a response that arrives
        after its call timed out is dropped while no call is in flight, but is taken for the
        next call's response if that one was already sent.

        Raises:
            ProtocolError: not connected, or the device serves no service ``name``.
            MessageTooLargeError: the request exceeds the device's input buffer.
        """
        table = self._require_table("call service %r", name)
        service = table.service_servers.get(name)
        if service is None:
            raise ProtocolError(
                f"the device serves no service {name!r}; it serves {_names(table.service_servers)}"
            )
        if not timeout > 0:
            raise ValueError(f"timeout must be positive, not {timeout}")
        data = bytes(request)
        self._check_size(data, service.input_buffer, "request for service %r", name)
        call = _Call(self._next_request_id, name, data, timeout, now + timeout)
        self._next_request_id += 1
        self.stats.service_calls += 1
        queue = self._calls.setdefault(name, deque())
        queue.append(call)
        if len(queue) == 1:
            self._send_call(call)
        return call.request_id

    def respond(self, name: str, response: bytes | bytearray | memoryview) -> None:
        """Answer the pending :class:`ServiceRequest` of the device's service client ``name``.

        Raises:
            ProtocolError: no such client, or it has no request waiting (the client library
                would write the answer through a stale pointer).
            MessageTooLargeError: the response exceeds the device's input buffer.
        """
        table = self._require_table("answer service %r", name)
        service = table.service_clients.get(name)
        if service is None:
            raise ProtocolError(
                f"the device has no service client {name!r}; it has {_names(table.service_clients)}"
            )
        if self._client_pending[name] <= 0:
            raise ProtocolError(f"the device's service client {name!r} has no request waiting")
        data = bytes(response)
        self._check_size(data, service.input_buffer, "response for service %r", name)
        self._client_pending[name] -= 1
        self._send(service.response_topic_id, data)

    def answer_param(self, name: str, value: ParamValue) -> None:
        """Answer the device's pending request for parameter ``name``.

        ``value`` is a bool, int, float or str, or a list of them (bools and ints go in the
        ``ints`` array, floats in ``floats``, strings in ``strings``; a list mixing ints and
        floats is sent as floats). None means the parameter does not exist: an empty answer,
        which the library reports as a length mismatch at once instead of waiting.

        Raises:
            ProtocolError: the device has no request for ``name`` waiting.
            SerializationError: the value has no rosserial form (dict, mixed strings and
                numbers, out of int32/float32 range).
            MessageTooLargeError: the answer exceeds the device's input buffer.
        """
        if self._params_pending[name] <= 0:
            raise ProtocolError(f"the device has no request for parameter {name!r} waiting")
        payload = self.encode_param(name, value)
        self._check_size(payload, self.input_buffer, "value of parameter %r", name)
        self._params_pending[name] -= 1
        self.stats.params_answered += 1
        self._send(ReservedId.PARAMETER_REQUEST, payload)

    def encode_param(self, name: str, value: ParamValue) -> bytes:
        """The ``RequestParam`` response bytes for ``value`` (see :meth:`answer_param`)."""
        ints: list[int] = []
        floats: list[float] = []
        strings: list[str] = []
        items = _param_items(name, value)
        kinds = {_param_kind(name, item) for item in items}
        if "str" in kinds and len(kinds) > 1:
            raise SerializationError(
                f"parameter {name!r}: a list must not mix strings and numbers (rosserial sends "
                f"one array type per parameter)"
            )
        if "str" in kinds:
            strings = [str(item) for item in items]
        elif "float" in kinds:
            floats = [_float32(name, float(item)) for item in items]
        else:
            ints = [_int32(name, int(item)) for item in items]
        message = self._param_response_cls(
            ints=np.array(ints, dtype=np.int32),
            floats=np.array(floats, dtype=np.float32),
            strings=strings,
        )
        return self.registry.serialize(message, self._param_response)

    def close(self) -> bytes:
        """Stop the session: returns the last bytes to write (TX_STOP included).

        Pending service calls are reported as :class:`ServiceFailed` by the next
        :meth:`tick` or :meth:`receive_data`; after that the host does nothing more.
        """
        if self._state is not _State.CLOSED:
            self._abandon_calls(self._pending_events, ProtocolError("the host closed the link"))
            self._send(ReservedId.TX_STOP, b"")
            self._state = _State.CLOSED
        return self.data_to_send()

    # ------------------------------------------------------------------ timers
    def _timers(self, now: float, events: list[HostEvent]) -> None:
        state = self._state
        if state is _State.WAITING:
            if now - self._opened_at >= self._start_delay:
                self._request_topics(now)
        elif self._table is not None and now - self._sync_ref >= self._sync_timeout:
            self._lose_sync(now, events)  # connected, or renegotiating with a table in use
        elif state is _State.NEGOTIATING:
            self._check_negotiation(now, events)
        elif (
            state is _State.CONNECTED
            and self._want_topics
            and (self._requested_at is None or now - self._requested_at >= _REQUEST_MIN_INTERVAL)
        ):
            self._request_topics(now)
        self._expire_calls(now, events)

    def _lose_sync(self, now: float, events: list[HostEvent]) -> None:
        silence = now - self._sync_ref
        self.stats.sync_lost += 1
        events.append(SyncLost(silence))
        self._abandon_calls(
            events,
            ProtocolError(f"lost sync with the device (no time request for {silence:.1f} s)"),
        )
        self._client_pending.clear()
        self._params_pending.clear()
        self._table = None
        self._rx = {}
        self._accepted = {}
        self._request_topics(now)

    def _check_negotiation(self, now: float, events: list[HostEvent]) -> None:
        neg = self._negotiation
        if neg is None:  # pragma: no cover - NEGOTIATING always has one
            return
        mark = neg.last_info_at if neg.last_info_at is not None else neg.answered_at
        if mark is not None and now - mark >= self._settle_time:
            self._finish_negotiation(now, events)
            return
        if (
            neg.answered_at is None
            and self._requested_at is not None
            and now - self._requested_at >= self._sync_timeout
        ):
            waited = now - self._requested_at
            events.append(
                Error(
                    HwBridgeTimeoutError(
                        f"no answer from the device to 'request topics' for {waited:.1f} s; "
                        "check the baud rate (rosserial's default is 57600), that the sketch "
                        "calls nh.initNode() and nh.spinOnce(), and that it is a rosserial "
                        "(hydro or later) sketch; asking again"
                    )
                )
            )
            self._request_topics(now)

    def _request_topics(self, now: float) -> None:
        self._want_topics = False
        self._send(ReservedId.PUBLISHER, b"")
        self.stats.topic_requests += 1
        self._requested_at = now
        self._negotiation = _Negotiation(started=now)
        self._parser.max_payload = self._max_payload
        self._state = _State.NEGOTIATING

    def _finish_negotiation(self, now: float, events: list[HostEvent]) -> None:
        neg = self._negotiation
        assert neg is not None
        self._negotiation = None
        publishers: dict[str, Topic] = {}
        subscribers: dict[str, Topic] = {}
        servers: dict[str, Service] = {}
        clients: dict[str, Service] = {}
        halves: dict[tuple[int, str], dict[int, _Info]] = {}
        rx: dict[int, tuple[str, str, str]] = {}
        for info in neg.infos.values():
            topic = Topic(info.name, info.type, info.md5, info.topic_id, info.buffer_size)
            if info.kind == ReservedId.PUBLISHER:
                publishers[info.name] = topic
                rx[info.topic_id] = (_RX_MESSAGE, info.name, info.type)
            elif info.kind == ReservedId.SUBSCRIBER:
                subscribers[info.name] = topic
            else:
                base: int = (
                    ReservedId.SERVICE_SERVER if info.kind < 4 else ReservedId.SERVICE_CLIENT
                )
                halves.setdefault((base, info.name), {})[info.kind - base] = info
        for (base, name), parts in halves.items():
            role = "service server" if base == ReservedId.SERVICE_SERVER else "service client"
            pub, sub = parts.get(0), parts.get(1)
            if pub is None or sub is None:
                missing = "publisher" if pub is None else "subscriber"
                events.append(
                    Error(
                        ProtocolError(
                            f"device {role} {name!r} announced no {missing} half "
                            f"(TopicInfo on id {base + (0 if pub is None else 1)}); it is "
                            "left out"
                        )
                    )
                )
                continue
            if base == ReservedId.SERVICE_SERVER:
                servers[name] = Service(
                    name, sub.type, sub.topic_id, pub.topic_id, sub.md5, pub.md5, sub.buffer_size
                )
                rx[pub.topic_id] = (_RX_SERVER_RESPONSE, name, pub.type)
            else:
                clients[name] = Service(
                    name, pub.type, pub.topic_id, sub.topic_id, pub.md5, sub.md5, sub.buffer_size
                )
                rx[pub.topic_id] = (_RX_CLIENT_REQUEST, name, pub.type)
        inputs = [i.buffer_size for i in neg.infos.values() if i.kind in _DEVICE_INPUT_KINDS]
        every = [i.buffer_size for i in neg.infos.values()]
        self._input_buffer = min(inputs) if inputs else (min(every) if every else None)
        outputs = [i.buffer_size for i in neg.infos.values() if i.kind in _DEVICE_OUTPUT_KINDS]
        # The library never sends a frame larger than its output buffer: accepting no more
        # bounds how long a corrupted header that claims a long payload can hold frames back.
        self._parser.max_payload = min(MAX_PAYLOAD, max(outputs)) if outputs else self._max_payload
        self._table = TopicTable(publishers, subscribers, servers, clients)
        self._accepted = dict(neg.infos)
        self._rx = rx
        self._state = _State.CONNECTED
        self._sync_ref = max(self._sync_ref, now)
        for name in list(self._calls):
            if name not in servers:
                self._abandon_calls(
                    events,
                    ProtocolError(f"the device no longer serves {name!r}"),
                    only=name,
                )
        events.append(Connected(self._table))

    def _expire_calls(self, now: float, events: list[HostEvent]) -> None:
        for name, queue in self._calls.items():
            expired = False
            while queue and queue[0].deadline <= now:
                call = queue.popleft()
                expired = True
                self.stats.service_timeouts += 1
                if call.sent:
                    why = (
                        "the request or its response may have been lost on the line "
                        "(rosserial has no retransmission)"
                    )
                else:
                    why = "it was never sent: an earlier call to it was still unanswered"
                events.append(
                    ServiceFailed(
                        call.request_id,
                        HwBridgeTimeoutError(
                            f"device service {name!r} did not answer call {call.request_id} "
                            f"within {call.timeout:g} s: {why}"
                        ),
                        name,
                    )
                )
            if expired and queue and not queue[0].sent:
                self._send_call(queue[0])

    def _abandon_calls(
        self, events: list[HostEvent], error: HwBridgeError, only: str | None = None
    ) -> None:
        for name in [only] if only is not None else list(self._calls):
            for call in self._calls.pop(name, ()):
                events.append(ServiceFailed(call.request_id, error, name))

    # ------------------------------------------------------------------ frames in
    def _on_frame(self, frame: RosFrame, now: float, events: list[HostEvent]) -> None:
        topic_id = frame.topic_id
        if topic_id >= FIRST_USER_TOPIC:
            self._on_data(frame, now, events)
        elif topic_id == ReservedId.TIME:
            self._on_time_request(now)
        elif topic_id in _TOPIC_INFO_IDS:
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

    def _on_time_request(self, now: float) -> None:
        self._sync_ref = max(self._sync_ref, now)
        neg = self._negotiation
        if neg is not None and neg.answered_at is None:
            neg.answered_at = now
        if self._state is _State.WAITING:
            return  # not talking yet
        wall = max(0.0, self._wall_clock())
        sec = math.floor(wall)
        nsec = round((wall - sec) * 1e9)
        if nsec >= 1_000_000_000:
            sec, nsec = sec + 1, nsec - 1_000_000_000
        stamp = self._time_msg(data=self._time_field(sec=sec & 0xFFFFFFFF, nanosec=nsec))
        self._send(ReservedId.TIME, self.registry.serialize(stamp, TIME_TYPE))
        self.stats.time_syncs += 1

    def _on_topic_info(
        self, kind: int, payload: bytes, now: float, events: list[HostEvent]
    ) -> None:
        self.stats.topic_infos += 1
        try:
            msg = self.registry.deserialize(payload, TOPIC_INFO_TYPE)
        except SerializationError as exc:
            self.stats.undecodable += 1
            self.stats.topics_refused += 1
            events.append(Error(ProtocolError(f"undecodable TopicInfo on id {kind}: {exc}")))
            return
        info = _Info(
            kind,
            int(msg.topic_id),
            str(msg.topic_name),
            str(msg.message_type),
            str(msg.md5sum),
            int(msg.buffer_size),
        )
        neg = self._negotiation
        if neg is None:  # a late TopicInfo: reopen, keeping what was accepted
            neg = self._negotiation = _Negotiation(started=now)
            neg.infos.update(self._accepted_infos())
            if self._state is _State.CONNECTED:
                self._state = _State.NEGOTIATING
        if neg.answered_at is None:
            neg.answered_at = now
        neg.last_info_at = now
        problem = self._check_info(info)
        if problem is not None:
            self.stats.topics_refused += 1
            self._refused_ids.add(info.topic_id)
            neg.infos.pop(info.topic_id, None)
            events.append(Error(problem))
            return
        self._refused_ids.discard(info.topic_id)
        neg.infos[info.topic_id] = info

    def _accepted_infos(self) -> dict[int, _Info]:
        """The TopicInfos behind the current table (to merge late TopicInfos into)."""
        return dict(self._accepted)

    def _check_info(self, info: _Info) -> HwBridgeError | None:
        """Why the host refuses ``info`` (unknown type, md5 mismatch), or None."""
        role = _ROLE.get(info.kind, f"endpoint (id {info.kind})")
        where = f"device {role} {info.name!r} (topic id {info.topic_id})"
        try:
            if info.kind in (ReservedId.PUBLISHER, ReservedId.SUBSCRIBER):
                host_type = self.registry.message(info.type)
                half = ""
            else:
                service = self.registry.service(info.type)
                is_request = info.kind in (ReservedId.SERVICE_SERVER + 1, ReservedId.SERVICE_CLIENT)
                host_type = service.request if is_request else service.response
                half = " request" if is_request else " response"
        except UnknownTypeError as exc:
            kind = "message" if info.kind <= ReservedId.SUBSCRIBER else "service"
            ext = ".msg" if kind == "message" else ".srv"
            error = MessageTypeError(
                f"{where} has {kind} type {info.type!r}, which hwbridge does not know ({exc}); "
                f"add its {ext} file to the message search path. This endpoint is left out."
            )
            error.__cause__ = exc
            return error
        if info.md5 != host_type.md5:
            return ProtocolMismatchError(
                f"md5 mismatch on {where}: the device's {info.type}{half} has md5 {info.md5}, "
                f"hwbridge's {host_type.name} (from {host_type.source}) has md5 "
                f"{host_type.md5}. Build both from the same definition (regenerate the "
                "sketch's ros_lib, or fix hwbridge's .msg). This endpoint is left out; the "
                "others keep working."
            )
        return None

    def _on_data(self, frame: RosFrame, now: float, events: list[HostEvent]) -> None:
        topic_id = frame.topic_id
        neg = self._negotiation
        if (
            neg is not None
            and self._state is _State.NEGOTIATING
            and topic_id in neg.infos
            and neg.infos[topic_id].kind in _DEVICE_OUTPUT_KINDS
        ):
            self._finish_negotiation(now, events)  # the device publishes: it is configured
        entry = self._rx.get(topic_id)
        if entry is None:
            if topic_id in self._refused_ids:
                self.stats.refused_topic_frames += 1
                return
            self.stats.unknown_topic_frames += 1
            if self._state is _State.CONNECTED and not self._want_topics:
                # the device knows a topic the host does not: ask again (the request goes out
                # at once, or a second after the previous one)
                _log.info("rosserial frame on unknown topic id %d: asking for topics", topic_id)
                self._want_topics = True
                self._timers(now, events)
            return
        kind, name, type_name = entry
        if kind == _RX_MESSAGE:
            self.stats.messages_in += 1
            events.append(Message(name, type_name, frame.payload))
        elif kind == _RX_SERVER_RESPONSE:
            queue = self._calls.get(name)
            if not queue or not queue[0].sent:
                self.stats.late_service_responses += 1
                return
            call = queue.popleft()
            self.stats.service_responses += 1
            events.append(ServiceResponse(call.request_id, frame.payload, name))
            if queue:
                self._send_call(queue[0])
        else:
            self.stats.device_service_requests += 1
            self._client_pending[name] += 1
            events.append(ServiceRequest(name, frame.payload, type_name))

    def _on_param_request(self, payload: bytes, events: list[HostEvent]) -> None:
        try:
            request = self.registry.deserialize(payload, self._param_request)
        except SerializationError as exc:
            self.stats.undecodable += 1
            events.append(Error(ProtocolError(f"undecodable parameter request: {exc}")))
            return
        name = str(request.name)
        self.stats.params_requested += 1
        if self._params_pending[name] < _MAX_PENDING_PARAMS:
            self._params_pending[name] += 1
        events.append(ParamRequest(name))

    def _on_log(self, payload: bytes, events: list[HostEvent]) -> None:
        try:
            record = self.registry.deserialize(payload, LOG_TYPE)
        except SerializationError as exc:
            self.stats.undecodable += 1
            events.append(Error(ProtocolError(f"undecodable Log frame: {exc}")))
            return
        self.stats.logs += 1
        events.append(Log(int(record.level), str(record.msg)))

    def _on_old_protocol(self, events: list[HostEvent]) -> None:
        self._old_streak += 1
        if self._old_streak >= self._old_threshold and not self._old_reported:
            self._old_reported = True
            events.append(Error(ProtocolMismatchError(OLD_FIRMWARE_MESSAGE)))

    # ------------------------------------------------------------------ helpers
    def _take_pending(self) -> list[HostEvent]:
        events = self._pending_events
        self._pending_events = []
        return events

    def _send(self, topic_id: int, payload: bytes) -> None:
        frame = encode_frame(topic_id, payload)
        self._tx += frame
        self.stats.tx_frames += 1
        self.stats.tx_bytes += len(frame)

    def _send_call(self, call: _Call) -> None:
        table = self._table
        service = table.service_servers.get(call.name) if table is not None else None
        if service is None:  # pragma: no cover - calls are abandoned when a service goes away
            return
        call.sent = True
        self._send(service.request_topic_id, call.payload)

    def _require_table(self, action: str, *args: object) -> TopicTable:
        """The topic table, or a ProtocolError saying why there is none; ``action % args``
        (formatted only then) says what could not be done."""
        if self._state is _State.CLOSED:
            raise ProtocolError(f"cannot {action % args}: the session is closed")
        if self._table is None:
            raise ProtocolError(
                f"cannot {action % args}: the device is not connected yet (wait for Connected)"
            )
        return self._table

    @staticmethod
    def _check_size(payload: bytes, limit: int, what: str, *args: object) -> None:
        if len(payload) > limit:
            raise MessageTooLargeError(
                f"{what % args} is {len(payload)} bytes, larger than the device's input buffer of "
                f"{limit} bytes; not sent (the rosserial client library would overrun its "
                "memory). Send less, or build the firmware with a larger INPUT_SIZE."
            )


def _names(items: Iterable[str]) -> str:
    found = sorted(items)
    return ", ".join(repr(n) for n in found) if found else "nothing"


def _param_items(name: str, value: ParamValue) -> list[Any]:
    if value is None:
        return []
    if isinstance(value, list | tuple):
        return list(value)
    return [value]


def _param_kind(name: str, item: Any) -> str:
    if isinstance(item, bool | int | np.integer):
        return "int"
    if isinstance(item, float | np.floating):
        return "float"
    if isinstance(item, str):
        return "str"
    raise SerializationError(
        f"parameter {name!r}: {type(item).__name__} values cannot be sent to a rosserial "
        "device (only bool, int, float, str and lists of one of them)"
    )


def _int32(name: str, value: int) -> int:
    low, high = INT_RANGES["int32"]
    if not low <= value <= high:
        raise SerializationError(
            f"parameter {name!r}: {value} does not fit an int32 (rosserial sends ints as int32)"
        )
    return value


def _float32(name: str, value: float) -> float:
    if math.isfinite(value) and abs(value) > float(np.finfo(np.float32).max):
        raise SerializationError(
            f"parameter {name!r}: {value} does not fit a float32 (rosserial sends floats as "
            "float32)"
        )
    return value
