"""Emulation of the rosserial client library (ros_lib's ``NodeHandle``) for tests, sans-I/O.

:class:`RosserialDevice` behaves on the wire as a sketch built on rosserial_arduino does, so
host code can be tested against it without a board:

- topic ids as the library numbers them: subscriber slot i -> 100 + i, publisher slot i ->
  100 + ``max_subscribers`` + i; a service server or client takes one publisher slot and one
  subscriber slot, in the order endpoints are added;
- receiving: the library's byte state machine (it abandons a frame on a bad length checksum and
  does not rescan; a frame whose parts arrive more than 20 ms apart is dropped; a frame after
  ``FF`` + a wrong version byte makes an unconfigured device send a time request);
- on "request topics": a time request, then one TopicInfo per publisher slot (ids 0/2/4) and per
  subscriber slot (ids 1/3/5), with ``output_size`` / ``input_size`` as ``buffer_size``; then it
  is configured. Bytes after the request wait for the next call, as ``spinOnce`` returns there;
- its own publications on ids >= 100 are dropped silently until configured; a frame larger than
  ``output_size`` is dropped with an ERROR log, as the library does;
- a time request every 2.5 s while configured; unconfigured after 11 s without a time reply,
  and on TX_STOP; :meth:`RosserialDevice.ros_time` follows the library's clock arithmetic;
- parameters: :meth:`RosserialDevice.request_param` waits (1 s by default) and logs
  "Failed to get param: timeout expired" when nothing comes;
- services: a server's handler answers on its publisher id; a client call waits for the
  response on its subscriber id (or until the device is unconfigured).

Differences, because an emulation cannot block or corrupt memory: the sketch is not blocked
while a service call or parameter request waits, and a payload larger than ``input_size``
(which would overrun the real library's buffer) is reported as :class:`InputOverrun` and dropped,
and an error log that does not fit ``output_size`` itself is dropped (the library would recurse).
Times (``now``) are seconds; the emulated ``hardware.time()`` is ``now`` in whole milliseconds,
wrapping at 2**32 as on the board.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Final

from hwbridge.protocols.errors import ProtocolError, SerializationError
from hwbridge.protocols.msgtypes import TypeRegistry
from hwbridge.protocols.rosserial.device_events import (
    Configured,
    DeviceEvent,
    DeviceStats,
    Endpoint,
    InputOverrun,
    ParamResult,
    Received,
    ServiceCalled,
    ServiceEndpoint,
    ServiceHandler,
    ServiceResult,
    TimeSynced,
    Unconfigured,
)
from hwbridge.protocols.rosserial.framing import (
    FRAME_OVERHEAD,
    SYNC,
    VERSION_V2,
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
    "DEBUG",
    "ERROR",
    "FATAL",
    "INFO",
    "WARN",
    "Configured",
    "DeviceEvent",
    "DeviceStats",
    "Endpoint",
    "InputOverrun",
    "ParamResult",
    "Received",
    "RosserialDevice",
    "ServiceCalled",
    "ServiceEndpoint",
    "ServiceHandler",
    "ServiceResult",
    "TimeSynced",
    "Unconfigured",
]

DEBUG: Final = 0
INFO: Final = 1
WARN: Final = 2
ERROR: Final = 3
FATAL: Final = 4

SYNC_SECONDS: Final = 5
"""The library's time base: a time request every SYNC_SECONDS * 500 ms, unconfigured after
SYNC_SECONDS * 2200 ms without a time reply."""
SERIAL_MSG_TIMEOUT_MS: Final = 20
"""A frame must be complete within this many ms of its first byte."""
_MASK: Final = 0xFFFFFFFF
_NSEC: Final = 1_000_000_000

# receive state machine modes, as in node_handle.h
_FIRST_FF, _PROTOCOL_VER, _SIZE_L, _SIZE_H, _SIZE_CHECKSUM = 0, 1, 2, 3, 4
_TOPIC_L, _TOPIC_H, _MESSAGE, _MSG_CHECKSUM = 5, 6, 7, 8


@dataclass
class _Pub:
    id: int
    name: str
    type: str
    md5: str
    kind: int  # TopicInfo id: 0, 2 or 4


@dataclass
class _Sub:
    id: int
    name: str
    type: str
    md5: str
    kind: int  # TopicInfo id: 1, 3 or 5
    handler: ServiceHandler | None = None
    pub: _Pub | None = None  # the publisher half of a service


@dataclass
class _ParamWait:
    name: str
    end_ms: int
    answer: ParamResult | None = None


class RosserialDevice:
    """One emulated board running a rosserial sketch; see the module docstring."""

    def __init__(
        self,
        registry: TypeRegistry | None = None,
        *,
        publishers: Iterable[Endpoint] = (),
        subscribers: Iterable[Endpoint] = (),
        service_servers: Iterable[ServiceEndpoint] = (),
        service_clients: Iterable[ServiceEndpoint] = (),
        input_size: int = 512,
        output_size: int = 512,
        max_subscribers: int = 25,
        max_publishers: int = 25,
    ) -> None:
        self.registry = registry if registry is not None else TypeRegistry()
        self.input_size = input_size
        self.output_size = output_size
        self.max_subscribers = max_subscribers
        self.max_publishers = max_publishers
        self.stats = DeviceStats()
        self._publishers: list[_Pub | None] = [None] * max_publishers
        self._subscribers: list[_Sub | None] = [None] * max_subscribers
        self._topic_info = self.registry.message_class(TOPIC_INFO_TYPE)
        self._log_cls = self.registry.message_class(LOG_TYPE)
        param = self.registry.service(PARAM_SERVICE)
        self._param_request = param.request.name
        self._param_response = param.response.name
        self._param_request_cls = self.registry.message_class(self._param_request)
        self._time_cls = self.registry.message_class(TIME_TYPE)
        self._stamp_cls = self.registry.message_class("builtin_interfaces/msg/Time")
        self._tx = bytearray()
        self._events: list[DeviceEvent] = []
        self._power_on()
        for ep in publishers:
            self.advertise(ep.name, ep.type, ep.md5)
        for ep in subscribers:
            self.subscribe(ep.name, ep.type, ep.md5)
        for sv in service_servers:
            self.advertise_service(sv.name, sv.type, sv.handler, sv.request_md5, sv.response_md5)
        for sv in service_clients:
            self.service_client(sv.name, sv.type, sv.request_md5, sv.response_md5)

    def _power_on(self) -> None:
        self.configured = False
        self._mode = _FIRST_FF
        self._bytes = 0
        self._topic = 0
        self._checksum = 0
        self._message = bytearray()
        self._overrun = False
        self._backlog = b""
        self._last_sync_time = 0
        self._last_sync_receive_time = 0
        self._last_msg_timeout_time = 0
        self._rt_time = 0
        self._sec_offset = 0
        self._nsec_offset = 0
        self._param_wait: _ParamWait | None = None
        self._client_wait: str | None = None

    # ------------------------------------------------------------------ set-up (advertise...)
    def advertise(self, name: str, type_name: str, md5: str | None = None) -> int:
        """Add a publisher (``nh.advertise``); returns its topic id."""
        digest = md5 if md5 is not None else self.registry.message(type_name).md5
        return self._add_pub(name, type_name, digest, ReservedId.PUBLISHER).id

    def subscribe(self, name: str, type_name: str, md5: str | None = None) -> int:
        """Add a subscriber (``nh.subscribe``); returns its topic id."""
        digest = md5 if md5 is not None else self.registry.message(type_name).md5
        return self._add_sub(_Sub(0, name, type_name, digest, ReservedId.SUBSCRIBER))

    def advertise_service(
        self,
        name: str,
        srv_type: str,
        handler: ServiceHandler | None,
        request_md5: str | None = None,
        response_md5: str | None = None,
    ) -> tuple[int, int]:
        """Add a service server; returns (request topic id, response topic id)."""
        srv = self.registry.service(srv_type)
        pub = self._add_pub(
            name,
            srv_type,
            response_md5 if response_md5 is not None else srv.response.md5,
            ReservedId.SERVICE_SERVER,
        )
        digest = request_md5 if request_md5 is not None else srv.request.md5
        sub = _Sub(0, name, srv_type, digest, ReservedId.SERVICE_SERVER + 1, handler, pub)
        return self._add_sub(sub), pub.id

    def service_client(
        self,
        name: str,
        srv_type: str,
        request_md5: str | None = None,
        response_md5: str | None = None,
    ) -> tuple[int, int]:
        """Add a service client; returns (request topic id, response topic id)."""
        srv = self.registry.service(srv_type)
        pub = self._add_pub(
            name,
            srv_type,
            request_md5 if request_md5 is not None else srv.request.md5,
            ReservedId.SERVICE_CLIENT,
        )
        digest = response_md5 if response_md5 is not None else srv.response.md5
        sub = _Sub(0, name, srv_type, digest, ReservedId.SERVICE_CLIENT + 1, None, pub)
        return pub.id, self._add_sub(sub)

    def _add_pub(self, name: str, type_name: str, md5: str, kind: int) -> _Pub:
        for i, slot in enumerate(self._publishers):
            if slot is None:
                pub = _Pub(FIRST_USER_TOPIC + self.max_subscribers + i, name, type_name, md5, kind)
                self._publishers[i] = pub
                return pub
        raise ProtocolError(f"no free publisher slot for {name!r} (MAX_PUBLISHERS is full)")

    def _add_sub(self, sub: _Sub) -> int:
        for i, slot in enumerate(self._subscribers):
            if slot is None:
                sub.id = FIRST_USER_TOPIC + i
                self._subscribers[i] = sub
                return sub.id
        raise ProtocolError(f"no free subscriber slot for {sub.name!r} (MAX_SUBSCRIBERS is full)")

    def topic_id(self, name: str, *, publisher: bool = True) -> int:
        """The id of publisher (or subscriber) ``name``; services: their publisher half."""
        slots: list[Any] = self._publishers if publisher else self._subscribers
        for slot in slots:
            if slot is not None and slot.name == name:
                return int(slot.id)
        raise KeyError(name)

    # ------------------------------------------------------------------ h11-style I/O
    def data_to_send(self) -> bytes:
        """Bytes the board wrote to the link; empties the queue."""
        out = bytes(self._tx)
        self._tx.clear()
        return out

    def chunks_to_send(self) -> list[bytes]:
        """:meth:`data_to_send` as the pump writes it: one chunk, or none."""
        out = self.data_to_send()
        return [out] if out else []

    def receive_data(self, data: bytes | bytearray | memoryview, now: float) -> list[DeviceEvent]:
        """One ``spinOnce`` at ``now`` with ``data`` available; returns what happened."""
        self._backlog += bytes(data)
        self._spin_once(now)
        return self._take_events()

    def tick(self, now: float) -> list[DeviceEvent]:
        """One ``spinOnce`` at ``now`` (also handles bytes left over from the last one)."""
        self._spin_once(now)
        return self._take_events()

    def reset(self) -> None:
        """Emulate pressing the reset button: unconfigured, clock and parser state lost."""
        was = self.configured
        self._power_on()
        if was:
            self._events.append(Unconfigured("reset"))

    def reflash(self) -> None:
        """Emulate flashing another sketch: a reset that also forgets every endpoint (advertise
        the new sketch's endpoints next)."""
        self.reset()
        self._publishers = [None] * self.max_publishers
        self._subscribers = [None] * self.max_subscribers

    # ------------------------------------------------------------------ sketch API
    def publish(self, name: str, payload: bytes | bytearray | memoryview) -> int:
        """``pub.publish(&msg)`` with ``payload`` already serialized.

        Returns the frame length written, 0 if dropped because not configured, -1 if larger
        than ``output_size`` (the library then logs an ERROR).
        """
        for slot in self._publishers:
            if slot is not None and slot.name == name and slot.kind == ReservedId.PUBLISHER:
                return self._publish(slot.id, bytes(payload))
        raise KeyError(f"the device has no publisher {name!r}")

    def log(self, level: int, text: str) -> int:
        """``nh.loginfo`` and friends; ``level`` is DEBUG 0 .. FATAL 4."""
        record = self._log_cls(level=level, msg=text)
        return self._publish(ReservedId.LOG, self.registry.serialize(record, LOG_TYPE))

    def request_param(self, name: str, now: float, timeout: float = 1.0) -> None:
        """Start ``nh.getParam(name, ...)``; a :class:`ParamResult` event reports the outcome.

        Raises:
            ProtocolError: a parameter request is already waiting (the library blocks).
        """
        if self._param_wait is not None:
            raise ProtocolError(f"parameter {self._param_wait.name!r} is still being requested")
        request = self._param_request_cls(name=name)
        self._publish(
            ReservedId.PARAMETER_REQUEST, self.registry.serialize(request, self._param_request)
        )
        self._param_wait = _ParamWait(name, (_ms(now) + round(timeout * 1000)) & _MASK)

    def call_service(self, name: str, request: bytes | bytearray | memoryview) -> bool:
        """``client.call(req, resp)``: False (nothing sent) if not configured.

        The outcome comes as :class:`ServiceResult`.

        Raises:
            KeyError: no service client ``name``.
            ProtocolError: a client call is already waiting (the library blocks).
        """
        for slot in self._publishers:
            if slot is not None and slot.name == name and slot.kind == ReservedId.SERVICE_CLIENT:
                break
        else:
            raise KeyError(f"the device has no service client {name!r}")
        if not self.configured:
            return False
        if self._client_wait is not None:
            raise ProtocolError(f"service client {self._client_wait!r} is still waiting")
        self._client_wait = name
        self._publish(slot.id, bytes(request))
        return True

    def ros_time(self, now: float) -> tuple[int, int]:
        """``nh.now()`` at ``now``: (sec, nsec) as the library computes it."""
        return self._now(_ms(now))

    def _now(self, ms: int) -> tuple[int, int]:
        sec = (ms // 1000 + self._sec_offset) & _MASK
        nsec = ((ms % 1000) * 1_000_000 + self._nsec_offset) & _MASK
        return _normalize(sec, nsec)

    # ------------------------------------------------------------------ internals
    def _take_events(self) -> list[DeviceEvent]:
        events = self._events
        self._events = []
        return events

    def _publish(self, topic_id: int, payload: bytes) -> int:
        if topic_id >= FIRST_USER_TOPIC and not self.configured:
            self.stats.dropped_unconfigured += 1
            return 0
        size = len(payload) + FRAME_OVERHEAD
        if size > self.output_size:
            self.stats.dropped_too_large += 1
            if topic_id != ReservedId.LOG:  # the library would recurse until its stack overflows
                self.log(ERROR, "Message from device dropped: message larger than buffer.")
            return -1
        self._tx += encode_frame(topic_id, payload)
        self.stats.frames_out += 1
        self.stats.bytes_out += size
        return size

    def _unconfigure(self, reason: str) -> None:
        if self.configured:
            self.configured = False
            self._events.append(Unconfigured(reason))
        if self._client_wait is not None:
            name, self._client_wait = self._client_wait, None
            self._events.append(ServiceResult(name, None))

    def _request_sync_time(self, c_time: int) -> None:
        stamp = self._time_cls(data=self._stamp_cls(sec=0, nanosec=0))
        self._publish(ReservedId.TIME, self.registry.serialize(stamp, TIME_TYPE))
        self._rt_time = c_time
        self.stats.time_requests += 1

    def _negotiate_topics(self) -> None:
        for pub in self._publishers:
            if pub is not None:
                self._send_topic_info(
                    pub.kind, pub.id, pub.name, pub.type, pub.md5, self.output_size
                )
        for sub in self._subscribers:
            if sub is not None:
                self._send_topic_info(
                    sub.kind, sub.id, sub.name, sub.type, sub.md5, self.input_size
                )
        self.configured = True
        self.stats.negotiations += 1
        self._events.append(Configured())

    def _send_topic_info(
        self, kind: int, topic_id: int, name: str, type_name: str, md5: str, size: int
    ) -> None:
        info = self._topic_info(
            topic_id=topic_id, topic_name=name, message_type=type_name, md5sum=md5, buffer_size=size
        )
        self._publish(kind, self.registry.serialize(info, TOPIC_INFO_TYPE))

    def _spin_once(self, now: float) -> None:
        c_time = _ms(now)
        if (c_time - self._last_sync_receive_time) & _MASK > SYNC_SECONDS * 2200:
            self._unconfigure("sync_timeout")
        if self._mode != _FIRST_FF and c_time > self._last_msg_timeout_time:
            self._mode = _FIRST_FF
            self.stats.timed_out_frames += 1
        data = self._backlog
        self._backlog = b""
        # a negotiation ends spinOnce early (SPIN_ERR), skipping the periodic time request
        finished = self._parse(data, c_time)
        due = (c_time - self._last_sync_time) & _MASK > SYNC_SECONDS * 500
        if finished and self.configured and due:
            self._request_sync_time(c_time)
            self._last_sync_time = c_time
        self._check_param(c_time)

    def _parse(self, data: bytes, c_time: int) -> bool:
        """Run the library's state machine over ``data``; False if spinOnce returned early."""
        i = 0
        n = len(data)
        while i < n:
            mode = self._mode
            if mode == _MESSAGE:
                take = min(self._bytes, n - i)
                chunk = data[i : i + take]
                i += take
                self._checksum += sum(chunk)
                self._message += chunk
                self._bytes -= take
                if len(self._message) > self.input_size and not self._overrun:
                    self._overrun = True
                    self.stats.input_overruns += 1
                    self._events.append(InputOverrun(self._topic, len(self._message) + self._bytes))
                if self._bytes == 0:
                    self._mode = _MSG_CHECKSUM
                continue
            byte = data[i]
            i += 1
            self._checksum += byte
            if mode == _FIRST_FF:
                if byte == SYNC:
                    self._mode = _PROTOCOL_VER
                    self._last_msg_timeout_time = (c_time + SERIAL_MSG_TIMEOUT_MS) & _MASK
            elif mode == _PROTOCOL_VER:
                if byte == VERSION_V2:
                    self._mode = _SIZE_L
                else:
                    self._mode = _FIRST_FF
                    self.stats.version_mismatches += 1
                    if not self.configured:
                        self._request_sync_time(c_time)
            elif mode == _SIZE_L:
                self._bytes = byte
                self._message = bytearray()
                self._overrun = False
                self._mode = _SIZE_H
                self._checksum = byte
            elif mode == _SIZE_H:
                self._bytes += byte << 8
                self._mode = _SIZE_CHECKSUM
            elif mode == _SIZE_CHECKSUM:
                if self._checksum % 256 == 255:
                    self._mode = _TOPIC_L
                else:
                    self._mode = _FIRST_FF
                    self.stats.length_checksum_errors += 1
            elif mode == _TOPIC_L:
                self._topic = byte
                self._mode = _TOPIC_H
                self._checksum = byte
            elif mode == _TOPIC_H:
                self._topic += byte << 8
                self._mode = _MESSAGE if self._bytes else _MSG_CHECKSUM
            else:  # _MSG_CHECKSUM
                self._mode = _FIRST_FF
                if self._checksum % 256 != 255:
                    self.stats.checksum_errors += 1
                    continue
                self.stats.frames_in += 1
                if self._overrun:
                    continue  # the real board has just overwritten its memory
                if self._topic == ReservedId.PUBLISHER:
                    self._request_sync_time(c_time)
                    self._negotiate_topics()
                    self._last_sync_time = c_time
                    self._last_sync_receive_time = c_time
                    self._backlog = data[i:] + self._backlog
                    return False
                self._dispatch(self._topic, bytes(self._message), c_time)
        return True

    def _dispatch(self, topic: int, payload: bytes, c_time: int) -> None:
        if topic == ReservedId.TIME:
            self._sync_time(payload, c_time)
        elif topic == ReservedId.PARAMETER_REQUEST:
            self._param_answer(payload)
        elif topic == ReservedId.TX_STOP:
            self._unconfigure("tx_stop")
        else:
            index = topic - FIRST_USER_TOPIC
            sub = self._subscribers[index] if 0 <= index < self.max_subscribers else None
            if sub is None:
                self.stats.unknown_topic += 1
                return
            self._callback(sub, payload)

    def _callback(self, sub: _Sub, payload: bytes) -> None:
        if sub.kind == ReservedId.SUBSCRIBER:
            self._events.append(Received(sub.name, payload))
        elif sub.kind == ReservedId.SERVICE_SERVER + 1:
            self._events.append(ServiceCalled(sub.name, payload))
            response = sub.handler(payload) if sub.handler is not None else None
            if response is not None and sub.pub is not None:
                self._publish(sub.pub.id, response)
        elif self._client_wait == sub.name:
            self._client_wait = None
            self._events.append(ServiceResult(sub.name, payload))
        else:
            self.stats.stray_responses += 1

    def _sync_time(self, payload: bytes, c_time: int) -> None:
        try:
            stamp = self.registry.deserialize(payload, TIME_TYPE)
        except SerializationError:
            self.stats.undecodable += 1
            return
        offset = (c_time - self._rt_time) & _MASK
        sec = (int(stamp.data.sec) + offset // 1000) & _MASK
        nsec = (int(stamp.data.nanosec) + (offset % 1000) * 1_000_000) & _MASK
        # setNow
        self._sec_offset = (sec - c_time // 1000 - 1) & _MASK
        self._nsec_offset = (nsec - (c_time % 1000) * 1_000_000 + _NSEC) & _MASK
        self._sec_offset, self._nsec_offset = _normalize(self._sec_offset, self._nsec_offset)
        self._last_sync_receive_time = c_time
        self.stats.time_syncs += 1
        self._events.append(TimeSynced(*self._now(c_time)))

    def _param_answer(self, payload: bytes) -> None:
        wait = self._param_wait
        if wait is None:
            self.stats.stray_responses += 1
            return
        try:
            answer = self.registry.deserialize(payload, self._param_response)
        except SerializationError:
            self.stats.undecodable += 1
            return
        wait.answer = ParamResult(
            wait.name,
            True,
            tuple(int(v) for v in answer.ints),
            tuple(float(v) for v in answer.floats),
            tuple(str(v) for v in answer.strings),
        )

    def _check_param(self, c_time: int) -> None:
        """The library's wait loop: after each spinOnce, the deadline first, then the answer."""
        wait = self._param_wait
        if wait is None:
            return
        if c_time > wait.end_ms:
            self._param_wait = None
            self.log(WARN, "Failed to get param: timeout expired")
            self._events.append(ParamResult(wait.name, False))
        elif wait.answer is not None:
            self._param_wait = None
            self._events.append(wait.answer)


def _ms(now: float) -> int:
    """The emulated ``hardware.time()``: milliseconds, wrapping at 2**32."""
    return int(now * 1000) & _MASK


def _normalize(sec: int, nsec: int) -> tuple[int, int]:
    """``normalizeSecNSec`` of the library, in uint32 arithmetic."""
    return (sec + nsec // _NSEC) & _MASK, nsec % _NSEC
