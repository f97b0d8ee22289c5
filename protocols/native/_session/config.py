"""Configuration and descriptions of native sessions, and their errors."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import Final, TypeAlias

from hwbridge.protocols.base import Endpoint, FirmwareIdentity
from hwbridge.protocols.calling import BOOTLOADER_QUIET, check_bursts
from hwbridge.protocols.errors import HwBridgeError, ProtocolMismatchError
from hwbridge.protocols.native._control.common import (
    ALL_FEATURES,
    MAX_NAME_BYTES,
    MAX_WINDOW,
    MIN_MTU,
    EntryFlags,
    Features,
)
from hwbridge.protocols.native._control.table import TopicMsg
from hwbridge.protocols.native.identity import parse_identity

_U32: Final = 1 << 32
_MAX_TIME_SAMPLES: Final = 4
ACK_DELAY_MAX: Final = 0.01
"""Longest a receiver may hold an ACK back (seconds, PROTOCOL.md 2.4); a fifth of the default
rto_min, so a held ACK does not make the peer resend."""
RTO_MIN_FLOOR: Final = 2 * ACK_DELAY_MAX
"""Smallest allowed rto_min: a peer may hold its ACK for ACK_DELAY_MAX, and an RTO that expires
before the ACK can come resends frames that arrived."""
_VERSION_FRAMES_TO_REPORT: Final = 2
"""CRC-valid frames of another version needed before reporting (noise passes a CRC at times)."""
_MAX_TIME_AGE: Final = 10.0
"""Time responses older than this (seconds) are ignored: they cannot be matched safely."""


# --------------------------------------------------------------------------------------------
# Errors


class SessionError(HwBridgeError):
    """An action is impossible: unknown channel, wrong direction, message too large, ..."""


class SessionResetError(SessionError):
    """A pending operation was abandoned because the session ended (reset, link lost, closed)."""


class TopicMismatchError(ProtocolMismatchError):
    """Board and host disagree on a topic's type: names the topic, both types and both md5s."""

    def __init__(
        self,
        topic: str,
        channel: int,
        board_type: str,
        board_md5: str,
        host_type: str,
        host_md5: str,
    ) -> None:
        self.topic = topic
        self.channel = channel
        self.board_type = board_type
        self.board_md5 = board_md5
        self.host_type = host_type
        self.host_md5 = host_md5
        super().__init__(
            f"type mismatch on {topic} (channel {channel}): the board uses {board_type} "
            f"(md5 {board_md5}) but the host expects {host_type} (md5 {host_md5 or 'unknown'}); "
            f"rebuild the firmware from the same message definitions as the host"
        )


# --------------------------------------------------------------------------------------------
# Configuration and descriptions


