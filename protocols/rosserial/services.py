"""Request ids for rosserial's id-less services and parameter requests (host side).

rosserial carries no request ids on the wire, so the host makes them up (one counter for all
three kinds below) and keeps the order the protocol implies:

- calls of a device service server (:class:`HostCalls`): one FIFO per channel; only its head is
  on the wire, the next one goes out when the head is answered or fails. A response on the
  server's response topic answers the head (a response while nothing is on the wire is late
  and dropped);
- requests of a device service client (:class:`PendingRequests`): one FIFO of request ids per
  channel; answering one removes it wherever it is (the device takes any response on the
  topic as the answer of the call it waits on; it has one at a time);
- parameter requests: the same, with the parameter name as the value, all on one queue.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

from hwbridge.protocols.base import ServiceResponse
from hwbridge.protocols.errors import FramingError, HwBridgeError, HwBridgeTimeoutError
from hwbridge.protocols.rosserial.framing import MAX_PAYLOAD

__all__ = [
    "Call",
    "HostCalls",
    "MessageTooLargeError",
    "PendingRequests",
    "RequestIds",
    "check_size",
]

MAX_PENDING: Final = 64
"""Requests remembered per queue before the oldest are forgotten (an unanswering bridge)."""


class MessageTooLargeError(FramingError):
    """A payload does not fit the device's input buffer; nothing was sent."""


def check_size(payload: bytes, limit: int, what: str, *args: object) -> None:
    """Raise :class:`MessageTooLargeError` if ``payload`` exceeds the device's ``limit`` or a
    frame; ``what % args`` (formatted only then) names it."""
    if len(payload) > limit:
        raise MessageTooLargeError(
            f"{what % args} is {len(payload)} bytes, larger than the device's input buffer of "
            f"{limit} bytes; not sent (the rosserial client library would overrun its "
            "memory). Send less, or build the firmware with a larger INPUT_SIZE."
        )
    if len(payload) > MAX_PAYLOAD:
        raise MessageTooLargeError(
            f"{what % args} is {len(payload)} bytes, more than a rosserial frame carries "
            f"({MAX_PAYLOAD} bytes); not sent"
        )


class RequestIds:
    """The host's request ids: 1, 2, ... wrapping at 2**31 (never 0)."""

    __slots__ = ("_next",)

    def __init__(self) -> None:
        self._next = 1

    def new(self) -> int:
        value = self._next
        self._next = value + 1 if value < 0x7FFFFFFF else 1
        return value


@dataclass(slots=True)
class Call:
    """One host call of a device service server."""

    request_id: int
    channel: int
    name: str
    payload: bytes
    timeout: float
    deadline: float
    sent: bool = False


class HostCalls:
    """Calls of device service servers, queued per channel (see the module docstring)."""

    __slots__ = ("_queues",)

    def __init__(self) -> None:
        self._queues: dict[int, deque[Call]] = {}

    def __bool__(self) -> bool:
        return any(self._queues.values())

    def __len__(self) -> int:
        return sum(len(q) for q in self._queues.values())

    def add(self, call: Call) -> bool:
        """Queue ``call``; True if it is the head (to be sent now)."""
        queue = self._queues.setdefault(call.channel, deque())
        queue.append(call)
        return len(queue) == 1

    def answered(self, channel: int) -> tuple[Call | None, Call | None]:
        """A response arrived on ``channel``: (the call it answers or None if late, the next
        call to send or None)."""
        queue = self._queues.get(channel)
        if not queue or not queue[0].sent:
            return None, None
        call = queue.popleft()
        return call, (queue[0] if queue else None)

    def expire(self, now: float) -> tuple[list[ServiceResponse], list[Call]]:
        """Fail the calls due at ``now``: (their responses, the calls to send next)."""
        failed: list[ServiceResponse] = []
        resend: list[Call] = []
        for queue in self._queues.values():
            expired = False
            while queue and queue[0].deadline <= now:
                call = queue.popleft()
                expired = True
                if call.sent:
                    why = (
                        "the request or its response may have been lost on the line "
                        "(rosserial has no retransmission)"
                    )
                else:
                    why = "it was never sent: an earlier call to it was still unanswered"
                error = HwBridgeTimeoutError(
                    f"device service {call.name!r} did not answer call {call.request_id} "
                    f"within {call.timeout:g} s: {why}"
                )
                failed.append(ServiceResponse(call.channel, call.request_id, b"", error))
            if expired and queue and not queue[0].sent:
                resend.append(queue[0])
        return failed, resend

    def abandon(
        self, error: HwBridgeError, channels: Iterable[int] | None = None
    ) -> list[ServiceResponse]:
        """Fail every call (of ``channels`` only, if given) with ``error``."""
        keys = list(self._queues) if channels is None else list(channels)
        out: list[ServiceResponse] = []
        for channel in keys:
            for call in self._queues.pop(channel, ()):
                out.append(ServiceResponse(channel, call.request_id, b"", error))
        return out

    def channels(self) -> list[tuple[int, str]]:
        """(channel, service name) of every queue with calls."""
        return [(ch, q[0].name) for ch, q in self._queues.items() if q]

    def deadline(self) -> float | None:
        """The earliest deadline of a queue head."""
        times = [q[0].deadline for q in self._queues.values() if q]
        return min(times) if times else None


class PendingRequests:
    """Request ids the host has to answer, by key (a channel or 0 for parameters), in order."""

    __slots__ = ("_queues",)

    def __init__(self) -> None:
        self._queues: dict[int, dict[int, str]] = {}

    def add(self, key: int, request_id: int, what: str = "") -> None:
        queue = self._queues.setdefault(key, {})
        queue[request_id] = what
        while len(queue) > MAX_PENDING:
            del queue[next(iter(queue))]

    def take(self, key: int, request_id: int) -> str | None:
        """Remove ``request_id`` from ``key``'s queue; its value, or None if not pending."""
        queue = self._queues.get(key)
        if queue is None or request_id not in queue:
            return None
        return queue.pop(request_id)

    def peek(self, key: int, request_id: int) -> str | None:
        queue = self._queues.get(key)
        return None if queue is None else queue.get(request_id)

    def count(self, key: int | None = None) -> int:
        if key is None:
            return sum(len(q) for q in self._queues.values())
        return len(self._queues.get(key, ()))

    def clear(self) -> None:
        self._queues.clear()
