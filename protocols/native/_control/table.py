"""Control messages of the topic table: BOARD_INFO, TOPIC, TABLE_END, TOPIC_ACK, READY.

All travel on the reliable stream; PROTOCOL.md 2.6.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from hwbridge.protocols.errors import ProtocolError
from hwbridge.protocols.native._control.common import (
    MAX_NAME_BYTES,
    EntryFlags,
    EntryKind,
    Opcode,
    TopicStatus,
    _check_u,
    _Control,
    _Reader,
    _short,
)


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
