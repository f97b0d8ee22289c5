"""SERVICE_CHANNELS (PROTOCOL.md 2.8): when both ends have the feature, a service call travels
as reliable messages on the service's own channel, ``request_id u16`` then the body (request)
or ``request_id u16``, ``status u8``, body (response), instead of SERVICE_REQUEST and
SERVICE_RESPONSE on channel 0.

Here the board (or the scripted peer) has SERVICE_CHANNELS without SHORT_CALLS, as a board
built before SHORT_CALLS: the heads are the two- and three-byte ones. The one-byte heads of
SHORT_CALLS are tested in ``test_native_short_calls.py``.

Real sessions talk to each other over ``lossy.SimLink``, or to :class:`Scripted`, a peer the
test writes out frame by frame for what no session sends at that moment (a request before the
server is CONNECTED, a message shorter than its fields, an old-form call in a SERVICE_CHANNELS
session). What went over the wire is checked against the layouts of PROTOCOL.md written out
here with ``struct``, not against the session's own encoders.
"""

from __future__ import annotations

import dataclasses
import json
import random
import struct
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hwbridge.protocols.errors import ProtocolError
from hwbridge.protocols.native import control as ctl
from hwbridge.protocols.native.control import (
    ALL_FEATURES,
    BoardInfoMsg,
    Features,
    HelloFlags,
    HelloMsg,
    ReadyMsg,
    Role,
    ServiceStatus,
    TableEndMsg,
    TopicAckMsg,
    TopicStatus,
)
from hwbridge.protocols.native.framing import Frag, Frame, FrameDecoder, FrameType, encode_frame
from hwbridge.protocols.native.session import (
    DeviceConfig,
    DeviceSession,
    Error,
    Event,
    ExpectedType,
    HostConfig,
    HostSession,
    ServiceRequest,
    ServiceResponse,
    SessionError,
    SessionState,
    TopicEntry,
)
from tests.protocols.lossy import SimLink
from tests.protocols.test_native_session import (
    BOARD,
    CH_CHATTER,
    CH_CMD,
    CH_GET_TIME,
    CH_RESET,
    DEVICE_FEATURES_BEFORE_SERVICE_CHANNELS,
    FEATURES_BEFORE_SERVICE_CHANNELS,
    MD5_TRIGGER,
    PATIENT,
    TOPICS,
    VECTORS,
    _connected_vector_pair,
    _service_call_vectors,
    connect,
    errors,
    lossy,
    of_type,
)
from tests.protocols.test_native_session import make_link as make_any_link
from tests.strategies import bounded

HOST_FEATURES = HostConfig().features & ~Features.SHORT_CALLS
DEVICE_FEATURES = DeviceConfig().features & ~Features.SHORT_CALLS
"""A board's features before SHORT_CALLS: with it, the calls of a session have the heads of
SERVICE_CHANNELS alone."""
OK, ERROR, NO_SERVICE = 0, 1, 2
"""The status bytes of PROTOCOL.md 2.8."""


def make_link(seed: int = 0, *, dev_cfg: DeviceConfig | None = None, **kwargs: Any) -> SimLink:
    """``test_native_session.make_link`` with a board without SHORT_CALLS."""
    cfg = dev_cfg or DeviceConfig()
    cfg = dataclasses.replace(cfg, features=cfg.features & ~Features.SHORT_CALLS)
    return make_any_link(seed, dev_cfg=cfg, **kwargs)


# ---------------------------------------------------------------------------------------------
# the wire, as PROTOCOL.md 2.8 lays it out


def ref_request(channels: bool, channel: int, request_id: int, body: bytes) -> tuple[int, bytes]:
    """(frame channel, message) of a request: on its channel with SERVICE_CHANNELS, else a
    SERVICE_REQUEST (0x20) on channel 0."""
    if channels:
        return channel, struct.pack("<H", request_id) + body
    return 0, struct.pack("<BBH", 0x20, channel, request_id) + body


def ref_response(
    channels: bool, channel: int, request_id: int, status: int, body: bytes
) -> tuple[int, bytes]:
    """(frame channel, message) of a response, as :func:`ref_request` (SERVICE_RESPONSE 0x21)."""
    if channels:
        return channel, struct.pack("<HB", request_id, status) + body
    return 0, struct.pack("<BBHB", 0x21, channel, request_id, status) + body


def ref_cut(text: str, limit: int) -> bytes:
    """``text`` in UTF-8 cut to ``limit`` bytes on a character boundary."""
    return text.encode()[:limit].decode("utf-8", errors="ignore").encode()


def reliable_messages(chunks: list[bytes]) -> list[tuple[int, bytes]]:
    """(channel, message) of every unfragmented reliable frame in one direction's writes, each
    seq once (a retransmission is the same message)."""
    out: list[tuple[int, bytes]] = []
    seen: set[tuple[int, int, bytes]] = set()
    for frame in FrameDecoder(1 << 16).feed(b"".join(chunks)):
        if isinstance(frame, Frame) and frame.type is FrameType.RELIABLE:
            if frame.frag is not Frag.WHOLE:
                continue
            key = (frame.seq, frame.channel, frame.payload)
            if key not in seen:
                seen.add(key)
                out.append((frame.channel, frame.payload))
    return out


