"""Parameters of a native session: the board asks, the host answers and pushes changes.

PROTOCOL.md 2.8 (PARAM_GET, PARAM_VALUE). :class:`HostParams` is the host's side,
:class:`DeviceParams` the board's.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from hwbridge.protocols.errors import HwBridgeTimeoutError
from hwbridge.protocols.native._control.common import (
    CONTROL_CHANNEL,
    Features,
    ParamGetFlags,
    ParamInput,
    ParamStatus,
    ParamType,
)
from hwbridge.protocols.native._session.config import SessionError, SessionResetError
from hwbridge.protocols.native._session.core import SessionCore, _Pending
from hwbridge.protocols.native._session.events import ParamRequest, ParamResponse, ParamUpdate
from hwbridge.protocols.native.control import ParamGetMsg, ParamValueMsg, coerce_param


class HostParams(SessionCore[Any]):
    """The host's side: requests of the board, answers, subscriptions and pushes."""

    _param_requests: dict[int, ParamGetMsg]
    _subscriptions: dict[str, tuple[ParamType, int]]

    def _init_params(self) -> None:
        self._param_requests = {}
        self._subscriptions = {}

    @property
    def param_subscriptions(self) -> Mapping[str, ParamType]:
        """Parameters the board subscribed to, with the type it asked for."""
        return {name: typ for name, (typ, _) in self._subscriptions.items()}

    def answer_param(self, request_id: int, value: ParamInput | None, /) -> bool:
        """Answer a :class:`ParamRequest`; ``None`` answers "not found".

        The value is converted to the type the board asked for (PARAM_GET rules, see
        :func:`~hwbridge.protocols.native.control.coerce_param`); if it does not convert or
        fit, the board gets TYPE_MISMATCH or TOO_LARGE instead. Returns False when the request
        is no longer pending (the session ended meanwhile).
        """
        request = self._param_requests.pop(request_id, None)
        if request is None or not self._established:
            return False
        msg = self._param_value(request_id, request.name, request.type, request.max_count, value)
        self._send_control(msg)
        return True

    def push_param(self, name: str, value: ParamInput, /) -> bool:
        """Send a new value of a parameter the board subscribed to; False if it did not."""
        sub = self._subscriptions.get(name)
        link = self._link
        if sub is None or not self.connected or link is None:
            return False
        if not link.features & Features.PARAM_PUSH:
            return False
        msg = self._param_value(0, name, sub[0], sub[1], value)
        if msg.status != ParamStatus.OK:
            self._error(
                SessionError(
                    f"parameter {name}: new value {value!r} not pushed: {msg.status.name} for "
                    f"the board's type {sub[0].name}"
                )
            )
            return False
        self._send_control(msg)
        return True

    def _param_value(
        self, request_id: int, name: str, want: ParamType, max_count: int, value: ParamInput | None
    ) -> ParamValueMsg:
        if value is None:
            return ParamValueMsg(request_id, ParamStatus.NOT_FOUND, name)
        status, ptype, typed = coerce_param(value, want, max_count)
        if status != ParamStatus.OK:
            return ParamValueMsg(request_id, status, name)
        msg = ParamValueMsg(request_id, status, name, ptype, typed)
        if len(msg.encode()) > self._peer_max:
            return ParamValueMsg(request_id, ParamStatus.TOO_LARGE, name)
        return msg

    def _on_param_get(self, msg: ParamGetMsg) -> None:
        self._param_requests[msg.request_id] = msg
        subscribe = bool(msg.flags & ParamGetFlags.SUBSCRIBE)
        if subscribe:
            self._subscriptions[msg.name] = (msg.type, msg.max_count)
        self._events.append(
            ParamRequest(
                msg.request_id, msg.name, subscribe, type=msg.type, max_count=msg.max_count
            )
        )

    def _clear_params(self) -> None:
        self._param_requests.clear()
        self._subscriptions.clear()


class DeviceParams(SessionCore[Any]):
    """The board's side: its requests, their timeouts, and the host's answers and pushes."""

    _params: dict[int, _Pending]

    def get_param(
        self,
        name: str,
        type: ParamType = ParamType.ANY,
        *,
        max_count: int = 0,
        subscribe: bool = False,
        timeout: float | None = None,
        now: float | None = None,
    ) -> int:
        """Ask the host for a parameter; returns the request id.

        Exactly one :class:`ParamResponse` with this id follows: the host's answer (value, or
        NOT_FOUND / TYPE_MISMATCH / TOO_LARGE), or an error (timeout after ``timeout`` seconds,
        default ``config.param_timeout``; session reset). With ``subscribe`` the host pushes
        later changes as :class:`ParamUpdate` events.
        """
        self._advance_opt(now)
        request_id = self._new_request_id()
        timeout = self._cfg.param_timeout if timeout is None else timeout
        if not self.connected:
            self._c.tx_refused += 1
            self._events.append(
                ParamResponse(request_id, name, None, None, SessionError("not connected to a host"))
            )
            return request_id
        flags = ParamGetFlags.SUBSCRIBE if subscribe else ParamGetFlags.NONE
        try:
            msg = ParamGetMsg(request_id, type, flags, max_count, name).encode()
        except ValueError as exc:
            raise SessionError(f"parameter request for {name[:40]!r}: {exc}") from None
        self._check_size(len(msg), "parameter request for %s", name)
        if not self._send_reliable(CONTROL_CHANNEL, msg):
            self._events.append(
                ParamResponse(request_id, name, None, None, SessionError("transmit queue full"))
            )
            return request_id
        self._params[request_id] = _Pending(CONTROL_CHANNEL, name, self._now + timeout)
        return request_id

    def _request_id_in_use(self, request_id: int) -> bool:
        return request_id in self._params

    def _fail_role_pending(self, reason: str) -> None:
        for request_id, pending in sorted(self._params.items()):
            self._events.append(
                ParamResponse(
                    request_id,
                    pending.name,
                    None,
                    None,
                    SessionResetError(f"parameter request for {pending.name} abandoned: {reason}"),
                )
            )
        self._params.clear()

    def _other_deadlines(self) -> Iterable[float]:
        return (p.deadline for p in self._params.values())

    def _run_role_timers(self, now: float) -> None:
        for request_id, pending in list(self._params.items()):
            if now >= pending.deadline:
                del self._params[request_id]
                self._events.append(
                    ParamResponse(
                        request_id,
                        pending.name,
                        None,
                        None,
                        HwBridgeTimeoutError(
                            f"parameter {pending.name}: no answer from the host in time"
                        ),
                    )
                )

    def _on_param_value(self, msg: ParamValueMsg) -> None:
        if msg.request_id == 0:
            if msg.status == ParamStatus.OK and msg.value is not None:
                self._events.append(ParamUpdate(msg.name, msg.value))
            return
        pending = self._params.pop(msg.request_id, None)
        if pending is None:
            return  # answered after its timeout
        self._events.append(ParamResponse(msg.request_id, msg.name, msg.status, msg.value))
