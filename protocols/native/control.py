"""Control messages of the native protocol: the payloads carried on channel 0.

Every control message starts with an opcode byte, followed by a fixed little-endian layout
(``struct``) and, for some, a trailing UTF-8 string or opaque body that runs to the end of the
payload. ``protocols/PROTOCOL.md`` (Part 2) specifies every byte; this module is its executable
form. Opcodes below 0x10 travel in best-effort frames (they have their own retry timers); opcodes
from 0x10 travel on the reliable stream.

The messages are defined by group in ``_control/``: ``common`` (constants, enums, the codec
helpers), ``link`` (HELLO, HEARTBEAT, GOODBYE, time sync), ``table`` (the topic table), ``calls``
(services, parameters, logs) and ``params`` (:func:`coerce_param`); this module re-exports them
and decodes any control payload (:func:`decode_control`). :class:`EntryKind` is
:class:`hwbridge.protocols.base.EntryKind`.

Pure data: nothing here keeps state or knows about time.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final, TypeAlias

from hwbridge.protocols.errors import ProtocolError
from hwbridge.protocols.native._control.calls import (
    CHANNEL_REQUEST_HEAD_SIZE,
    CHANNEL_RESPONSE_HEAD_SIZE,
    SERVICE_RESPONSE_HEAD_SIZE,
    SHORT_ID_MAX,
    SHORT_STATUS_FOLLOWS,
    LogMsg,
    ParamGetMsg,
    ParamValueMsg,
    ServiceRequestMsg,
    ServiceResponseMsg,
    encode_channel_request,
    encode_channel_response,
    encode_service_request,
    encode_service_response,
    encode_short_request,
    encode_short_response,
)
from hwbridge.protocols.native._control.common import (
    ALL_FEATURES,
    CONTROL_CHANNEL,
    FEATURES_BEFORE_ACK_IN_DATA,
    MAX_NAME_BYTES,
    MAX_WINDOW,
    MIN_MTU,
    NO_SESSION,
    PROTOCOL_VERSION,
    EntryFlags,
    EntryKind,
    Features,
    HelloFlags,
    LogLevel,
    Opcode,
    ParamGetFlags,
    ParamInput,
    ParamStatus,
    ParamType,
    ParamValue,
    Role,
    ServiceStatus,
    TopicStatus,
    is_best_effort_opcode,
)
from hwbridge.protocols.native._control.link import (
    GoodbyeMsg,
    HeartbeatMsg,
    HelloMsg,
    HostTimeRequestMsg,
    HostTimeResponseMsg,
    TimeRequestMsg,
    TimeResponseMsg,
)
from hwbridge.protocols.native._control.params import coerce_param
from hwbridge.protocols.native._control.table import (
    BoardInfoMsg,
    ReadyMsg,
    TableEndMsg,
    TopicAckMsg,
    TopicMsg,
)

__all__ = [
    "ALL_FEATURES",
    "CHANNEL_REQUEST_HEAD_SIZE",
    "CHANNEL_RESPONSE_HEAD_SIZE",
    "CONTROL_CHANNEL",
    "FEATURES_BEFORE_ACK_IN_DATA",
    "MAX_NAME_BYTES",
    "MAX_WINDOW",
    "MIN_MTU",
    "NO_SESSION",
    "PROTOCOL_VERSION",
    "SERVICE_RESPONSE_HEAD_SIZE",
    "SHORT_ID_MAX",
    "SHORT_STATUS_FOLLOWS",
    "BoardInfoMsg",
    "ControlMessage",
    "EntryFlags",
    "EntryKind",
    "Features",
    "GoodbyeMsg",
    "HeartbeatMsg",
    "HelloFlags",
    "HelloMsg",
    "HostTimeRequestMsg",
    "HostTimeResponseMsg",
    "LogLevel",
    "LogMsg",
    "Opcode",
    "ParamGetFlags",
    "ParamGetMsg",
    "ParamInput",
    "ParamStatus",
    "ParamType",
    "ParamValue",
    "ParamValueMsg",
    "ReadyMsg",
    "Role",
    "ServiceRequestMsg",
    "ServiceResponseMsg",
    "ServiceStatus",
    "TableEndMsg",
    "TimeRequestMsg",
    "TimeResponseMsg",
    "TopicAckMsg",
    "TopicMsg",
    "TopicStatus",
    "coerce_param",
    "decode_control",
    "encode_channel_request",
    "encode_channel_response",
    "encode_service_request",
    "encode_service_response",
    "encode_short_request",
    "encode_short_response",
    "is_best_effort_opcode",
]

ControlMessage: TypeAlias = (
    HelloMsg
    | HeartbeatMsg
    | GoodbyeMsg
    | TimeRequestMsg
    | TimeResponseMsg
    | HostTimeRequestMsg
    | HostTimeResponseMsg
    | BoardInfoMsg
    | TopicMsg
    | TableEndMsg
    | TopicAckMsg
    | ReadyMsg
    | ServiceRequestMsg
    | ServiceResponseMsg
    | ParamGetMsg
    | ParamValueMsg
    | LogMsg
)

_DECODERS: Final[dict[int, Callable[[bytes], ControlMessage]]] = {
    cls.OPCODE: cls.decode
    for cls in (
        HelloMsg,
        HeartbeatMsg,
        GoodbyeMsg,
        TimeRequestMsg,
        TimeResponseMsg,
        HostTimeRequestMsg,
        HostTimeResponseMsg,
        BoardInfoMsg,
        TopicMsg,
        TableEndMsg,
        TopicAckMsg,
        ReadyMsg,
        ServiceRequestMsg,
        ServiceResponseMsg,
        ParamGetMsg,
        ParamValueMsg,
        LogMsg,
    )
}


def decode_control(payload: bytes) -> ControlMessage:
    """Decode one control payload; raises ProtocolError naming what is wrong."""
    if not payload:
        raise ProtocolError("empty control payload (no opcode)")
    decoder = _DECODERS.get(payload[0])
    if decoder is None:
        raise ProtocolError(f"unknown control opcode {payload[0]:#04x}")
    return decoder(payload)