def service_control_messages(chunks: list[bytes]) -> list[bytes]:
    """The SERVICE_REQUEST and SERVICE_RESPONSE messages among one direction's writes."""
    return [
        payload
        for channel, payload in reliable_messages(chunks)
        if channel == 0 and payload[:1] in (b"\x20", b"\x21")
    ]


# ---------------------------------------------------------------------------------------------
# a scripted peer


class Scripted:
    """The peer of one real session, played by the test one frame at a time (mtu 64, window 1).

    It acknowledges every reliable frame the session sends as soon as it reads it (so that the
    session's window keeps moving) and keeps all of them; nothing else happens on its own:
    there are no timers, and the session is never ticked after its first HELLO.
    """

    def __init__(
        self, end: HostSession | DeviceSession, features: Features = DEVICE_FEATURES
    ) -> None:
        self.end = end
        self.role = Role.DEVICE if isinstance(end, HostSession) else Role.HOST
        self.features = features
        self.session_id = 0x5C0FFEE5
        self.isn = 0xFE  # the seq wraps during the tests
        self.seq = self.isn
        self.be_seq = 0
        self.now = 0.0
        self.frames: list[Frame] = []
        """Every frame the session sent, in order."""
        self.events: list[Event] = []
        self._decoder = FrameDecoder(1 << 16)
        self.events += end.tick(self.now)
        self.read()

    def write(self, *frames: Frame) -> list[Event]:
        """Hand ``frames`` to the session; returns the events they caused (kept too)."""
        self.now += 0.001
        events = self.end.receive_data(b"".join(encode_frame(f) for f in frames), self.now)
        self.events += events
        self.read()
        return events

    def read(self) -> None:
        """Take what the session sends, acknowledging its reliable frames, until it is quiet."""
        while True:
            new = [f for f in self._decoder.feed(self.end.data_to_send()) if isinstance(f, Frame)]
            self.frames += new
            acks = [
                encode_frame(Frame(FrameType.ACK, 0, f.seq, b""))
                for f in new
                if f.type is FrameType.RELIABLE
            ]
            if not acks:
                return
            self.now += 0.001
            self.events += self.end.receive_data(b"".join(acks), self.now)

    def hello(self) -> Frame:
        msg = HelloMsg(
            role=self.role,
            flags=HelloFlags.NONE,
            session=self.session_id,
            peer_session=self.end.session_id,
            mtu=64,
            max_message=64,
            window=1,
            isn=self.isn,
            features=self.features,
        )
        frame = Frame(FrameType.BEST_EFFORT, 0, self.be_seq, msg.encode())
        self.be_seq = (self.be_seq + 1) & 0xFF
        return frame

    def reliable(self, channel: int, payload: bytes) -> Frame:
        frame = Frame(FrameType.RELIABLE, channel, self.seq, payload)
        self.seq = (self.seq + 1) & 0xFF
        return frame

    def best_effort(self, channel: int, payload: bytes) -> Frame:
        frame = Frame(FrameType.BEST_EFFORT, channel, self.be_seq, payload)
        self.be_seq = (self.be_seq + 1) & 0xFF
        return frame

    def control(self, msg: ctl.ControlMessage) -> Frame:
        return self.reliable(0, msg.encode())

    def sent(self, channel: int) -> list[bytes]:
        """The reliable messages (single frames) the session sent on ``channel``."""
        return [
            f.payload
            for f in self.frames
            if f.type is FrameType.RELIABLE and f.channel == channel and f.frag is Frag.WHOLE
        ]

    def service_controls(self) -> list[bytes]:
        """The SERVICE_REQUEST and SERVICE_RESPONSE messages the session sent."""
        return [p for p in self.sent(0) if p[:1] in (b"\x20", b"\x21")]


def scripted_board(
    host_features: Features = HOST_FEATURES,
    board_features: Features = DEVICE_FEATURES,
    *,
    topics: tuple[TopicEntry, ...] = TOPICS,
    table_end: bool = True,
) -> Scripted:
    """A real host and a scripted board that announced ``topics``; CONNECTED unless
    ``table_end`` is False (then the host is CONFIGURING: the table has not ended)."""
    host = HostSession(HostConfig(features=host_features), rng=random.Random(1))
    board = Scripted(host, board_features)
    board.write(board.hello())
    assert host.state is SessionState.CONFIGURING
    info = BoardInfoMsg(len(topics), "scripted", b"\x01", "0.1.0")
    board.write(board.control(info), *(board.control(e.to_msg()) for e in topics))
    if table_end:
        board.write(board.control(TableEndMsg(len(topics))))
        assert host.state is SessionState.CONNECTED
    return board


def scripted_host(
    host_features: Features = HOST_FEATURES,
    board_features: Features = DEVICE_FEATURES,
    *,
    ready: bool = True,
    refuse: int | None = None,
) -> Scripted:
    """A real board (TOPICS) and a scripted host that accepts its whole table but the entry on
    channel ``refuse``; CONNECTED unless ``ready`` is False (then the board is CONFIGURING: no
    TOPIC_ACK, no READY yet)."""
    device = DeviceSession(
        BOARD, TOPICS, DeviceConfig(features=board_features), rng=random.Random(2)
    )
    host = Scripted(device, host_features)
    host.write(host.hello())
    assert device.state is SessionState.CONFIGURING
    if ready:
        acks = [
            host.control(
                TopicAckMsg(e.channel, TopicStatus.ACCEPTED)
                if e.channel != refuse
                else TopicAckMsg(e.channel, TopicStatus.MISMATCH, MD5_TRIGGER, "other/Type")
            )
            for e in TOPICS
        ]
        accepted = sum(e.channel != refuse for e in TOPICS)
        host.write(*acks, host.control(ReadyMsg(accepted)))
        assert device.state is SessionState.CONNECTED
    return host


