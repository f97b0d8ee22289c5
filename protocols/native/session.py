"""Sessions of the native protocol: handshake, topic table, services, params, time, logs.

Two sans-I/O state machines share this code, shaped like h11:

* :class:`HostSession` runs on the host, one per board link;
* :class:`DeviceSession` is the board's side. It drives emulated boards today and is the
  executable specification of what the C++ firmware does (PROTOCOL.md, Part 2).

Feed received bytes with ``receive_data(data, now)``, call ``tick(now)`` when
``next_deadline()`` is due, call action methods (``publish``, ``call_service``, ...), and write
``data_to_send()`` to the link. Both return or produce :data:`Event` objects. ``now`` is a
monotonic clock in seconds; actions use the latest ``now`` seen unless given their own.

Nothing here reads a clock, sleeps, or touches a socket.
"""

from __future__ import annotations

import random
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, fields
from enum import Enum
from typing import ClassVar, Final, TypeAlias, TypeVar

from hwbridge.protocols.errors import (
    HwBridgeError,
    HwBridgeTimeoutError,
    ProtocolError,
    ProtocolMismatchError,
)
from hwbridge.protocols.native.control import (
    ALL_FEATURES,
    CONTROL_CHANNEL,
    MAX_NAME_BYTES,
    MAX_WINDOW,
    MIN_MTU,
    NO_SESSION,
    PROTOCOL_VERSION,
    BoardInfoMsg,
    ControlMessage,
    EntryFlags,
    EntryKind,
    Features,
    GoodbyeMsg,
    HeartbeatMsg,
    HelloFlags,
    HelloMsg,
    HostTimeRequestMsg,
    HostTimeResponseMsg,
    LogLevel,
    LogMsg,
    Opcode,
    ParamGetFlags,
    ParamGetMsg,
    ParamInput,
    ParamStatus,
    ParamType,
    ParamValue,
    ParamValueMsg,
    ReadyMsg,
    Role,
    ServiceRequestMsg,
    ServiceResponseMsg,
    ServiceStatus,
    TableEndMsg,
    TimeRequestMsg,
    TimeResponseMsg,
    TopicAckMsg,
    TopicMsg,
    TopicStatus,
    coerce_param,
    decode_control,
    encode_service_request,
    encode_service_response,
    is_best_effort_opcode,
)
from hwbridge.protocols.native.framing import (
    BadFrame,
    BadFrameReason,
    Frame,
    FrameDecoder,
    FrameType,
    NonFrameBytes,
    encode_frame,
    slot_setter,
)
from hwbridge.protocols.native.reliable import (
    BestEffortReceiver,
    BestEffortSender,
    Delivery,
    ReliableReceiver,
    ReliableSender,
    RttEstimator,
    SequenceStats,
)

__all__ = [
    "ACK_DELAY_MAX",
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
    "HostSession",
    "LinkParams",
    "LinkStats",
    "Log",
    "Message",
    "ParamRequest",
    "ParamResponse",
    "ParamUpdate",
    "ServiceRequest",
    "ServiceResponse",
    "SessionConfig",
    "SessionError",
    "SessionResetError",
    "SessionState",
    "TimeSynced",
    "TopicAnnounced",
    "TopicEntry",
    "TopicMismatchError",
    "TypeCheck",
]

_U32: Final = 1 << 32
_MAX_TIME_SAMPLES: Final = 4
ACK_DELAY_MAX: Final = 0.01
"""Longest a receiver may hold an ACK back (seconds, PROTOCOL.md 2.4); a fifth of the default
rto_min, so a held ACK does not make the peer resend."""
RTO_MIN_FLOOR: Final = 2 * ACK_DELAY_MAX
"""Smallest allowed rto_min: a peer may hold its ACK for ACK_DELAY_MAX, and an RTO that expires
before the ACK can come resends frames that arrived."""
_IDLE_LEAD: Final = 0.1
"""A frame sent after the line was idle this long (seconds) gets a leading 0x00."""
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


@dataclass(frozen=True, slots=True, kw_only=True)
class DeviceConfig(SessionConfig):
    """A board's limits and timers; the defaults fit an ATmega328P (PROTOCOL.md 2.10)."""

    mtu: int = 64
    max_message: int = 64
    window: int = 1
    features: Features = Features.TIME_SYNC | Features.PARAM_PUSH
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


@dataclass(frozen=True, slots=True)
class TopicEntry:
    """One row of a board's topic/service table."""

    channel: int
    """1..255, chosen by the board."""
    kind: EntryKind
    """Direction, seen from the board."""
    name: str
    type_name: str
    """ROS 1 type (``std_msgs/String``) or, for services, service type (``std_srvs/Trigger``)."""
    md5: str
    """32 lowercase hex digits: the message md5, or the combined service md5."""
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

    @property
    def is_service(self) -> bool:
        """True for service servers and clients."""
        return self.kind in (EntryKind.SERVICE_SERVER, EntryKind.SERVICE_CLIENT)

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


@dataclass(frozen=True, slots=True)
class LinkStats:
    """Counters of one end of a link (cumulative over sessions) and its RTT estimate."""

    frames_sent: int
    bytes_sent: int
    frames_received: int
    bytes_received: int
    crc_errors: int
    bad_frames: int
    """Runs rejected by the frame decoder for any reason (CRC errors included)."""
    non_frame_bytes: int
    be_frames_sent: int
    be_frames_received: int
    be_frames_lost: int
    """Best-effort frames the peer sent that never arrived (seq gaps)."""
    be_frames_late: int
    be_resyncs: int
    be_messages_sent: int
    be_messages_received: int
    be_messages_incomplete: int
    be_fragments_discarded: int
    rel_frames_sent: int
    rel_frames_received: int
    rel_messages_sent: int
    rel_messages_received: int
    retransmits: int
    fast_retransmits: int
    duplicates: int
    out_of_window: int
    acks_sent: int
    acks_received: int
    oversize_messages: int
    malformed_messages: int
    ignored_frames: int
    """Valid frames that did not belong to the current session (e.g. before the handshake)."""
    dropped_messages: int
    """Messages received on channels that are unknown, refused, or not yet connected."""
    tx_refused: int
    """Sends refused because the session was not connected or the queue was full."""
    protocol_errors: int
    hellos_sent: int
    heartbeats_sent: int
    sessions: int
    """Sessions established."""
    link_losses: int
    """Sessions ended by the link timeout or the retry limit."""
    peer_resets: int
    """Sessions ended because the peer restarted or dropped the session."""
    rtt: float | None
    """Smoothed round-trip time of reliable frames, seconds."""
    rto: float

    def as_dict(self) -> dict[str, int | float | None]:
        """Counters by name, for logs and JSON."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


# --------------------------------------------------------------------------------------------
# Events


@dataclass(frozen=True, slots=True)
class Connected:
    """The session is up: the table was exchanged and accepted entries can be used."""

    board: BoardInfo
    topics: tuple[TopicEntry, ...]
    """Accepted entries (refused ones are reported as Error events)."""
    link: LinkParams
    host_session: int
    device_session: int
    resumed: bool
    """The board kept its session id since the last session (it did not restart)."""


@dataclass(frozen=True, slots=True)
class Disconnected:
    """A connected session ended; pending operations were failed just before this event."""

    reason: str
    error: HwBridgeError


@dataclass(frozen=True, slots=True)
class TopicAnnounced:
    """Host: the board announced an entry and the host accepted it."""

    entry: TopicEntry


@dataclass(frozen=True, slots=True)
class Message:
    """A topic message (opaque ROS 1 serialized bytes)."""

    channel: int
    payload: bytes
    seq: int
    """Seq of its first frame in its (best-effort or reliable) sequence space."""


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
    """Host: the board asks for a parameter; answer with ``answer_param``."""

    request_id: int
    name: str
    type: ParamType
    max_count: int
    subscribe: bool


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


@dataclass(frozen=True, slots=True)
class Log:
    """A log line from the peer."""

    level: LogLevel
    text: str


@dataclass(frozen=True, slots=True)
class TimeSynced:
    """A time sync exchange completed.

    ``offset`` is host time minus board time (seconds) of the best of the last few samples;
    on the host, board time is the board's 32-bit microsecond counter as seconds.
    """

    offset: float
    rtt: float


@dataclass(frozen=True, slots=True)
class DebugOutput:
    """Bytes on the link that were not frames but looked like text (a board's debug print)."""

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
    | ParamResponse
    | ParamUpdate
    | Log
    | TimeSynced
    | DebugOutput
    | Error
)


