"""Control messages of the native protocol: the payloads carried on channel 0.

Every control message starts with an opcode byte, followed by a fixed little-endian layout
(``struct``) and, for some, a trailing UTF-8 string or opaque body that runs to the end of the
payload. ``protocols/PROTOCOL.md`` (Part 2) specifies every byte; this module is its executable
form. Opcodes below 0x10 travel in best-effort frames (they have their own retry timers); opcodes
from 0x10 travel on the reliable stream.

Pure data: nothing here keeps state or knows about time.
"""

from __future__ import annotations

import functools
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from typing import ClassVar, Final, TypeAlias, TypeVar, cast

from hwbridge.protocols.errors import ProtocolError, ProtocolMismatchError
from hwbridge.protocols.native.framing import slot_setter

__all__ = [
    "CONTROL_CHANNEL",
    "MAX_NAME_BYTES",
    "MAX_WINDOW",
    "MIN_MTU",
    "NO_SESSION",
    "PROTOCOL_VERSION",
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
    "encode_service_request",
    "encode_service_response",
    "is_best_effort_opcode",
]

PROTOCOL_VERSION: Final = 1
"""Session protocol version carried in HELLO; both ends must speak the same one."""
CONTROL_CHANNEL: Final = 0
"""The channel that carries control messages; channels 1..255 are announced topics/services."""
MIN_MTU: Final = 24
"""Smallest frame payload any end may announce: a HELLO (21 bytes) must fit in one frame."""
MAX_WINDOW: Final = 64
"""Largest reliable window; keeps every in-flight seq unambiguous in the 8-bit seq space."""
NO_SESSION: Final = 0
"""Session id meaning "none known"; real session ids are never 0."""
MAX_NAME_BYTES: Final = 255
"""Names with a one-byte length prefix (topic names, parameter names) are at most this long."""

_NS_PER_S: Final = 1_000_000_000
_U32: Final = 0xFFFFFFFF
_INT32_MIN: Final = -(2**31)
_INT32_MAX: Final = 2**31 - 1
_FLOAT32_MAX: Final = 3.4028234663852886e38


class Opcode(IntEnum):
    """First byte of every control payload."""

    HELLO = 0x01
    HEARTBEAT = 0x02
    TIME_REQUEST = 0x03
    TIME_RESPONSE = 0x04
    GOODBYE = 0x05
    HOST_TIME_REQUEST = 0x06
    HOST_TIME_RESPONSE = 0x07
    BOARD_INFO = 0x10
    TOPIC = 0x11
    TABLE_END = 0x12
    TOPIC_ACK = 0x13
    READY = 0x14
    SERVICE_REQUEST = 0x20
    SERVICE_RESPONSE = 0x21
    PARAM_GET = 0x30
    PARAM_VALUE = 0x31
    LOG = 0x40


def is_best_effort_opcode(opcode: int) -> bool:
    """True for opcodes that travel in best-effort frames (below 0x10)."""
    return opcode < 0x10


class Role(IntEnum):
    """Which end sent a HELLO."""

    HOST = 0
    DEVICE = 1


class HelloFlags(IntFlag):
    """HELLO flags byte."""

    NONE = 0
    ESTABLISHED = 0x01
    """The sender has seen a HELLO that echoes its own session id: it needs no answer."""


class Features(IntFlag):
    """Optional abilities; the session uses the bitwise AND of both ends' bits."""

    NONE = 0
    TIME_SYNC = 0x01
    """Answers time requests (TIME_REQUEST on the host, HOST_TIME_REQUEST on the device)."""
    PARAM_PUSH = 0x02
    """The device accepts unsolicited PARAM_VALUE updates for parameters it subscribed to."""
    HOST_LOG = 0x04
    """The device accepts LOG messages from the host."""


ALL_FEATURES: Final = Features.TIME_SYNC | Features.PARAM_PUSH | Features.HOST_LOG


class EntryKind(IntEnum):
    """Direction of a topic-table entry, seen from the device."""

    PUBLISHER = 0
    SUBSCRIBER = 1
    SERVICE_SERVER = 2
    SERVICE_CLIENT = 3