def serve_and_call_channels(peer: Scripted) -> tuple[int, int]:
    """(the channel the real end serves, the channel it calls) in TOPICS."""
    return (CH_GET_TIME, CH_RESET) if isinstance(peer.end, HostSession) else (CH_RESET, CH_GET_TIME)


# ---------------------------------------------------------------------------------------------
# both ends with SERVICE_CHANNELS


Answer = Callable[[bytes], "bytes | str"]
"""A server's answer to a request body: the response body, or (a str) an error text."""


def answer_on(link: SimLink, server: str, answer: Answer) -> None:
    """``server`` ("host" or "board") answers every call on ``link`` with ``answer``."""
    end: HostSession | DeviceSession = link.host if server == "host" else link.device

    def on_event(event: Event) -> None:
        if isinstance(event, ServiceRequest):
            reply = answer(event.payload)
            if isinstance(reply, str):
                assert end.respond_service(event.channel, event.request_id, error=reply)
            else:
                assert end.respond_service(event.channel, event.request_id, reply)

    if server == "host":
        link.on_host = on_event
    else:
        link.on_device = on_event


def both_answered(link: SimLink, host_calls: int = 1, board_calls: int = 1) -> Callable[[], bool]:
    """A ``run`` condition: the host and the board have this many responses each."""
    return lambda: (
        len(of_type(link.host_events, ServiceResponse)) >= host_calls
        and len(of_type(link.device_events, ServiceResponse)) >= board_calls
    )


def call_both_ways(link: SimLink) -> tuple[int, int]:
    """On a connected ``link`` the host calls /reset with "ping" and the board /get_time with
    "time?", answered "r" + request by the board and "t" + request by the host; both answers
    arrive, OK, each to its call. Returns the two request ids (the host's, the board's)."""
    answer_on(link, "board", lambda p: b"r" + p)
    answer_on(link, "host", lambda p: b"t" + p)
    to_board = link.host.call_service(CH_RESET, b"ping")
    to_host = link.device.call_service(CH_GET_TIME, b"time?")
    link.flush()
    assert link.run(2.0, until=both_answered(link))
    for events, call in (
        (link.host_events, (CH_RESET, to_board, b"rping", True)),
        (link.device_events, (CH_GET_TIME, to_host, b"ttime?", True)),
    ):
        (answer,) = of_type(events, ServiceResponse)
        assert (answer.channel, answer.request_id, answer.payload, answer.ok) == call
    return to_board, to_host


def test_the_defaults_negotiate_service_channels() -> None:
    assert HOST_FEATURES & Features.SERVICE_CHANNELS
    assert DEVICE_FEATURES & Features.SERVICE_CHANNELS
    assert DEVICE_FEATURES == DEVICE_FEATURES_BEFORE_SERVICE_CHANNELS | Features.SERVICE_CHANNELS
    link = make_link(20)
    connect(link)
    for end in (link.host, link.device):
        assert end.link is not None
        assert end.link.features == DEVICE_FEATURES  # the board's features are the host's too


def test_calls_go_on_their_own_channels_both_ways() -> None:
    """The host calls the board's server, the board calls the host (its client): every request
    and response goes on the service's channel, in PROTOCOL.md's layout, and no
    SERVICE_REQUEST or SERVICE_RESPONSE goes either way."""
    link = make_link(21)
    connect(link)
    to_board, to_host = call_both_ways(link)
    h2d, d2h = reliable_messages(link.h2d_log), reliable_messages(link.d2h_log)
    assert [m for m in h2d if m[0] in (CH_RESET, CH_GET_TIME)] == [
        ref_request(True, CH_RESET, to_board, b"ping"),
        ref_response(True, CH_GET_TIME, to_host, OK, b"ttime?"),
    ]
    assert [m for m in d2h if m[0] in (CH_RESET, CH_GET_TIME)] == [
        ref_request(True, CH_GET_TIME, to_host, b"time?"),
        ref_response(True, CH_RESET, to_board, OK, b"rping"),
    ]
    assert service_control_messages(link.h2d_log) == []
    assert service_control_messages(link.d2h_log) == []
    assert link.host.stats.protocol_errors == link.device.stats.protocol_errors == 0


