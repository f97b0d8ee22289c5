"""Services of a native session: calls to the peer, answers to its calls (PROTOCOL.md 2.8)."""

from __future__ import annotations

from typing import Any

from hwbridge.protocols.errors import HwBridgeError, HwBridgeTimeoutError
from hwbridge.protocols.native._control.common import CONTROL_CHANNEL, ServiceStatus
from hwbridge.protocols.native._hotpath import CONNECTED, SERVICE_ERROR, SERVICE_NO_SERVICE
from hwbridge.protocols.native._session.config import SessionError
from hwbridge.protocols.native._session.core import SessionCore, _Pending, _truncate
from hwbridge.protocols.native._session.events import ServiceRequest, ServiceResponse
from hwbridge.protocols.native.control import (
    ServiceRequestMsg,
    ServiceResponseMsg,
    encode_service_request,
    encode_service_response,
)


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
        request_id = self._new_request_id()
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
        msg = encode_service_request(channel, request_id, request)
        self._check_size(len(msg), "request for %s (channel %d)", entry.name, channel)
        if not self._send_reliable(CONTROL_CHANNEL, msg):
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
        self._incoming_calls.discard(key)
        # The key came from a decoded request, so channel and request id are in range.
        if error is not None:
            limit = self._peer_max - 5
            body = _truncate(error, limit)
            msg = encode_service_response(channel, request_id, ServiceStatus.ERROR, body)
        else:
            msg = encode_service_response(channel, request_id, ServiceStatus.OK, payload)
            self._check_size(len(msg), "response on channel %d", channel)
        return self._send_reliable(CONTROL_CHANNEL, msg, force=True)

    def _expire_calls(self, now: float) -> None:
        for request_id, call in list(self._calls.items()):
            if now >= call.deadline:
                del self._calls[request_id]
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

    def _on_service_request(self, msg: ServiceRequestMsg) -> None:
        entry = self._entry(msg.channel) if self._state is CONNECTED else None
        if entry is None or entry.kind != self._SERVE_KIND:
            reply = ServiceResponseMsg(msg.channel, msg.request_id, ServiceStatus.NO_SERVICE, b"")
            self._send_control(reply)
            return
        self._incoming_calls.add((msg.channel, msg.request_id))
        self._events.append(ServiceRequest(msg.channel, msg.request_id, msg.body))

    def _on_service_response(self, msg: ServiceResponseMsg) -> None:
        call = self._calls.get(msg.request_id)
        if call is None or call.channel != msg.channel:
            return  # answered after its timeout: the caller already got an error
        del self._calls[msg.request_id]
        error: HwBridgeError | None = None
        status = msg.status
        if status is SERVICE_ERROR:
            text = msg.body.decode("utf-8", errors="replace")
            error = SessionError(f"service {call.name} (channel {msg.channel}) failed: {text}")
        elif status is SERVICE_NO_SERVICE:
            error = SessionError(
                f"service {call.name} (channel {msg.channel}): the peer does not serve it"
            )
        payload = msg.body if error is None else b""
        self._events.append(ServiceResponse(msg.channel, msg.request_id, payload, error))