class EntryFlags(IntFlag):
    """Flags byte of a TOPIC entry."""

    NONE = 0
    RELIABLE = 0x01
    """The topic's messages travel on the reliable stream (services always do)."""


class TopicStatus(IntEnum):
    """The host's verdict on one announced entry (TOPIC_ACK)."""

    ACCEPTED = 0
    MISMATCH = 1
    """The host knows the topic or type with another type name or md5."""
    INVALID = 2
    """The entry itself is malformed (duplicate channel, empty name, ...)."""


class ServiceStatus(IntEnum):
    """Status byte of SERVICE_RESPONSE."""

    OK = 0
    ERROR = 1
    """The server failed; the body is a UTF-8 explanation."""
    NO_SERVICE = 2
    """The channel is not a service this end serves."""


class ParamStatus(IntEnum):
    """Status byte of PARAM_VALUE."""

    OK = 0
    NOT_FOUND = 1
    TYPE_MISMATCH = 2
    TOO_LARGE = 3
    """The value has more elements than asked for, or does not fit the device's buffer."""


class ParamType(IntEnum):
    """Parameter value types; ``| LIST`` (0x80) marks a list of that element type."""

    ANY = 0
    """Only in PARAM_GET: "send it in its natural type"."""
    BOOL = 1
    INT32 = 2
    FLOAT32 = 3
    STRING = 4
    BOOL_LIST = 0x81
    INT32_LIST = 0x82
    FLOAT32_LIST = 0x83
    STRING_LIST = 0x84

    @property
    def is_list(self) -> bool:
        """True for the list types."""
        return bool(self & 0x80)

    @property
    def element(self) -> ParamType:
        """The element type of a list type (the type itself for scalars)."""
        return ParamType(self & 0x7F)


class ParamGetFlags(IntFlag):
    """Flags byte of PARAM_GET."""

    NONE = 0
    SUBSCRIBE = 0x01
    """Send later changes of this parameter as PARAM_VALUE with request id 0."""


class LogLevel(IntEnum):
    """Log levels (the same numbers as rosserial)."""

    DEBUG = 0
    INFO = 1
    WARN = 2
    ERROR = 3
    FATAL = 4


ParamValue: TypeAlias = (
    bool
    | int
    | float
    | str
    | tuple[bool, ...]
    | tuple[int, ...]
    | tuple[float, ...]
    | tuple[str, ...]
)
"""A decoded parameter value; lists are tuples."""
ParamInput: TypeAlias = ParamValue | list[bool] | list[int] | list[float] | list[str]
"""What callers may pass as a parameter value."""


@functools.cache
def _struct(fmt: str) -> struct.Struct:
    """The little-endian ``struct.Struct`` of ``fmt``, compiled once."""
    return struct.Struct("<" + fmt)


class _Reader:
    """Bounds-checked reads from one control payload, with errors that name the message."""

    def __init__(self, payload: bytes, what: str) -> None:
        self.data = payload
        self.pos = 1  # past the opcode
        self.what = what

    def take(self, n: int, field: str) -> bytes:
        end = self.pos + n
        if end > len(self.data):
            raise ProtocolError(
                f"{self.what} too short: {field} needs {n} bytes at offset {self.pos}, "
                f"payload has {len(self.data)}"
            )
        chunk = self.data[self.pos : end]
        self.pos = end
        return chunk

    def unpack(self, fmt: str, field: str) -> tuple[int, ...]:
        st = _struct(fmt)
        values: tuple[int, ...] = st.unpack(self.take(st.size, field))
        return values

    def u8(self, field: str) -> int:
        return self.take(1, field)[0]

    def u16(self, field: str) -> int:
        return self.unpack("H", field)[0]

    def u32(self, field: str) -> int:
        return self.unpack("I", field)[0]

    def host_time(self, field: str) -> int:
        sec, nsec = self.unpack("II", field)
        if nsec >= _NS_PER_S:
            raise ProtocolError(f"{self.what}: {field} nanoseconds {nsec} >= 1e9")
        return sec * _NS_PER_S + nsec

    def short_text(self, field: str) -> str:
        n = self.u8(field + " length")
        return self._text(self.take(n, field), field)

    def rest(self) -> bytes:
        chunk = self.data[self.pos :]
        self.pos = len(self.data)
        return chunk

    def rest_text(self, field: str, *, lenient: bool = False) -> str:
        raw = self.rest()
        if lenient:
            return raw.decode("utf-8", errors="replace")
        return self._text(raw, field)

    def _text(self, raw: bytes, field: str) -> str:
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ProtocolError(f"{self.what}: {field} is not UTF-8 ({exc})") from None


