"""Services of a native session: calls to the peer, answers to its calls (PROTOCOL.md 2.8).

A call travels in one of two forms, chosen once per session from the negotiated features: as
SERVICE_REQUEST and SERVICE_RESPONSE control messages on channel 0, or, when both ends have
SERVICE_CHANNELS, as reliable messages on the service's own channel without the opcode and
channel bytes (``request_id u16`` [``status u8``] ``body``); when both also have SHORT_CALLS,
with a one-byte head (``request_id u8``, bit 7 set when ``status u8`` follows: not OK). On a
service channel the board's table says which of the two a message is: a request on an entry of
the kind this end serves, a response on one of the kind it calls. All forms meet in
``_on_service_request`` and ``_on_service_response``; in a SERVICE_CHANNELS session every answer
goes in the channel form, also to a request that came in the old one (but for an id above 127 in
a SHORT_CALLS session, which no end sends: NO_SERVICE as a SERVICE_RESPONSE).
"""

from __future__ import annotations

from typing import Any

from hwbridge.protocols.errors import HwBridgeError, HwBridgeTimeoutError
from hwbridge.protocols.native._control.calls import _CHANNEL_RESPONSE_HEAD, _SERVICE_STATUS
from hwbridge.protocols.native._control.common import CONTROL_CHANNEL, ServiceStatus
from hwbridge.protocols.native._hotpath import (
    CONNECTED,
    SERVICE_ERROR,
    SERVICE_NO_SERVICE,
    SERVICE_OK,
)
from hwbridge.protocols.native._session.config import SessionError, TopicEntry
from hwbridge.protocols.native._session.core import (
    RETIRED_ID_HOLD,
    SessionCore,
    _Pending,
    _truncate,
)
from hwbridge.protocols.native._session.events import ServiceRequest, ServiceResponse
from hwbridge.protocols.native.control import (
    CHANNEL_REQUEST_HEAD_SIZE,
    CHANNEL_RESPONSE_HEAD_SIZE,
    SERVICE_RESPONSE_HEAD_SIZE,
    SHORT_ID_MAX,
    SHORT_STATUS_FOLLOWS,
    encode_channel_request,
    encode_channel_response,
    encode_service_request,
    encode_service_response,
    encode_short_request,
    encode_short_response,
)
from hwbridge.protocols.native.reliable import Delivery

_SHORT_ERROR_HEAD_SIZE = 2
"""Bytes before the body of a short response that is not OK (SHORT_CALLS): id | 0x80, status."""