@pytest.mark.parametrize(
    ("dev_features", "head"),
    [(DEVICE_FEATURES, 3), (DEVICE_FEATURES_BEFORE_SERVICE_CHANNELS, 5)],
    ids=["service channels", "SERVICE_RESPONSE"],
)
def test_an_error_text_is_cut_to_fill_the_callers_max_message(
    dev_features: Features, head: int
) -> None:
    """An ERROR answer's text is cut on a character boundary so that the response, its
    header counted (3 bytes on the channel, 5 as SERVICE_RESPONSE), is exactly the caller's
    max_message: a byte more and the caller would drop it, a byte less and it was cut short."""
    host_max, device_max = 40, DeviceConfig().max_message
    link = make_link(
        22,
        host_cfg=HostConfig(max_message=host_max),
        dev_cfg=DeviceConfig(features=dev_features),
    )
    connect(link)
    channels = bool(dev_features & Features.SERVICE_CHANNELS)
    text = "x" + "é" * 40  # 81 bytes: both cuts of it end on a character boundary
    answer_on(link, "board", lambda p: text)
    answer_on(link, "host", lambda p: "é" * 40)  # 80 bytes: both cuts split a character
    to_board = link.host.call_service(CH_RESET, b"")
    to_host = link.device.call_service(CH_GET_TIME, b"")
    link.flush()
    assert link.run(2.0, until=both_answered(link))
    board_cut = ref_cut(text, host_max - head)
    host_cut = ref_cut("é" * 40, device_max - head)
    assert len(board_cut) == host_max - head
    (answer,) = of_type(link.host_events, ServiceResponse)
    assert isinstance(answer.error, SessionError) and answer.payload == b""
    assert str(answer.error).endswith(f"failed: {board_cut.decode()}")
    (answer,) = of_type(link.device_events, ServiceResponse)
    assert isinstance(answer.error, SessionError)
    assert str(answer.error).endswith(f"failed: {host_cut.decode()}")
    sent = ref_response(channels, CH_RESET, to_board, ERROR, board_cut)
    assert len(sent[1]) == host_max
    assert sent in reliable_messages(link.d2h_log)
    assert ref_response(channels, CH_GET_TIME, to_host, ERROR, host_cut) in reliable_messages(
        link.h2d_log
    )
    assert link.host.stats.dropped_messages == link.device.stats.dropped_messages == 0


@pytest.mark.parametrize(
    ("dev_features", "heads"),
    [(DEVICE_FEATURES, (2, 3)), (DEVICE_FEATURES_BEFORE_SERVICE_CHANNELS, (4, 5))],
    ids=["service channels", "SERVICE_REQUEST"],
)
def test_bodies_up_to_the_peers_max_message(dev_features: Features, heads: tuple[int, int]) -> None:
    """Requests and responses fill the receiver's max_message with their header counted: on
    the channel the bodies may be 2 bytes longer than as SERVICE_REQUEST and SERVICE_RESPONSE.
    A byte more is refused by the sender; what it sends, the receiver takes."""
    request_head, response_head = heads
    host_max, device_max = 100, 64
    link = make_link(
        23,
        host_cfg=HostConfig(max_message=host_max),
        dev_cfg=DeviceConfig(features=dev_features, max_message=device_max),
    )
    connect(link)
    host, device = link.host, link.device
    with pytest.raises(SessionError, match=f"at most {device_max} bytes"):
        host.call_service(CH_RESET, bytes(device_max - request_head + 1))
    with pytest.raises(SessionError, match=f"at most {host_max} bytes"):
        device.call_service(CH_GET_TIME, bytes(host_max - request_head + 1))
    big_request = bytes(range(device_max - request_head))
    first = host.call_service(CH_RESET, big_request)
    second = host.call_service(CH_RESET, b"", timeout=1.0)
    from_board = device.call_service(CH_GET_TIME, bytes(range(host_max - request_head)))
    link.flush()
    assert link.run(1.0, until=lambda: len(of_type(link.device_events, ServiceRequest)) == 2)
    first_call, second_call = of_type(link.device_events, ServiceRequest)
    assert (first_call.request_id, first_call.payload) == (first, big_request)
    big_response = bytes(range(host_max - response_head))
    assert device.respond_service(CH_RESET, first, big_response)
    with pytest.raises(SessionError, match=f"at most {host_max} bytes") as refused:
        device.respond_service(
            CH_RESET, second_call.request_id, bytes(host_max - response_head + 1)
        )
    # A refused answer leaves its call open, for the answerer to fail it with the reason.
    assert device.respond_service(CH_RESET, second_call.request_id, error=str(refused.value))
    assert not device.respond_service(CH_RESET, second_call.request_id, error="twice")
    link.flush()
    assert link.run(1.0, until=lambda: len(of_type(link.host_events, ServiceResponse)) == 2)
    assert link.run(1.0, until=lambda: bool(of_type(link.host_events, ServiceRequest)))
    (call,) = of_type(link.host_events, ServiceRequest)
    assert (call.request_id, call.payload) == (from_board, bytes(range(host_max - request_head)))
    with pytest.raises(SessionError, match=f"at most {device_max} bytes"):
        host.respond_service(CH_GET_TIME, from_board, bytes(device_max - response_head + 1))
    again = device.call_service(CH_GET_TIME, b"again")
    link.flush()
    assert link.run(1.0, until=lambda: len(of_type(link.host_events, ServiceRequest)) == 2)
    assert of_type(link.host_events, ServiceRequest)[-1].request_id == again
    assert host.respond_service(CH_GET_TIME, again, bytes(device_max - response_head))
    link.flush()
    assert link.run(2.0, until=lambda: len(of_type(link.host_events, ServiceResponse)) == 2)
    by_id = {r.request_id: r for r in of_type(link.host_events, ServiceResponse)}
    assert by_id[first].payload == big_response and by_id[first].ok
    assert isinstance(by_id[second].error, SessionError)  # failed with its refusal's reason
    assert f"at most {host_max} bytes" in str(by_id[second].error)
    assert link.run(1.0, until=lambda: bool(of_type(link.device_events, ServiceResponse)))
    (answer,) = of_type(link.device_events, ServiceResponse)
    assert answer.request_id == again
    assert answer.payload == bytes(device_max - response_head) and answer.ok
    for end in (host, device):
        assert end.stats.oversize_messages == 0 and end.stats.protocol_errors == 0


