"""Control messages of the application: services, parameters and logs.

All travel on the reliable stream; PROTOCOL.md 2.8. The service messages, one per call, have
fast encoders and decoders (see :mod:`hwbridge.protocols.native._hotpath`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import ClassVar, Final

from hwbridge.protocols.errors import ProtocolError
from hwbridge.protocols.native._control.common import (
    MAX_NAME_BYTES,
    LogLevel,
    Opcode,
    ParamGetFlags,
    ParamStatus,
    ParamType,
    ParamValue,
    ServiceStatus,
    _check_u,
    _Control,
    _Reader,
    _short,
)
from hwbridge.protocols.native._hotpath import slot_setter

_SERVICE_REQUEST_HEAD: Final = struct.Struct("<BBH")
"""SERVICE_REQUEST up to its body: opcode, channel, request id."""
_SERVICE_RESPONSE_HEAD: Final = struct.Struct("<BBHB")
"""SERVICE_RESPONSE up to its body: opcode, channel, request id, status."""
_SERVICE_STATUS: Final = {int(status): status for status in ServiceStatus}
"""Each known status byte's member (an unknown byte is not a key)."""
_CHANNEL_RESPONSE_HEAD: Final = struct.Struct("<HB")
"""A response on its service's channel (SERVICE_CHANNELS) up to its body: request id, status."""
CHANNEL_REQUEST_HEAD_SIZE: Final = 2
"""Bytes before the body of a request on its service's channel (SERVICE_CHANNELS): request id."""
CHANNEL_RESPONSE_HEAD_SIZE: Final = _CHANNEL_RESPONSE_HEAD.size
"""Bytes before the body of a response on its service's channel: request id, status."""
SERVICE_RESPONSE_HEAD_SIZE: Final = _SERVICE_RESPONSE_HEAD.size
"""Bytes before the body of a SERVICE_RESPONSE: opcode, channel, request id, status."""


def encode_service_request(channel: int, request_id: int, body: bytes) -> bytes:
    """``ServiceRequestMsg(channel, request_id, body).encode()`` without building the message.

    For callers that know both numbers are in range (channel 0..255, request id 0..65535): they
    are not checked here, and ``struct.error`` is raised if they are not.
    """
    return _SERVICE_REQUEST_HEAD.pack(ServiceRequestMsg.OPCODE, channel, request_id) + body


def encode_service_response(
    channel: int, request_id: int, status: ServiceStatus, body: bytes
) -> bytes:
    """``ServiceResponseMsg(channel, request_id, status, body).encode()`` without building the
    message, for callers that know the numbers are in range (as :func:`encode_service_request`).
    """
    head = _SERVICE_RESPONSE_HEAD.pack(ServiceResponseMsg.OPCODE, channel, request_id, status)
    return head + body


def encode_channel_request(request_id: int, body: bytes) -> bytes:
    """A service request as it travels on its service's own channel when both ends have
    SERVICE_CHANNELS (PROTOCOL.md 2.8): SERVICE_REQUEST without its opcode and channel bytes.

    For callers that know the request id is in range (0..65535): ``OverflowError`` otherwise.
    """
    return request_id.to_bytes(2, "little") + body


def encode_channel_response(request_id: int, status: ServiceStatus, body: bytes) -> bytes:
    """A service response on its service's own channel (SERVICE_CHANNELS, PROTOCOL.md 2.8):
    SERVICE_RESPONSE without its opcode and channel bytes; numbers unchecked as in
    :func:`encode_channel_request` (``struct.error`` if out of range)."""
    return _CHANNEL_RESPONSE_HEAD.pack(request_id, status) + body


SHORT_ID_MAX: Final = 0x7F
"""The largest request id of a call in a SHORT_CALLS session (PROTOCOL.md 2.8)."""
SHORT_STATUS_FOLLOWS: Final = 0x80
"""Bit 7 of a short response's first byte: a status byte follows the id (not OK)."""
_SHORT_HEADS: Final = tuple(bytes((n,)) for n in range(256))


def encode_short_request(request_id: int, body: bytes) -> bytes:
    """A service request on its service's channel in a SHORT_CALLS session (PROTOCOL.md 2.8):
    the request id (1..127) as one byte, then the body. For callers that know the id is in
    range (``IndexError`` beyond 255)."""
    return _SHORT_HEADS[request_id] + body


def encode_short_response(request_id: int, status: ServiceStatus, body: bytes) -> bytes:
    """A service response on its service's channel in a SHORT_CALLS session (PROTOCOL.md 2.8):
    OK is the request id (1..127) and the body; another status sets the id's bit 7 and follows
    it with the status byte. Numbers unchecked as in :func:`encode_short_request`."""
    if status == ServiceStatus.OK:
        return _SHORT_HEADS[request_id] + body
    return bytes((request_id | SHORT_STATUS_FOLLOWS, status)) + body