def _short(text: str, field: str) -> bytes:
    raw = text.encode("utf-8")
    if len(raw) > MAX_NAME_BYTES:
        raise ValueError(f"{field} {text[:40]!r}... is {len(raw)} bytes, at most 255 allowed")
    return bytes([len(raw)]) + raw


def _host_time(ns: int) -> bytes:
    if ns < 0:
        raise ValueError(f"host time {ns} ns is negative")
    sec, nsec = divmod(ns, _NS_PER_S)
    return struct.pack("<II", sec & _U32, nsec)


def _check_u(value: int, bits: int, field: str) -> None:
    if not 0 <= value < (1 << bits):
        raise ValueError(f"{field} {value} does not fit in {bits} unsigned bits")


_M = TypeVar("_M", bound="_Control")


class _Control:
    """Base of the control message dataclasses."""

    __slots__ = ()
    OPCODE: ClassVar[Opcode]

    def encode(self) -> bytes:  # pragma: no cover - every subclass overrides
        raise NotImplementedError

    @classmethod
    def decode(cls: type[_M], payload: bytes) -> _M:  # pragma: no cover - overridden
        raise NotImplementedError


@dataclass(frozen=True, slots=True)
class HelloMsg(_Control):
    """HELLO (0x01, best effort): the session handshake; see PROTOCOL.md 2.4."""

    OPCODE: ClassVar[Opcode] = Opcode.HELLO
    _FMT: ClassVar[struct.Struct] = struct.Struct("<BBBBIIHIBBB")

    role: Role
    flags: HelloFlags
    session: int
    peer_session: int
    mtu: int
    max_message: int
    window: int
    isn: int
    features: Features
    version: int = PROTOCOL_VERSION

    SIZE: ClassVar[int] = 21

    def encode(self) -> bytes:
        _check_u(self.session, 32, "session id")
        _check_u(self.peer_session, 32, "peer session id")
        _check_u(self.mtu, 16, "mtu")
        _check_u(self.max_message, 32, "max_message")
        _check_u(self.window, 8, "window")
        _check_u(self.isn, 8, "isn")
        return self._FMT.pack(
            self.OPCODE,
            self.version,
            self.role,
            self.flags,
            self.session,
            self.peer_session,
            self.mtu,
            self.max_message,
            self.window,
            self.isn,
            self.features,
        )

    @classmethod
    def decode(cls, payload: bytes) -> HelloMsg:
        r = _Reader(payload, "HELLO")
        version = r.u8("version")
        if version != PROTOCOL_VERSION:
            raise ProtocolMismatchError(
                f"the peer speaks native protocol version {version}, this end speaks "
                f"version {PROTOCOL_VERSION}: update the firmware or hwbridge so both match"
            )
        role, flags, session, peer, mtu, max_message, window, isn, features = r.unpack(
            "BBIIHIBBB", "HELLO body"
        )
        if role not in (Role.HOST, Role.DEVICE):
            raise ProtocolError(f"HELLO: unknown role {role}")
        return cls(
            role=Role(role),
            flags=HelloFlags(flags & HelloFlags.ESTABLISHED),
            session=session,
            peer_session=peer,
            mtu=mtu,
            max_message=max_message,
            window=window,
            isn=isn,
            features=Features(features & ALL_FEATURES),
            version=version,
        )


class _Bare(_Control):
    """A control message that is its opcode alone."""

    __slots__ = ()

    def encode(self) -> bytes:
        return bytes([self.OPCODE])

    @classmethod
    def decode(cls: type[_M], payload: bytes) -> _M:
        return cls()


@dataclass(frozen=True, slots=True)
class HeartbeatMsg(_Bare):
    """HEARTBEAT (0x02, best effort): "still here"; no fields."""

    OPCODE: ClassVar[Opcode] = Opcode.HEARTBEAT