@pytest.mark.parametrize("caller", ["host", "board"])
def test_a_call_before_connected_fails_at_once_and_sends_nothing(caller: str) -> None:
    link = make_link(24)
    end: HostSession | DeviceSession = link.host if caller == "host" else link.device
    end.tick(0.0)
    end.data_to_send()  # the first HELLO
    request_id = end.call_service(CH_RESET if caller == "host" else CH_GET_TIME, b"")
    assert end.data_to_send() == b""
    (answer,) = of_type(end.tick(0.0), ServiceResponse)
    assert answer.request_id == request_id
    assert isinstance(answer.error, SessionError) and "not connected" in str(answer.error)


@pytest.mark.parametrize("server", ["board", "host"])
def test_a_request_before_the_server_is_connected_gets_no_service_on_its_channel(
    server: str,
) -> None:
    """A request on a service channel that comes while the server is still CONFIGURING (a
    board before READY; a host before TABLE_END, on a channel already announced) is answered
    NO_SERVICE on the same channel, where the caller reads it as the response."""
    if server == "board":
        peer = scripted_host(ready=False)
        channel = CH_RESET
    else:
        peer = scripted_board(topics=TOPICS, table_end=False)
        channel = CH_GET_TIME
    peer.write(peer.reliable(channel, struct.pack("<H", 0x1234) + b"early"))
    assert peer.sent(channel) == [ref_response(True, channel, 0x1234, NO_SERVICE, b"")[1]]
    assert not of_type(peer.events, ServiceRequest)
    assert peer.service_controls() == []
    assert peer.end.stats.protocol_errors == 0


def test_a_board_answers_no_service_on_a_channel_the_host_refused() -> None:
    host = scripted_host(refuse=CH_RESET)
    assert isinstance(host.end, DeviceSession) and CH_RESET not in host.end.accepted
    host.write(host.reliable(CH_RESET, struct.pack("<H", 300) + b"x"))
    assert host.sent(CH_RESET) == [struct.pack("<HB", 300, NO_SERVICE)]
    assert not of_type(host.events, ServiceRequest)
    assert host.service_controls() == []


def test_a_host_answers_no_service_on_a_channel_it_refused() -> None:
    refused = TopicEntry(7, ctl.EntryKind.SERVICE_CLIENT, "/bad", "std_srvs/Empty", "0" * 32)
    expected = ExpectedType("std_srvs/Trigger", MD5_TRIGGER)
    host = HostSession(
        HostConfig(),
        type_check=lambda e: expected if e.channel == 7 else None,
        rng=random.Random(3),
    )
    board = Scripted(host)
    board.write(board.hello())
    topics = (*TOPICS, refused)
    board.write(
        board.control(BoardInfoMsg(len(topics), "scripted", b"\x01", "0.1.0")),
        *(board.control(e.to_msg()) for e in topics),
        board.control(TableEndMsg(len(topics))),
    )
    assert host.connected and 7 not in host.topics
    board.write(board.reliable(7, struct.pack("<H", 9)))
    assert board.sent(7) == [struct.pack("<HB", 9, NO_SERVICE)]
    assert not of_type(board.events, ServiceRequest)
    assert board.service_controls() == []


@pytest.mark.parametrize("peer_role", ["board", "host"])
def test_short_messages_and_unknown_statuses_on_service_channels_are_protocol_errors(
    peer_role: str,
) -> None:
    """A request shorter than its request id, a response shorter than request id and status,
    or a response with a status byte PROTOCOL.md does not define: reported, counted, dropped;
    the session stays up, the pending call still takes its real answer, and the next request
    is served. A best-effort message on a service channel is no call: a message on the wrong
    channel."""
    peer = scripted_board() if peer_role == "board" else scripted_host()
    end = peer.end
    serves, calls = serve_and_call_channels(peer)
    request_id = end.call_service(calls, b"q")
    peer.read()
    assert peer.sent(calls) == [struct.pack("<H", request_id) + b"q"]
    bad = [
        peer.reliable(serves, b""),
        peer.reliable(serves, b"\x01"),
        peer.reliable(calls, b""),
        peer.reliable(calls, struct.pack("<H", request_id)),
        peer.reliable(calls, struct.pack("<HB", request_id, 3) + b"x"),
    ]
    for i, frame in enumerate(bad, start=1):
        events = peer.write(frame)
        assert end.stats.protocol_errors == i
        (error,) = errors(events)
        assert isinstance(error, ProtocolError)
        assert f"channel {frame.channel}" in str(error)
        assert not of_type(events, ServiceResponse) and not of_type(events, ServiceRequest)
    assert "unknown status 3" in str(errors(peer.events)[-1])
    assert "too short" in str(errors(peer.events)[0])
    assert end.connected
    events = peer.write(peer.best_effort(serves, struct.pack("<H", 5)))
    assert not of_type(events, ServiceRequest)
    assert end.stats.dropped_messages == 1
    events = peer.write(peer.reliable(calls, struct.pack("<HB", request_id, OK) + b"a"))
    (answer,) = of_type(events, ServiceResponse)
    assert (answer.request_id, answer.payload, answer.ok) == (request_id, b"a", True)
    events = peer.write(peer.reliable(serves, struct.pack("<H", 77) + b"next"))
    (call,) = of_type(events, ServiceRequest)
    assert (call.channel, call.request_id, call.payload) == (serves, 77, b"next")
    assert end.respond_service(serves, 77, b"done")
    peer.read()
    assert peer.sent(serves)[-1] == struct.pack("<HB", 77, OK) + b"done"
    assert peer.service_controls() == []