# Enum members for the per-message paths: looking one up on its class costs about 0.1 us on
# Python 3.11 (the enum metaclass defines __getattr__), a module global a fifth of that.
_CONFIGURING: Final = SessionState.CONFIGURING
_CONNECTED: Final = SessionState.CONNECTED
_CLOSED: Final = SessionState.CLOSED
_ACK: Final = FrameType.ACK
_BEST_EFFORT: Final = FrameType.BEST_EFFORT
_SERVICE_ERROR: Final = ServiceStatus.ERROR
_SERVICE_NO_SERVICE: Final = ServiceStatus.NO_SERVICE


# The events of every message, built the fast way (as framing.make_frame builds frames): a
# frozen dataclass's __init__ costs about twice as much as filling its slots directly.

_set_message: Final = tuple(slot_setter(Message, name) for name in ("channel", "payload", "seq"))
_set_request: Final = tuple(
    slot_setter(ServiceRequest, name) for name in ("channel", "request_id", "payload")
)
_set_response: Final = tuple(
    slot_setter(ServiceResponse, name) for name in ("channel", "request_id", "payload", "error")
)


def _message(channel: int, payload: bytes, seq: int) -> Message:
    """``Message(channel, payload, seq)``."""
    event = object.__new__(Message)
    set_channel, set_payload, set_seq = _set_message
    set_channel(event, channel)
    set_payload(event, payload)
    set_seq(event, seq)
    return event


def _service_request(channel: int, request_id: int, payload: bytes) -> ServiceRequest:
    """``ServiceRequest(channel, request_id, payload)``."""
    event = object.__new__(ServiceRequest)
    set_channel, set_request_id, set_payload = _set_request
    set_channel(event, channel)
    set_request_id(event, request_id)
    set_payload(event, payload)
    return event


def _service_response(
    channel: int, request_id: int, payload: bytes, error: HwBridgeError | None
) -> ServiceResponse:
    """``ServiceResponse(channel, request_id, payload, error)``."""
    event = object.__new__(ServiceResponse)
    set_channel, set_request_id, set_payload, set_error = _set_response
    set_channel(event, channel)
    set_request_id(event, request_id)
    set_payload(event, payload)
    set_error(event, error)
    return event


# --------------------------------------------------------------------------------------------
# Shared machinery


@dataclass(slots=True)
class _Pending:
    """An outgoing request waiting for its answer."""

    channel: int
    name: str
    deadline: float


@dataclass(slots=True)
class _Counters:
    frames_sent: int = 0
    bytes_sent: int = 0
    ignored_frames: int = 0
    dropped_messages: int = 0
    tx_refused: int = 0
    protocol_errors: int = 0
    hellos_sent: int = 0
    heartbeats_sent: int = 0
    sessions: int = 0
    link_losses: int = 0
    peer_resets: int = 0


def _truncate(text: str, limit: int) -> bytes:
    """``text`` as UTF-8, cut to at most ``limit`` bytes on a character boundary."""
    raw = text.encode("utf-8")
    if len(raw) <= limit:
        return raw
    return raw[: max(0, limit)].decode("utf-8", errors="ignore").encode("utf-8")


_S = TypeVar("_S", bound=tuple[float, ...])


def _best_sample(samples: Iterable[_S]) -> _S:
    """The newest time sample whose RTT is within 25 % (or 0.1 ms) of the smallest one.

    A short round trip bounds the offset error best (NTP's clock filter); among similar round
    trips the newest wins, because clocks drift.
    """
    items = list(samples)
    floor = min(item[0] for item in items)
    limit = floor + max(floor * 0.25, 1e-4)
    return [item for item in items if item[0] <= limit][-1]


def _role_name(role: Role) -> str:
    return "host" if role == Role.HOST else "board"