@dataclass(frozen=True, slots=True)
class GoodbyeMsg(_Bare):
    """GOODBYE (0x05, best effort): the sender closes the session; no fields."""

    OPCODE: ClassVar[Opcode] = Opcode.GOODBYE


@dataclass(frozen=True, slots=True)
class TimeRequestMsg(_Control):
    """TIME_REQUEST (0x03, device -> host): t1 = device clock in microseconds (u32, wraps)."""

    OPCODE: ClassVar[Opcode] = Opcode.TIME_REQUEST

    t1_us: int

    def encode(self) -> bytes:
        return struct.pack("<BI", self.OPCODE, self.t1_us & _U32)

    @classmethod
    def decode(cls, payload: bytes) -> TimeRequestMsg:
        return cls(_Reader(payload, "TIME_REQUEST").u32("t1"))


@dataclass(frozen=True, slots=True)
class TimeResponseMsg(_Control):
    """TIME_RESPONSE (0x04, host -> device): t1 echoed, t2/t3 host receive/send times (ns)."""

    OPCODE: ClassVar[Opcode] = Opcode.TIME_RESPONSE

    t1_us: int
    t2_ns: int
    t3_ns: int

    def encode(self) -> bytes:
        return (
            struct.pack("<BI", self.OPCODE, self.t1_us & _U32)
            + _host_time(self.t2_ns)
            + _host_time(self.t3_ns)
        )

    @classmethod
    def decode(cls, payload: bytes) -> TimeResponseMsg:
        r = _Reader(payload, "TIME_RESPONSE")
        return cls(r.u32("t1"), r.host_time("t2"), r.host_time("t3"))


@dataclass(frozen=True, slots=True)
class HostTimeRequestMsg(_Control):
    """HOST_TIME_REQUEST (0x06, host -> device): t1 = host time in ns (sec, nsec on the wire)."""

    OPCODE: ClassVar[Opcode] = Opcode.HOST_TIME_REQUEST

    t1_ns: int

    def encode(self) -> bytes:
        return bytes([self.OPCODE]) + _host_time(self.t1_ns)

    @classmethod
    def decode(cls, payload: bytes) -> HostTimeRequestMsg:
        return cls(_Reader(payload, "HOST_TIME_REQUEST").host_time("t1"))


@dataclass(frozen=True, slots=True)
class HostTimeResponseMsg(_Control):
    """HOST_TIME_RESPONSE (0x07, device -> host): t1 echoed, t2/t3 device times (us, u32)."""

    OPCODE: ClassVar[Opcode] = Opcode.HOST_TIME_RESPONSE

    t1_ns: int
    t2_us: int
    t3_us: int

    def encode(self) -> bytes:
        return (
            bytes([self.OPCODE])
            + _host_time(self.t1_ns)
            + struct.pack("<II", self.t2_us & _U32, self.t3_us & _U32)
        )

    @classmethod
    def decode(cls, payload: bytes) -> HostTimeResponseMsg:
        r = _Reader(payload, "HOST_TIME_RESPONSE")
        return cls(r.host_time("t1"), r.u32("t2"), r.u32("t3"))


@dataclass(frozen=True, slots=True)
class BoardInfoMsg(_Control):
    """BOARD_INFO (0x10, device -> host, reliable): who the board is and how many entries follow."""

    OPCODE: ClassVar[Opcode] = Opcode.BOARD_INFO

    topic_count: int
    name: str
    unique_id: bytes
    firmware_version: str

    def encode(self) -> bytes:
        _check_u(self.topic_count, 8, "topic count")
        if len(self.unique_id) > MAX_NAME_BYTES:
            raise ValueError(f"unique id is {len(self.unique_id)} bytes, at most 255 allowed")
        return (
            bytes([self.OPCODE, self.topic_count])
            + _short(self.name, "board name")
            + bytes([len(self.unique_id)])
            + self.unique_id
            + self.firmware_version.encode("utf-8")
        )

    @classmethod
    def decode(cls, payload: bytes) -> BoardInfoMsg:
        r = _Reader(payload, "BOARD_INFO")
        count = r.u8("topic count")
        name = r.short_text("board name")
        uid = r.take(r.u8("unique id length"), "unique id")
        return cls(count, name, uid, r.rest_text("firmware version"))