@pytest.mark.parametrize("peer_role", ["board", "host"])
def test_old_form_calls_in_a_service_channels_session_are_still_handled(peer_role: str) -> None:
    """A SERVICE_REQUEST that comes all the same is served, and answered on the channel (no
    SERVICE_RESPONSE in such a session); a SERVICE_RESPONSE to a call made on the channel is
    taken. An old-form request for a channel that is no service this end serves gets NO_SERVICE
    as a SERVICE_RESPONSE on channel 0: the caller's clear error, not a timeout."""
    peer = scripted_board() if peer_role == "board" else scripted_host()
    end = peer.end
    serves, calls = serve_and_call_channels(peer)
    events = peer.write(peer.control(ctl.ServiceRequestMsg(serves, 0x0102, b"old")))
    (call,) = of_type(events, ServiceRequest)
    assert (call.channel, call.request_id, call.payload) == (serves, 0x0102, b"old")
    assert end.respond_service(serves, 0x0102, b"new")
    peer.read()
    assert peer.sent(serves) == [ref_response(True, serves, 0x0102, OK, b"new")[1]]
    request_id = end.call_service(calls, b"q")
    peer.read()
    events = peer.write(
        peer.control(ctl.ServiceResponseMsg(calls, request_id, ServiceStatus.OK, b"a"))
    )
    (answer,) = of_type(events, ServiceResponse)
    assert (answer.request_id, answer.payload, answer.ok) == (request_id, b"a", True)
    # a SERVICE_REQUEST for a channel that is not a service this end serves
    topic = CH_CHATTER if peer_role == "board" else CH_CMD
    events = peer.write(peer.control(ctl.ServiceRequestMsg(topic, 5, b"")))
    assert errors(events) == []
    peer.read()
    assert peer.service_controls() == [
        ctl.ServiceResponseMsg(topic, 5, ServiceStatus.NO_SERVICE, b"").encode()
    ]
    assert peer.sent(topic) == []
    assert end.connected


# ---------------------------------------------------------------------------------------------
# one end without the feature: the old bytes


@pytest.mark.parametrize(
    ("host_features", "device_features"),
    [
        (HOST_FEATURES, DEVICE_FEATURES_BEFORE_SERVICE_CHANNELS),
        (FEATURES_BEFORE_SERVICE_CHANNELS, DEVICE_FEATURES),
    ],
    ids=["new host, old board", "old host, new board"],
)
def test_with_one_end_without_the_feature_the_bytes_are_the_golden_ones(
    host_features: Features, device_features: Features
) -> None:
    """The golden ACK_IN_DATA vectors were recorded between ends without SERVICE_CHANNELS:
    a host and a board of which only one has it send those very frames."""
    host, device, t = _connected_vector_pair(host_features, device_features)
    assert host.link is not None and not host.link.features & Features.SERVICE_CHANNELS
    steps = _service_call_vectors(host, device, t, "ack_in_data", ("", "", ""))
    stored = json.loads(VECTORS.read_text())
    golden = [v for v in stored["extra"] if v["name"].startswith("ack_in_data_")]
    assert len(golden) == 4
    assert [(s["name"], s["hex"]) for s in steps] == [(v["name"], v["hex"]) for v in golden]


@pytest.mark.parametrize(
    ("host_features", "device_features"),
    [
        (HOST_FEATURES, DEVICE_FEATURES_BEFORE_SERVICE_CHANNELS),
        (FEATURES_BEFORE_SERVICE_CHANNELS, DEVICE_FEATURES),
    ],
    ids=["new host, old board", "old host, new board"],
)
def test_with_one_end_without_the_feature_calls_use_channel_0(
    host_features: Features, device_features: Features
) -> None:
    """Calls both ways, an error answer, and no answer: all as SERVICE_REQUEST and
    SERVICE_RESPONSE on channel 0, nothing on the services' channels."""
    link = make_link(
        25,
        host_cfg=HostConfig(features=host_features),
        dev_cfg=DeviceConfig(features=device_features),
    )
    connect(link)
    answer_on(link, "board", lambda p: b"r" + p)
    answer_on(link, "host", lambda p: "no")
    to_board = link.host.call_service(CH_RESET, b"ping")
    to_host = link.device.call_service(CH_GET_TIME, b"?")
    link.flush()
    assert link.run(2.0, until=both_answered(link))
    h2d, d2h = reliable_messages(link.h2d_log), reliable_messages(link.d2h_log)
    assert [m for m in h2d + d2h if m[0] in (CH_RESET, CH_GET_TIME)] == []
    assert service_control_messages(link.h2d_log) == [
        ref_request(False, CH_RESET, to_board, b"ping")[1],
        ref_response(False, CH_GET_TIME, to_host, ERROR, b"no")[1],
    ]
    assert service_control_messages(link.d2h_log) == [
        ref_request(False, CH_GET_TIME, to_host, b"?")[1],
        ref_response(False, CH_RESET, to_board, OK, b"rping")[1],
    ]


