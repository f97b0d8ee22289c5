"""Control messages of the native protocol: constants, enums and the codec helpers they share.

Every control message starts with an opcode byte, followed by a fixed little-endian layout
(``struct``) and, for some, a trailing UTF-8 string or opaque body that runs to the end of the
payload. ``protocols/PROTOCOL.md`` (Part 2) specifies every byte. The messages themselves are
in :mod:`.link` (handshake, liveness, time), :mod:`.table` (the topic table) and :mod:`.calls`
(services, parameters, logs); :mod:`hwbridge.protocols.native.control` re-exports them all.

Pure data: nothing here keeps state or knows about time.
"""

from __future__ import annotations

import functools
import struct
from enum import IntEnum, IntFlag
from typing import ClassVar, Final, TypeAlias, TypeVar

from hwbridge.protocols.base import EntryKind
from hwbridge.protocols.errors import ProtocolError

__all__ = ["EntryKind"]  # the shared enum, re-exported (native's wire values are its values)

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
    ACK_IN_DATA = 0x08
    """A BEST_EFFORT or RELIABLE frame may carry the cumulative ACK of the other direction
    (PROTOCOL.md 1.4, 2.4): a service exchange needs no ACK frames of its own."""
    SERVICE_CHANNELS = 0x10
    """Service requests and responses travel on the service's own channel, without the opcode
    and channel bytes of SERVICE_REQUEST and SERVICE_RESPONSE (PROTOCOL.md 2.8)."""
    SHORT_CALLS = 0x20
    """With SERVICE_CHANNELS: a call on a service's channel has a one-byte head, the request id
    (1..127), and an OK response none more; another status sets the id's bit 7 and follows it
    (PROTOCOL.md 2.8). Three bytes less a call."""


ALL_FEATURES: Final = (
    Features.TIME_SYNC
    | Features.PARAM_PUSH
    | Features.HOST_LOG
    | Features.ACK_IN_DATA
    | Features.SERVICE_CHANNELS
    | Features.SHORT_CALLS
)
FEATURES_BEFORE_ACK_IN_DATA: Final = Features.TIME_SYNC | Features.PARAM_PUSH | Features.HOST_LOG
"""Every feature a host had before ACK_IN_DATA: the golden transcript's (PROTOCOL.md 2.12)."""


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
