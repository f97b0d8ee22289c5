"""The part of a native session both ends share: state, clock, input, output, ACK holding.

:class:`SessionCore` holds every piece of state the session's parts use and the per-frame
paths: ``receive_data`` feeds the framing's frames to ``_on_frame``, which hands reliable
frames to the reliability layer (:mod:`hwbridge.protocols.native.reliable`) and control
messages to ``_on_control``; ``_send_frame`` queues frames that ``chunks_to_send`` encodes with
the framing. The other parts are mixins on this class (handshake, services, time sync, the
topic table and parameters of each end); the hooks they fill in are declared here.
"""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, ClassVar, Generic, TypeVar

from hwbridge.protocols.calling import BOOTLOADER_QUIET, may_call, next_call
from hwbridge.protocols.errors import HwBridgeError, ProtocolError
from hwbridge.protocols.native._control.common import (
    CONTROL_CHANNEL,
    MIN_MTU,
    NO_SESSION,
    EntryKind,
    LogLevel,
    Role,
    ServiceStatus,
)
from hwbridge.protocols.native._framing.frames import BadFrame, Frame, NonFrameBytes
from hwbridge.protocols.native._framing.links import NativeFraming, NativeStreamFraming
from hwbridge.protocols.native._hotpath import ACK, CLOSED, CONFIGURING, CONNECTED, with_ack
from hwbridge.protocols.native._session.config import (
    _MAX_TIME_SAMPLES,
    _U32,
    BoardInfo,
    LinkParams,
    SessionConfig,
    SessionError,
    SessionResetError,
    SessionState,
    TopicEntry,
)
from hwbridge.protocols.native._session.events import DebugOutput, Error
from hwbridge.protocols.native._session.stats import NativeStats, SessionCounters, native_detail
from hwbridge.protocols.native.control import (
    ControlMessage,
    GoodbyeMsg,
    HelloMsg,
    LogMsg,
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

_E = TypeVar("_E")
"""The events a session gives (a host's are the shared vocabulary; a device has two more)."""

HELLO_FIRST_RETRY = 0.05
"""The first HELLO goes out at once; the next after this long, each wait doubling up to
``hello_interval`` (PROTOCOL.md 2.5)."""
RETIRED_ID_HOLD = 60.0
"""Seconds a SHORT_CALLS caller keeps the id of a call that timed out from new calls, unless
its late answer comes first (PROTOCOL.md 2.8)."""


@dataclass(slots=True)
class _Pending:
    """An outgoing request waiting for its answer."""

    channel: int
    name: str
    deadline: float


def _truncate(text: str, limit: int) -> bytes:
    """``text`` as UTF-8, cut to at most ``limit`` bytes on a character boundary."""
    raw = text.encode("utf-8")
    if len(raw) <= limit:
        return raw
    return raw[: max(0, limit)].decode("utf-8", errors="ignore").encode("utf-8")


def _role_name(role: Role) -> str:
    return "host" if role == Role.HOST else "board"


class SessionCore(Generic[_E]):
    """Code shared by both ends; the mixins and the subclasses add the rest."""

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
        framing: NativeFraming | None = None,
        session_id: int | None = None,
        rng: random.Random | None = None,
    ) -> None:
        self._cfg = config
        self._rng = rng if rng is not None else random.Random()
        if session_id is not None and not 0 < session_id < _U32:
            raise ValueError(f"session id must be 1..2**32-1, not {session_id}")
        self._id = session_id if session_id is not None else self._random_session_id()
        if framing is None:
            framing = NativeStreamFraming(config.mtu)
        else:
            framing.max_payload = config.mtu
        self._framing = framing
        self._out: list[Frame] = []
        """Frames not yet taken by chunks_to_send (encoded together, by the framing)."""
        self._events: list[Any] = []
        self._now = 0.0
        """The latest time seen (0.0 before the first); the clock of every action."""
        self._started = False
        """True once a time was seen: the timers start from that time."""
        self._settled = False
        """The last receive_data completed no frame (see :attr:`settled`)."""
        self._c = SessionCounters()
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
        self._awake_step = max(2 * config.heartbeat_interval, config.link_timeout / 4)
        """The longest gap between two calls that counts in full as time this end was running
        (it is called at least every heartbeat_interval while established)."""
        self._ack_due: float | None = None
        """When a held-back ACK must go out at the latest (None: none is held)."""
        self._ack_in_data = False
        """Both ends have ACK_IN_DATA: a due ACK rides in the next data frame (PROTOCOL.md 2.4)."""
        self._service_channels = False
        """Both ends have SERVICE_CHANNELS: service calls travel on their services' own channels,
        not as SERVICE_REQUEST and SERVICE_RESPONSE on channel 0 (PROTOCOL.md 2.8)."""
        self._short_calls = False
        """Both ends have SERVICE_CHANNELS and SHORT_CALLS: a call on a service's channel has a
        one-byte head, and this end's call ids are 1..127 (PROTOCOL.md 2.8)."""
        self._next_hello = 0.0
        self._hello_wait = min(HELLO_FIRST_RETRY, config.hello_interval)
        """Wait before the next HELLO retry: doubles from HELLO_FIRST_RETRY to hello_interval."""
        self._listen_first: bool = getattr(config, "listen_first", False)
        """HELLO retries only to a peer heard lately (HostConfig.listen_first)."""
        self._call_burst: float = getattr(config, "call_burst", 0.0)
        self._call_pause: float = getattr(config, "call_pause", BOOTLOADER_QUIET)
        """HELLO retries to a silent peer in bursts, with pauses (HostConfig.call_burst)."""
        self._heard_at = -math.inf
        """When the peer last sent a HELLO, or a reliable frame before this end established
        (listen_first's HELLO retries run for a link_timeout after it)."""
        self._waiting_since = 0.0
        """When the current wait for a connected session began."""
        self._wait_reported = False
        self._configuring_since = 0.0
        self._version_frames = 0
        self._reported: set[str] = set()
        """Keys of errors already reported this session (to avoid floods)."""
        self._calls: dict[int, _Pending] = {}
        self._retired_ids: dict[int, float] = {}
        """In a SHORT_CALLS session, the ids of calls that timed out, each with the time it may
        be drawn again: with 127 ids, a late answer must not be taken for a newer call that got
        its id (PROTOCOL.md 2.8). An id is free again once its late answer came."""
        self._incoming_calls: set[tuple[int, int]] = set()
        self._next_request_id = 1
        self._time_next = 0.0
        self._time_samples: deque[tuple[float, float, float]] = deque(maxlen=_MAX_TIME_SAMPLES)
        """(rtt, offset, reference) of recent time sync exchanges."""

    def _start(self, now: float | None) -> None:
        """Start the clock at ``now`` (if given) and run the timers: the first HELLO goes out."""
        if now is not None:
            self._advance(now)
            self._run_timers()
            self._flush()

    # ---- public API shared by both ends --------------------------------------------------

    @property
    def state(self) -> SessionState:
        """Where the session is."""
        return self._state

    @property
    def connected(self) -> bool:
        """True in the CONNECTED state."""
        return self._state is CONNECTED

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
    def framing(self) -> NativeFraming:
        """The framing this session reads and writes with (stream or datagram)."""
        return self._framing

    @property
    def settled(self) -> bool:
        """True when the last :meth:`receive_data` completed no frame (it held the first bytes
        of one, as a service answer comes in several reads): the timers are as they were, so
        :meth:`next_deadline` is what it was before it. A pump need not ask again."""
        return self._settled

    @property
    def rtt(self) -> float | None:
        """Smoothed round-trip time of reliable frames (seconds), None before a sample."""
        return self._rtt.srtt

    @property
    def stats(self) -> NativeStats:
        """A snapshot of this end's counters (as :meth:`counters`)."""
        d = self._framing.stats
        bad = (
            d.crc_errors
            + d.cobs_errors
            + d.too_short
            + d.version_errors
            + d.reserved_type
            + d.oversize
        )
        c = self._c
        return NativeStats(
            frames_sent=c.frames_sent,
            bytes_sent=c.bytes_sent,
            frames_received=d.frames,
            bytes_received=d.bytes,
            bad_frames=bad,
            crc_errors=d.crc_errors,
            non_frame_bytes=d.non_frame_bytes,
            dropped_messages=c.dropped_messages,
            protocol_errors=c.protocol_errors,
            sessions=c.sessions,
            detail=native_detail(self._seq, c, self._rtt.srtt, self._rtt.rto),
        )

    def counters(self) -> NativeStats:
        """A snapshot of this end's counters."""
        return self.stats

    def receive_data(self, data: bytes, now: float, /) -> list[_E]:
        """Feed what one link read returned (a stream chunk, or one datagram on a datagram
        framing); returns the events it causes."""
        started = self._started  # (the first time seen starts the timers)
        self._advance(now)
        self._settled = False
        if self._state is not CLOSED:
            items = self._framing.decode(data)
            # (none: a frame's first bytes, as a service answer comes in several reads; then
            # nothing changed that _flush() or next_deadline() acts on)
            self._settled = started and not items
            if items:
                on_frame = self._on_frame
                for item in items:
                    if isinstance(item, Frame):
                        on_frame(item)
                    elif isinstance(item, NonFrameBytes):
                        self._events.append(DebugOutput(item.data))
                    else:
                        self._on_bad_frame(item)
                self._flush()
        events: list[_E] = self._events  # _take_events(), inline: a per-read path
        self._events = []
        return events

    def tick(self, now: float, /) -> list[_E]:
        """Run the timers due at ``now``; returns the events they cause."""
        self._advance(now)
        if self._state is not CLOSED:
            self._run_timers()
            self._flush()
        events: list[_E] = self._events  # _take_events(), inline
        self._events = []
        return events

    def keepalive(self, now: float, /) -> list[_E]:
        """The timers at ``now`` for a caller that is not reading the link meanwhile (its pump
        busy handing events on, say): heartbeats, held ACKs and retransmissions go out, but the
        time the link was not read is not the peer's silence (PROTOCOL.md 2.9: only silence an
        end was there to see counts), so at most the awake step of it counts. A peer that really
        went silent is declared lost a link timeout after reading resumes."""
        self._advance(now)  # (its own stall rule first: it moves _last_rx too)
        if self._established:
            self._last_rx = max(self._last_rx, now - self._awake_step)
        return self.tick(now)

    def chunks_to_send(self) -> list[bytes]:
        """What to write to the link, one write per item (one chunk on a stream framing, one
        datagram per frame on a datagram framing); the buffer is emptied."""
        out = self._out
        if not out:
            return []
        self._out = []
        chunks = self._framing.encode(out, self._now)
        self._c.bytes_sent += sum(map(len, chunks))
        return chunks

    def data_to_send(self) -> bytes:
        """:meth:`chunks_to_send`, joined (for stream links, tests and simple users)."""
        chunks = self.chunks_to_send()
        return chunks[0] if len(chunks) == 1 else b"".join(chunks)

    def next_deadline(self) -> float | None:
        """The time at which ``tick`` has work next, or None (closed, or nothing timed: a
        listening-first host waiting for its quiet board's HELLO)."""
        # The pump asks after every read that completes a frame, about once per service call:
        # the timers are compared as they come, without a list, and with ``x if x < t``, not
        # min() (with a call in flight: 2.0 us against 0.6 us, best of 5 timeit runs).
        state = self._state
        if state is CLOSED:
            return None
        cfg = self._cfg
        t = math.inf
        if not self._wait_reported and state is not CONNECTED:
            t = self._waiting_since + cfg.handshake_timeout
        if not self._established:
            hello = self._next_call()
            if hello is not None and hello < t:
                t = hello
        else:
            x = self._last_rx + cfg.link_timeout
            t = x if x < t else t
            x = self._last_tx + cfg.heartbeat_interval
            t = x if x < t else t
            due = self._ack_due
            if due is not None and due < t:
                t = due
            sender = self._rel_tx
            if sender is not None:
                rel = sender.next_deadline()
                if rel is not None and rel < t:
                    t = rel
            if state is CONFIGURING:
                x = self._configuring_since + cfg.handshake_timeout
                t = x if x < t else t
            else:
                for call in self._calls.values():
                    x = call.deadline
                    t = x if x < t else t
                for x in self._other_deadlines():
                    t = x if x < t else t
                if self._time_sync and self._time_next < t:
                    t = self._time_next
        return None if t == math.inf else t  # (listen_first, quiet: data will come first)

    def publish(self, channel: int, payload: bytes) -> bool:
        """Send one topic message; False when not connected or the queue is full.

        Raises:
            SessionError: the channel is not a topic this end publishes, or the message is
                larger than the peer accepts.
        """
        if self._state is not CONNECTED:
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

    def log(self, level: LogLevel, text: str) -> bool:
        """Send a log line to the peer (truncated to fit); False when it cannot be sent."""
        if not self.connected or not self._may_log():
            self._c.tx_refused += 1
            return False
        raw = _truncate(text, self._peer_max - 2)
        return self._send_reliable(CONTROL_CHANNEL, LogMsg(level, raw.decode("utf-8")).encode())

    def close(self, now: float | None = None, /) -> list[_E]:
        """End the session: tell the peer (GOODBYE), fail pending operations, stop all timers."""
        self._advance_opt(now)
        if self._state is CLOSED:
            return self._take_events()
        if self._established:
            self._send_control_be(GoodbyeMsg())
        self._teardown("closed by this end", SessionResetError("the session was closed"))
        self._state = SessionState.CLOSED
        return self._take_events()

    # ---- hooks: filled in by the mixins (handshake, services, time) and the two ends -------

    def _entry(self, channel: int) -> TopicEntry | None:
        """The accepted entry on ``channel`` in the current session."""
        raise NotImplementedError

    def _board_entry(self, channel: int) -> TopicEntry | None:
        """The entry on ``channel`` in the board's table as this end knows it this session,
        accepted or not (a board's own table; what the board announced, on the host). With
        SERVICE_CHANNELS its kind says what a message on the channel is (PROTOCOL.md 2.8)."""
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

    def _on_frame(self, frame: Frame) -> None:
        """Handle one valid frame (receive mixin)."""
        raise NotImplementedError

    def _on_bad_frame(self, item: BadFrame) -> None:
        raise NotImplementedError

    def _run_timers(self) -> None:
        """Run the timers due at ``self._now`` (handshake mixin)."""
        raise NotImplementedError

    def _on_hello(self, msg: HelloMsg) -> None:
        raise NotImplementedError

    def _teardown(self, reason: str, error: HwBridgeError) -> None:
        raise NotImplementedError

    def _connect(self, board: BoardInfo, topics: tuple[TopicEntry, ...]) -> None:
        raise NotImplementedError

    def _on_service_request(self, channel: int, request_id: int, body: bytes) -> None:
        raise NotImplementedError

    def _expire_calls(self, now: float) -> None:
        raise NotImplementedError

    def _on_service_response(
        self, channel: int, request_id: int, status: ServiceStatus, body: bytes
    ) -> None:
        raise NotImplementedError

    def _on_service_message(self, delivery: Delivery, entry: TopicEntry | None) -> bool:
        """A reliable message on a channel other than 0 that is no topic message for this end,
        in a SERVICE_CHANNELS session (services mixin); False when it is no service call either.
        """
        raise NotImplementedError

    # ---- clock -----------------------------------------------------------------------------

    def _advance(self, now: float) -> None:
        if not self._started:
            self._started = True
            self._now = now
            self._next_hello = now
            self._waiting_since = now
            self._last_tx = now
        elif now > self._now:
            step = now - self._now
            if step > self._awake_step:
                # This end did not run for a while (a starved process, a stopped one): time it
                # was not looking is not the peer's silence (PROTOCOL.md 2.9).
                self._last_rx += step - self._awake_step
                self._c.stalls += 1
            self._now = now

    def _alive(self) -> None:
        self._last_rx = self._now

    def _may_call(self) -> bool:
        """Whether a HELLO retry may go out now: to a peer heard within a ``link_timeout``
        (``_heard_at``); else never with ``listen_first``, and with ``call_burst`` only in the
        bursts that began when this end started waiting for a session."""
        now = self._now
        if now < self._heard_at + self._cfg.link_timeout:
            return True
        if self._listen_first:
            return False
        return may_call(now, self._waiting_since, self._call_burst, self._call_pause)

    def _next_call(self) -> float | None:
        """When the next HELLO retry is due: ``_next_hello``, or later the start of the next
        burst; None with ``listen_first`` and a silent peer (only its HELLO wakes this end)."""
        if self._may_call():
            return self._next_hello
        if self._listen_first:
            return None
        start = next_call(self._now, self._waiting_since, self._call_burst, self._call_pause)
        return max(self._next_hello, start)

    def _advance_opt(self, now: float | None) -> None:
        if now is not None:
            self._advance(now)

    # ---- output -----------------------------------------------------------------------------

    def _take_events(self) -> list[_E]:
        events: list[_E] = self._events
        self._events = []
        return events

    def _send_frame(self, frame: Frame) -> None:
        if self._ack_due is not None:  # a held ACK goes out with the first frame that does
            carried = self._carry_ack(frame) if self._ack_in_data else None
            if carried is None:
                self._send_ack()
            else:
                frame = carried
        self._out.append(frame)
        self._c.frames_sent += 1
        self._last_tx = self._now

    def _send_best_effort(self, channel: int, payload: bytes) -> None:
        mtu = self._link.mtu if self._link is not None else MIN_MTU
        for frame in self._be_tx.frames(channel, payload, mtu):
            self._send_frame(frame)

    def _send_control_be(self, msg: ControlMessage) -> None:
        self._send_best_effort(CONTROL_CHANNEL, msg.encode())

    # ---- reliability glue: queueing, pumping the window, holding ACKs ----------------------
    def _send_reliable(self, channel: int, payload: bytes, *, force: bool = False) -> bool:
        sender = self._rel_tx
        if sender is None:
            self._c.tx_refused += 1
            return False
        frame = sender.send_now(channel, payload, self._now)
        if frame is not None:
            self._send_frame(frame)
            return True
        if not sender.queue(channel, payload, force=force):
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
                if self._ack_in_data:
                    # ACK_IN_DATA: the ACK rides in a frame of this write (one already out, or
                    # the first the window releases), or goes alone after them.
                    self._ack_due = self._now
                    if not self._carry_in_out():
                        self._pump()
                    if self._ack_due is not None:
                        self._send_ack()
                    return
                self._send_ack()
            elif self._ack_due is None:
                self._ack_due = self._now + self._cfg.ack_delay
        self._pump()

    def _send_ack(self) -> None:
        self._ack_due = None
        receiver = self._rel_rx
        if receiver is not None:
            self._send_frame(receiver.ack_frame())

    def _carry_ack(self, frame: Frame) -> Frame | None:
        """``frame`` carrying the due ACK (ACK_IN_DATA, PROTOCOL.md 2.4), or None when it cannot:
        an ACK frame, one that already carries one, a payload that fills the MTU, or an ACK
        with a selective bitmap (early frames held), which goes as a frame of its own."""
        receiver = self._rel_rx
        link = self._link
        if (
            receiver is None
            or link is None
            or frame.type is ACK
            or frame.ack is not None
            or len(frame.payload) >= link.mtu
        ):
            return None
        ack = receiver.carried_ack()
        if ack is None:
            return None
        self._ack_due = None
        self._seq.acks_carried += 1
        return with_ack(frame, ack)

    def _carry_in_out(self) -> bool:
        """Put the due ACK into the last data frame already queued for this write, if one can
        carry it; True when it went."""
        out = self._out
        for i in range(len(out) - 1, -1, -1):
            carried = self._carry_ack(out[i])
            if carried is not None:
                out[i] = carried
                return True
        return False

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

    def _new_request_id(self, top: int = 0xFFFF) -> int:
        """A request id in 1..``top`` that no pending call or role request of this end uses
        (``top`` 127 for a service call in a SHORT_CALLS session, PROTOCOL.md 2.8)."""
        retired = self._retired_ids
        for _ in range(top):
            request_id = (self._next_request_id - 1) % top + 1
            self._next_request_id = request_id % 0xFFFF + 1
            if request_id in retired:
                if retired[request_id] > self._now:
                    continue
                del retired[request_id]
            if request_id not in self._calls and not self._request_id_in_use(request_id):
                return request_id
        if retired:
            raise SessionError(
                f"no request id is free: {len(self._calls)} calls are pending and the ids of "
                f"{len(retired)} that timed out are held for their late answers (at most "
                f"{RETIRED_ID_HOLD:g} s)"
            )
        raise SessionError(f"{top} requests are pending: no request id is free")

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