@dataclass(frozen=True, slots=True)
class TopicMsg(_Control):
    """TOPIC (0x11, device -> host, reliable): one entry of the device's topic/service table."""

    OPCODE: ClassVar[Opcode] = Opcode.TOPIC

    channel: int
    kind: EntryKind
    flags: EntryFlags
    md5: str
    """32 lowercase hex digits (16 raw bytes on the wire)."""
    name: str
    type_name: str

    def encode(self) -> bytes:
        _check_u(self.channel, 8, "channel")
        try:
            md5 = bytes.fromhex(self.md5)
        except ValueError:
            md5 = b""
        if len(md5) != 16:
            raise ValueError(f"md5 {self.md5!r} of {self.name} is not 32 hex digits")
        return (
            bytes([self.OPCODE, self.channel, self.kind, self.flags])
            + md5
            + _short(self.name, "topic name")
            + self.type_name.encode("utf-8")
        )

    @classmethod
    def decode(cls, payload: bytes) -> TopicMsg:
        r = _Reader(payload, "TOPIC")
        channel, kind, flags = r.unpack("BBB", "channel, kind, flags")
        if kind > EntryKind.SERVICE_CLIENT:
            raise ProtocolError(f"TOPIC channel {channel}: unknown kind {kind}")
        md5 = r.take(16, "md5").hex()
        name = r.short_text("topic name")
        return cls(
            channel,
            EntryKind(kind),
            EntryFlags(flags & EntryFlags.RELIABLE),
            md5,
            name,
            r.rest_text("type name"),
        )


@dataclass(frozen=True, slots=True)
class TableEndMsg(_Control):
    """TABLE_END (0x12, device -> host, reliable): all entries sent; count for a cross-check."""

    OPCODE: ClassVar[Opcode] = Opcode.TABLE_END

    count: int

    def encode(self) -> bytes:
        _check_u(self.count, 8, "entry count")
        return bytes([self.OPCODE, self.count])

    @classmethod
    def decode(cls, payload: bytes) -> TableEndMsg:
        return cls(_Reader(payload, "TABLE_END").u8("count"))


@dataclass(frozen=True, slots=True)
class TopicAckMsg(_Control):
    """TOPIC_ACK (0x13, host -> device, reliable): the host's verdict on one entry.

    When the status is not ACCEPTED, the host's md5 (16 bytes, zeros when it has none) and a
    detail text (the host's type name for MISMATCH, a reason for INVALID) follow.
    """

    OPCODE: ClassVar[Opcode] = Opcode.TOPIC_ACK

    channel: int
    status: TopicStatus
    host_md5: str = ""
    detail: str = ""

    def encode(self) -> bytes:
        head = bytes([self.OPCODE, self.channel, self.status])
        if self.status == TopicStatus.ACCEPTED:
            return head
        md5 = bytes.fromhex(self.host_md5) if self.host_md5 else bytes(16)
        if len(md5) != 16:
            raise ValueError(f"host md5 {self.host_md5!r} is not 32 hex digits")
        return head + md5 + self.detail.encode("utf-8")

    @classmethod
    def decode(cls, payload: bytes) -> TopicAckMsg:
        r = _Reader(payload, "TOPIC_ACK")
        channel, status = r.unpack("BB", "channel, status")
        if status > TopicStatus.INVALID:
            raise ProtocolError(f"TOPIC_ACK channel {channel}: unknown status {status}")
        if status == TopicStatus.ACCEPTED:
            return cls(channel, TopicStatus.ACCEPTED)
        md5 = r.take(16, "host md5")
        host_md5 = "" if md5 == bytes(16) else md5.hex()
        return cls(channel, TopicStatus(status), host_md5, r.rest_text("detail", lenient=True))


@dataclass(frozen=True, slots=True)
class ReadyMsg(_Control):
    """READY (0x14, host -> device, reliable): table processed; the session is connected."""

    OPCODE: ClassVar[Opcode] = Opcode.READY

    accepted: int

    def encode(self) -> bytes:
        _check_u(self.accepted, 8, "accepted count")
        return bytes([self.OPCODE, self.accepted])

    @classmethod
    def decode(cls, payload: bytes) -> ReadyMsg:
        return cls(_Reader(payload, "READY").u8("accepted"))


