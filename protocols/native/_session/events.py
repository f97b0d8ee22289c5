"""The events of native sessions: the shared ones of :mod:`hwbridge.protocols.base`, and more.

Native uses the shared event classes as they are (``Message``, ``ServiceRequest``, ...), and
subclasses two of them to carry what only native knows: :class:`Connected` (the board's
identity and the negotiated link) and :class:`ParamRequest` (the type and size the board asked
for). Two events exist only on the device side: :class:`ParamResponse` and :class:`ParamUpdate`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeAlias

from hwbridge.protocols import base
from hwbridge.protocols.base import (
    DebugOutput,
    Disconnected,
    Error,
    Log,
    Message,
    ServiceRequest,
    ServiceResponse,
    TimeSynced,
    TopicAnnounced,
)
from hwbridge.protocols.errors import HwBridgeError
from hwbridge.protocols.native._control.common import ParamStatus, ParamType, ParamValue
from hwbridge.protocols.native._session.config import BoardInfo, LinkParams, TopicEntry

__all__ = [
    "Connected",
    "DebugOutput",
    "Disconnected",
    "Error",
    "Event",
    "HostEvent",
    "Log",
    "Message",
    "ParamRequest",
    "ParamResponse",
    "ParamUpdate",
    "ServiceRequest",
    "ServiceResponse",
    "TimeSynced",
    "TopicAnnounced",
]


@dataclass(frozen=True, slots=True, kw_only=True)
class Connected(base.Connected):
    """The session is up: the table was exchanged and accepted entries can be used.

    ``endpoints`` holds the accepted :class:`TopicEntry` rows (refused ones are reported as
    Error events); ``resumed`` is True when the board kept its session id since the last
    session (it did not restart).
    """

    board: BoardInfo
    link: LinkParams
    host_session: int
    device_session: int

    @property
    def topics(self) -> tuple[TopicEntry, ...]:
        """``endpoints``, as the native entries they are."""
        return self.endpoints  # type: ignore[return-value]  # native builds it of TopicEntry


@dataclass(frozen=True, slots=True, kw_only=True)
class ParamRequest(base.ParamRequest):
    """Host: the board asks for a parameter; answer with ``answer_param``."""

    type: ParamType
    """The type the board asked for (ANY: the value's natural type)."""
    max_count: int
    """Most list elements the board can take (0: no limit besides max_message)."""


@dataclass(frozen=True, slots=True)
class ParamResponse:
    """Device: the outcome of ``get_param``.

    ``status`` is the host's answer (OK, NOT_FOUND, TYPE_MISMATCH, TOO_LARGE) and ``value`` is
    set when it is OK; when no answer came (timeout, reset) ``status`` is None and ``error`` set.
    """

    request_id: int
    name: str
    status: ParamStatus | None
    value: ParamValue | None
    error: HwBridgeError | None = None


@dataclass(frozen=True, slots=True)
class ParamUpdate:
    """Device: the host pushed a new value of a subscribed parameter."""

    name: str
    value: ParamValue


HostEvent: TypeAlias = base.Event
"""The events of a :class:`HostSession`: the shared vocabulary (native's subclasses included)."""

Event: TypeAlias = base.Event | ParamResponse | ParamUpdate
"""The events of either end (a device session also gives ParamResponse and ParamUpdate)."""