@dataclass(frozen=True, slots=True)
class ServiceRequestMsg(_Control):
    """SERVICE_REQUEST (0x20, either way, reliable): call the service on ``channel``."""

    OPCODE: ClassVar[Opcode] = Opcode.SERVICE_REQUEST

    channel: int
    request_id: int
    body: bytes

    def encode(self) -> bytes:
        _check_u(self.channel, 8, "channel")
        _check_u(self.request_id, 16, "request id")
        return encode_service_request(self.channel, self.request_id, self.body)

    @classmethod
    def decode(cls, payload: bytes) -> ServiceRequestMsg:
        if len(payload) >= _SERVICE_REQUEST_HEAD.size:
            # Hot path: one precompiled unpack; the reader below is for its error message.
            _, channel, request_id = _SERVICE_REQUEST_HEAD.unpack_from(payload)
            msg = object.__new__(cls)
            _set_request_channel(msg, channel)
            _set_request_id(msg, request_id)
            _set_request_body(msg, payload[_SERVICE_REQUEST_HEAD.size :])
            return msg
        r = _Reader(payload, "SERVICE_REQUEST")
        channel, request_id = r.unpack("BH", "channel, request id")
        return cls(channel, request_id, r.rest())


@dataclass(frozen=True, slots=True)
class ServiceResponseMsg(_Control):
    """SERVICE_RESPONSE (0x21, either way, reliable): the answer to one SERVICE_REQUEST."""

    OPCODE: ClassVar[Opcode] = Opcode.SERVICE_RESPONSE

    channel: int
    request_id: int
    status: ServiceStatus
    body: bytes

    def encode(self) -> bytes:
        _check_u(self.channel, 8, "channel")
        _check_u(self.request_id, 16, "request id")
        return encode_service_response(self.channel, self.request_id, self.status, self.body)

    @classmethod
    def decode(cls, payload: bytes) -> ServiceResponseMsg:
        if len(payload) >= _SERVICE_RESPONSE_HEAD.size:
            # Hot path: one precompiled unpack; anything odd goes to the reader for its error.
            _, channel, request_id, status = _SERVICE_RESPONSE_HEAD.unpack_from(payload)
            known = _SERVICE_STATUS.get(status)
            if known is not None:
                msg = object.__new__(cls)
                _set_response_channel(msg, channel)
                _set_response_id(msg, request_id)
                _set_response_status(msg, known)
                _set_response_body(msg, payload[_SERVICE_RESPONSE_HEAD.size :])
                return msg
        r = _Reader(payload, "SERVICE_RESPONSE")
        channel, request_id, status = r.unpack("BHB", "channel, request id, status")
        if status > ServiceStatus.NO_SERVICE:
            raise ProtocolError(f"SERVICE_RESPONSE request {request_id}: unknown status {status}")
        return cls(channel, request_id, ServiceStatus(status), r.rest())


# The service messages' decoders build them the fast way (see framing.slot_setter).
_set_request_channel: Final = slot_setter(ServiceRequestMsg, "channel")
_set_request_id: Final = slot_setter(ServiceRequestMsg, "request_id")
_set_request_body: Final = slot_setter(ServiceRequestMsg, "body")
_set_response_channel: Final = slot_setter(ServiceResponseMsg, "channel")
_set_response_id: Final = slot_setter(ServiceResponseMsg, "request_id")
_set_response_status: Final = slot_setter(ServiceResponseMsg, "status")
_set_response_body: Final = slot_setter(ServiceResponseMsg, "body")


@dataclass(frozen=True, slots=True)
class ParamGetMsg(_Control):
    """PARAM_GET (0x30, device -> host, reliable): ask for a parameter in a given type."""

    OPCODE: ClassVar[Opcode] = Opcode.PARAM_GET

    request_id: int
    type: ParamType
    flags: ParamGetFlags
    max_count: int
    """Most list elements the device can take (0: no limit besides max_message)."""
    name: str

    def encode(self) -> bytes:
        _check_u(self.request_id, 16, "request id")
        _check_u(self.max_count, 16, "max_count")
        if self.request_id == 0:
            raise ValueError("request id 0 is reserved for pushed parameter updates")
        head = struct.pack(
            "<BHBBH", self.OPCODE, self.request_id, self.type, self.flags, self.max_count
        )
        raw = self.name.encode("utf-8")
        if len(raw) > MAX_NAME_BYTES:
            raise ValueError(f"parameter name {self.name[:40]!r}... longer than 255 bytes")
        return head + raw

    @classmethod
    def decode(cls, payload: bytes) -> ParamGetMsg:
        r = _Reader(payload, "PARAM_GET")
        request_id, typ, flags, max_count = r.unpack("HBBH", "PARAM_GET header")
        try:
            ptype = ParamType(typ)
        except ValueError:
            raise ProtocolError(
                f"PARAM_GET request {request_id}: unknown type {typ:#04x}"
            ) from None
        return cls(
            request_id,
            ptype,
            ParamGetFlags(flags & ParamGetFlags.SUBSCRIBE),
            max_count,
            r.rest_text("parameter name"),
        )