_SERVICE_REQUEST_HEAD: Final = struct.Struct("<BBH")
"""SERVICE_REQUEST up to its body: opcode, channel, request id."""
_SERVICE_RESPONSE_HEAD: Final = struct.Struct("<BBHB")
"""SERVICE_RESPONSE up to its body: opcode, channel, request id, status."""
_SERVICE_STATUS: Final = {int(status): status for status in ServiceStatus}


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


def _param_kind(value: object) -> ParamType | None:
    """Natural wire type of a scalar, or None when it is not a parameter scalar."""
    if isinstance(value, bool):
        return ParamType.BOOL
    if isinstance(value, int):
        return ParamType.INT32
    if isinstance(value, float):
        return ParamType.FLOAT32
    if isinstance(value, str):
        return ParamType.STRING
    return None


def _coerce_scalar(value: object, want: ParamType) -> bool | int | float | str | None:
    """``value`` converted to element type ``want``, or None when it does not convert."""
    kind = _param_kind(value)
    if kind is None:
        return None
    if want == ParamType.BOOL:
        if kind == ParamType.BOOL:
            return bool(value)
        if kind == ParamType.INT32 and value in (0, 1):
            return bool(value)
        return None
    if want == ParamType.INT32:
        if kind in (ParamType.BOOL, ParamType.INT32):
            number = int(value)  # type: ignore[call-overload]
            return number if _INT32_MIN <= number <= _INT32_MAX else None
        return None
    if want == ParamType.FLOAT32:
        if kind in (ParamType.INT32, ParamType.FLOAT32):
            number_f = float(value)  # type: ignore[arg-type]
            if math.isfinite(number_f) and abs(number_f) > _FLOAT32_MAX:
                return None
            return struct.unpack("<f", struct.pack("<f", number_f))[0]  # type: ignore[no-any-return]
        return None
    if want == ParamType.STRING:
        return value if isinstance(value, str) else None
    return None


def coerce_param(
    value: ParamInput, want: ParamType = ParamType.ANY, max_count: int = 0
) -> tuple[ParamStatus, ParamType, ParamValue | None]:
    """Convert a host-side value to the type a device asked for.

    Returns ``(status, wire type, value)``; value is None unless the status is OK. Rules: ANY
    keeps the natural type (bool, int32, float32, string, or a list of one of them); ints
    convert to floats and 0/1 to bools; a scalar converts to a one-element list; a list never
    converts to a scalar; ints outside int32 are a TYPE_MISMATCH; a list longer than a non-zero
    ``max_count`` is TOO_LARGE. Float values come back rounded to float32, as the device sees them.
    """
    if isinstance(value, (list, tuple)):
        items: list[object] = list(value)
        if want != ParamType.ANY and not want.is_list:
            return ParamStatus.TYPE_MISMATCH, ParamType.ANY, None
        if want == ParamType.ANY:
            kinds = {_param_kind(item) for item in items}
            if None in kinds:
                return ParamStatus.TYPE_MISMATCH, ParamType.ANY, None
            if kinds == {ParamType.INT32, ParamType.FLOAT32}:
                elem = ParamType.FLOAT32
            elif len(kinds) > 1:
                return ParamStatus.TYPE_MISMATCH, ParamType.ANY, None
            else:
                elem = next((k for k in kinds if k is not None), ParamType.INT32)
        else:
            elem = want.element
    else:
        if want == ParamType.ANY:
            natural = _param_kind(value)
            if natural is None:
                return ParamStatus.TYPE_MISMATCH, ParamType.ANY, None
            want = natural
        items = [value]
        elem = want.element
    if max_count and len(items) > max_count:
        return ParamStatus.TOO_LARGE, ParamType.ANY, None
    converted = [_coerce_scalar(item, elem) for item in items]
    if any(item is None for item in converted):
        return ParamStatus.TYPE_MISMATCH, ParamType.ANY, None
    if want != ParamType.ANY and not want.is_list:
        return ParamStatus.OK, want, converted[0]
    as_list = cast(ParamValue, tuple(converted))
    return ParamStatus.OK, ParamType(elem | 0x80), as_list