@dataclass(frozen=True, slots=True, kw_only=True)
class SessionConfig:
    """Limits and timers of one end. Defaults are the host's; see DeviceConfig for a board's."""

    mtu: int = 1024
    """Largest frame payload this end accepts (bytes, header and CRC excluded)."""
    max_message: int = 1 << 20
    """Largest message this end reassembles (bytes)."""
    window: int = 16
    """Most reliable frames this end lets be in flight (1..64)."""
    features: Features = ALL_FEATURES
    hello_interval: float = 0.25
    """HELLO period while no session is established."""
    heartbeat_interval: float = 0.1
    """A HEARTBEAT is sent when nothing else was sent for this long."""
    link_timeout: float = 0.8
    """No valid frame for this long ends the session ("link lost")."""
    handshake_timeout: float = 3.0
    """An Error event is raised once when no session is connected after this long."""
    rto_initial: float = 0.25
    rto_min: float = 0.05
    rto_max: float = 1.0
    max_retries: int = 10
    """Retransmissions of one reliable frame before the link is declared dead."""
    ack_delay: float = 0.005
    """Longest an ACK is held back waiting for other bytes to go out with (seconds, at most
    ACK_DELAY_MAX; 0 sends every ACK at once). Held only on links with a window of 4 or more,
    never for frames out of order or duplicates (PROTOCOL.md 2.4)."""
    service_timeout: float = 5.0
    param_timeout: float = 2.0
    time_sync_interval: float = 5.0
    """Period of time requests sent by this end (0 disables them; answers are always sent)."""
    time_sync_retry: float = 1.0
    """Resend a time request that got no answer after this long."""
    tx_queue_limit: int = 8 << 20
    """Most payload bytes waiting for the reliable window before sends are refused."""

    def __post_init__(self) -> None:
        if not MIN_MTU <= self.mtu <= 0xFFFF:
            raise ValueError(f"mtu must be {MIN_MTU}..65535, not {self.mtu}")
        if not 1 <= self.window <= MAX_WINDOW:
            raise ValueError(f"window must be 1..{MAX_WINDOW}, not {self.window}")
        if not 1 <= self.max_message < _U32:
            raise ValueError(f"max_message must be 1..2**32-1, not {self.max_message}")
        if self.link_timeout <= self.heartbeat_interval:
            raise ValueError("link_timeout must be longer than heartbeat_interval")
        if self.max_retries < 1:
            raise ValueError(f"max_retries must be >= 1, not {self.max_retries}")
        if not 0 <= self.ack_delay <= ACK_DELAY_MAX:
            raise ValueError(f"ack_delay must be 0..{ACK_DELAY_MAX} s, not {self.ack_delay}")
        if self.rto_min < RTO_MIN_FLOOR:
            raise ValueError(
                f"rto_min must be at least {RTO_MIN_FLOOR} s (the peer may hold an ACK for "
                f"{ACK_DELAY_MAX} s), not {self.rto_min}"
            )
        if not self.rto_min <= self.rto_initial <= self.rto_max:
            raise ValueError(
                "need rto_min <= rto_initial <= rto_max, not "
                f"{self.rto_min}, {self.rto_initial}, {self.rto_max}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class HostConfig(SessionConfig):
    """The host's limits and timers."""

    epoch_offset: float = 0.0
    """Added to ``now`` to get the host time sent in time sync (e.g. ``time() - monotonic()``)."""
    listen_first: bool = False
    """Call no HELLO of this end's to a board that is not heard (PROTOCOL.md 2.5, listening
    first): while no session is established, HELLOs go only in answer to the board's and, as
    retries, for a ``link_timeout`` after the board was last heard. For boards whose bootloader
    takes any byte after a reset as an upload and waits for the next one (a Mega's stk500v2):
    a host calling every ``hello_interval`` would hold a reset board there for good."""
    call_burst: float = 0.0
    """Seconds this end calls (HELLO retries) a board it does not hear before it leaves it
    ``call_pause`` seconds of silence, and so on (:mod:`hwbridge.protocols.calling`; 0: calls
    without pause). Stream links use CALL_BURST: a Mega whose bootloader took a HELLO goes on
    to its sketch in a pause."""
    call_pause: float = BOOTLOADER_QUIET
    """The silence after each ``call_burst``."""

    def __post_init__(self) -> None:
        SessionConfig.__post_init__(self)  # (no zero-argument super() in a slots dataclass)
        check_bursts(self.call_burst, self.call_pause)


@dataclass(frozen=True, slots=True, kw_only=True)
class DeviceConfig(SessionConfig):
    """A board's limits and timers; the defaults fit an ATmega328P (PROTOCOL.md 2.10)."""

    mtu: int = 64
    max_message: int = 64
    window: int = 1
    features: Features = (
        Features.TIME_SYNC
        | Features.PARAM_PUSH
        | Features.ACK_IN_DATA
        | Features.SERVICE_CHANNELS
        | Features.SHORT_CALLS
    )
    tx_queue_limit: int = 128


@dataclass(frozen=True, slots=True)
class LinkParams:
    """What both ends agreed in the handshake (identical on both ends)."""

    mtu: int
    """min(host mtu, device mtu): largest frame payload in either direction."""
    window: int
    """min(host window, device window)."""
    host_max_message: int
    """Largest message the device may send (the host's reassembly limit)."""
    device_max_message: int
    """Largest message the host may send (the device's reassembly limit)."""
    features: Features
    """Bitwise AND of both ends' features."""


@dataclass(frozen=True, slots=True)
class BoardInfo:
    """Who a board is (sent once per session in BOARD_INFO)."""

    name: str
    unique_id: bytes
    firmware_version: str

    def __post_init__(self) -> None:
        if len(self.name.encode("utf-8")) > MAX_NAME_BYTES or len(self.unique_id) > MAX_NAME_BYTES:
            raise ValueError("board name and unique id are at most 255 bytes each")

    @property
    def identity(self) -> FirmwareIdentity:
        """The firmware identity carried in ``firmware_version`` (PROTOCOL.md 2.6.1)."""
        return parse_identity(self.firmware_version)


@dataclass(frozen=True, slots=True)
class TopicEntry(Endpoint):
    """One row of a board's topic/service table: a :class:`~hwbridge.protocols.base.Endpoint`
    whose ``channel`` is 1..255 (chosen by the board) and whose ``md5`` is 32 lowercase hex
    digits, plus the stream its messages use."""

    reliable: bool = False
    """Send on the reliable stream (always True for services)."""

    def __post_init__(self) -> None:
        if not 1 <= self.channel <= 255:
            raise ValueError(f"{self.name}: channel must be 1..255, not {self.channel}")
        if not self.name:
            raise ValueError(f"channel {self.channel}: empty topic name")
        if len(self.md5) != 32 or any(c not in "0123456789abcdef" for c in self.md5):
            raise ValueError(f"{self.name}: md5 {self.md5!r} is not 32 lowercase hex digits")
        if self.is_service and not self.reliable:
            object.__setattr__(self, "reliable", True)  # services always use the reliable stream

    def to_msg(self) -> TopicMsg:
        """The TOPIC control message announcing this entry."""
        flags = EntryFlags.RELIABLE if self.reliable else EntryFlags.NONE
        return TopicMsg(self.channel, self.kind, flags, self.md5, self.name, self.type_name)

    @classmethod
    def from_msg(cls, msg: TopicMsg) -> TopicEntry:
        """The entry a TOPIC message announces."""
        return cls(
            msg.channel,
            msg.kind,
            msg.name,
            msg.type_name,
            msg.md5,
            bool(msg.flags & EntryFlags.RELIABLE),
        )


@dataclass(frozen=True, slots=True)
class ExpectedType:
    """What the host expects for a topic: returned by a :data:`TypeCheck` callback."""

    type_name: str
    md5: str


TypeCheck: TypeAlias = Callable[[TopicEntry], ExpectedType | None]
"""Host callback: the type the host expects for an announced entry, or None to accept it as is."""


class SessionState(Enum):
    """Where a session is."""

    HANDSHAKE = "handshake"
    """Exchanging HELLOs; no session."""
    CONFIGURING = "configuring"
    """Session established; the board's table is being announced and checked."""
    CONNECTED = "connected"
    """Table done: topics, services, params, time and logs work."""
    CLOSED = "closed"
    """``close()`` was called; nothing more happens."""