class _Session:
    """Code shared by both ends; the subclasses add the role-specific messages."""

    _ROLE: ClassVar[Role]
    _PUBLISH_KIND: ClassVar[EntryKind]
    """Entry kind this end publishes on."""
    _RECEIVE_KIND: ClassVar[EntryKind]
    """Entry kind whose messages this end receives."""
    _CALL_KIND: ClassVar[EntryKind]
    """Entry kind of services this end calls."""
    _SERVE_KIND: ClassVar[EntryKind]
    """Entry kind of services this end serves."""

    def __init__(
        self,
        config: SessionConfig,
        *,
        session_id: int | None = None,
        rng: random.Random | None = None,
    ) -> None:
        self._cfg = config
        self._rng = rng if rng is not None else random.Random()
        if session_id is not None and not 0 < session_id < _U32:
            raise ValueError(f"session id must be 1..2**32-1, not {session_id}")
        self._id = session_id if session_id is not None else self._random_session_id()
        self._decoder = FrameDecoder(config.mtu)
        self._out: list[bytes] = []
        """Encoded frames not yet taken by data_to_send (joined once, not copied per frame)."""
        self._events: list[Event] = []
        self._now = 0.0
        """The latest time seen (0.0 before the first); the clock of every action."""
        self._started = False
        """True once a time was seen: the timers start from that time."""
        self._c = _Counters()
        self._seq = SequenceStats()
        self._rtt = RttEstimator(config.rto_initial, config.rto_min, config.rto_max)
        self._be_tx = BestEffortSender(self._seq)
        self._be_rx = BestEffortReceiver(self._seq, config.max_message)
        self._be_peer = NO_SESSION
        """Peer session whose best-effort seq space ``_be_rx`` follows."""
        self._rel_tx: ReliableSender | None = None
        self._rel_rx: ReliableReceiver | None = None
        self._state = SessionState.HANDSHAKE
        self._established = False
        self._peer_id = NO_SESSION
        self._last_peer_id = NO_SESSION
        self._isn = self._rng.getrandbits(8)
        self._link: LinkParams | None = None
        self._peer_max = MIN_MTU
        """The largest message the peer accepts (its max_message; MIN_MTU without a session)."""
        self._time_sync = False
        """Time requests run in this session (both ends have TIME_SYNC, the interval is > 0)."""
        self._last_rx = 0.0
        self._last_tx = 0.0
        self._ack_due: float | None = None
        """When a held-back ACK must go out at the latest (None: none is held)."""
        self._next_hello = 0.0
        self._waiting_since = 0.0
        """When the current wait for a connected session began."""
        self._wait_reported = False
        self._configuring_since = 0.0
        self._version_frames = 0
        self._reported: set[str] = set()
        """Keys of errors already reported this session (to avoid floods)."""
        self._calls: dict[int, _Pending] = {}
        self._incoming_calls: set[tuple[int, int]] = set()
        self._next_request_id = 1
        self._time_next = 0.0
        self._time_samples: deque[tuple[float, float, float]] = deque(maxlen=_MAX_TIME_SAMPLES)
        """(rtt, offset, reference) of recent time sync exchanges."""

    # ---- public API shared by both ends --------------------------------------------------

    @property
    def state(self) -> SessionState:
        """Where the session is."""
        return self._state

    @property
    def connected(self) -> bool:
        """True in the CONNECTED state."""
        return self._state is SessionState.CONNECTED

    @property
    def session_id(self) -> int:
        """This end's session id (a device picks a new one at every boot)."""
        return self._id

    @property
    def peer_session_id(self) -> int:
        """The peer's session id, 0 when no session is established."""
        return self._peer_id if self._established else NO_SESSION

    @property
    def link(self) -> LinkParams | None:
        """The negotiated parameters, None without a session."""
        return self._link

    @property
    def config(self) -> SessionConfig:
        """This end's configuration."""
        return self._cfg

    @property
    def rtt(self) -> float | None:
        """Smoothed round-trip time of reliable frames (seconds), None before a sample."""
        return self._rtt.srtt

    @property
    def stats(self) -> LinkStats:
        """A snapshot of this end's counters."""
        d = self._decoder.stats
        bad = (
            d.crc_errors
            + d.cobs_errors
            + d.too_short
            + d.version_errors
            + d.reserved_type
            + d.oversize
        )
        return LinkStats(
            frames_sent=self._c.frames_sent,
            bytes_sent=self._c.bytes_sent,
            frames_received=d.frames,
            bytes_received=d.bytes,
            crc_errors=d.crc_errors,
            bad_frames=bad,
            non_frame_bytes=d.non_frame_bytes,
            ignored_frames=self._c.ignored_frames,
            dropped_messages=self._c.dropped_messages,
            tx_refused=self._c.tx_refused,
            protocol_errors=self._c.protocol_errors,
            hellos_sent=self._c.hellos_sent,
            heartbeats_sent=self._c.heartbeats_sent,
            sessions=self._c.sessions,
            link_losses=self._c.link_losses,
            peer_resets=self._c.peer_resets,
            rtt=self._rtt.srtt,
            rto=self._rtt.rto,
            **self._seq.as_dict(),
        )

    def receive_data(self, data: bytes, now: float) -> list[Event]:
        """Feed bytes read from the link; returns the events they (and due timers) cause."""
        self._advance(now)
        if self._state is not _CLOSED:
            on_frame = self._on_frame
            for item in self._decoder.feed(data):
                if isinstance(item, Frame):
                    on_frame(item)
                elif isinstance(item, NonFrameBytes):
                    self._events.append(DebugOutput(item.data))
                else:
                    self._on_bad_frame(item)
            self._flush()
        events = self._events  # _take_events(), inline: a per-read path
        self._events = []
        return events

    def tick(self, now: float) -> list[Event]:
        """Run the timers due at ``now``; returns the events they cause."""
        self._advance(now)
        if self._state is not _CLOSED:
            self._run_timers()
            self._flush()
        events = self._events  # _take_events(), inline
        self._events = []
        return events

    def data_to_send(self) -> bytes:
        """Bytes to write to the link (all of them; the buffer is emptied)."""
        out = b"".join(self._out)
        self._out.clear()
        return out

    def next_deadline(self) -> float | None:
        """The time at which ``tick`` has work next, or None (closed)."""
        state = self._state
        if state is _CLOSED:
            return None
        cfg = self._cfg
        times: list[float] = []
        if not self._wait_reported and state is not _CONNECTED:
            times.append(self._waiting_since + cfg.handshake_timeout)
        if not self._established:
            times.append(self._next_hello)
        else:
            times.append(self._last_rx + cfg.link_timeout)
            times.append(self._last_tx + cfg.heartbeat_interval)
            if self._ack_due is not None:
                times.append(self._ack_due)
            if self._rel_tx is not None:
                rel = self._rel_tx.next_deadline()
                if rel is not None:
                    times.append(rel)
            if state is _CONFIGURING:
                times.append(self._configuring_since + cfg.handshake_timeout)
            else:
                for call in self._calls.values():
                    times.append(call.deadline)
                times.extend(self._other_deadlines())
                if self._time_sync:
                    times.append(self._time_next)
        return min(times)

    def publish(self, channel: int, payload: bytes) -> bool:
        """Send one topic message; False when not connected or the queue is full.

        Raises:
            SessionError: the channel is not a topic this end publishes, or the message is
                larger than the peer accepts.
        """
        if self._state is not _CONNECTED:
            self._c.tx_refused += 1
            return False
        entry = self._entry(channel)
        if entry is None or entry.kind != self._PUBLISH_KIND:
            raise SessionError(self._wrong_channel(channel, entry, "publish on"))
        self._check_size(len(payload), "message for %s (channel %d)", entry.name, channel)
        if entry.reliable:
            return self._send_reliable(channel, payload)
        self._send_best_effort(channel, payload)
        return True

    def call_service(
        self,
        channel: int,
        payload: bytes,
        *,
        timeout: float | None = None,
        now: float | None = None,
    ) -> int:
        """Call a service of the peer; returns the request id.

        Exactly one :class:`ServiceResponse` with this id follows: the answer, or an error
        (:class:`HwBridgeTimeoutError` after ``timeout`` seconds, default
        ``config.service_timeout``; :class:`SessionResetError` if the session ends first;
        :class:`SessionError` if not connected or the peer refused).

        Raises:
            SessionError: connected, but the channel is not a service this end calls, or the
                request is larger than the peer accepts.
        """
        if now is not None:
            self._advance(now)
        request_id = self._new_request_id()
        deadline = self._now + (self._cfg.service_timeout if timeout is None else timeout)
        if self._state is not _CONNECTED:
            self._c.tx_refused += 1
            self._events.append(
                ServiceResponse(
                    channel,
                    request_id,
                    b"",
                    SessionError(f"service call on channel {channel}: not connected to a board"),
                )
            )
            return request_id
        entry = self._entry(channel)
        if entry is None or entry.kind != self._CALL_KIND:
            raise SessionError(self._wrong_channel(channel, entry, "call a service on"))
        # An accepted entry's channel and a request id of ours: both are in range.
        msg = encode_service_request(channel, request_id, payload)
        self._check_size(len(msg), "request for %s (channel %d)", entry.name, channel)
        if not self._send_reliable(CONTROL_CHANNEL, msg):
            self._events.append(
                ServiceResponse(
                    channel,
                    request_id,
                    b"",
                    SessionError(f"service call to {entry.name}: transmit queue full"),
                )
            )
            return request_id
        self._calls[request_id] = _Pending(channel, entry.name, deadline)
        return request_id

    def respond_service(
        self,
        channel: int,
        request_id: int,
        payload: bytes = b"",
        *,
        error: str | None = None,
    ) -> bool:
        """Answer a :class:`ServiceRequest`; with ``error`` the call fails with that text.

        Returns False when the request is no longer pending (the session ended meanwhile).

        Raises:
            SessionError: the response is larger than the peer accepts.
        """
        key = (channel, request_id)
        if key not in self._incoming_calls or not self._established:
            return False
        self._incoming_calls.discard(key)
        # The key came from a decoded request, so channel and request id are in range.
        if error is not None:
            limit = self._peer_max - 5
            body = _truncate(error, limit)
            msg = encode_service_response(channel, request_id, ServiceStatus.ERROR, body)
        else:
            msg = encode_service_response(channel, request_id, ServiceStatus.OK, payload)
            self._check_size(len(msg), "response on channel %d", channel)
        return self._send_reliable(CONTROL_CHANNEL, msg, force=True)

    def log(self, level: LogLevel, text: str) -> bool:
        """Send a log line to the peer (truncated to fit); False when it cannot be sent."""
        if not self.connected or not self._may_log():
            self._c.tx_refused += 1
            return False
        raw = _truncate(text, self._peer_max - 2)
        return self._send_reliable(CONTROL_CHANNEL, LogMsg(level, raw.decode("utf-8")).encode())

    def request_time_sync(self, now: float | None = None) -> bool:
        """Start a time sync exchange now (they also run every ``time_sync_interval``)."""
        self._advance_opt(now)
        if not self.connected or not self._link or not self._link.features & Features.TIME_SYNC:
            return False
        self._send_time_request()
        self._time_next = self._now + self._cfg.time_sync_retry
        return True

    def close(self, now: float | None = None) -> list[Event]:
        """End the session: tell the peer (GOODBYE), fail pending operations, stop all timers."""
        self._advance_opt(now)
        if self._state is SessionState.CLOSED:
            return self._take_events()
        if self._established:
            self._send_control_be(GoodbyeMsg())
        self._teardown("closed by this end", SessionResetError("the session was closed"))
        self._state = SessionState.CLOSED
        return self._take_events()

    # ---- hooks for the subclasses ------------------------------------------------------------

    def _entry(self, channel: int) -> TopicEntry | None:
        """The accepted entry on ``channel`` in the current session."""
        raise NotImplementedError

    def _on_established(self) -> None:
        """The handshake completed (state CONFIGURING)."""

    def _on_teardown(self) -> None:
        """The session ended; drop role-specific state."""

    def _on_role_control(self, msg: ControlMessage) -> bool:
        """Handle a role-specific control message; False if this end does not accept it."""
        raise NotImplementedError

    def _other_deadlines(self) -> Iterable[float]:
        """Role-specific timer deadlines (CONNECTED state)."""
        return ()

    def _run_role_timers(self, now: float) -> None:
        """Role-specific timers (CONNECTED state)."""

    def _send_time_request(self) -> None:
        raise NotImplementedError

    def _may_log(self) -> bool:
        return True

    def _request_id_in_use(self, request_id: int) -> bool:
        """True when a role-specific request uses this id."""
        return False

    def _fail_role_pending(self, reason: str) -> None:
        """Fail role-specific pending operations (the session ended)."""

    def _hello_context(self) -> str:
        return ""

    # ---- clock -----------------------------------------------------------------------------

    def _advance(self, now: float) -> None:
        if not self._started:
            self._started = True
            self._now = now
            self._next_hello = now
            self._waiting_since = now
            self._last_tx = now
        elif now > self._now:
            self._now = now

    def _advance_opt(self, now: float | None) -> None:
        if now is not None:
            self._advance(now)

    # ---- output -----------------------------------------------------------------------------

    def _take_events(self) -> list[Event]:
        events = self._events
        self._events = []
        return events

    def _send_frame(self, frame: Frame, *, lead: bool = False) -> None:
        if self._ack_due is not None:  # a held ACK goes out with the first frame that does
            self._send_ack()
        # PROTOCOL.md 1.3: a 0x00 before a frame that follows an idle line flushes the receiver.
        now = self._now
        wire = encode_frame(frame, lead=lead or now - self._last_tx >= _IDLE_LEAD)
        self._out.append(wire)
        counters = self._c
        counters.frames_sent += 1
        counters.bytes_sent += len(wire)
        self._last_tx = now

    def _send_best_effort(self, channel: int, payload: bytes, *, lead: bool = False) -> None:
        mtu = self._link.mtu if self._link is not None else MIN_MTU
        for frame in self._be_tx.frames(channel, payload, mtu):
            self._send_frame(frame, lead=lead)

    def _send_control_be(self, msg: ControlMessage, *, lead: bool = False) -> None:
        self._send_best_effort(CONTROL_CHANNEL, msg.encode(), lead=lead)

    def _send_reliable(self, channel: int, payload: bytes, *, force: bool = False) -> bool:
        if self._rel_tx is None:
            self._c.tx_refused += 1
            return False
        if not self._rel_tx.queue(channel, payload, force=force):
            self._c.tx_refused += 1
            return False
        self._pump()
        return True

    def _send_control(self, msg: ControlMessage) -> None:
        self._send_reliable(CONTROL_CHANNEL, msg.encode(), force=True)

    def _pump(self) -> None:
        sender = self._rel_tx
        if sender is not None and sender.has_pending:
            for frame in sender.transmit(self._now):
                self._send_frame(frame)

    def _flush(self) -> None:
        """Send a pending ACK (or hold it back, PROTOCOL.md 2.4) and release reliable frames the
        window allows."""
        receiver = self._rel_rx
        if receiver is not None and receiver.ack_needed:
            if receiver.ack_urgent or self._out or self._rel_tx is None or self._rel_tx.has_pending:
                self._send_ack()
            elif self._ack_due is None:
                self._ack_due = self._now + self._cfg.ack_delay
        self._pump()

    def _send_ack(self) -> None:
        self._ack_due = None
        receiver = self._rel_rx
        if receiver is not None:
            self._send_frame(receiver.ack_frame())

    def _check_size(self, size: int, what: str, *args: object) -> None:
        """Raise if ``size`` is above the peer's max_message; ``what % args`` names the
        message (formatted only then: this runs for every message sent)."""
        limit = self._peer_max
        if size > limit:
            peer = "board" if self._ROLE == Role.HOST else "host"
            raise SessionError(
                f"{what % args} is {size} bytes but the {peer} accepts messages of at most {limit} "
                f"bytes (its max_message): send less, or raise max_message on the {peer}"
            )

    def _new_request_id(self) -> int:
        for _ in range(0x10000):
            request_id = self._next_request_id
            self._next_request_id = request_id % 0xFFFF + 1
            if request_id not in self._calls and not self._request_id_in_use(request_id):
                return request_id
        raise SessionError("65535 requests are pending: no request id is free")

    def _random_session_id(self) -> int:
        return self._rng.randrange(1, _U32)

    def _error(self, error: HwBridgeError, key: str | None = None) -> None:
        """Report an error, once per session for a given ``key``."""
        if key is not None:
            if key in self._reported:
                return
            self._reported.add(key)
        self._events.append(Error(error))

    def _protocol_error(self, text: str, key: str | None = None) -> None:
        self._c.protocol_errors += 1
        self._error(ProtocolError(text), key)

    def _wrong_channel(self, channel: int, entry: TopicEntry | None, action: str) -> str:
        if entry is None:
            return f"cannot {action} channel {channel}: no accepted entry has that channel"
        return f"cannot {action} channel {channel}: it is {entry.name}, a {entry.kind.name.lower()}"

    # ---- input ------------------------------------------------------------------------------

    def _on_bad_frame(self, item: BadFrame) -> None:
        if item.reason is BadFrameReason.VERSION:
            self._version_frames += 1
            if self._version_frames < _VERSION_FRAMES_TO_REPORT:
                return
            self._protocol_error(
                "received a frame of another native protocol version: update the firmware or "
                "hwbridge so both match",
                key="frame-version",
            )

    def _on_frame(self, frame: Frame) -> None:
        # A per-frame path: _alive() is written out (``self._last_rx = self._now``).
        ftype = frame.type
        if ftype is _ACK:
            sender = self._rel_tx
            if sender is None:
                self._c.ignored_frames += 1
                return
            self._last_rx = self._now
            for again in sender.on_ack(frame, self._now):
                self._send_frame(again)
            return
        if ftype is _BEST_EFFORT:
            self._on_best_effort(frame)
            return
        receiver = self._rel_rx
        if receiver is None:
            self._c.ignored_frames += 1
            return
        self._last_rx = self._now
        for delivery in receiver.receive(frame):
            if delivery.channel == CONTROL_CHANNEL:
                self._on_control(delivery.payload, reliable=True)
            else:
                self._on_data(delivery)
            if self._rel_rx is not receiver:  # the session ended while handling it
                break

    def _on_best_effort(self, frame: Frame) -> None:
        payload = frame.payload
        if (
            frame.channel == CONTROL_CHANNEL
            and len(payload) >= 8
            and payload[0] == Opcode.HELLO
            and payload[1] == PROTOCOL_VERSION
        ):
            # A HELLO names the sender's session: a new one has its own seq space.
            peer = int.from_bytes(payload[4:8], "little")
            if peer not in (self._be_peer, self._id):
                self._be_peer = peer
                self._be_rx.resync()
        if not self._be_rx.accept(frame.seq):
            return
        delivery = self._be_rx.receive(frame)
        if delivery is None:
            return
        if delivery.channel == CONTROL_CHANNEL:
            self._on_control(delivery.payload, reliable=False)
        elif self._established:
            self._last_rx = self._now  # _alive(), on a per-message path
            self._on_data(delivery)
        else:
            self._c.ignored_frames += 1

    def _alive(self) -> None:
        self._last_rx = self._now

    def _on_data(self, delivery: Delivery) -> None:
        connected = self._state is _CONNECTED
        entry = self._entry(delivery.channel) if connected else None
        if entry is None or entry.kind != self._RECEIVE_KIND:
            self._c.dropped_messages += 1
            if connected:
                self._protocol_error(
                    self._wrong_channel(delivery.channel, entry, "receive a message on"),
                    key=f"data-{delivery.channel}",
                )
            return
        self._events.append(_message(delivery.channel, delivery.payload, delivery.seq))

    def _on_control(self, payload: bytes, *, reliable: bool) -> None:
        try:
            msg = decode_control(payload)
        except ProtocolMismatchError as exc:
            self._c.protocol_errors += 1
            self._error(exc, key="version")
            return
        except ProtocolError as exc:
            self._c.protocol_errors += 1
            self._error(exc)
            return
        if is_best_effort_opcode(msg.OPCODE) == reliable:
            stream = "reliable" if reliable else "best-effort"
            self._protocol_error(
                f"control message {msg.OPCODE.name} arrived on the {stream} stream"
            )
            return
        if isinstance(msg, HelloMsg):
            self._on_hello(msg)
            return
        if not self._established:
            self._c.ignored_frames += 1
            return
        self._last_rx = self._now  # _alive(), on a per-message path
        # The message classes are disjoint: the common ones are tested first.
        if isinstance(msg, ServiceRequestMsg):
            self._on_service_request(msg)
        elif isinstance(msg, ServiceResponseMsg):
            self._on_service_response(msg)
        elif isinstance(msg, HeartbeatMsg):
            return
        elif isinstance(msg, GoodbyeMsg):
            self._c.peer_resets += 1
            peer = _role_name(Role(1 - self._ROLE))
            self._teardown(
                f"the {peer} closed the session",
                SessionResetError(f"the {peer} closed the session"),
            )
        elif isinstance(msg, LogMsg):
            self._events.append(Log(msg.level, msg.text))
        elif not self._on_role_control(msg):
            self._protocol_error(
                f"the {_role_name(Role(1 - self._ROLE))} sent {msg.OPCODE.name}, which only "
                f"the {_role_name(self._ROLE)} sends",
                key=f"opcode-{msg.OPCODE}",
            )

    # ---- handshake --------------------------------------------------------------------------

    def _hello(self) -> HelloMsg:
        cfg = self._cfg
        return HelloMsg(
            role=self._ROLE,
            flags=HelloFlags.ESTABLISHED if self._established else HelloFlags.NONE,
            session=self._id,
            peer_session=self._peer_id,
            mtu=cfg.mtu,
            max_message=cfg.max_message,
            window=cfg.window,
            isn=self._isn,
            features=cfg.features,
        )

    def _send_hello(self) -> None:
        self._c.hellos_sent += 1
        self._send_control_be(self._hello(), lead=True)

    def _on_hello(self, msg: HelloMsg) -> None:
        if msg.role == self._ROLE:
            if msg.session == self._id:
                self._protocol_error(
                    "received this end's own HELLO: the link echoes (loopback) what is sent",
                    key="echo",
                )
            else:
                role = _role_name(self._ROLE)
                self._protocol_error(
                    f"the peer is also a {role}: connect a host to a board", key="role"
                )
            return
        if self._established and (msg.session != self._peer_id or msg.peer_session != self._id):
            self._c.peer_resets += 1
            peer = _role_name(msg.role)
            if msg.session != self._peer_id:
                reason = (
                    f"the {peer} restarted (session {self._peer_id:#010x} -> {msg.session:#010x})"
                )
            else:
                reason = f"the {peer} dropped the session (its link timed out or it restarted)"
            self._teardown(reason, SessionResetError(reason))
        if not self._established:
            problem = self._check_peer_limits(msg)
            if problem:
                self._protocol_error(problem, key=f"limits-{msg.session}")
                return
            self._peer_id = msg.session
            if msg.peer_session == self._id:
                self._establish(msg)
        else:
            self._alive()
        if not msg.flags & HelloFlags.ESTABLISHED:
            self._send_hello()

    def _check_peer_limits(self, msg: HelloMsg) -> str:
        peer = _role_name(msg.role)
        if msg.mtu < MIN_MTU:
            return f"the {peer} announces mtu {msg.mtu}, below the minimum {MIN_MTU}"
        if not 1 <= msg.window <= 255:
            return f"the {peer} announces window {msg.window}; it must be at least 1"
        if msg.max_message < 1:
            return f"the {peer} announces max_message {msg.max_message}"
        if msg.session == NO_SESSION:
            return f"the {peer} announces session id 0, which is reserved"
        return ""

    def _establish(self, peer: HelloMsg) -> None:
        cfg = self._cfg
        window = min(cfg.window, peer.window, MAX_WINDOW)
        mtu = min(cfg.mtu, peer.mtu)
        own_features = cfg.features
        if self._ROLE == Role.HOST:
            host_max, device_max = cfg.max_message, peer.max_message
        else:
            host_max, device_max = peer.max_message, cfg.max_message
        link = LinkParams(mtu, window, host_max, device_max, own_features & peer.features)
        self._link = link
        self._peer_max = device_max if self._ROLE == Role.HOST else host_max
        self._time_sync = cfg.time_sync_interval > 0 and bool(link.features & Features.TIME_SYNC)
        self._established = True
        self._reported.clear()
        self._c.sessions += 1
        self._rel_tx = ReliableSender(
            self._seq,
            self._rtt,
            isn=self._isn,
            window=window,
            mtu=mtu,
            max_retries=cfg.max_retries,
            queue_limit=cfg.tx_queue_limit,
        )
        self._rel_rx = ReliableReceiver(
            self._seq,
            isn=peer.isn,
            window=window,
            max_message=cfg.max_message,
            # ACKs wait (ack_delay) only while the peer keeps at least half its window free.
            ack_every=max(1, window // 2) if cfg.ack_delay > 0 else 1,
        )
        self._ack_due = None
        self._decoder.max_payload = mtu
        self._state = SessionState.CONFIGURING
        self._configuring_since = self._now
        self._alive()
        self._on_established()

    def _teardown(self, reason: str, error: HwBridgeError) -> None:
        was_connected = self._state is SessionState.CONNECTED
        for request_id, call in sorted(self._calls.items()):
            self._events.append(
                ServiceResponse(
                    call.channel,
                    request_id,
                    b"",
                    SessionResetError(
                        f"service call {request_id} to {call.name} (channel {call.channel}) "
                        f"abandoned: {reason}"
                    ),
                )
            )
        self._calls.clear()
        self._incoming_calls.clear()
        self._fail_role_pending(reason)
        self._on_teardown()
        if self._established:
            self._last_peer_id = self._peer_id
        self._rel_tx = None
        self._rel_rx = None
        self._ack_due = None
        self._established = False
        self._peer_id = NO_SESSION
        self._link = None
        self._peer_max = MIN_MTU
        self._time_sync = False
        self._isn = self._rng.getrandbits(8)
        self._decoder.max_payload = self._cfg.mtu
        self._time_samples.clear()
        if self._state is not SessionState.CONFIGURING:
            self._waiting_since = self._now
            self._wait_reported = False
        self._state = SessionState.HANDSHAKE
        self._next_hello = self._now
        if was_connected:
            self._events.append(Disconnected(reason, error))

    def _connect(self, board: BoardInfo, topics: tuple[TopicEntry, ...]) -> None:
        assert self._link is not None
        self._state = SessionState.CONNECTED
        self._wait_reported = False
        resumed = self._last_peer_id == self._peer_id
        host_id, device_id = (
            (self._id, self._peer_id) if self._ROLE == Role.HOST else (self._peer_id, self._id)
        )
        self._time_next = self._now
        self._events.append(Connected(board, topics, self._link, host_id, device_id, resumed))

    # ---- timers -----------------------------------------------------------------------------

    def _run_timers(self) -> None:
        now = self._now
        cfg = self._cfg
        if (
            self._state is not _CONNECTED
            and not self._wait_reported
            and now >= self._waiting_since + cfg.handshake_timeout
        ):
            self._wait_reported = True
            self._error(HwBridgeTimeoutError(self._handshake_timeout_text()))
        if not self._established:
            if now >= self._next_hello:
                self._send_hello()
                self._next_hello = now + cfg.hello_interval
            return
        if now >= self._last_rx + cfg.link_timeout:
            self._c.link_losses += 1
            peer = _role_name(Role(1 - self._ROLE))
            reason = f"link lost: nothing received from the {peer} for {cfg.link_timeout:.2f} s"
            self._teardown(reason, HwBridgeTimeoutError(reason))
            self._run_timers()
            return
        if self._state is _CONFIGURING and (now >= self._configuring_since + cfg.handshake_timeout):
            reason = f"the topic table exchange did not complete in {cfg.handshake_timeout:.1f} s"
            self._error(HwBridgeTimeoutError(reason))
            self._teardown(reason, HwBridgeTimeoutError(reason))
            self._run_timers()
            return
        if self._ack_due is not None and now >= self._ack_due:
            self._send_ack()
        sender = self._rel_tx
        assert sender is not None
        try:
            for frame in sender.poll(now):
                self._send_frame(frame)
        except HwBridgeTimeoutError as exc:
            self._c.link_losses += 1
            self._teardown(f"link lost: {exc}", exc)
            self._run_timers()
            return
        if self._state is _CONNECTED:
            if self._calls:
                self._expire_calls(now)
            self._run_role_timers(now)
            if self._time_sync and now >= self._time_next:
                self._send_time_request()
                self._time_next = now + cfg.time_sync_retry
        if now >= self._last_tx + cfg.heartbeat_interval:
            self._c.heartbeats_sent += 1
            self._send_control_be(HeartbeatMsg())

    def _handshake_timeout_text(self) -> str:
        peer = _role_name(Role(1 - self._ROLE))
        if self._established:
            what = "the session is established but the topic table exchange has not completed"
        elif self._peer_id:
            what = f"the {peer} answers HELLO but the handshake does not complete"
        else:
            what = f"no HELLO from the {peer}"
        return f"no connected session after {self._cfg.handshake_timeout:.1f} s: {what}" + (
            self._hello_context()
        )

    def _time_answered(self) -> None:
        self._time_next = self._now + self._cfg.time_sync_interval

    def _expire_calls(self, now: float) -> None:
        for request_id, call in list(self._calls.items()):
            if now >= call.deadline:
                del self._calls[request_id]
                self._events.append(
                    ServiceResponse(
                        call.channel,
                        request_id,
                        b"",
                        HwBridgeTimeoutError(
                            f"service {call.name} (channel {call.channel}) request {request_id}: "
                            f"no response in time"
                        ),
                    )
                )

    # ---- services ---------------------------------------------------------------------------

    def _on_service_request(self, msg: ServiceRequestMsg) -> None:
        entry = self._entry(msg.channel) if self._state is _CONNECTED else None
        if entry is None or entry.kind != self._SERVE_KIND:
            reply = ServiceResponseMsg(msg.channel, msg.request_id, ServiceStatus.NO_SERVICE, b"")
            self._send_control(reply)
            return
        self._incoming_calls.add((msg.channel, msg.request_id))
        self._events.append(_service_request(msg.channel, msg.request_id, msg.body))

    def _on_service_response(self, msg: ServiceResponseMsg) -> None:
        call = self._calls.get(msg.request_id)
        if call is None or call.channel != msg.channel:
            return  # answered after its timeout: the caller already got an error
        del self._calls[msg.request_id]
        error: HwBridgeError | None = None
        status = msg.status
        if status is _SERVICE_ERROR:
            text = msg.body.decode("utf-8", errors="replace")
            error = SessionError(f"service {call.name} (channel {msg.channel}) failed: {text}")
        elif status is _SERVICE_NO_SERVICE:
            error = SessionError(
                f"service {call.name} (channel {msg.channel}): the peer does not serve it"
            )
        payload = msg.body if error is None else b""
        self._events.append(_service_response(msg.channel, msg.request_id, payload, error))


# --------------------------------------------------------------------------------------------
# Host


class HostSession(_Session):
    """The host's end of one board link.

    ``type_check`` is called for every entry the board announces and returns the type the host
    expects for it (for example from its type registry or from the topic already on the graph),
    or None to accept the entry as announced. A different type name or md5 refuses the entry:
    an :class:`Error` event carries a :class:`TopicMismatchError` and the board is told too.
    """

    _ROLE = Role.HOST
    _PUBLISH_KIND = EntryKind.SUBSCRIBER
    _RECEIVE_KIND = EntryKind.PUBLISHER
    _CALL_KIND = EntryKind.SERVICE_SERVER
    _SERVE_KIND = EntryKind.SERVICE_CLIENT

    def __init__(
        self,
        config: HostConfig | None = None,
        *,
        type_check: TypeCheck | None = None,
        session_id: int | None = None,
        rng: random.Random | None = None,
    ) -> None:
        self._host_cfg = config if config is not None else HostConfig()
        super().__init__(self._host_cfg, session_id=session_id, rng=rng)
        self._type_check = type_check
        self._board: BoardInfo | None = None
        self._announced: dict[int, TopicEntry] = {}
        self._topics: dict[int, TopicEntry] = {}
        self._param_requests: dict[int, ParamGetMsg] = {}
        self._subscriptions: dict[str, tuple[ParamType, int]] = {}

    @property
    def board(self) -> BoardInfo | None:
        """The connected board, None before BOARD_INFO."""
        return self._board

    @property
    def topics(self) -> Mapping[int, TopicEntry]:
        """Accepted entries by channel (current session)."""
        return dict(self._topics)

    @property
    def param_subscriptions(self) -> Mapping[str, ParamType]:
        """Parameters the board subscribed to, with the type it asked for."""
        return {name: typ for name, (typ, _) in self._subscriptions.items()}

    def answer_param(self, request_id: int, value: ParamInput | None) -> bool:
        """Answer a :class:`ParamRequest`; ``None`` answers "not found".

        The value is converted to the type the board asked for (PARAM_GET rules, see
        :func:`~hwbridge.protocols.native.control.coerce_param`); if it does not convert or
        fit, the board gets TYPE_MISMATCH or TOO_LARGE instead. Returns False when the request
        is no longer pending (the session ended meanwhile).
        """
        request = self._param_requests.pop(request_id, None)
        if request is None or not self._established:
            return False
        msg = self._param_value(request_id, request.name, request.type, request.max_count, value)
        self._send_control(msg)
        return True

    def push_param(self, name: str, value: ParamInput) -> bool:
        """Send a new value of a parameter the board subscribed to; False if it did not."""
        sub = self._subscriptions.get(name)
        link = self._link
        if sub is None or not self.connected or link is None:
            return False
        if not link.features & Features.PARAM_PUSH:
            return False
        msg = self._param_value(0, name, sub[0], sub[1], value)
        if msg.status != ParamStatus.OK:
            self._error(
                SessionError(
                    f"parameter {name}: new value {value!r} not pushed: {msg.status.name} for "
                    f"the board's type {sub[0].name}"
                )
            )
            return False
        self._send_control(msg)
        return True

    def board_to_host(self, board_us: int) -> float:
        """Host time of a board timestamp (its 32-bit microsecond counter).

        Valid within +-35 minutes of the last time sync.

        Raises:
            SessionError: no time sync has completed in this session.
        """
        _, host_ref, board_ref = self._best_time_sample()
        delta = (board_us - int(board_ref)) % _U32
        if delta >= _U32 // 2:
            delta -= _U32
        return host_ref + delta / 1e6

    def host_to_board(self, host_time: float) -> int:
        """The board's 32-bit microsecond counter at a host time.

        Raises:
            SessionError: no time sync has completed in this session.
        """
        _, host_ref, board_ref = self._best_time_sample()
        return (int(board_ref) + round((host_time - host_ref) * 1e6)) % _U32

    @property
    def time_offset(self) -> float | None:
        """Host time minus board time (board counter as seconds), None before a sync."""
        if not self._time_samples:
            return None
        _, host_ref, board_ref = _best_sample(self._time_samples)
        return host_ref - board_ref / 1e6

    def _best_time_sample(self) -> tuple[float, float, float]:
        if not self._time_samples:
            raise SessionError("no time sync with the board has completed in this session")
        return _best_sample(self._time_samples)

    def _host_time_ns(self) -> int:
        # whole microseconds: a float of ~1.7e9 s carries nothing finer
        return max(0, round((self._now + self._host_cfg.epoch_offset) * 1e6) * 1000)

    def _param_value(
        self, request_id: int, name: str, want: ParamType, max_count: int, value: ParamInput | None
    ) -> ParamValueMsg:
        if value is None:
            return ParamValueMsg(request_id, ParamStatus.NOT_FOUND, name)
        status, ptype, typed = coerce_param(value, want, max_count)
        if status != ParamStatus.OK:
            return ParamValueMsg(request_id, status, name)
        msg = ParamValueMsg(request_id, status, name, ptype, typed)
        if len(msg.encode()) > self._peer_max:
            return ParamValueMsg(request_id, ParamStatus.TOO_LARGE, name)
        return msg

    def _entry(self, channel: int) -> TopicEntry | None:
        return self._topics.get(channel)

    def _may_log(self) -> bool:
        return self._link is not None and bool(self._link.features & Features.HOST_LOG)

    def _on_teardown(self) -> None:
        self._board = None
        self._announced.clear()
        self._topics.clear()
        self._param_requests.clear()
        self._subscriptions.clear()

    def _send_time_request(self) -> None:
        self._send_control_be(HostTimeRequestMsg(self._host_time_ns()))

    def _on_role_control(self, msg: ControlMessage) -> bool:
        if isinstance(msg, TimeRequestMsg):
            if self._cfg.features & Features.TIME_SYNC:
                now_ns = self._host_time_ns()
                self._send_control_be(TimeResponseMsg(msg.t1_us, now_ns, now_ns))
        elif isinstance(msg, HostTimeResponseMsg):
            self._on_time_response(msg)
        elif isinstance(msg, BoardInfoMsg):
            self._board = BoardInfo(msg.name, msg.unique_id, msg.firmware_version)
        elif isinstance(msg, TopicMsg):
            self._on_topic(msg)
        elif isinstance(msg, TableEndMsg):
            self._on_table_end(msg)
        elif isinstance(msg, ParamGetMsg):
            self._param_requests[msg.request_id] = msg
            subscribe = bool(msg.flags & ParamGetFlags.SUBSCRIBE)
            if subscribe:
                self._subscriptions[msg.name] = (msg.type, msg.max_count)
            self._events.append(
                ParamRequest(msg.request_id, msg.name, msg.type, msg.max_count, subscribe)
            )
        else:
            return False
        return True

    def _on_time_response(self, msg: HostTimeResponseMsg) -> None:
        now = self._now
        t1 = msg.t1_ns / 1e9 - self._host_cfg.epoch_offset
        if not 0 <= now - t1 <= _MAX_TIME_AGE:
            return
        board_busy = ((msg.t3_us - msg.t2_us) % _U32) / 1e6
        rtt = max(0.0, (now - t1) - board_busy)
        host_mid = (t1 + now) / 2 + self._host_cfg.epoch_offset
        board_mid_us = (msg.t2_us + ((msg.t3_us - msg.t2_us) % _U32) / 2) % _U32
        self._time_samples.append((rtt, host_mid, board_mid_us))
        self._time_answered()
        offset = self.time_offset
        assert offset is not None
        self._events.append(TimeSynced(offset, rtt))

    def _on_topic(self, msg: TopicMsg) -> None:
        if self._state is not SessionState.CONFIGURING:
            self._protocol_error(f"TOPIC for channel {msg.channel} after the table ended")
            return
        problem = ""
        entry: TopicEntry | None = None
        try:
            entry = TopicEntry.from_msg(msg)
        except ValueError as exc:
            problem = str(exc)
        if entry is not None and entry.channel in self._announced:
            other = self._announced[entry.channel]
            problem = f"channel {entry.channel} announced twice ({other.name} and {entry.name})"
        if entry is None or problem:
            self._protocol_error(f"the board announced an invalid entry: {problem}")
            detail = _truncate(problem, self._peer_max - 19).decode("utf-8")
            self._send_control(TopicAckMsg(msg.channel, TopicStatus.INVALID, "", detail))
            return
        self._announced[entry.channel] = entry
        expected = self._type_check(entry) if self._type_check is not None else None
        if expected is not None and (
            expected.type_name != entry.type_name or expected.md5.lower() != entry.md5
        ):
            self._c.protocol_errors += 1
            self._error(
                TopicMismatchError(
                    entry.name,
                    entry.channel,
                    entry.type_name,
                    entry.md5,
                    expected.type_name,
                    expected.md5,
                )
            )
            detail = _truncate(expected.type_name, self._peer_max - 19).decode("utf-8")
            md5 = expected.md5.lower() if len(expected.md5) == 32 else ""
            self._send_control(TopicAckMsg(entry.channel, TopicStatus.MISMATCH, md5, detail))
            return
        self._topics[entry.channel] = entry
        self._events.append(TopicAnnounced(entry))
        self._send_control(TopicAckMsg(entry.channel, TopicStatus.ACCEPTED))

    def _on_table_end(self, msg: TableEndMsg) -> None:
        if self._state is not SessionState.CONFIGURING:
            self._protocol_error("TABLE_END after the table ended")
            return
        if msg.count != len(self._announced):
            self._protocol_error(
                f"the board announced {len(self._announced)} entries but TABLE_END counts "
                f"{msg.count}"
            )
        board = self._board
        if board is None:
            self._protocol_error("the board sent TABLE_END without BOARD_INFO")
            board = BoardInfo("", b"", "")
            self._board = board
        self._send_control(ReadyMsg(len(self._topics)))
        self._connect(board, tuple(self._topics.values()))

    def _hello_context(self) -> str:
        return (
            " (is the board connected, powered, flashed with hwbridge firmware, and is the baud "
            "rate right?)"
        )


# --------------------------------------------------------------------------------------------
# Device


class DeviceSession(_Session):
    """A board's end of the link: announces its table, publishes, serves, asks for params.

    It honours its configured limits: the host never gets a reason to send it a frame larger
    than ``config.mtu`` or a message larger than ``config.max_message``, and its own decoder
    rejects anything larger. A real board picks a new random session id at every boot; create a
    new DeviceSession to emulate a reset.
    """

    _ROLE = Role.DEVICE
    _PUBLISH_KIND = EntryKind.PUBLISHER
    _RECEIVE_KIND = EntryKind.SUBSCRIBER
    _CALL_KIND = EntryKind.SERVICE_CLIENT
    _SERVE_KIND = EntryKind.SERVICE_SERVER

    def __init__(
        self,
        board: BoardInfo,
        topics: Sequence[TopicEntry] = (),
        config: DeviceConfig | None = None,
        *,
        session_id: int | None = None,
        rng: random.Random | None = None,
    ) -> None:
        super().__init__(
            config if config is not None else DeviceConfig(), session_id=session_id, rng=rng
        )
        self._board = board
        table: dict[int, TopicEntry] = {}
        for entry in topics:
            if entry.channel in table:
                raise ValueError(
                    f"channel {entry.channel} used twice ({table[entry.channel].name}, "
                    f"{entry.name})"
                )
            table[entry.channel] = entry
        if len(table) > 255:
            raise ValueError(f"{len(table)} entries; a board announces at most 255")
        self._table = table
        self._accepted: set[int] = set()
        self._params: dict[int, _Pending] = {}
        self._time_offset_samples: deque[tuple[float, float]] = deque(maxlen=_MAX_TIME_SAMPLES)

    @property
    def board(self) -> BoardInfo:
        """This board."""
        return self._board

    @property
    def topics(self) -> Mapping[int, TopicEntry]:
        """This board's whole table by channel."""
        return dict(self._table)

    @property
    def accepted(self) -> frozenset[int]:
        """Channels the host accepted in the current session."""
        return frozenset(self._accepted)

    def get_param(
        self,
        name: str,
        type: ParamType = ParamType.ANY,
        *,
        max_count: int = 0,
        subscribe: bool = False,
        timeout: float | None = None,
        now: float | None = None,
    ) -> int:
        """Ask the host for a parameter; returns the request id.

        Exactly one :class:`ParamResponse` with this id follows: the host's answer (value, or
        NOT_FOUND / TYPE_MISMATCH / TOO_LARGE), or an error (timeout after ``timeout`` seconds,
        default ``config.param_timeout``; session reset). With ``subscribe`` the host pushes
        later changes as :class:`ParamUpdate` events.
        """
        self._advance_opt(now)
        request_id = self._new_request_id()
        timeout = self._cfg.param_timeout if timeout is None else timeout
        if not self.connected:
            self._c.tx_refused += 1
            self._events.append(
                ParamResponse(request_id, name, None, None, SessionError("not connected to a host"))
            )
            return request_id
        flags = ParamGetFlags.SUBSCRIBE if subscribe else ParamGetFlags.NONE
        try:
            msg = ParamGetMsg(request_id, type, flags, max_count, name).encode()
        except ValueError as exc:
            raise SessionError(f"parameter request for {name[:40]!r}: {exc}") from None
        self._check_size(len(msg), "parameter request for %s", name)
        if not self._send_reliable(CONTROL_CHANNEL, msg):
            self._events.append(
                ParamResponse(request_id, name, None, None, SessionError("transmit queue full"))
            )
            return request_id
        self._params[request_id] = _Pending(CONTROL_CHANNEL, name, self._now + timeout)
        return request_id

    def to_host_time(self, device_time: float) -> float:
        """Host time at a device time (both seconds; device time is this session's ``now``).

        Raises:
            SessionError: no time sync has completed in this session.
        """
        return device_time + self._offset()

    def to_device_time(self, host_time: float) -> float:
        """Device time at a host time.

        Raises:
            SessionError: no time sync has completed in this session.
        """
        return host_time - self._offset()

    @property
    def time_offset(self) -> float | None:
        """Host time minus device time (seconds), None before a sync."""
        if not self._time_offset_samples:
            return None
        return _best_sample(self._time_offset_samples)[1]

    def _offset(self) -> float:
        offset = self.time_offset
        if offset is None:
            raise SessionError("no time sync with the host has completed in this session")
        return offset

    def _entry(self, channel: int) -> TopicEntry | None:
        return self._table.get(channel) if channel in self._accepted else None

    def _request_id_in_use(self, request_id: int) -> bool:
        return request_id in self._params

    def _on_established(self) -> None:
        self._accepted.clear()
        entries = list(self._table.values())
        board = self._board
        self._send_control(
            BoardInfoMsg(len(entries), board.name, board.unique_id, board.firmware_version)
        )
        for entry in entries:
            self._send_control(entry.to_msg())
        self._send_control(TableEndMsg(len(entries)))

    def _on_teardown(self) -> None:
        self._accepted.clear()
        self._time_offset_samples.clear()

    def _fail_role_pending(self, reason: str) -> None:
        for request_id, pending in sorted(self._params.items()):
            self._events.append(
                ParamResponse(
                    request_id,
                    pending.name,
                    None,
                    None,
                    SessionResetError(f"parameter request for {pending.name} abandoned: {reason}"),
                )
            )
        self._params.clear()

    def _other_deadlines(self) -> Iterable[float]:
        return (p.deadline for p in self._params.values())

    def _run_role_timers(self, now: float) -> None:
        for request_id, pending in list(self._params.items()):
            if now >= pending.deadline:
                del self._params[request_id]
                self._events.append(
                    ParamResponse(
                        request_id,
                        pending.name,
                        None,
                        None,
                        HwBridgeTimeoutError(
                            f"parameter {pending.name}: no answer from the host in time"
                        ),
                    )
                )

    def _send_time_request(self) -> None:
        self._send_control_be(TimeRequestMsg(self._device_us()))

    def _device_us(self) -> int:
        return round(self._now * 1e6) % _U32

    def _on_role_control(self, msg: ControlMessage) -> bool:
        if isinstance(msg, HostTimeRequestMsg):
            if self._cfg.features & Features.TIME_SYNC:
                now_us = self._device_us()
                self._send_control_be(HostTimeResponseMsg(msg.t1_ns, now_us, now_us))
        elif isinstance(msg, TimeResponseMsg):
            self._on_time_response(msg)
        elif isinstance(msg, TopicAckMsg):
            self._on_topic_ack(msg)
        elif isinstance(msg, ReadyMsg):
            self._on_ready(msg)
        elif isinstance(msg, ParamValueMsg):
            self._on_param_value(msg)
        else:
            return False
        return True

    def _on_time_response(self, msg: TimeResponseMsg) -> None:
        now = self._now
        elapsed = ((self._device_us() - msg.t1_us) % _U32) / 1e6
        if elapsed > _MAX_TIME_AGE:
            return
        t1 = now - elapsed
        t2, t3 = msg.t2_ns / 1e9, msg.t3_ns / 1e9
        rtt = max(0.0, elapsed - (t3 - t2))
        offset = ((t2 - t1) + (t3 - now)) / 2
        self._time_offset_samples.append((rtt, offset))
        self._time_answered()
        best = self.time_offset
        assert best is not None
        self._events.append(TimeSynced(best, rtt))

    def _on_topic_ack(self, msg: TopicAckMsg) -> None:
        entry = self._table.get(msg.channel)
        if entry is None:
            self._protocol_error(f"TOPIC_ACK for channel {msg.channel}, which this board lacks")
            return
        if msg.status == TopicStatus.ACCEPTED:
            self._accepted.add(msg.channel)
        elif msg.status == TopicStatus.MISMATCH:
            self._c.protocol_errors += 1
            self._error(
                TopicMismatchError(
                    entry.name, entry.channel, entry.type_name, entry.md5, msg.detail, msg.host_md5
                )
            )
        else:
            self._protocol_error(
                f"the host refused {entry.name} (channel {entry.channel}): {msg.detail}"
            )

    def _on_ready(self, msg: ReadyMsg) -> None:
        if self._state is not SessionState.CONFIGURING:
            return
        if msg.accepted != len(self._accepted):
            self._protocol_error(
                f"READY counts {msg.accepted} accepted entries, this board saw "
                f"{len(self._accepted)}"
            )
        topics = tuple(self._table[c] for c in self._table if c in self._accepted)
        self._connect(self._board, topics)

    def _on_param_value(self, msg: ParamValueMsg) -> None:
        if msg.request_id == 0:
            if msg.status == ParamStatus.OK and msg.value is not None:
                self._events.append(ParamUpdate(msg.name, msg.value))
            return
        pending = self._params.pop(msg.request_id, None)
        if pending is None:
            return  # answered after its timeout
        self._events.append(ParamResponse(msg.request_id, msg.name, msg.status, msg.value))
