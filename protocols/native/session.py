"""Sessions of the native protocol: handshake, topic table, services, params, time, logs.

Two sans-I/O state machines share this code, shaped like h11:

* :class:`HostSession` runs on the host, one per board link; it is a
  :class:`hwbridge.protocols.base.BoardSession`;
* :class:`DeviceSession` is the board's side. It drives emulated boards today and is the
  executable specification of what the C++ firmware does (PROTOCOL.md, Part 2).

Feed what a link read returned with ``receive_data(data, now)``, call ``tick(now)`` when
``next_deadline()`` is due, call action methods (``publish``, ``call_service``, ...), and write
each item of ``chunks_to_send()`` to the link (``data_to_send()`` joins them). Both return or
produce events: the shared ones of :mod:`hwbridge.protocols.base` (``session.Message is
base.Message``), native's :class:`Connected` and :class:`ParamRequest` subclasses, and the
device's :class:`ParamResponse` and :class:`ParamUpdate`. ``now`` is a monotonic clock in
seconds; actions use the latest ``now`` seen unless given their own. A session is built with a
framing (:class:`~hwbridge.protocols.native.framing.NativeStreamFraming` by default, or
:class:`~hwbridge.protocols.native.framing.NativeDatagramFraming`) and never sees link bytes
any other way.

Nothing here reads a clock, sleeps, or touches a socket. The code is in ``_session/``:
``config`` (configuration, descriptions, counters, errors), ``events``, ``core`` (state, input,
output, ACK holding), ``handshake`` (HELLO, negotiation, timers), ``services``, ``timesync``,
``params``, ``topics`` (the table), ``host`` and ``device``; this module re-exports it.
"""

from __future__ import annotations

from hwbridge.protocols.native._framing.links import NativeDatagramFraming, NativeStreamFraming
from hwbridge.protocols.native._session.config import (
    ACK_DELAY_MAX,
    RTO_MIN_FLOOR,
    BoardInfo,
    DeviceConfig,
    ExpectedType,
    HostConfig,
    LinkParams,
    SessionConfig,
    SessionError,
    SessionResetError,
    SessionState,
    TopicEntry,
    TopicMismatchError,
    TypeCheck,
)
from hwbridge.protocols.native._session.core import HELLO_FIRST_RETRY, RETIRED_ID_HOLD
from hwbridge.protocols.native._session.device import DeviceSession
from hwbridge.protocols.native._session.events import (
    Connected,
    DebugOutput,
    Disconnected,
    Error,
    Event,
    HostEvent,
    Log,
    Message,
    ParamRequest,
    ParamResponse,
    ParamUpdate,
    ServiceRequest,
    ServiceResponse,
    TimeSynced,
    TopicAnnounced,
)
from hwbridge.protocols.native._session.host import HostSession
from hwbridge.protocols.native._session.stats import NativeStats, SessionCounters

__all__ = [
    "ACK_DELAY_MAX",
    "HELLO_FIRST_RETRY",
    "RETIRED_ID_HOLD",
    "RTO_MIN_FLOOR",
    "BoardInfo",
    "Connected",
    "DebugOutput",
    "DeviceConfig",
    "DeviceSession",
    "Disconnected",
    "Error",
    "Event",
    "ExpectedType",
    "HostConfig",
    "HostEvent",
    "HostSession",
    "LinkParams",
    "Log",
    "Message",
    "NativeDatagramFraming",
    "NativeStats",
    "NativeStreamFraming",
    "ParamRequest",
    "ParamResponse",
    "ParamUpdate",
    "ServiceRequest",
    "ServiceResponse",
    "SessionConfig",
    "SessionCounters",
    "SessionError",
    "SessionResetError",
    "SessionState",
    "TimeSynced",
    "TopicAnnounced",
    "TopicEntry",
    "TopicMismatchError",
    "TypeCheck",
]
