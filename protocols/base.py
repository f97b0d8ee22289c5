"""The contract between a protocol and the runtime: framing, sessions, events, statistics.

Every protocol hwbridge speaks with a board (native, rosserial, and later CAN or MAVLink
tunnels) is a sans-I/O session that the runtime drives the same way:

* a :class:`Framing` turns what a link carries into the protocol's frames and back. A *stream*
  link (serial, TCP, a pty) delivers bytes in arbitrary chunks, so its framing finds frame
  boundaries (COBS and ``0x00`` for native, rosserial's ``FF FE`` header); a *datagram* link (a CAN
  frame, a UDP packet, a MAVLink tunnel message) delivers one whole frame per read, so its framing
  only checks and parses it. The session owns the framing it was given and never sees link bytes
  in any other way: it works on frames.
* the session turns frames into :data:`Event` objects of one shared vocabulary (below) and takes
  actions (:class:`BoardSession`) that produce frames to send.

The bridge knows only this module: it matches events by type, calls the actions by channel, and
never asks which protocol it is talking to. A protocol may subclass an event to carry more
detail (native's :class:`Connected` adds the negotiated link parameters); handlers of the base
class see it as the base.

Channels. Every endpoint a board declares has an integer *channel* chosen by the protocol
(native: the table channel; rosserial: the topic id) that names it in events and actions.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from enum import IntEnum
from typing import Any, Final, NamedTuple, Protocol, TypeAlias

from hwbridge.protocols.errors import HwBridgeError

__all__ = [
    "BoardSession",
    "BuildTag",
    "Connected",
    "DebugOutput",
    "Disconnected",
    "Endpoint",
    "EntryKind",
    "Error",
    "Event",
    "FirmwareIdentity",
    "Framing",
    "Log",
    "Message",
    "ParamRequest",
    "ServiceRequest",
    "ServiceResponse",
    "SessionStats",
    "TimeSynced",
    "TopicAnnounced",
    "parse_build_tag",
]


class EntryKind(IntEnum):
    """Direction of an endpoint, seen from the board (the values are native's wire values)."""

    PUBLISHER = 0
    SUBSCRIBER = 1
    SERVICE_SERVER = 2
    SERVICE_CLIENT = 3


@dataclass(frozen=True, slots=True)
class Endpoint:
    """One topic or service a board declared."""

    channel: int
    """The protocol's key of this endpoint in events and actions."""
    kind: EntryKind
    name: str
    """As the board gave it (relative names are resolved in the board's namespace)."""
    type_name: str
    """ROS 1 type (``std_msgs/String``) or, for services, service type (``std_srvs/Trigger``)."""
    md5: str
    """The message md5, or the combined service md5."""

    @property
    def is_service(self) -> bool:
        """True for service servers and clients."""
        return self.kind in (EntryKind.SERVICE_SERVER, EntryKind.SERVICE_CLIENT)


_BUILD_TAG: Final = re.compile(r"(?P<robot>[^/@\n]+)/(?P<board>[^/@\n]+)@(?P<digest>[0-9a-f]{12})")


class BuildTag(NamedTuple):
    """A build tag's parts (see :func:`hwbridge.robot.identity.build_tag` for the formula)."""

    robot: str
    board: str
    digest: str


def parse_build_tag(text: str) -> BuildTag | None:
    """The parts of a build tag, or None if ``text`` is not of the form ``robot/board@12hex``
    (12 lowercase hex digits)."""
    match = _BUILD_TAG.fullmatch(text)
    if match is None:
        return None
    return BuildTag(match["robot"], match["board"], match["digest"])


@dataclass(frozen=True, slots=True)
class FirmwareIdentity:
    """Which firmware a board runs, as far as its protocol says (native: BOARD_INFO, PROTOCOL.md
    2.6.1). An empty string is "not told": old boards tell nothing, and the host never treats
    that as a fault."""

    version: str = ""
    """The sketch's own version text (``initNode``'s ``firmware`` argument)."""
    name: str = ""
    """What the firmware calls itself (``HWBRIDGE_FIRMWARE_NAME``)."""
    library_version: str = ""
    """The version of the HwBridge library it was built with."""
    schema_hash: str = ""
    """Hash of the control-message schema it was built with."""
    messages_hash: str = ""
    """Hash of the message definitions of the library's generated headers."""
    build_tag: str = ""
    """``<robot>/<board>@<hash of the robot file>`` of a generated firmware
    (``HWBRIDGE_BUILD_TAG``)."""

    @property
    def known(self) -> bool:
        """The board sent an identity (any item beyond its version text)."""
        return bool(
            self.name
            or self.library_version
            or self.schema_hash
            or self.messages_hash
            or self.build_tag
        )

    @property
    def firmware_name(self) -> str:
        """``name``, or the part of ``build_tag`` before its ``@`` (a board whose send buffer
        cut the name off still names itself through its tag)."""
        if self.name or "@" not in self.build_tag:
            return self.name
        return self.build_tag.rsplit("@", 1)[0]

    def as_dict(self) -> dict[str, str]:
        """The items, for ``hwbridge board info`` (JSON-able)."""
        return {
            "name": self.firmware_name,
            "version": self.version,
            "library_version": self.library_version,
            "schema_hash": self.schema_hash,
            "messages_hash": self.messages_hash,
            "build_tag": self.build_tag,
        }


# --------------------------------------------------------------------------------------------
# Events


@dataclass(frozen=True, slots=True)
class Connected:
    """The board's endpoints are known and usable (sent again when the table changes)."""

    endpoints: tuple[Endpoint, ...]
    """Accepted endpoints (refused ones are reported as :class:`Error` events)."""
    board_name: str = ""
    """What the board calls itself, where the protocol says."""
    resumed: bool = False
    """The board kept its session since the last one (it did not restart)."""
    firmware: FirmwareIdentity | None = None
    """Which firmware the board runs (None: its protocol does not say, as rosserial)."""


@dataclass(frozen=True, slots=True)
class Disconnected:
    """A connected session ended (the board reset, went silent or said goodbye); the session
    negotiates again by itself. Pending operations were failed just before this event."""

    reason: str
    error: HwBridgeError


@dataclass(frozen=True, slots=True)
class TopicAnnounced:
    """An endpoint the board added while connected."""

    endpoint: Endpoint


@dataclass(frozen=True, slots=True)
class Message:
    """A topic message (opaque ROS 1 serialized bytes) on ``channel``."""

    channel: int
    payload: bytes
    seq: int
    """The protocol's sequence number of it (0 where the protocol has none)."""


@dataclass(frozen=True, slots=True)
class ServiceRequest:
    """The peer calls a service this end serves; answer with ``respond_service``."""

    channel: int
    request_id: int
    payload: bytes


@dataclass(frozen=True, slots=True)
class ServiceResponse:
    """The outcome of ``call_service``: a payload, or an error (timeout, reset, refusal)."""

    channel: int
    request_id: int
    payload: bytes
    error: HwBridgeError | None = None

    @property
    def ok(self) -> bool:
        """True when the call succeeded."""
        return self.error is None


@dataclass(frozen=True, slots=True)
class ParamRequest:
    """The board asks for a parameter; answer with ``answer_param(request_id, value)``."""

    request_id: int
    name: str
    subscribe: bool = False
    """The board also wants later changes pushed (``push_param``)."""


@dataclass(frozen=True, slots=True)
class Log:
    """A log line from the board; ``level`` 0..4 is DEBUG, INFO, WARN, ERROR, FATAL."""

    level: int
    text: str


@dataclass(frozen=True, slots=True)
class TimeSynced:
    """A time sync exchange completed: ``offset`` is host minus board time, seconds."""

    offset: float
    rtt: float


@dataclass(frozen=True, slots=True)
class DebugOutput:
    """Bytes on a stream link that were not frames but looked like text (a debug print)."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Error:
    """Something went wrong that does not end the session (or explains why it ended)."""

    error: HwBridgeError


Event: TypeAlias = (
    Connected
    | Disconnected
    | TopicAnnounced
    | Message
    | ServiceRequest
    | ServiceResponse
    | ParamRequest
    | Log
    | TimeSynced
    | DebugOutput
    | Error
)
"""The events a host session gives the runtime (protocol subclasses included)."""


# --------------------------------------------------------------------------------------------
# Statistics


@dataclass(frozen=True, slots=True)
class SessionStats:
    """Counters every protocol keeps for one board, cumulative over its sessions.

    The link itself counts bytes (:class:`hwbridge.links.LinkStats`); these count what the
    protocol made of them. A protocol's own counters go in ``detail``.
    """

    frames_sent: int = 0
    bytes_sent: int = 0
    frames_received: int = 0
    bytes_received: int = 0
    bad_frames: int = 0
    """Frames rejected for any reason (CRC and checksum errors included)."""
    crc_errors: int = 0
    non_frame_bytes: int = 0
    """Bytes between frames on a stream link (noise, debug prints)."""
    dropped_messages: int = 0
    """Messages received that went nowhere (unknown, refused or oversize endpoints)."""
    protocol_errors: int = 0
    sessions: int = 0
    """Sessions established (a board that resets counts again)."""
    detail: Mapping[str, int | float | None] = field(default_factory=dict)
    """The protocol's own counters by name."""

    def as_dict(self) -> dict[str, Any]:
        """Every counter by name (the protocol's own ones included), for logs and JSON."""
        out: dict[str, Any] = {
            f.name: getattr(self, f.name) for f in fields(self) if f.name != "detail"
        }
        out.update(self.detail)
        return out


# --------------------------------------------------------------------------------------------
# What a protocol implements


class Framing(Protocol):
    """Turns link input into frames and frames into link output, for one kind of link.

    A protocol gives one framing for stream links and, if it can run on them, one for datagram
    links; the session is built with one of them. ``decode`` takes a chunk of a stream (any
    size, frames may straddle chunks) or exactly one datagram and returns the protocol's frame
    objects and its notes about what was not a frame; ``encode`` returns what to write: one
    chunk for a stream link, one datagram per frame for a datagram link.
    """

    datagram: bool
    """True for a framing of datagram links."""

    def decode(self, data: bytes, /) -> Sequence[Any]: ...

    def encode(self, frames: Sequence[Any], now: float, /) -> list[bytes]: ...


class BoardSession(Protocol):
    """The host side of one board's session, as the runtime drives it (sans-I/O)."""

    # ---- driving (the pump) ---------------------------------------------------------------

    def receive_data(self, data: bytes, now: float, /) -> list[Event]:
        """Feed what one link read returned (a stream chunk or one datagram)."""
        ...

    def tick(self, now: float, /) -> list[Event]:
        """Run the timers due at ``now``."""
        ...

    def next_deadline(self) -> float | None:
        """When ``tick`` has work next (None: only when data arrives)."""
        ...

    def chunks_to_send(self) -> list[bytes]:
        """What to write to the link, each item in one write (a datagram each on datagram
        links); the buffer is emptied."""
        ...

    # ---- state -----------------------------------------------------------------------------

    @property
    def connected(self) -> bool: ...

    def counters(self) -> SessionStats:
        """A snapshot of the session's counters."""
        ...

    def describe(self) -> dict[str, Any]:
        """Facts about the board and the session for ``hwbridge board info`` (JSON-able)."""
        ...

    # ---- actions (the bridge, under the pump's lock) ---------------------------------------

    def publish(self, channel: int, payload: bytes, /) -> bool:
        """Send a message to a topic the board subscribes to; False if not sent."""
        ...

    def call_service(self, channel: int, request: bytes, *, timeout: float, now: float) -> int:
        """Call a service the board serves; returns the request id its
        :class:`ServiceResponse` will carry (also for a timeout, after ``timeout`` s)."""
        ...

    def respond_service(
        self, channel: int, request_id: int, payload: bytes = b"", *, error: str | None = None
    ) -> bool:
        """Answer a :class:`ServiceRequest`, or fail it with ``error`` where the protocol can
        tell the board (False where it cannot)."""
        ...

    def answer_param(self, request_id: int, value: Any, /) -> bool:
        """Answer a :class:`ParamRequest` (None: the parameter does not exist)."""
        ...

    def push_param(self, name: str, value: Any, /) -> bool:
        """Send a new value of a parameter the board subscribed to (False if unsupported)."""
        ...

    def close(self, now: float, /) -> list[Event]:
        """End the session (a goodbye goes to :meth:`chunks_to_send` where the protocol has
        one); nothing more happens after it."""
        ...