_ELEMENT_FMT: Final = {ParamType.BOOL: "B", ParamType.INT32: "i", ParamType.FLOAT32: "f"}


def _encode_value(ptype: ParamType, value: ParamValue) -> bytes:
    out = bytearray([ptype])
    items: tuple[bool | int | float | str, ...]
    if ptype.is_list:
        assert isinstance(value, tuple)
        items = value
        out += struct.pack("<H", len(items))
    else:
        items = (value,)  # type: ignore[assignment]
    elem = ptype.element
    for item in items:
        if elem == ParamType.STRING:
            raw = str(item).encode("utf-8")
            out += struct.pack("<H", len(raw)) + raw
        else:
            out += struct.pack("<" + _ELEMENT_FMT[elem], item)
    return bytes(out)


def _decode_value(r: _Reader) -> tuple[ParamType, ParamValue]:
    typ = r.u8("value type")
    try:
        ptype = ParamType(typ)
    except ValueError:
        raise ProtocolError(f"{r.what}: unknown value type {typ:#04x}") from None
    if ptype == ParamType.ANY:
        raise ProtocolError(f"{r.what}: value type ANY is only allowed in PARAM_GET")
    count = r.u16("list length") if ptype.is_list else 1
    elem = ptype.element
    items: list[bool | int | float | str] = []
    for i in range(count):
        if elem == ParamType.STRING:
            raw = r.take(r.u16(f"string {i} length"), f"string {i}")
            items.append(raw.decode("utf-8", errors="replace"))
        elif elem == ParamType.BOOL:
            items.append(bool(r.u8(f"bool {i}")))
        else:
            items.append(r.unpack(_ELEMENT_FMT[elem], f"element {i}")[0])
    if ptype.is_list:
        return ptype, tuple(items)  # type: ignore[return-value]
    return ptype, items[0]


@dataclass(frozen=True, slots=True)
class ParamValueMsg(_Control):
    """PARAM_VALUE (0x31, host -> device, reliable): an answer (request id > 0) or a push (0)."""

    OPCODE: ClassVar[Opcode] = Opcode.PARAM_VALUE

    request_id: int
    status: ParamStatus
    name: str
    type: ParamType = ParamType.ANY
    """Type of ``value``; ANY exactly when the status is not OK (no value follows)."""
    value: ParamValue | None = None

    def encode(self) -> bytes:
        _check_u(self.request_id, 16, "request id")
        head = struct.pack("<BHB", self.OPCODE, self.request_id, self.status)
        head += _short(self.name, "parameter name")
        if self.status != ParamStatus.OK:
            return head
        if self.value is None or self.type == ParamType.ANY:
            raise ValueError(f"PARAM_VALUE {self.name!r} with status OK needs a typed value")
        return head + _encode_value(self.type, self.value)

    @classmethod
    def decode(cls, payload: bytes) -> ParamValueMsg:
        r = _Reader(payload, "PARAM_VALUE")
        request_id, status = r.unpack("HB", "request id, status")
        if status > ParamStatus.TOO_LARGE:
            raise ProtocolError(f"PARAM_VALUE request {request_id}: unknown status {status}")
        name = r.short_text("parameter name")
        if status != ParamStatus.OK:
            return cls(request_id, ParamStatus(status), name)
        ptype, value = _decode_value(r)
        return cls(request_id, ParamStatus.OK, name, ptype, value)


@dataclass(frozen=True, slots=True)
class LogMsg(_Control):
    """LOG (0x40, either way, reliable): one log line with a level."""

    OPCODE: ClassVar[Opcode] = Opcode.LOG

    level: LogLevel
    text: str

    def encode(self) -> bytes:
        return bytes([self.OPCODE, self.level]) + self.text.encode("utf-8")

    @classmethod
    def decode(cls, payload: bytes) -> LogMsg:
        r = _Reader(payload, "LOG")
        level = r.u8("level")
        if level > LogLevel.FATAL:
            raise ProtocolError(f"LOG: unknown level {level}")
        return cls(LogLevel(level), r.rest_text("text", lenient=True))