@pytest.mark.parametrize("peer_role", ["board", "host"])
def test_a_peer_without_the_feature_gets_no_service_as_service_response(peer_role: str) -> None:
    """The real end has SERVICE_CHANNELS, the scripted one has not: a request before the server
    is connected is answered with SERVICE_RESPONSE NO_SERVICE on channel 0, as always."""
    old = ALL_FEATURES & ~Features.SERVICE_CHANNELS
    if peer_role == "board":
        peer = scripted_board(board_features=old, table_end=False)
        channel = CH_GET_TIME
    else:
        peer = scripted_host(host_features=old, ready=False)
        channel = CH_RESET
    peer.write(peer.control(ctl.ServiceRequestMsg(channel, 3, b"")))
    assert peer.service_controls() == [ref_response(False, channel, 3, NO_SERVICE, b"")[1]]
    assert peer.sent(channel) == []


# ---------------------------------------------------------------------------------------------
# the golden vectors


def test_the_service_channel_vectors_are_the_layout_of_protocol_md() -> None:
    """The four frames of two calls on /reset (channel 2) read as PROTOCOL.md 2.8 says."""
    stored = json.loads(VECTORS.read_text())
    vectors = {v["name"]: v for v in stored["extra"] if v["name"].startswith("service_channel_")}
    assert list(vectors) == [
        "service_channel_request_1",
        "service_channel_response_1",
        "service_channel_request_2",
        "service_channel_response_2",
    ]
    for call in (1, 2):
        for name, expected in (
            (f"service_channel_request_{call}", ref_request(True, 2, call, b"")),
            (
                f"service_channel_response_{call}",
                ref_response(True, 2, call, OK, b"\x01\x02\x00\x00\x00ok"),
            ),
        ):
            vec = vectors[name]
            (frame,) = FrameDecoder(4096).feed(bytes.fromhex(vec["hex"]))
            assert isinstance(frame, Frame) and frame.type is FrameType.RELIABLE
            assert (frame.channel, frame.payload) == expected
            assert "control" not in vec["frame"]


# ---------------------------------------------------------------------------------------------
# properties

_bodies = st.binary(max_size=40)
_answers = st.one_of(
    st.tuples(st.just(OK), _bodies),
    st.tuples(st.just(ERROR), st.text(max_size=10).map(str.encode)),  # at most 40 bytes
)


@pytest.mark.parametrize("peer_role", ["board", "host"])
@bounded(60)
@given(
    calls=st.lists(st.tuples(st.integers(1, 0xFFFF), _bodies, _answers), min_size=1, max_size=6),
    answers=st.lists(st.tuples(_bodies, st.sampled_from([OK, ERROR, NO_SERVICE])), max_size=6),
)
def test_any_request_id_and_body_round_trips_on_the_channel(
    peer_role: str,
    calls: list[tuple[int, bytes, tuple[int, bytes]]],
    answers: list[tuple[bytes, int]],
) -> None:
    """The real end serves requests with any id and body the peer sends on the channel and
    answers each with the same id on it; its own calls go out with their id and body, and take
    any answer the peer gives: OK with its body, ERROR with its text, NO_SERVICE."""
    peer = scripted_board() if peer_role == "board" else scripted_host()
    end = peer.end
    serves, calls_on = serve_and_call_channels(peer)
    for request_id, body, (status, reply) in calls:
        events = peer.write(peer.reliable(serves, struct.pack("<H", request_id) + body))
        (call,) = of_type(events, ServiceRequest)
        assert (call.channel, call.request_id, call.payload) == (serves, request_id, body)
        if status == OK:
            assert end.respond_service(serves, request_id, reply)
        else:
            assert end.respond_service(serves, request_id, error=reply.decode())
        peer.read()
        assert peer.sent(serves)[-1] == struct.pack("<HB", request_id, status) + reply
    for body, status in answers:
        request_id = end.call_service(calls_on, body)
        peer.read()
        assert peer.sent(calls_on)[-1] == struct.pack("<H", request_id) + body
        reply = body[::-1]
        events = peer.write(peer.reliable(calls_on, struct.pack("<HB", request_id, status) + reply))
        (answer,) = of_type(events, ServiceResponse)
        assert answer.request_id == request_id
        if status == OK:
            assert answer.ok and answer.payload == reply
        else:
            assert isinstance(answer.error, SessionError) and answer.payload == b""
            if status == ERROR:
                assert reply.decode("utf-8", errors="replace") in str(answer.error)
    assert peer.service_controls() == []
    assert end.stats.protocol_errors == 0


