"""Control messages of the session's own traffic: HELLO, HEARTBEAT, GOODBYE and time sync.

All travel in best-effort frames (opcodes below 0x10); PROTOCOL.md 2.5, 2.8 and 2.9.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import ClassVar

from hwbridge.protocols.errors import ProtocolError, ProtocolMismatchError
from hwbridge.protocols.native._control.common import (
    _M,
    _U32,
    ALL_FEATURES,
    PROTOCOL_VERSION,
    Features,
    HelloFlags,
    Opcode,
    Role,
    _check_u,
    _Control,
    _host_time,
    _Reader,
)


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