class Services(SessionCore[Any]):
    """Service calls both ways: the pending calls of this end and the incoming ones."""

    def call_service(
        self,
        channel: int,
        request: bytes,
        *,
        timeout: float | None = None,
        now: float | None = None,
    ) -> int:
        """Call a service of the peer; returns the request id.

        Exactly one :class:`ServiceResponse` with this id follows: the answer, or an error
        (:class:`HwBridgeTimeoutError` after ``timeout`` seconds, default
        ``config.service_timeout``; :class:`SessionResetError` if the session ends first;
        :class:`SessionError` if not connected or the peer refused).

        Raises:
            SessionError: connected, but the channel is not a service this end calls, or the
                request is larger than the peer accepts.
        """
        if now is not None:
            self._advance(now)
        short = self._short_calls
        request_id = self._new_request_id(SHORT_ID_MAX if short else 0xFFFF)
        deadline = self._now + (self._cfg.service_timeout if timeout is None else timeout)
        if self._state is not CONNECTED:
            self._c.tx_refused += 1
            self._events.append(
                ServiceResponse(
                    channel,
                    request_id,
                    b"",
                    SessionError(f"service call on channel {channel}: not connected to a board"),
                )
            )
            return request_id
        entry = self._entry(channel)
        if entry is None or entry.kind != self._CALL_KIND:
            raise SessionError(self._wrong_channel(channel, entry, "call a service on"))
        # An accepted entry's channel and a request id of ours: both are in range.
        if short:
            msg = encode_short_request(request_id, request)
            send_on = channel
        elif self._service_channels:
            msg = encode_channel_request(request_id, request)
            send_on = channel
        else:
            msg = encode_service_request(channel, request_id, request)
            send_on = CONTROL_CHANNEL
        self._check_size(len(msg), "request for %s (channel %d)", entry.name, channel)
        if not self._send_reliable(send_on, msg):
            self._events.append(
                ServiceResponse(
                    channel,
                    request_id,
                    b"",
                    SessionError(f"service call to {entry.name}: transmit queue full"),
                )
            )
            return request_id
        self._calls[request_id] = _Pending(channel, entry.name, deadline)
        return request_id

    def respond_service(
        self,
        channel: int,
        request_id: int,
        payload: bytes = b"",
        *,
        error: str | None = None,
    ) -> bool:
        """Answer a :class:`ServiceRequest`; with ``error`` the call fails with that text.

        Returns False when the request is no longer pending (the session ended meanwhile).

        Raises:
            SessionError: the response is larger than the peer accepts.
        """
        key = (channel, request_id)
        if key not in self._incoming_calls or not self._established:
            return False
        # The key came from a decoded request, so channel and request id are in range; with
        # SERVICE_CHANNELS the channel is a service one (_on_service_request made sure).
        channels = self._service_channels
        short = self._short_calls
        if error is not None:
            if short:
                head = _SHORT_ERROR_HEAD_SIZE
            else:
                head = CHANNEL_RESPONSE_HEAD_SIZE if channels else SERVICE_RESPONSE_HEAD_SIZE
            status, body = SERVICE_ERROR, _truncate(error, self._peer_max - head)
        else:
            status, body = SERVICE_OK, payload
        if short:
            msg = encode_short_response(request_id, status, body)
        elif channels:
            msg = encode_channel_response(request_id, status, body)
        else:
            msg = encode_service_response(channel, request_id, status, body)
        if error is None:  # (an answer too large leaves the call pending: it may fail it)
            self._check_size(len(msg), "response on channel %d", channel)
        self._incoming_calls.discard(key)
        return self._send_reliable(channel if channels else CONTROL_CHANNEL, msg, force=True)

    def _expire_calls(self, now: float) -> None:
        for request_id, call in list(self._calls.items()):
            if now >= call.deadline:
                del self._calls[request_id]
                if self._short_calls:
                    self._retired_ids[request_id] = now + RETIRED_ID_HOLD
                self._events.append(
                    ServiceResponse(
                        call.channel,
                        request_id,
                        b"",
                        HwBridgeTimeoutError(
                            f"service {call.name} (channel {call.channel}) request {request_id}: "
                            f"no response in time"
                        ),
                    )
                )

    # ---- services ---------------------------------------------------------------------------

    def _on_service_message(self, delivery: Delivery, entry: TopicEntry | None) -> bool:
        # Once per call, after _on_data found no topic message: the fields are read at once (by
        # index, or one precompiled unpack: the faster of the two for each, by ~20 ns) and handed
        # on as they are, without a message object.
        if entry is None:
            entry = self._board_entry(delivery.channel)
            if entry is None:
                return False
        if self._short_calls:
            return self._on_short_call(delivery, entry)
        kind = entry.kind
        payload = delivery.payload
        if kind == self._SERVE_KIND:
            if len(payload) < CHANNEL_REQUEST_HEAD_SIZE:
                self._too_short(delivery, entry, "request", "request id", CHANNEL_REQUEST_HEAD_SIZE)
                return True
            request_id = payload[0] | payload[1] << 8
            self._on_service_request(delivery.channel, request_id, payload[2:])
            return True
        if kind == self._CALL_KIND:
            if len(payload) < CHANNEL_RESPONSE_HEAD_SIZE:
                self._too_short(
                    delivery, entry, "response", "request id, status", CHANNEL_RESPONSE_HEAD_SIZE
                )
                return True
            request_id, status_byte = _CHANNEL_RESPONSE_HEAD.unpack_from(payload)
            self._on_channel_response(delivery, entry, request_id, status_byte, payload[3:])
            return True
        return False

    def _on_channel_response(
        self, delivery: Delivery, entry: TopicEntry, request_id: int, status_byte: int, body: bytes
    ) -> None:
        """A response read on its service's channel, in either form: taken, or a protocol error
        when its status is none of PROTOCOL.md 2.8's."""
        status = _SERVICE_STATUS.get(status_byte)
        if status is None:
            self._protocol_error(
                f"service response on channel {delivery.channel} ({entry.name}) request "
                f"{request_id}: unknown status {status_byte}"
            )
            return
        self._on_service_response(delivery.channel, request_id, status, body)

    def _on_short_call(self, delivery: Delivery, entry: TopicEntry) -> bool:
        """A message on a service's channel in a SHORT_CALLS session (PROTOCOL.md 2.8): a
        request ``request_id u8`` (bit 7 reserved), ``body``; a response ``request_id u8``,
        then ``status u8`` when the id's bit 7 is set (else OK), ``body``."""
        payload = delivery.payload
        serves = entry.kind == self._SERVE_KIND
        if not serves and entry.kind != self._CALL_KIND:
            return False
        if not payload:
            self._too_short(delivery, entry, "request" if serves else "response", "request id", 1)
            return True
        head = payload[0]
        if serves:
            self._on_service_request(delivery.channel, head & SHORT_ID_MAX, payload[1:])
            return True
        request_id = head & SHORT_ID_MAX
        if not head & SHORT_STATUS_FOLLOWS:
            self._on_service_response(delivery.channel, request_id, SERVICE_OK, payload[1:])
            return True
        if len(payload) < _SHORT_ERROR_HEAD_SIZE:
            self._too_short(delivery, entry, "response", "request id, status", 2)
            return True
        self._on_channel_response(delivery, entry, request_id, payload[1], payload[2:])
        return True

    def _too_short(
        self, delivery: Delivery, entry: TopicEntry, what: str, fields: str, need: int
    ) -> None:
        """A call on a service's channel shorter than its fixed ``fields`` (``need`` bytes): a
        protocol error."""
        self._protocol_error(
            f"service {what} on channel {delivery.channel} ({entry.name}) too short: {fields} "
            f"needs {need} bytes, the message has {len(delivery.payload)}"
        )

    def _on_service_request(self, channel: int, request_id: int, body: bytes) -> None:
        entry = self._entry(channel) if self._state is CONNECTED else None
        # (an id above 127 in a SHORT_CALLS session came in a SERVICE_REQUEST, which no end
        # sends in one: the short answer cannot echo it, so it is not served)
        if (
            entry is None
            or entry.kind != self._SERVE_KIND
            or (request_id > SHORT_ID_MAX and self._short_calls)
        ):
            self._answer_no_service(channel, request_id)
            return
        self._incoming_calls.add((channel, request_id))
        self._events.append(ServiceRequest(channel, request_id, body))

    def _answer_no_service(self, channel: int, request_id: int) -> None:
        """NO_SERVICE for a request this end cannot take (not CONNECTED, the channel is no
        service it serves, or an id the short answer cannot echo). With SERVICE_CHANNELS it
        goes on the channel when the board's table has a service this end serves there and the
        id fits its form; otherwise (an old-form request for any other channel, or with an id
        above 127 in a SHORT_CALLS session) as a SERVICE_RESPONSE on channel 0, which the caller
        always reads as the answer (PROTOCOL.md 2.8): a clear error instead of a timeout."""
        if self._service_channels and (request_id <= SHORT_ID_MAX or not self._short_calls):
            entry = self._board_entry(channel)
            if entry is not None and entry.kind == self._SERVE_KIND:
                if self._short_calls:
                    msg = encode_short_response(request_id, SERVICE_NO_SERVICE, b"")
                else:
                    msg = encode_channel_response(request_id, SERVICE_NO_SERVICE, b"")
                self._send_reliable(channel, msg, force=True)
                return
        self._send_reliable(
            CONTROL_CHANNEL,
            encode_service_response(channel, request_id, SERVICE_NO_SERVICE, b""),
            force=True,
        )

    def _on_service_response(
        self, channel: int, request_id: int, status: ServiceStatus, body: bytes
    ) -> None:
        call = self._calls.get(request_id)
        if call is None or call.channel != channel:
            # answered after its timeout: the caller already got an error, and the id is free
            self._retired_ids.pop(request_id, None)
            return
        del self._calls[request_id]
        error: HwBridgeError | None = None
        if status is SERVICE_ERROR:
            text = body.decode("utf-8", errors="replace")
            error = SessionError(f"service {call.name} (channel {channel}) failed: {text}")
        elif status is SERVICE_NO_SERVICE:
            error = SessionError(
                f"service {call.name} (channel {channel}): the peer does not serve it"
            )
        payload = body if error is None else b""
        self._events.append(ServiceResponse(channel, request_id, payload, error))