def _bodies_of_sizes(max_size: int) -> st.SearchStrategy[list[bytes]]:
    """1 to 5 bodies, each 0..``max_size`` bytes, their sizes drawn first (so that the
    largest are tried as often as the smallest)."""
    size = st.integers(0, max_size)
    return st.lists(
        size.flatmap(lambda n: st.binary(min_size=n, max_size=n)), min_size=1, max_size=5
    )


def _echo_or_refuse(max_body: int) -> Answer:
    """Answers three times the request, cut to ``max_body``; a request whose size is 1 more
    than a multiple of 4 is refused with an error text naming its size."""

    def answer(payload: bytes) -> bytes | str:
        if refused(payload):
            return f"refused {len(payload)}"
        return (payload * 3)[:max_body]

    return answer


def refused(request: bytes) -> bool:
    return len(request) % 4 == 1


LOSSY_MAX = (160, 96)
"""The max_message of the host and of the board in :func:`lossy_link`."""


def lossy_link(
    make: Callable[..., SimLink],
    seed: int,
    faults: tuple[float, float, float],
    window: int,
    queue_limit: int,
) -> SimLink:
    """A host and a board (``make``'s, with LOSSY_MAX, the board's ``window`` and transmit
    ``queue_limit``, patient timers), connected over a link that loses, duplicates and
    reorders frames at the ``faults`` rates, both ways, in chunks of up to 13 bytes."""
    loss, duplicate, reorder = faults
    host_max, device_max = LOSSY_MAX
    link: SimLink = make(
        seed,
        host_cfg=HostConfig(max_message=host_max, **PATIENT),
        dev_cfg=DeviceConfig(
            window=window, max_message=device_max, tx_queue_limit=queue_limit, **PATIENT
        ),
        h2d=lossy(loss, duplicate=duplicate, reorder=reorder, max_chunk=13),
        d2h=lossy(loss, duplicate=duplicate, reorder=reorder, max_chunk=13),
    )
    connect(link, 60.0)
    return link


lossy_calls = given(
    seed=st.integers(0, 2**16),
    loss=st.floats(0.0, 0.3),
    duplicate=st.floats(0.0, 0.2),
    reorder=st.floats(0.0, 0.2),
    window=st.sampled_from([1, 2, 4]),
    data=st.data(),
)
"""The arguments of a test of calls over a lossy link: its seed, loss, duplication and
reordering rates, the board's window, and draws of the test's own."""


@bounded(20)
@lossy_calls
def test_calls_both_ways_over_a_lossy_duplicating_link_end_once_each(
    seed: int, loss: float, duplicate: float, reorder: float, window: int, data: st.DataObject
) -> None:
    """Random bodies up to the receiver's max_message, answered OK (up to the caller's) or
    ERROR, both ways, over a link that loses, corrupts, duplicates and reorders frames: each
    call ends with exactly one response, its own, and only the services' channels carried
    them."""
    host_max, device_max = LOSSY_MAX
    link = lossy_link(make_link, seed, (loss, duplicate, reorder), window, 4096)
    host_bodies = data.draw(_bodies_of_sizes(device_max - 2), label="the host's requests")
    board_bodies = data.draw(_bodies_of_sizes(host_max - 2), label="the board's requests")
    calls_end_once_each(link, host_bodies, board_bodies, (host_max - 3, device_max - 3), 300.0)


def calls_end_once_each(
    link: SimLink,
    host_bodies: list[bytes],
    board_bodies: list[bytes],
    max_bodies: tuple[int, int],
    seconds: float,
) -> tuple[list[int], list[int]]:
    """The host calls /reset with each of ``host_bodies`` and the board /get_time with each of
    ``board_bodies``, all at once on the connected ``link``; the answers (:func:`_echo_or_refuse`
    cut to ``max_bodies``: the host's largest answer body, then the board's) come within
    ``seconds``, one for each call, its own, and only on the services' channels. Returns the
    request ids of the host's calls and the board's."""
    answer_on(link, "board", _echo_or_refuse(max_bodies[0]))
    answer_on(link, "host", _echo_or_refuse(max_bodies[1]))
    host_ids = {link.host.call_service(CH_RESET, b): b for b in host_bodies}
    board_ids = {link.device.call_service(CH_GET_TIME, b): b for b in board_bodies}
    link.flush()
    assert link.run(seconds, until=both_answered(link, len(host_ids), len(board_ids)))
    link.run(1.0)  # a second answer to any call would come now
    for events, ids, max_body in (
        (link.host_events, host_ids, max_bodies[0]),
        (link.device_events, board_ids, max_bodies[1]),
    ):
        responses = of_type(events, ServiceResponse)
        assert sorted(r.request_id for r in responses) == sorted(ids)
        for r in responses:
            sent = ids[r.request_id]
            if refused(sent):
                assert isinstance(r.error, SessionError)
                assert str(r.error).endswith(f"failed: refused {len(sent)}")
            else:
                assert r.ok, r.error
                assert r.payload == (sent * 3)[:max_body]
    assert service_control_messages(link.h2d_log) == []
    assert service_control_messages(link.d2h_log) == []
    assert link.host.stats.protocol_errors == link.device.stats.protocol_errors == 0
    assert not [e for e in link.host_events + link.device_events if isinstance(e, Error)]
    return list(host_ids), list(board_ids)
