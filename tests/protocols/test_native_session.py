"""Tests of the native protocol's control messages, reliability layer and sessions.

Sessions run over ``lossy.SimLink`` (a seeded, simulated lossy link on a virtual clock): every
time below is simulated time, nothing sleeps and nothing reads a wall clock.
"""

from __future__ import annotations

import contextlib
import json
import random
import re
import struct
from collections.abc import Callable
from dataclasses import fields, is_dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hwbridge.protocols.base import FirmwareIdentity
from hwbridge.protocols.errors import (
    HwBridgeError,
    HwBridgeTimeoutError,
    ProtocolError,
    ProtocolMismatchError,
)
from hwbridge.protocols.native import control as ctl
from hwbridge.protocols.native.control import (
    EntryKind,
    Features,
    LogLevel,
    ParamStatus,
    ParamType,
    coerce_param,
    decode_control,
)
from hwbridge.protocols.native.framing import (
    Frag,
    Frame,
    FrameDecoder,
    FrameType,
    cobs_encode,
    crc16,
    encode_frame,
)
from hwbridge.protocols.native.identity import format_identity
from hwbridge.protocols.native.reliable import (
    BestEffortReceiver,
    BestEffortSender,
    ReliableReceiver,
    ReliableSender,
    RttEstimator,
    SequenceStats,
)
from hwbridge.protocols.native.session import (
    ACK_DELAY_MAX,
    RTO_MIN_FLOOR,
    BoardInfo,
    Connected,
    DebugOutput,
    DeviceConfig,
    DeviceSession,
    Disconnected,
    Error,
    Event,
    ExpectedType,
    HostConfig,
    HostSession,
    Log,
    Message,
    ParamRequest,
    ParamResponse,
    ParamUpdate,
    ServiceRequest,
    ServiceResponse,
    SessionError,
    SessionResetError,
    SessionState,
    TimeSynced,
    TopicAnnounced,
    TopicEntry,
    TopicMismatchError,
)
from tests.protocols.lossy import Faults, SimLink

VECTORS = Path(__file__).parents[2] / "protocols" / "vectors" / "native_session.json"

MD5_STRING = "992ce8a1687cec8c8bd883ec73ca41d1"
MD5_INT32 = "da5909fbe378aeaf85e547e830cc1bb7"
MD5_TRIGGER = "937c9679a518e3a18d831e57125ea522"
MD5_EMPTY_SRV = "d41d8cd98f00b204e9800998ecf8427e"

CH_CHATTER, CH_STATUS, CH_CMD, CH_CONFIG, CH_RESET, CH_GET_TIME = 1, 2, 3, 4, 5, 6
TOPICS = (
    TopicEntry(CH_CHATTER, EntryKind.PUBLISHER, "/chatter", "std_msgs/String", MD5_STRING),
    TopicEntry(CH_STATUS, EntryKind.PUBLISHER, "/status", "std_msgs/String", MD5_STRING, True),
    TopicEntry(CH_CMD, EntryKind.SUBSCRIBER, "/cmd", "std_msgs/String", MD5_STRING),
    TopicEntry(CH_CONFIG, EntryKind.SUBSCRIBER, "/config", "std_msgs/String", MD5_STRING, True),
    TopicEntry(CH_RESET, EntryKind.SERVICE_SERVER, "/reset", "std_srvs/Trigger", MD5_TRIGGER),
    TopicEntry(CH_GET_TIME, EntryKind.SERVICE_CLIENT, "/get_time", "std_srvs/Empty", MD5_EMPTY_SRV),
)
BOARD = BoardInfo("uno-1", bytes.fromhex("1e950f0a"), "hwbridge-fw 0.1.0")

PATIENT: dict[str, Any] = {
    "link_timeout": 30.0,
    "max_retries": 200,
    "handshake_timeout": 60.0,
    "service_timeout": 120.0,
    "param_timeout": 120.0,
}
"""Timers for property tests at high loss: the link must not be declared dead by bad luck."""

SETTINGS = settings(
    max_examples=12,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)

LINK_FAULTS: dict[str, st.SearchStrategy[Any]] = {
    "seed": st.integers(0, 2**16),
    "loss": st.floats(0.0, 0.3),
    "duplicate": st.floats(0.0, 0.2),
    "reorder": st.floats(0.0, 0.3),
}
"""``@given`` arguments of the property tests of a session over a lossy link: the link's seed
and its fault rates."""


# ---------------------------------------------------------------------------------------------
# helpers


def make_link(
    seed: int = 0,
    *,
    host_cfg: HostConfig | None = None,
    dev_cfg: DeviceConfig | None = None,
    topics: tuple[TopicEntry, ...] = TOPICS,
    h2d: Faults | None = None,
    d2h: Faults | None = None,
    type_check: Callable[[TopicEntry], ExpectedType | None] | None = None,
    **kwargs: Any,
) -> SimLink:
    host = HostSession(host_cfg, type_check=type_check, rng=random.Random(seed))
    device = DeviceSession(BOARD, topics, dev_cfg, rng=random.Random(seed + 1))
    return SimLink(host, device, seed=seed, h2d=h2d, d2h=d2h, **kwargs)


def connect(link: SimLink, timeout: float = 10.0) -> None:
    ok = link.run(timeout, until=lambda: link.host.connected and link.device.connected)
    assert ok, f"not connected after {timeout} s: {errors(link.host_events + link.device_events)}"


def of_type(events: list[Event], cls: type[Any]) -> list[Any]:
    return [e for e in events if isinstance(e, cls)]


def errors(events: list[Event]) -> list[HwBridgeError]:
    return [e.error for e in events if isinstance(e, Error)]


def messages(events: list[Event], channel: int) -> list[bytes]:
    return [e.payload for e in events if isinstance(e, Message) and e.channel == channel]


def lossy(rate: float, **kw: Any) -> Faults:
    return Faults(drop=rate / 2, corrupt=rate / 2, **kw)


def is_subsequence(sub: list[bytes], full: list[bytes]) -> bool:
    it = iter(full)
    return all(any(x == y for y in it) for x in sub)


# ---------------------------------------------------------------------------------------------
# control messages

_u8 = st.integers(0, 255)
_u16 = st.integers(0, 0xFFFF)
_u32 = st.integers(0, 0xFFFFFFFF)
_ns = st.integers(0, 0xFFFFFFFF * 10**9 + 999_999_999)
_name = st.text(max_size=20).filter(lambda s: len(s.encode()) <= 255)
_md5 = st.binary(min_size=16, max_size=16).map(bytes.hex)
_f32 = st.floats(width=32, allow_nan=False)
_values = st.one_of(
    st.tuples(st.just(ParamType.BOOL), st.booleans()),
    st.tuples(st.just(ParamType.INT32), st.integers(-(2**31), 2**31 - 1)),
    st.tuples(st.just(ParamType.FLOAT32), _f32),
    st.tuples(st.just(ParamType.STRING), st.text(max_size=10)),
    st.tuples(st.just(ParamType.BOOL_LIST), st.lists(st.booleans(), max_size=5).map(tuple)),
    st.tuples(
        st.just(ParamType.INT32_LIST),
        st.lists(st.integers(-(2**31), 2**31 - 1), max_size=5).map(tuple),
    ),
    st.tuples(st.just(ParamType.FLOAT32_LIST), st.lists(_f32, max_size=5).map(tuple)),
    st.tuples(st.just(ParamType.STRING_LIST), st.lists(st.text(max_size=5), max_size=5).map(tuple)),
)

CONTROL_MESSAGES = st.one_of(
    st.builds(
        ctl.HelloMsg,
        role=st.sampled_from(ctl.Role),
        flags=st.sampled_from(ctl.HelloFlags),
        session=_u32,
        peer_session=_u32,
        mtu=_u16,
        max_message=_u32,
        window=_u8,
        isn=_u8,
        features=st.integers(0, 7).map(Features),
    ),
    st.just(ctl.HeartbeatMsg()),
    st.just(ctl.GoodbyeMsg()),
    st.builds(ctl.TimeRequestMsg, _u32),
    st.builds(ctl.TimeResponseMsg, _u32, _ns, _ns),
    st.builds(ctl.HostTimeRequestMsg, _ns),
    st.builds(ctl.HostTimeResponseMsg, _ns, _u32, _u32),
    st.builds(ctl.BoardInfoMsg, _u8, _name, st.binary(max_size=16), st.text(max_size=20)),
    st.builds(
        ctl.TopicMsg,
        _u8,
        st.sampled_from(EntryKind),
        st.sampled_from(ctl.EntryFlags),
        _md5,
        _name,
        st.text(max_size=30),
    ),
    st.builds(ctl.TableEndMsg, _u8),
    st.builds(ctl.TopicAckMsg, _u8, st.just(ctl.TopicStatus.ACCEPTED)),
    st.builds(
        ctl.TopicAckMsg,
        _u8,
        st.sampled_from([ctl.TopicStatus.MISMATCH, ctl.TopicStatus.INVALID]),
        _md5,
        st.text(max_size=30),
    ),
    st.builds(ctl.ReadyMsg, _u8),
    st.builds(ctl.ServiceRequestMsg, _u8, _u16, st.binary(max_size=40)),
    st.builds(ctl.ServiceResponseMsg, _u8, _u16, st.sampled_from(ctl.ServiceStatus), st.binary()),
    st.builds(
        ctl.ParamGetMsg,
        st.integers(1, 0xFFFF),
        st.sampled_from(ParamType),
        st.sampled_from(ctl.ParamGetFlags),
        _u16,
        _name,
    ),
    _values.flatmap(
        lambda tv: st.builds(
            ctl.ParamValueMsg, _u16, st.just(ParamStatus.OK), _name, st.just(tv[0]), st.just(tv[1])
        )
    ),
    st.builds(
        ctl.ParamValueMsg,
        _u16,
        st.sampled_from([ParamStatus.NOT_FOUND, ParamStatus.TYPE_MISMATCH, ParamStatus.TOO_LARGE]),
        _name,
    ),
    st.builds(ctl.LogMsg, st.sampled_from(LogLevel), st.text(max_size=40)),
)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(CONTROL_MESSAGES)
def test_control_messages_round_trip(msg: ctl.ControlMessage) -> None:
    payload = msg.encode()
    assert payload[0] == msg.OPCODE
    if isinstance(msg, ctl.HelloMsg):
        assert len(payload) == ctl.HelloMsg.SIZE
    assert decode_control(payload) == msg


@settings(max_examples=300, deadline=None, derandomize=True)
@given(CONTROL_MESSAGES, st.data())
def test_truncated_control_messages_raise_protocol_error(
    msg: ctl.ControlMessage, data: st.DataObject
) -> None:
    payload = msg.encode()
    cut = data.draw(st.integers(0, len(payload) - 1))
    try:
        decoded = decode_control(payload[:cut])
    except ProtocolError as exc:
        assert str(exc)
    else:
        # Only messages ending in a free-length field can be cut and still decode.
        assert type(decoded) is type(msg)
        assert decoded != msg or cut == len(payload)


@settings(max_examples=500, deadline=None, derandomize=True)
@given(st.binary(max_size=40))
def test_decode_control_raises_only_protocol_error(payload: bytes) -> None:
    """Garbage never escapes as struct.error, UnicodeDecodeError, ValueError, IndexError..."""
    with contextlib.suppress(ProtocolError):
        decode_control(payload)


def test_control_errors_name_the_problem() -> None:
    with pytest.raises(ProtocolError, match="empty control payload"):
        decode_control(b"")
    with pytest.raises(ProtocolError, match="unknown control opcode 0x7f"):
        decode_control(b"\x7f")
    with pytest.raises(ProtocolError, match="HELLO too short"):
        decode_control(bytes([1, 1, 0, 0, 1, 2]))
    with pytest.raises(ProtocolMismatchError, match="version 2, this end speaks version 1"):
        decode_control(bytes([1, 2]) + bytes(19))
    with pytest.raises(ProtocolError, match="LOG: unknown level 9"):
        decode_control(b"\x40\x09hi")


@pytest.mark.parametrize(
    ("value", "want", "max_count", "expected"),
    [
        (3, ParamType.ANY, 0, (ParamStatus.OK, ParamType.INT32, 3)),
        (True, ParamType.ANY, 0, (ParamStatus.OK, ParamType.BOOL, True)),
        (0.5, ParamType.ANY, 0, (ParamStatus.OK, ParamType.FLOAT32, 0.5)),
        ("x", ParamType.ANY, 0, (ParamStatus.OK, ParamType.STRING, "x")),
        ([1, 2.5], ParamType.ANY, 0, (ParamStatus.OK, ParamType.FLOAT32_LIST, (1.0, 2.5))),
        ([], ParamType.ANY, 0, (ParamStatus.OK, ParamType.INT32_LIST, ())),
        (3, ParamType.FLOAT32, 0, (ParamStatus.OK, ParamType.FLOAT32, 3.0)),
        (1, ParamType.BOOL, 0, (ParamStatus.OK, ParamType.BOOL, True)),
        (2, ParamType.BOOL, 0, (ParamStatus.TYPE_MISMATCH, ParamType.ANY, None)),
        (2**31, ParamType.INT32, 0, (ParamStatus.TYPE_MISMATCH, ParamType.ANY, None)),
        (2**31, ParamType.ANY, 0, (ParamStatus.TYPE_MISMATCH, ParamType.ANY, None)),
        (1e39, ParamType.FLOAT32, 0, (ParamStatus.TYPE_MISMATCH, ParamType.ANY, None)),
        ("x", ParamType.INT32, 0, (ParamStatus.TYPE_MISMATCH, ParamType.ANY, None)),
        (0.5, ParamType.INT32, 0, (ParamStatus.TYPE_MISMATCH, ParamType.ANY, None)),
        (5, ParamType.INT32_LIST, 0, (ParamStatus.OK, ParamType.INT32_LIST, (5,))),
        ([5], ParamType.INT32, 0, (ParamStatus.TYPE_MISMATCH, ParamType.ANY, None)),
        ([1, 2, 3], ParamType.INT32_LIST, 2, (ParamStatus.TOO_LARGE, ParamType.ANY, None)),
        ([1, "a"], ParamType.ANY, 0, (ParamStatus.TYPE_MISMATCH, ParamType.ANY, None)),
        (0.1, ParamType.FLOAT32, 0, (ParamStatus.OK, ParamType.FLOAT32, 0.10000000149011612)),
    ],
)
def test_coerce_param(value: Any, want: ParamType, max_count: int, expected: Any) -> None:
    assert coerce_param(value, want, max_count) == expected


# ---------------------------------------------------------------------------------------------
# reliability layer, unit level


def _sender(window: int, *, mtu: int = 64, retries: int = 3, isn: int = 250) -> ReliableSender:
    rtt = RttEstimator(0.2, 0.05, 1.0)
    return ReliableSender(
        SequenceStats(), rtt, isn=isn, window=window, mtu=mtu, max_retries=retries, queue_limit=1000
    )


def test_sender_respects_window_and_wraps_seq() -> None:
    tx = _sender(3)
    for i in range(10):
        assert tx.queue(1, bytes([i]))
    first = tx.transmit(0.0)
    assert [f.seq for f in first] == [250, 251, 252]
    assert tx.transmit(0.0) == []  # window full
    assert tx.on_ack(Frame(FrameType.ACK, 0, 251, b""), 0.01) == []
    assert [f.seq for f in tx.transmit(0.01)] == [253, 254]
    tx.on_ack(Frame(FrameType.ACK, 0, 254, b""), 0.02)
    assert [f.seq for f in tx.transmit(0.02)] == [255, 0, 1]


def test_send_now_takes_the_queue_path_only_when_it_can() -> None:
    """``send_now`` sends at once only with nothing queued, room in the window and a message
    of one frame; otherwise it leaves the sender as it was, for ``queue``."""
    tx = _sender(2, mtu=6)
    assert tx.send_now(1, b"abcdefg", 0.0) is None  # over the MTU: fragments go through the queue
    assert tx.in_flight == 0 and tx.stats.rel_messages_sent == 0
    first = tx.send_now(1, bytearray(b"ab"), 0.0)
    assert first is not None and (first.seq, first.payload) == (250, b"ab")
    assert type(first.payload) is bytes
    assert tx.queue(1, b"abcdefg")  # two fragments, one released now, one left queued
    assert [f.seq for f in tx.transmit(0.0)] == [251]
    tx.on_ack(Frame(FrameType.ACK, 0, 251, b""), 0.01)
    assert tx.send_now(1, b"x", 0.01) is None  # one is queued: it goes first
    assert [f.seq for f in tx.transmit(0.01)] == [252]
    assert tx.send_now(1, b"x", 0.02) is not None
    assert tx.send_now(1, b"y", 0.02) is None  # the window (2) is full
    assert tx.in_flight == 2


@settings(max_examples=200, deadline=None, derandomize=True)
@given(
    st.lists(
        st.one_of(
            st.tuples(st.just("send"), st.binary(max_size=12)),
            st.tuples(st.just("ack"), st.integers(0, 3)),
        ),
        max_size=40,
    ),
    st.integers(1, 4),
)
def test_send_now_or_queue_is_queue_then_transmit(ops: list[tuple[str, Any]], window: int) -> None:
    """A session's way of sending (``send_now``, else ``queue`` then ``transmit``) puts the
    same frames on the wire at the same moments, with the same counters and timers, as always
    queueing: the fast path is only a shortcut."""
    fast, slow = _sender(window, mtu=8), _sender(window, mtu=8)
    now = 0.0
    for op, arg in ops:
        now += 0.001
        if op == "send":
            frame = fast.send_now(3, arg, now)
            if frame is None:
                assert fast.queue(3, arg)
                got = fast.transmit(now)
            else:
                got = [frame]
            assert slow.queue(3, arg)
            assert got == slow.transmit(now)
        else:  # acknowledge the oldest frames in flight (arg of them), then release more
            acked = (slow._base + arg - 1) & 0xFF
            ack = Frame(FrameType.ACK, 0, acked, b"")
            assert fast.on_ack(ack, now) == slow.on_ack(ack, now)
            assert fast.transmit(now) == slow.transmit(now)
        assert fast.stats == slow.stats
        assert (fast.in_flight, fast.next_deadline()) == (slow.in_flight, slow.next_deadline())
        assert fast.rtt.srtt == slow.rtt.srtt


def test_sender_selective_ack_and_fast_retransmit() -> None:
    tx = _sender(4)
    for i in range(4):
        tx.queue(1, bytes([i]))
    tx.transmit(0.0)
    # seq 250 lost; 251 and 253 received: ack 249 (nothing in order), bits for 251 and 253.
    again = tx.on_ack(Frame(FrameType.ACK, 0, 249, bytes([0b101])), 0.3)
    assert [f.seq for f in again] == [250, 252]
    assert tx.stats.fast_retransmits == 2
    # only unacknowledged frames time out afterwards
    later = tx.poll(10.0)
    assert sorted(f.seq for f in later) == [250, 252]


def test_sender_backoff_and_retry_limit() -> None:
    tx = _sender(1, retries=3)
    tx.queue(1, b"x")
    tx.transmit(0.0)
    times = []
    now = 0.0
    with pytest.raises(HwBridgeTimeoutError, match="not acknowledged after 3 retransmissions"):
        for _ in range(10):
            deadline = tx.next_deadline()
            assert deadline is not None
            now = deadline
            if tx.poll(now):
                times.append(now)
    # RTO 0.2 s, doubling per retransmission, capped at 1 s
    assert times == pytest.approx([0.2, 0.6, 1.4])
    assert now == pytest.approx(2.4)


def test_rtt_estimator_follows_rfc6298() -> None:
    rtt = RttEstimator(1.0, 0.05, 10.0)
    rtt.sample(0.1)
    assert (rtt.srtt, rtt.rttvar, rtt.rto) == pytest.approx((0.1, 0.05, 0.3))
    rtt.sample(0.2)
    assert rtt.srtt == pytest.approx(0.875 * 0.1 + 0.125 * 0.2)
    assert rtt.rttvar == pytest.approx(0.75 * 0.05 + 0.25 * 0.1)
    assert rtt.timeout(2) == pytest.approx(min(10.0, rtt.rto * 4))


def test_receiver_reorders_suppresses_duplicates_and_reports_sack() -> None:
    stats = SequenceStats()
    rx = ReliableReceiver(stats, isn=254, window=4, max_message=100)
    frames = [Frame(FrameType.RELIABLE, 7, s, bytes([s])) for s in (254, 255, 0, 1)]
    assert rx.receive(frames[1]) == []
    assert rx.receive(frames[3]) == []
    ack = rx.ack_frame()
    assert (ack.type, ack.seq, ack.payload) == (FrameType.ACK, 253, bytes([0b101]))
    assert rx.receive(frames[1]) == []  # duplicate of a buffered frame
    delivered = rx.receive(frames[0])
    assert [d.payload for d in delivered] == [b"\xfe", b"\xff"]
    assert [d.payload for d in rx.receive(frames[2])] == [b"\x00", b"\x01"]
    assert rx.receive(frames[0]) == []  # duplicate of a delivered frame
    assert stats.duplicates == 2
    assert rx.receive(Frame(FrameType.RELIABLE, 7, 6, b"")) == []  # beyond the window
    assert stats.out_of_window == 1
    assert rx.ack_frame() == Frame(FrameType.ACK, 0, 1, b"")


def test_window_one_receiver_holds_nothing_out_of_order() -> None:
    stats = SequenceStats()
    rx = ReliableReceiver(stats, isn=0, window=1, max_message=100)
    assert rx.receive(Frame(FrameType.RELIABLE, 1, 1, b"b")) == []
    assert rx.buffered == 0
    assert stats.out_of_window == 1
    assert rx.ack_frame().payload == b""


def test_receiver_holds_acks_only_for_frames_in_order() -> None:
    """ack_every 3: in-order frames make an ACK due but not urgent until the third; anything
    that tells the sender of a gap or a lost ACK is urgent at once."""
    rx = ReliableReceiver(SequenceStats(), isn=10, window=8, max_message=100, ack_every=3)

    def frame(seq: int) -> Frame:
        return Frame(FrameType.RELIABLE, 7, seq & 0xFF, b"")

    for seq, urgent in ((10, False), (11, False), (12, True)):
        rx.receive(frame(seq))
        assert (rx.ack_needed, rx.ack_urgent) == (True, urgent)
    assert rx.ack_frame().seq == 12
    assert (rx.ack_needed, rx.ack_urgent) == (False, False)
    rx.receive(frame(13))  # the count starts again after an ACK
    assert not rx.ack_urgent
    for name, seq in (("duplicate", 12), ("early", 15), ("fills the gap", 14), ("outside", 40)):
        rx.ack_frame()
        rx.receive(frame(seq))
        assert rx.ack_needed and rx.ack_urgent, name
    with pytest.raises(ValueError, match=r"ack_every must be 1\.\.max\(window, 2\)"):
        ReliableReceiver(SequenceStats(), isn=0, window=2, max_message=10, ack_every=3)
    with pytest.raises(ValueError, match="ack_delay must be"):
        HostConfig(ack_delay=0.5)
    # The peer may hold an ACK for ACK_DELAY_MAX: an RTO shorter than that resends frames that
    # arrived. The floor itself is accepted.
    assert ACK_DELAY_MAX < RTO_MIN_FLOOR
    HostConfig(rto_min=RTO_MIN_FLOOR)
    with pytest.raises(ValueError, match="rto_min must be at least"):
        HostConfig(rto_min=ACK_DELAY_MAX)
    with pytest.raises(ValueError, match="rto_min <= rto_initial <= rto_max"):
        HostConfig(rto_initial=2.0)


def _frame_types(wire: bytes) -> list[FrameType]:
    return [f.type for f in FrameDecoder(4096).feed(wire) if isinstance(f, Frame)]


def _quiet_link(
    window: int, ack_delay: float = 0.005, features: Features = ctl.FEATURES_BEFORE_ACK_IN_DATA
) -> SimLink:
    """A connected link with no timer traffic of its own (no time sync) and nothing in flight;
    without ACK_IN_DATA unless ``features`` has it."""
    link = make_link(
        11,
        host_cfg=HostConfig(time_sync_interval=0, ack_delay=ack_delay, features=features),
        dev_cfg=DeviceConfig(
            window=window,
            mtu=64,
            max_message=256,
            time_sync_interval=0,
            ack_delay=ack_delay,
            features=features,
        ),
    )
    connect(link)
    link.run(0.5)
    link.drain()
    return link


def test_acks_ride_with_the_next_frame_on_a_wide_window() -> None:
    link = _quiet_link(window=8)
    host, device = link.host, link.device
    t = link.now
    host.call_service(CH_RESET, b"ping", now=t)
    request = host.data_to_send()
    assert _frame_types(request) == [FrameType.RELIABLE]
    (call,) = of_type(device.receive_data(request, link.device_time(t)), ServiceRequest)
    assert device.data_to_send() == b""  # the ACK of the request waits for the answer ...
    device.respond_service(call.channel, call.request_id, b"pong")
    answer = device.data_to_send()
    assert _frame_types(answer) == [FrameType.ACK, FrameType.RELIABLE]  # ... and goes with it
    (response,) = of_type(host.receive_data(answer, t), ServiceResponse)
    assert response.ok and response.payload == b"pong"
    assert host.data_to_send() == b""  # held too: the next request takes it along
    t += 0.001
    host.call_service(CH_RESET, b"again", now=t)
    request = host.data_to_send()
    assert _frame_types(request) == [FrameType.ACK, FrameType.RELIABLE]

    # With nothing else to send, a held ACK goes out once ack_delay has passed.
    (call,) = of_type(device.receive_data(request, link.device_time(t)), ServiceRequest)
    answer_then_ack_alone(link, call, t)
    assert host.stats.retransmits == device.stats.retransmits == 0


def answer_then_ack_alone(link: SimLink, call: ServiceRequest, t: float) -> None:
    """The board answers ``call``; the host, with nothing to send, holds its ACK of the answer
    for ack_delay (5 ms) and then sends it as an ACK frame."""
    host, device = link.host, link.device
    device.respond_service(call.channel, call.request_id, b"done")
    (response,) = of_type(host.receive_data(device.data_to_send(), t), ServiceResponse)
    assert response.payload == b"done"
    assert host.data_to_send() == b""
    due = host.next_deadline()
    assert due is not None and t < due <= t + 0.005 + 1e-9
    host.tick(due - 0.0001)
    assert host.data_to_send() == b""
    host.tick(due)
    assert _frame_types(host.data_to_send()) == [FrameType.ACK]


@pytest.mark.parametrize(("window", "ack_delay"), [(1, 0.005), (3, 0.005), (8, 0.0)])
def test_acks_go_at_once_on_narrow_windows_or_without_a_delay(
    window: int, ack_delay: float
) -> None:
    link = _quiet_link(window, ack_delay)
    host, device = link.host, link.device
    t = link.now
    host.call_service(CH_RESET, b"ping", now=t)
    (call,) = of_type(device.receive_data(host.data_to_send(), link.device_time(t)), ServiceRequest)
    assert _frame_types(device.data_to_send()) == [FrameType.ACK]
    device.respond_service(call.channel, call.request_id, b"pong")
    answer = device.data_to_send()
    assert _frame_types(answer) == [FrameType.RELIABLE]
    host.receive_data(answer, t)
    assert _frame_types(host.data_to_send()) == [FrameType.ACK]


def test_best_effort_gaps_and_lost_fragments_are_counted() -> None:
    stats = SequenceStats()
    tx = BestEffortSender(stats)
    rx = BestEffortReceiver(stats, max_message=1000)
    frames = tx.frames(1, b"a" * 10, 32) + tx.frames(2, bytes(100), 32) + tx.frames(3, b"c", 32)
    assert [f.frag for f in frames] == [Frag.WHOLE, Frag.FIRST, *[Frag.MIDDLE] * 2, Frag.LAST, 0]
    got = []
    for i, frame in enumerate(frames):
        if i == 2:
            continue  # lose one fragment
        if rx.accept(frame.seq):
            delivery = rx.receive(frame)
            if delivery is not None:
                got.append(delivery.payload)
    assert got == [b"a" * 10, b"c"]
    assert stats.be_frames_lost == 1
    assert stats.be_messages_incomplete == 1
    assert stats.be_fragments_discarded == 2
    assert stats.be_frames_sent - stats.be_frames_received == stats.be_frames_lost
    assert not rx.accept(frames[3].seq)  # late
    assert stats.be_frames_late == 1


# ---------------------------------------------------------------------------------------------
# sessions: handshake and table


def test_handshake_negotiates_limits_and_announces_table() -> None:
    dev_cfg = DeviceConfig(mtu=48, max_message=200, window=3, features=Features.TIME_SYNC)
    link = make_link(1, dev_cfg=dev_cfg, host_cfg=HostConfig(window=2, mtu=512))
    connect(link, 2.0)
    assert link.now < 0.1
    (hc,) = of_type(link.host_events, Connected)
    (dc,) = of_type(link.device_events, Connected)
    assert hc.link == dc.link
    assert (hc.link.mtu, hc.link.window) == (48, 2)
    assert (hc.link.device_max_message, hc.link.host_max_message) == (200, 1 << 20)
    assert hc.link.features == Features.TIME_SYNC
    assert hc.board == BOARD
    assert hc.endpoints == TOPICS == dc.topics
    assert (hc.host_session, hc.device_session) == (link.host.session_id, link.device.session_id)
    assert (dc.host_session, dc.device_session) == (hc.host_session, hc.device_session)
    assert not hc.resumed
    assert [e.endpoint for e in of_type(link.host_events, TopicAnnounced)] == list(TOPICS)
    assert link.host.topics == {e.channel: e for e in TOPICS}
    assert not errors(link.host_events + link.device_events)


def test_services_are_always_reliable() -> None:
    entry = TopicEntry(9, EntryKind.SERVICE_SERVER, "/s", "std_srvs/Trigger", MD5_TRIGGER)
    assert entry.reliable
    assert entry.to_msg().flags == ctl.EntryFlags.RELIABLE


def test_md5_mismatch_is_a_clear_error_on_both_ends() -> None:
    def check(entry: TopicEntry) -> ExpectedType | None:
        if entry.name == "/chatter":
            return ExpectedType("std_msgs/Int32", MD5_INT32)
        return ExpectedType(entry.type_name, entry.md5)

    link = make_link(2, type_check=check)
    connect(link)
    (host_err,) = errors(link.host_events)
    (dev_err,) = errors(link.device_events)
    for err in (host_err, dev_err):
        assert isinstance(err, TopicMismatchError)
        assert isinstance(err, ProtocolMismatchError)
        text = str(err)
        for part in ("/chatter", "std_msgs/String", MD5_STRING, "std_msgs/Int32", MD5_INT32):
            assert part in text
        assert (err.topic, err.channel, err.board_md5, err.host_md5) == (
            "/chatter",
            CH_CHATTER,
            MD5_STRING,
            MD5_INT32,
        )
    assert CH_CHATTER not in link.host.topics
    assert CH_CHATTER not in link.device.accepted
    (connected,) = of_type(link.host_events, Connected)
    assert CH_CHATTER not in [e.channel for e in connected.topics]
    with pytest.raises(SessionError, match="channel 1"):
        link.device.publish(CH_CHATTER, b"x")


def test_wrong_direction_and_unknown_channels_raise() -> None:
    link = make_link(3)
    connect(link)
    with pytest.raises(SessionError, match="it is /chatter, a publisher"):
        link.host.publish(CH_CHATTER, b"x")
    with pytest.raises(SessionError, match="channel 99"):
        link.device.publish(99, b"x")
    with pytest.raises(SessionError, match="/get_time"):
        link.host.call_service(CH_GET_TIME, b"")


def test_actions_before_connection_fail_cleanly() -> None:
    host = HostSession()
    assert host.publish(1, b"x") is False
    request_id = host.call_service(1, b"")
    events = host.tick(0.0)
    (resp,) = of_type(events, ServiceResponse)
    assert resp.request_id == request_id and isinstance(resp.error, SessionError)
    assert host.stats.tx_refused == 2


@SETTINGS
@given(
    seed=st.integers(0, 2**16),
    loss=st.floats(0.0, 0.9),
)
def test_handshake_completes_or_reports_a_timeout(seed: int, loss: float) -> None:
    """Defaults; any loss: within handshake_timeout it connects or says why not, never hangs."""
    link = make_link(seed, h2d=lossy(loss, max_chunk=7), d2h=lossy(loss, max_chunk=7))
    timeout = link.host.config.handshake_timeout
    link.run(timeout + 0.5, until=lambda: link.host.connected and link.device.connected)
    if not (link.host.connected and link.device.connected):
        timeouts = [e for e in errors(link.host_events) if isinstance(e, HwBridgeTimeoutError)]
        if not timeouts:  # the host connected, and the board's table stalled (READY lost)
            assert of_type(link.host_events, Connected), "neither connected nor reported"
            assert of_type(link.host_events, Disconnected)
            return
        assert "no connected session after 3.0 s" in str(timeouts[0])


def test_silent_board_is_reported_once_after_handshake_timeout() -> None:
    link = make_link(4, d2h=Faults(cut=True))
    link.run(10.0)
    reports = errors(link.host_events)
    assert len(reports) == 1
    assert isinstance(reports[0], HwBridgeTimeoutError)
    assert "no HELLO from the board" in str(reports[0])
    assert link.host.stats.hellos_sent == pytest.approx(10 / 0.25, abs=2)


# ---------------------------------------------------------------------------------------------
# sessions: reliable and best-effort traffic under loss


@SETTINGS
@given(
    **LINK_FAULTS,
    window=st.integers(1, 12),
    ack_delay=st.sampled_from([0.0, 0.005, 0.01]),
    mtu=st.sampled_from([24, 32, 64, 100]),
    sizes=st.lists(st.integers(0, 300), min_size=1, max_size=25),
)
def test_reliable_traffic_arrives_exactly_once_in_order(
    seed: int,
    loss: float,
    duplicate: float,
    reorder: float,
    window: int,
    ack_delay: float,
    mtu: int,
    sizes: list[int],
) -> None:
    faults: dict[str, Any] = {"duplicate": duplicate, "reorder": reorder, "max_chunk": 9}
    link = make_link(
        seed,
        host_cfg=HostConfig(ack_delay=ack_delay, **PATIENT),
        dev_cfg=DeviceConfig(
            mtu=mtu,
            max_message=400,
            window=window,
            tx_queue_limit=1 << 20,
            ack_delay=ack_delay,
            **PATIENT,
        ),
        h2d=lossy(loss, **faults),
        d2h=lossy(loss, **faults),
    )
    connect(link, 60.0)
    rng = random.Random(seed)
    up = [rng.randbytes(n) for n in sizes]
    down = [rng.randbytes(n) for n in reversed(sizes)]
    for a, b in zip(up, down, strict=True):
        assert link.device.publish(CH_STATUS, a)
        assert link.host.publish(CH_CONFIG, b)
    link.flush()
    done = link.run(
        600.0,
        until=lambda: (
            len(messages(link.host_events, CH_STATUS)) >= len(up)
            and len(messages(link.device_events, CH_CONFIG)) >= len(down)
        ),
    )
    assert done
    link.run(1.0)  # late duplicates, if any, would show up now
    assert messages(link.host_events, CH_STATUS) == up
    assert messages(link.device_events, CH_CONFIG) == down
    assert not of_type(link.host_events + link.device_events, Disconnected)
    if duplicate > 0.05 and loss > 0.05:
        assert link.host.stats.duplicates + link.device.stats.duplicates > 0


@SETTINGS
@given(
    seed=st.integers(0, 2**16),
    drop=st.floats(0.0, 0.3),
    corrupt=st.floats(0.0, 0.2),
    sizes=st.lists(st.integers(1, 150), min_size=1, max_size=40),
)
def test_best_effort_drops_are_counted_exactly(
    seed: int, drop: float, corrupt: float, sizes: list[int]
) -> None:
    dev_cfg = DeviceConfig(max_message=256, **PATIENT)
    link = make_link(seed, host_cfg=HostConfig(**PATIENT), dev_cfg=dev_cfg)
    connect(link)  # clean start: each end syncs on the peer's first frame
    bad = Faults(drop=drop, corrupt=corrupt, max_chunk=5)
    link.h2d.faults, link.d2h.faults = bad, Faults(drop=drop, corrupt=corrupt, max_chunk=5)
    rng = random.Random(seed)
    # binary payloads, so that a corrupted frame is never taken for text
    up = [bytes([0x80 | rng.randrange(128) for _ in range(n)]) for n in sizes]
    down = [bytes([0x80 | rng.randrange(128) for _ in range(n)]) for n in sizes]
    for a, b in zip(up, down, strict=True):
        assert link.device.publish(CH_CHATTER, a)
        assert link.host.publish(CH_CMD, b)
        link.flush()
        link.run(0.05)
    link.h2d.faults = link.d2h.faults = Faults()  # clean tail: heartbeats reveal trailing losses
    link.run(1.0)
    link.drain()
    host, dev = link.host.stats, link.device.stats
    assert dev.be_frames_sent - host.be_frames_received == host.be_frames_lost
    assert host.be_frames_sent - dev.be_frames_received == dev.be_frames_lost
    assert host.be_frames_lost == link.d2h.stats.be_dropped + link.d2h.stats.be_corrupted
    assert dev.be_frames_lost == link.h2d.stats.be_dropped + link.h2d.stats.be_corrupted
    assert host.bad_frames == link.d2h.stats.corrupted
    assert dev.bad_frames == link.h2d.stats.corrupted
    assert host.be_frames_late == dev.be_frames_late == 0
    got_up = messages(link.host_events, CH_CHATTER)
    got_down = messages(link.device_events, CH_CMD)
    assert is_subsequence(got_up, up) and is_subsequence(got_down, down)
    if drop + corrupt == 0:
        assert (got_up, got_down) == (up, down)


@SETTINGS
@given(
    seed=st.integers(0, 2**16),
    loss=st.floats(0.0, 0.2),
    duplicate=st.floats(0.0, 0.3),
    reorder=st.floats(0.0, 0.5),
)
def test_best_effort_under_reordering_and_duplication(
    seed: int, loss: float, duplicate: float, reorder: float
) -> None:
    link = make_link(seed, host_cfg=HostConfig(**PATIENT), dev_cfg=DeviceConfig(**PATIENT))
    connect(link)
    link.d2h.faults = lossy(loss, duplicate=duplicate, reorder=reorder, reorder_delay=0.05)
    sent = [struct.pack("<I", i) + bytes(i % 90) for i in range(60)]
    for payload in sent:
        link.device.publish(CH_CHATTER, payload)
        link.flush()
        link.run(0.01)
    link.d2h.faults = Faults()
    link.run(1.0)
    link.drain()
    got = messages(link.host_events, CH_CHATTER)
    assert is_subsequence(got, sent)  # never duplicated, never out of order
    host, dev = link.host.stats, link.device.stats
    assert dev.be_frames_sent - host.be_frames_received == host.be_frames_lost
    assert host.be_frames_late >= 0
    if loss == duplicate == reorder == 0:
        assert got == sent


@settings(max_examples=3, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**16), loss=st.floats(0.05, 0.2))
def test_large_messages_fragment_and_reassemble_under_loss(seed: int, loss: float) -> None:
    dev_cfg = DeviceConfig(
        mtu=1024, max_message=70_000, window=4, tx_queue_limit=1 << 20, **PATIENT
    )
    link = make_link(
        seed,
        host_cfg=HostConfig(**PATIENT),
        dev_cfg=dev_cfg,
        h2d=lossy(loss, max_chunk=200),
        d2h=lossy(loss, max_chunk=200),
    )
    connect(link, 60.0)
    rng = random.Random(seed)
    big_up, big_down = rng.randbytes(65536), rng.randbytes(65536)
    assert link.device.publish(CH_STATUS, big_up)
    assert link.host.publish(CH_CONFIG, big_down)
    assert link.run(
        300.0,
        until=lambda: (
            bool(messages(link.host_events, CH_STATUS))
            and bool(messages(link.device_events, CH_CONFIG))
        ),
    )
    assert messages(link.host_events, CH_STATUS) == [big_up]
    assert messages(link.device_events, CH_CONFIG) == [big_down]
    assert link.host.stats.retransmits + link.device.stats.retransmits > 0


def test_device_limits_are_honoured() -> None:
    dev_cfg = DeviceConfig(mtu=32, max_message=48, window=2)
    long_type = "very_long_package_name/VeryLongMessageTypeName" * 3

    def check(entry: TopicEntry) -> ExpectedType | None:
        return ExpectedType(long_type, MD5_INT32) if entry.channel == CH_CHATTER else None

    link = make_link(5, dev_cfg=dev_cfg, type_check=check)
    connect(link)
    assert link.host.publish(CH_CONFIG, bytes(48))
    assert link.host.publish(CH_CMD, bytes(range(48)))  # best effort, in two fragments
    with pytest.raises(SessionError, match="at most 48 bytes"):
        link.host.publish(CH_CONFIG, bytes(49))
    with pytest.raises(SessionError, match="at most 48 bytes"):
        link.host.call_service(CH_RESET, bytes(48))  # + the request id (SHORT_CALLS: 1 byte)
    link.host.log(LogLevel.INFO, "x" * 500)  # HOST_LOG is off on this board: refused
    link.run(1.0)
    assert messages(link.device_events, CH_CONFIG) == [bytes(48)]
    assert messages(link.device_events, CH_CMD) == [bytes(range(48))]
    # the host never sent the device a frame above its mtu (the TOPIC_ACK detail was cut)
    assert link.h2d.stats.max_payload <= 32
    decoder = FrameDecoder(max_payload=32)
    frames = decoder.feed(b"".join(link.h2d_log))
    assert all(isinstance(f, Frame) for f in frames)
    assert link.device.stats.oversize_messages == 0
    (err,) = errors(link.device_events)
    assert isinstance(err, TopicMismatchError)
    assert long_type.startswith(err.host_type)
    assert len(err.host_type) <= 48 - 19


# ---------------------------------------------------------------------------------------------
# services, parameters, logs


def _serve_device(link: SimLink, answer: Callable[[bytes], bytes] | None) -> None:
    def on_device(event: Event) -> None:
        if isinstance(event, ServiceRequest) and answer is not None:
            link.device.respond_service(event.channel, event.request_id, answer(event.payload))

    link.on_device = on_device


@pytest.mark.parametrize(
    "dev_features",
    [DeviceConfig().features, DeviceConfig().features & ~Features.SERVICE_CHANNELS],
    ids=["service channels", "SERVICE_REQUEST"],
)
@SETTINGS
@given(seed=st.integers(0, 2**16), loss=st.floats(0.0, 0.3), calls=st.integers(1, 8))
def test_services_complete_in_both_directions_under_loss(
    dev_features: Features, seed: int, loss: float, calls: int
) -> None:
    """Either form of the calls (the board's features decide): each call both ways is
    answered once, with its own answer."""
    link = make_link(
        seed,
        host_cfg=HostConfig(**PATIENT),
        dev_cfg=DeviceConfig(window=2, features=dev_features, **PATIENT),
        h2d=lossy(loss, duplicate=0.05, max_chunk=11),
        d2h=lossy(loss, duplicate=0.05, max_chunk=11),
    )
    connect(link, 60.0)

    def on_host(event: Event) -> None:
        if isinstance(event, ServiceRequest):
            assert event.channel == CH_GET_TIME
            link.host.respond_service(event.channel, event.request_id, b"t" + event.payload)

    _serve_device(link, lambda p: b"r" + p)
    link.on_host = on_host
    host_ids = {link.host.call_service(CH_RESET, bytes([i])): i for i in range(calls)}
    dev_ids = {link.device.call_service(CH_GET_TIME, bytes([i])): i for i in range(calls)}
    link.flush()

    def done() -> bool:
        return (
            len(of_type(link.host_events, ServiceResponse)) >= calls
            and len(of_type(link.device_events, ServiceResponse)) >= calls
        )

    assert link.run(300.0, until=done)
    for events, ids, prefix in (
        (link.host_events, host_ids, b"r"),
        (link.device_events, dev_ids, b"t"),
    ):
        responses = of_type(events, ServiceResponse)
        assert sorted(r.request_id for r in responses) == sorted(ids)
        for r in responses:
            assert r.ok, r.error
            assert r.payload == prefix + bytes([ids[r.request_id]])


@SETTINGS
@given(seed=st.integers(0, 2**16), loss=st.floats(0.0, 0.6))
def test_service_calls_resolve_or_time_out_at_defaults(seed: int, loss: float) -> None:
    """Default timers, heavy loss: every call gets exactly one response within its timeout."""
    link = make_link(seed)
    connect(link)
    link.h2d.faults = link.d2h.faults = lossy(loss)
    _serve_device(link, lambda p: p)
    ids = [link.host.call_service(CH_RESET, bytes([i]), timeout=2.0) for i in range(5)]
    start = link.now
    link.run(2.0 + 0.05)
    responses = of_type(link.host_events, ServiceResponse)
    assert sorted(r.request_id for r in responses) == sorted(ids)
    for r in responses:
        assert r.ok or isinstance(r.error, (HwBridgeTimeoutError, SessionResetError))
    assert link.now - start <= 2.05


def test_service_timeout_and_error_answers() -> None:
    link = make_link(6)
    connect(link)
    request_id = link.host.call_service(CH_RESET, b"", timeout=1.5)
    start = link.now
    link.run(1.49)
    assert not of_type(link.host_events, ServiceResponse)
    link.run(0.1)
    (resp,) = of_type(link.host_events, ServiceResponse)
    assert resp.request_id == request_id
    assert isinstance(resp.error, HwBridgeTimeoutError)
    assert "/reset" in str(resp.error)
    assert 1.5 <= link.now - start <= 1.6
    # the late answer is ignored
    (req,) = of_type(link.device_events, ServiceRequest)
    assert link.device.respond_service(req.channel, req.request_id, b"late")
    link.run(0.5)
    assert len(of_type(link.host_events, ServiceResponse)) == 1

    # a failing server
    def failing_server(event: Event) -> None:
        if isinstance(event, ServiceRequest):
            link.device.respond_service(event.channel, event.request_id, error="driver fault")

    link.on_device = failing_server
    link.host.call_service(CH_RESET, b"")
    link.run(0.5)
    resp = of_type(link.host_events, ServiceResponse)[-1]
    assert isinstance(resp.error, SessionError) and "driver fault" in str(resp.error)


def _answer_params(link: SimLink, table: dict[str, Any]) -> None:
    def on_host(event: Event) -> None:
        if isinstance(event, ParamRequest):
            link.host.answer_param(event.request_id, table.get(event.name))

    link.on_host = on_host


def test_params_typed_values_not_found_and_push() -> None:
    link = make_link(7, dev_cfg=DeviceConfig(max_message=128))
    connect(link)
    _answer_params(
        link,
        {"kp": 2, "name": "uno", "gains": [1, 2.5, 3], "on": True, "big": list(range(40))},
    )
    dev = link.device
    asks = {
        dev.get_param("kp", ParamType.FLOAT32): ("kp", ParamStatus.OK, 2.0),
        dev.get_param("name"): ("name", ParamStatus.OK, "uno"),
        dev.get_param("gains", ParamType.FLOAT32_LIST, max_count=4): (
            "gains",
            ParamStatus.OK,
            (1.0, 2.5, 3.0),
        ),
        dev.get_param("gains", ParamType.FLOAT32_LIST, max_count=2): (
            "gains",
            ParamStatus.TOO_LARGE,
            None,
        ),
        dev.get_param("on", ParamType.BOOL, subscribe=True): ("on", ParamStatus.OK, True),
        dev.get_param("missing"): ("missing", ParamStatus.NOT_FOUND, None),
        dev.get_param("name", ParamType.INT32): ("name", ParamStatus.TYPE_MISMATCH, None),
        dev.get_param("big", ParamType.INT32_LIST): ("big", ParamStatus.TOO_LARGE, None),
    }
    link.run(1.0)
    requests = of_type(link.host_events, ParamRequest)
    assert [r.name for r in requests] == [a[0] for a in asks.values()]
    assert requests[4].subscribe and requests[4].type == ParamType.BOOL
    responses = {r.request_id: r for r in of_type(link.device_events, ParamResponse)}
    assert responses.keys() == asks.keys()
    for request_id, (name, status, value) in asks.items():
        r = responses[request_id]
        assert (r.name, r.status, r.value, r.error) == (name, status, value, None)
    assert link.host.param_subscriptions == {"on": ParamType.BOOL}
    assert link.host.push_param("on", 0)
    assert not link.host.push_param("kp", 3)  # not subscribed
    link.run(0.5)
    assert of_type(link.device_events, ParamUpdate) == [ParamUpdate("on", False)]


def test_param_request_times_out_when_the_host_does_not_answer() -> None:
    link = make_link(8)
    connect(link)
    request_id = link.device.get_param("kp", timeout=0.7)
    link.run(0.69)
    assert not of_type(link.device_events, ParamResponse)
    link.run(0.1)
    (resp,) = of_type(link.device_events, ParamResponse)
    assert resp.request_id == request_id and resp.status is None
    assert isinstance(resp.error, HwBridgeTimeoutError) and "kp" in str(resp.error)
    (req,) = of_type(link.host_events, ParamRequest)
    assert link.host.answer_param(req.request_id, 1)  # too late: ignored by the board
    link.run(0.5)
    assert len(of_type(link.device_events, ParamResponse)) == 1


@SETTINGS
@given(seed=st.integers(0, 2**16), loss=st.floats(0.0, 0.3))
def test_params_complete_under_loss(seed: int, loss: float) -> None:
    link = make_link(
        seed,
        host_cfg=HostConfig(**PATIENT),
        dev_cfg=DeviceConfig(**PATIENT),
        h2d=lossy(loss),
        d2h=lossy(loss),
    )
    connect(link, 60.0)
    _answer_params(link, {f"p{i}": i for i in range(5)})
    ids = [link.device.get_param(f"p{i}", ParamType.INT32) for i in range(6)]
    assert link.run(300.0, until=lambda: len(of_type(link.device_events, ParamResponse)) == 6)
    got = {r.request_id: (r.status, r.value) for r in of_type(link.device_events, ParamResponse)}
    assert got == {
        **{ids[i]: (ParamStatus.OK, i) for i in range(5)},
        ids[5]: (ParamStatus.NOT_FOUND, None),
    }


def test_logs_in_both_directions() -> None:
    link = make_link(
        9, dev_cfg=DeviceConfig(features=Features.TIME_SYNC | Features.HOST_LOG, max_message=40)
    )
    connect(link)
    assert link.device.log(LogLevel.WARN, "battery low: 6.1 V")
    assert link.device.log(LogLevel.FATAL, "é" * 100)  # the host accepts long lines
    assert link.host.log(LogLevel.INFO, "ü" * 100)  # cut to fit the board's 40 bytes
    link.run(0.5)
    host_logs = of_type(link.host_events, Log)
    assert host_logs == [Log(LogLevel.WARN, "battery low: 6.1 V"), Log(LogLevel.FATAL, "é" * 100)]
    (dev_log,) = of_type(link.device_events, Log)
    assert dev_log == Log(LogLevel.INFO, "ü" * 19)
    # without HOST_LOG the host does not send logs
    link2 = make_link(10)
    connect(link2)
    assert not link2.host.log(LogLevel.INFO, "x")


# ---------------------------------------------------------------------------------------------
# time sync


@pytest.mark.parametrize(("h2d_latency", "d2h_latency"), [(0.002, 0.002), (0.001, 0.009)])
def test_time_sync_measures_offset_and_rtt(h2d_latency: float, d2h_latency: float) -> None:
    drift = 50e-6
    link = make_link(
        11,
        h2d=Faults(latency=h2d_latency),
        d2h=Faults(latency=d2h_latency),
        clock_offset=1234.5,
        clock_drift=drift,
        host_cfg=HostConfig(epoch_offset=1.7e9),
    )
    connect(link)
    link.run(12.0)
    dev_syncs = of_type(link.device_events, TimeSynced)
    host_syncs = of_type(link.host_events, TimeSynced)
    assert len(dev_syncs) >= 3 and len(host_syncs) >= 3  # at connect, then every 5 s
    rtt = h2d_latency + d2h_latency
    asym = abs(h2d_latency - d2h_latency) / 2
    assert dev_syncs[-1].rtt == pytest.approx(rtt, abs=1e-5)
    assert host_syncs[-1].rtt == pytest.approx(rtt, abs=1e-5)
    now = link.now
    true_host = now + 1.7e9
    dev_now = link.device_time(now)
    # the board's view of host time
    assert link.device.to_host_time(dev_now) == pytest.approx(true_host, abs=asym + 5e-4)
    assert link.device.to_device_time(true_host) == pytest.approx(dev_now, abs=asym + 5e-4)
    # the host's view of board timestamps (32-bit microsecond counter)
    board_us = round(dev_now * 1e6) % 2**32
    assert link.host.board_to_host(board_us) == pytest.approx(true_host, abs=asym + 5e-4)
    assert abs(link.host.host_to_board(true_host) - board_us) <= (asym + 5e-4) * 1e6


def test_time_conversions_need_a_sync() -> None:
    with pytest.raises(SessionError, match="no time sync"):
        HostSession().board_to_host(0)
    with pytest.raises(SessionError, match="no time sync"):
        DeviceSession(BOARD).to_host_time(0.0)


# ---------------------------------------------------------------------------------------------
# resets, dead links, close


@SETTINGS
@given(seed=st.integers(0, 2**16), loss=st.floats(0.0, 0.2), at=st.floats(0.0, 1.0))
def test_board_reset_renegotiates_without_stale_state(seed: int, loss: float, at: float) -> None:
    link = make_link(
        seed,
        host_cfg=HostConfig(**PATIENT),
        dev_cfg=DeviceConfig(window=2, **PATIENT),
        h2d=lossy(loss),
        d2h=lossy(loss),
    )
    connect(link, 60.0)
    old_id = link.device.session_id
    call = link.host.call_service(CH_RESET, b"never answered")
    for i in range(5):
        link.host.publish(CH_CONFIG, b"old %d" % i)
    link.flush()
    link.run(at)
    new_device = DeviceSession(
        BOARD, TOPICS, DeviceConfig(window=2, **PATIENT), rng=random.Random(seed + 7)
    )
    before = len(link.device_events)
    link.reset_device(new_device)
    assert link.run(
        60.0, until=lambda: len(of_type(link.host_events, Connected)) == 2 and new_device.connected
    )
    new_events = link.device_events[before:]
    # the host failed the pending call with a clear error, then reconnected to the new board
    (resp,) = [r for r in of_type(link.host_events, ServiceResponse) if r.request_id == call]
    assert isinstance(resp.error, SessionResetError)
    assert "restarted" in str(resp.error) or "dropped the session" in str(resp.error)
    (disc,) = of_type(link.host_events, Disconnected)
    assert isinstance(disc.error, SessionResetError)
    reconnected = of_type(link.host_events, Connected)[-1]
    assert reconnected.device_session == new_device.session_id != old_id
    assert not reconnected.resumed
    # nothing of the old session reaches the new board
    assert not of_type(new_events, Message) and not of_type(new_events, ServiceRequest)
    # and the new session works
    assert link.host.publish(CH_CONFIG, b"new")
    link.flush()
    assert link.run(60.0, until=lambda: bool(messages(link.device_events[before:], CH_CONFIG)))
    assert messages(link.device_events[before:], CH_CONFIG) == [b"new"]
    assert link.host.stats.peer_resets >= 1
    # the new board's best-effort seq space restarted at 0: the host followed, dropped nothing
    assert link.host.stats.be_frames_late == 0
    assert link.host.stats.be_resyncs == 2


@pytest.mark.parametrize("cut", ["both", "h2d", "d2h"])
def test_dead_link_detected_within_one_second_at_defaults(cut: str) -> None:
    link = make_link(12)
    connect(link)
    link.run(2.0)
    pending = link.device.call_service(CH_GET_TIME, b"")
    link.flush()
    t_cut = link.now
    if cut in ("both", "h2d"):
        link.h2d.faults = Faults(cut=True)
    if cut in ("both", "d2h"):
        link.d2h.faults = Faults(cut=True)
    link.run(1.0, until=lambda: not link.host.connected and not link.device.connected)
    assert link.now - t_cut <= 1.0
    for events in (link.host_events, link.device_events):
        (disc,) = of_type(events, Disconnected)
        assert isinstance(disc.error, HwBridgeError)
    if cut == "both":
        for events in (link.host_events, link.device_events):
            (disc,) = of_type(events, Disconnected)
            assert isinstance(disc.error, HwBridgeTimeoutError)
            assert "link lost" in disc.reason
    (resp,) = of_type(link.device_events, ServiceResponse)
    assert resp.request_id == pending and isinstance(resp.error, SessionResetError)
    # the link comes back: the same board session resumes
    link.h2d.faults = link.d2h.faults = Faults()
    connect(link, 5.0)
    assert of_type(link.host_events, Connected)[-1].resumed
    assert link.host.stats.sessions == 2
    link.run(link.device.config.service_timeout + 1.0)
    assert len(of_type(link.device_events, ServiceResponse)) == 1  # failed once, not again


def test_time_this_end_did_not_run_is_not_the_peers_silence() -> None:
    """PROTOCOL.md 2.9: a host process starved for 3 s, whose timers run before it gets to read
    what the board sent meanwhile (a bus reader thread starved too), keeps the session, and so
    does a board that was stopped with it; a board
    that really went silent is still found within link_timeout of the host running again."""
    link = make_link(16)
    connect(link)
    link.run(1.0)
    host = link.host
    stalled_at = link.now
    # the machine stalls: neither end runs for 2.5 s, then the board runs alone for 0.5 s
    link.now += 2.5
    while link.now < stalled_at + 3.0:
        link.now += 0.01
        dnow = link.device_time(link.now)
        for chunk in link.h2d.pop_due(link.now):
            link.device.receive_data(chunk, dnow)
        link.device.tick(dnow)
        link.d2h.send(link.device.data_to_send(), link.now)
    events = host.tick(link.now)  # timers first, the backlog after
    assert not of_type(events, Disconnected), events
    assert host.connected and host.stats.stalls == 1
    assert link.run(0.5, until=lambda: bool(link.host.stats.heartbeats_sent))
    assert host.connected and not of_type(link.host_events, Disconnected)
    assert link.device.connected and not of_type(link.device_events, Disconnected)
    assert link.device.stats.stalls == 1
    # a real silence after a stall: the board is cut off while the host is stalled again
    link.d2h.faults = Faults(cut=True)
    resumed = link.now + 2.0
    assert not of_type(host.tick(resumed), Disconnected)
    link.now = resumed
    assert link.run(2.0, until=lambda: not link.host.connected)
    assert link.now - resumed <= host.config.link_timeout + 0.05
    assert host.stats.stalls == 2 and host.stats.link_losses == 1


def test_retry_limit_declares_the_link_dead() -> None:
    """Heartbeats get through but acknowledgements do not: the board gives up after 10 tries.
    (Without ACK_IN_DATA: with it, the ACKs ride in the host's data frames.)"""
    link = make_link(15, host_cfg=HostConfig(features=ctl.FEATURES_BEFORE_ACK_IN_DATA))
    connect(link)
    link.h2d.faults = Faults(drop_types=frozenset({FrameType.ACK}))
    assert link.device.publish(CH_STATUS, b"unacknowledged")
    link.flush()
    start = link.now
    assert link.run(30.0, until=lambda: bool(of_type(link.device_events, Disconnected)))
    (disc,) = of_type(link.device_events, Disconnected)
    assert isinstance(disc.error, HwBridgeTimeoutError)
    assert "not acknowledged after 10 retransmissions" in str(disc.error)
    # measured RTO 0.05 s (its floor), doubling per try, capped at 1 s:
    # 0.05 + 0.1 + 0.2 + 0.4 + 0.8 + 5 x 1 s, then the 10th retransmission's own 1 s
    assert link.device.rtt == pytest.approx(0.004)
    assert link.now - start == pytest.approx(7.55, abs=0.02)
    assert link.device.stats.retransmits == 10
    assert link.device.stats.link_losses == 1
    link.run(0.5)  # the board starts over; the host sees it dropped the session
    (host_disc,) = of_type(link.host_events, Disconnected)
    assert "dropped the session" in host_disc.reason


@SETTINGS
@given(seed=st.integers(0, 2**16), loss=st.floats(0.0, 0.1))
def test_idle_link_stays_up_at_defaults(seed: int, loss: float) -> None:
    link = make_link(seed, h2d=lossy(loss), d2h=lossy(loss))
    connect(link)
    link.run(20.0)
    assert not of_type(link.host_events + link.device_events, Disconnected)
    assert link.host.stats.heartbeats_sent > 100


def test_link_statistics_from_both_ends() -> None:
    faults: dict[str, Any] = {"drop": 0.1, "corrupt": 0.1, "duplicate": 0.1, "latency": 0.002}
    link = make_link(
        14,
        host_cfg=HostConfig(**PATIENT),
        dev_cfg=DeviceConfig(window=4, max_message=256, tx_queue_limit=1 << 20, **PATIENT),
        h2d=Faults(**faults),
        d2h=Faults(**faults),
    )
    connect(link, 60.0)
    for i in range(100):
        assert link.device.publish(CH_STATUS, bytes([i]) * 100)
        assert link.host.publish(CH_CONFIG, bytes([i]) * 100)
        assert link.device.publish(CH_CHATTER, bytes([i]) * 10)
    link.flush()
    assert link.run(
        300,
        until=lambda: (
            len(messages(link.host_events, CH_STATUS)) == 100
            and len(messages(link.device_events, CH_CONFIG)) == 100
        ),
    )
    for end, incoming, outgoing in (
        (link.host, link.d2h.stats, link.h2d.stats),
        (link.device, link.h2d.stats, link.d2h.stats),
    ):
        stats = end.stats
        assert stats.frames_sent == outgoing.frames
        # (a corrupted frame that reads as text is reported as DebugOutput; duplicates repeat)
        assert 0 < stats.crc_errors <= stats.bad_frames <= 2 * incoming.corrupted
        assert stats.retransmits > 0 and stats.duplicates > 0
        assert stats.be_frames_lost > 0 and stats.acks_sent > 0 and stats.acks_received > 0
        assert stats.rel_messages_received >= 100
        assert stats.bytes_sent > 100 * 100 and stats.bytes_received > 100 * 100
        # Karn: only frames sent once are timed, so loss does not inflate the estimate
        assert stats.rtt == pytest.approx(0.004, abs=0.001)
        assert stats.as_dict()["rtt"] == stats.rtt


def test_close_sends_goodbye() -> None:
    link = make_link(13)
    connect(link)
    (disc,) = link.host.close()
    assert isinstance(disc, Disconnected) and disc.reason == "closed by this end"
    assert link.host.state is SessionState.CLOSED
    link.flush()
    link.run(0.1)
    (disc,) = of_type(link.device_events, Disconnected)
    assert "closed" in disc.reason
    assert link.device.state is SessionState.HANDSHAKE
    assert link.host.next_deadline() is None


def test_peer_problems_are_reported() -> None:
    host = HostSession(rng=random.Random(1))
    host.tick(0.0)
    own = host.data_to_send()
    events = host.receive_data(own, 0.01)  # a loopback link echoes the HELLO
    (err,) = errors(events)
    assert "loopback" in str(err)
    other_host = HostSession(rng=random.Random(2))
    other_host.tick(0.0)
    (err,) = errors(host.receive_data(other_host.data_to_send(), 0.02))
    assert "also a host" in str(err)
    future = encode_frame(Frame(FrameType.BEST_EFFORT, 0, 5, bytes([1, 2]) + bytes(19)))
    (err,) = errors(host.receive_data(future, 0.03))
    assert isinstance(err, ProtocolMismatchError) and "version 2" in str(err)
    again = encode_frame(Frame(FrameType.BEST_EFFORT, 0, 6, bytes([1, 2]) + bytes(19)))
    assert not errors(host.receive_data(again, 0.04))  # reported once
    (text,) = of_type(host.receive_data(b"booting...\r\n\x00", 0.05), DebugOutput)
    assert text.data == b"booting...\r\n"
    # CRC-valid frames with version bits 2: reported from the second one on (noise can pass)
    body = bytes([0x80, 0, 0, 1])
    crc = crc16(body)
    v2 = cobs_encode(body + bytes([crc & 0xFF, crc >> 8])) + b"\x00"
    assert not errors(host.receive_data(v2, 0.06))
    (err,) = errors(host.receive_data(v2, 0.07))
    assert "another native protocol version" in str(err)


# ---------------------------------------------------------------------------------------------
# golden vectors


class _FixedRandom(random.Random):
    """An RNG whose every draw is 0 (so ISNs are 0 in the vectors)."""

    def getrandbits(self, k: int) -> int:
        return 0

    def randrange(self, *args: Any, **kwargs: Any) -> int:
        return 1


HOST_ID = 0x12345678
DEVICE_ID = 0xCAFEF00D
VECTOR_TOPICS = (
    TopicEntry(1, EntryKind.PUBLISHER, "/chatter", "std_msgs/String", MD5_STRING),
    TopicEntry(2, EntryKind.SERVICE_SERVER, "/reset", "std_srvs/Trigger", MD5_TRIGGER),
)


def _jsonable(value: Any) -> Any:
    if isinstance(value, Enum):
        return value.name if not isinstance(value, Features) else int(value)
    if isinstance(value, bytes):
        return value.hex()
    if isinstance(value, tuple):
        return [_jsonable(v) for v in value]
    if is_dataclass(value) and not isinstance(value, type):
        return {f.name: _jsonable(getattr(value, f.name)) for f in fields(value)}
    return value


def _describe(wire: bytes) -> dict[str, Any]:
    (frame,) = [f for f in FrameDecoder(max_payload=4096).feed(wire) if isinstance(f, Frame)]
    out: dict[str, Any] = {
        "type": frame.type.name,
        "channel": frame.channel,
        "seq": frame.seq,
        "frag": frame.frag.name,
        "payload": frame.payload.hex(),
    }
    if frame.ack is not None:
        out["ack"] = frame.ack
    if frame.type is not FrameType.ACK and frame.channel == 0 and frame.frag == Frag.WHOLE:
        msg = decode_control(frame.payload)
        out["control"] = {"opcode": msg.OPCODE.name, **_jsonable(msg)}
    return out


def _split(data: bytes) -> list[bytes]:
    """Wire bytes -> one entry per frame (a leading 0x00 stays with its frame)."""
    out: list[bytes] = []
    lead = b""
    for run in data.split(b"\x00")[:-1]:
        if not run:
            lead += b"\x00"
            continue
        out.append(lead + run + b"\x00")
        lead = b""
    return out


def build_transcript() -> list[dict[str, Any]]:
    """Run a scripted host/board exchange on a clean link and record every frame. Both ends
    are without ACK_IN_DATA, as before it (the transcript's bytes stay those of the first
    version); ``_ack_in_data_vectors`` shows the feature."""
    host = HostSession(
        HostConfig(epoch_offset=1_700_000_000.0, features=ctl.FEATURES_BEFORE_ACK_IN_DATA),
        session_id=HOST_ID,
        rng=_FixedRandom(),
    )
    board = BoardInfo("uno", bytes.fromhex("0102030405060708"), format_identity(GOLDEN_IDENTITY))
    device = DeviceSession(
        board,
        VECTOR_TOPICS,
        DeviceConfig(features=Features.TIME_SYNC | Features.PARAM_PUSH),
        session_id=DEVICE_ID,
        rng=_FixedRandom(),
    )
    steps: list[dict[str, Any]] = []
    dclock = 10.0  # the board's clock reads host time + 10 s

    def record(name: str, sender: HostSession | DeviceSession, note: str) -> bytes:
        data = sender.data_to_send()
        direction = "host->device" if sender is host else "device->host"
        frames = _split(data)
        for i, wire in enumerate(frames):
            label = name if len(frames) == 1 else f"{name}[{i}]"
            steps.append(
                {
                    "name": label,
                    "direction": direction,
                    "note": note,
                    "hex": wire.hex(" "),
                    "frame": _describe(wire),
                }
            )
        return data

    t = 0.0
    host.tick(t)
    d = record("hello_host", host, "host's first HELLO: knows no board yet (peer_session 0)")
    device.receive_data(d, t + dclock)
    d = record("hello_device", device, "board answers: echoes the host session id")
    host.receive_data(d, t)
    d = record("hello_host_established", host, "host established; ESTABLISHED flag set")
    device.receive_data(d, t + dclock)
    d = record("board_info", device, "board established; first reliable message (seq = isn 0)")
    host.receive_data(d, t)
    d = record("ack", host, "cumulative ACK of reliable seq 0, no selective bits")
    device.receive_data(d, t + dclock)
    d = record("topic_entry", device, "first table entry (window 1: one frame in flight)")
    host.receive_data(d, t)
    d = record("topic_ack", host, "host accepts channel 1, then acknowledges the frame")
    device.receive_data(d, t + dclock)
    d = record("topic_entry_service", device, "ACK for the host's TOPIC_ACK, then entry 2")
    host.receive_data(d, t)
    d = record("topic_ack_service", host, "")
    device.receive_data(d, t + dclock)
    d = record("table_end", device, "")
    host.receive_data(d, t)
    d = record("ready", host, "host is connected; READY tells the board")
    device.receive_data(d, t + dclock)
    d = record("ack_ready", device, "board is connected")
    host.receive_data(d, t)
    t = 0.001
    device.tick(t + dclock)
    d = record("time_request", device, "board's first time sync: t1 = its clock in us")
    host.receive_data(d, t + 0.001)
    d = record("time_response", host, "t1 echoed, t2 = t3 = host time (sec, nsec)")
    host.tick(t + 0.001)
    d2 = record("host_time_request", host, "host's own time sync request")
    device.receive_data(d + d2, t + 0.002 + dclock)
    d = record("host_time_response", device, "t1 echoed, t2 = t3 = board clock in us")
    host.receive_data(d, t + 0.003)
    device.publish(1, b"\x05\x00\x00\x00hello")
    d = record("topic_data", device, "best-effort std_msgs/String 'hello' on channel 1")
    host.receive_data(d, t + 0.003)
    device.publish(1, b"\x28\x00\x00\x00" + b"0123456789" * 4 + b"!" * 26)
    d = record(
        "topic_data_fragments", device, "70-byte message over mtu 64: FIRST carries the length"
    )
    host.receive_data(d, t + 0.004)
    host.call_service(2, b"")
    d = record("service_request", host, "host calls /reset (std_srvs/Trigger, empty request)")
    events = device.receive_data(d, t + 0.005 + dclock)
    (req,) = of_type(events, ServiceRequest)
    device.respond_service(req.channel, req.request_id, b"\x01\x02\x00\x00\x00ok")
    d = record("service_response", device, "ACK, then the response {success: true, 'ok'}")
    host.receive_data(d, t + 0.006)
    d = record("ack_service_response", host, "")
    device.receive_data(d, t + 0.006 + dclock)
    device.get_param("rate", ParamType.INT32, subscribe=True)
    d = record("param_get", device, "board asks for int32 'rate' and subscribes to changes")
    (preq,) = of_type(host.receive_data(d, t + 0.007), ParamRequest)
    host.answer_param(preq.request_id, 50)
    d = record("param_value", host, "ACK, then the answer 50")
    device.receive_data(d, t + 0.008 + dclock)
    d = record("ack_param_value", device, "")
    host.receive_data(d, t + 0.008)
    device.get_param("missing")
    d = record("param_get_missing", device, "")
    (preq,) = of_type(host.receive_data(d, t + 0.009), ParamRequest)
    host.answer_param(preq.request_id, None)
    d = record("param_not_found", host, "ACK, then NOT_FOUND")
    device.receive_data(d, t + 0.010 + dclock)
    d = record("ack_param_not_found", device, "")
    host.receive_data(d, t + 0.010)
    assert host.push_param("rate", 100)
    d = record("param_push", host, "pushed update of the subscribed 'rate': request id 0")
    device.receive_data(d, t + 0.011 + dclock)
    d = record("ack_param_push", device, "")
    host.receive_data(d, t + 0.011)
    device.log(LogLevel.WARN, "low battery")
    d = record("log", device, "")
    host.receive_data(d, t + 0.012)
    d = record("ack_log", host, "")
    device.receive_data(d, t + 0.012 + dclock)
    host.tick(t + 0.2)
    d = record("heartbeat_host", host, "nothing sent for heartbeat_interval")
    device.receive_data(d, t + 0.2 + dclock)
    host.close()
    record("goodbye", host, "host closes the session")
    return steps


FEATURES_BEFORE_SERVICE_CHANNELS = ctl.FEATURES_BEFORE_ACK_IN_DATA | Features.ACK_IN_DATA
"""Every feature a host had before SERVICE_CHANNELS (the ACK_IN_DATA vectors' host)."""
DEVICE_FEATURES_BEFORE_SERVICE_CHANNELS = (
    Features.TIME_SYNC | Features.PARAM_PUSH | Features.ACK_IN_DATA
)
"""DeviceConfig's features before SERVICE_CHANNELS (the ACK_IN_DATA vectors' board)."""


def _connected_vector_pair(
    host_features: Features | None, device_features: Features | None
) -> tuple[HostSession, DeviceSession, float]:
    """The transcript's host and board (their defaults unless features are given), connected
    on a clean link without recording; also the host time reached."""
    host_cfg = HostConfig(epoch_offset=1_700_000_000.0)
    dev_cfg = DeviceConfig()
    if host_features is not None:
        host_cfg = HostConfig(epoch_offset=1_700_000_000.0, features=host_features)
    if device_features is not None:
        dev_cfg = DeviceConfig(features=device_features)
    host = HostSession(host_cfg, session_id=HOST_ID, rng=_FixedRandom())
    board = BoardInfo("uno", bytes.fromhex("0102030405060708"), format_identity(GOLDEN_IDENTITY))
    device = DeviceSession(board, VECTOR_TOPICS, dev_cfg, session_id=DEVICE_ID, rng=_FixedRandom())
    dclock = 10.0
    t = 0.0
    host.tick(t)
    for _ in range(40):  # the handshake and the table, not recorded (held ACKs wait 5 ms)
        device.receive_data(host.data_to_send(), t + dclock)
        host.receive_data(device.data_to_send(), t)
        t += 0.002
        host.tick(t)
        device.tick(t + dclock)
    device.receive_data(host.data_to_send(), t + dclock)
    host.receive_data(device.data_to_send(), t)
    assert host.state is SessionState.CONNECTED and device.state is SessionState.CONNECTED
    return host, device, t


def _service_call_vectors(
    host: HostSession, device: DeviceSession, t: float, prefix: str, notes: tuple[str, str, str]
) -> list[dict[str, Any]]:
    """Two calls of /reset (channel 2, empty request) on a connected pair, answered
    {success: true, 'ok'} at once: their four frames, named ``{prefix}_request_1`` and so on.
    ``notes``: the first request's, the next request's and every response's."""
    dclock = 10.0
    steps: list[dict[str, Any]] = []

    def record(name: str, data: bytes, direction: str, note: str) -> bytes:
        (wire,) = _split(data)
        steps.append(
            {
                "name": name,
                "direction": direction,
                "note": note,
                "hex": wire.hex(" "),
                "frame": _describe(wire),
            }
        )
        return data

    for call, note in ((1, notes[0]), (2, notes[1])):
        host.call_service(2, b"")
        d = record(f"{prefix}_request_{call}", host.data_to_send(), "host->device", note)
        (req,) = of_type(device.receive_data(d, t + dclock), ServiceRequest)
        device.respond_service(req.channel, req.request_id, b"\x01\x02\x00\x00\x00ok")
        d = record(f"{prefix}_response_{call}", device.data_to_send(), "device->host", notes[2])
        (response,) = of_type(host.receive_data(d, t + 0.0001), ServiceResponse)
        assert response.ok and response.payload == b"\x01\x02\x00\x00\x00ok"
        assert host.data_to_send() == b""  # the host holds its ACK for the next frame
        t += 0.001
    return steps


def _ack_in_data_vectors() -> list[dict[str, Any]]:
    """Two service calls between a host and a board that both have ACK_IN_DATA (and, as before
    SERVICE_CHANNELS, the old service messages; otherwise as the transcript): no ACK frame,
    each data frame carries the ACK of the one before it (PROTOCOL.md 2.12 P)."""
    host, device, t = _connected_vector_pair(
        FEATURES_BEFORE_SERVICE_CHANNELS, DEVICE_FEATURES_BEFORE_SERVICE_CHANNELS
    )
    return _service_call_vectors(
        host,
        device,
        t,
        "ack_in_data",
        (
            "first call: the board's frames before it are acknowledged, so it carries no ACK",
            "the next call, within ack_delay: carries the ACK of the board's last reliable frame",
            "the response carries the ACK of the request: no ACK frame",
        ),
    )


DEVICE_FEATURES_BEFORE_SHORT_CALLS = DEVICE_FEATURES_BEFORE_SERVICE_CHANNELS | (
    Features.SERVICE_CHANNELS
)
"""DeviceConfig's features before SHORT_CALLS (the SERVICE_CHANNELS vectors' board)."""


def _service_channel_vectors() -> list[dict[str, Any]]:
    """The ACK_IN_DATA vectors' two calls between a host with its defaults and a board that has
    SERVICE_CHANNELS too, but not SHORT_CALLS: each request and response goes on the service's
    channel (2) as request id [status] body, without opcode and channel (PROTOCOL.md 2.8)."""
    host, device, t = _connected_vector_pair(None, DEVICE_FEATURES_BEFORE_SHORT_CALLS)
    assert host.link is not None and host.link.features & Features.SERVICE_CHANNELS
    assert not host.link.features & Features.SHORT_CALLS
    return _service_call_vectors(
        host,
        device,
        t,
        "service_channel",
        (
            "first call, on /reset's own channel 2: request id 1, the empty request",
            "the next call, within ack_delay: request id 2; carries the ACK of the response",
            "on the same channel: request id, status OK, the body; carries the ACK of the "
            "request: no ACK frame",
        ),
    )


def _short_call_vectors() -> list[dict[str, Any]]:
    """The same two calls between a host and a board with their defaults, which have
    SHORT_CALLS too: a request's head is its id, one byte, and an OK response's too
    (PROTOCOL.md 2.8)."""
    host, device, t = _connected_vector_pair(None, None)
    assert host.link is not None and host.link.features & Features.SHORT_CALLS
    return _service_call_vectors(
        host,
        device,
        t,
        "short_call",
        (
            "first call, on /reset's own channel 2: request id 1 in one byte, the empty request",
            "the next call, within ack_delay: request id 2; carries the ACK of the response",
            "on the same channel: the request id (bit 7 clear: OK, no status byte), the body; "
            "carries the ACK of the request: no ACK frame",
        ),
    )


def _sack_vector() -> dict[str, Any]:
    stats = SequenceStats()
    rx = ReliableReceiver(stats, isn=10, window=4, max_message=64)
    rx.receive(Frame(FrameType.RELIABLE, 1, 11, b"b"))
    rx.receive(Frame(FrameType.RELIABLE, 1, 13, b"d"))
    wire = encode_frame(rx.ack_frame())
    return {
        "name": "ack_selective",
        "direction": "either",
        "note": "window 4; seq 10 missing, 11 and 13 held: ack 9, bits 0 and 2 (seq 11, 13)",
        "hex": wire.hex(" "),
        "frame": _describe(wire),
    }


GOLDEN_IDENTITY = FirmwareIdentity(
    version="0.1.0",
    name="golden",
    library_version="0.1.0",
    schema_hash="5c0e1a2b",
    messages_hash="7d3f9e46",
)
"""The golden board's identity: example values (firmware/tests/session_harness.h defines them in
the C++ golden board), not this build's hashes."""


def _old_board_info_vector() -> dict[str, Any]:
    """BOARD_INFO as boards built before the firmware identity send it: the version text alone."""
    payload = ctl.BoardInfoMsg(2, "uno", bytes.fromhex("0102030405060708"), "0.1.0").encode()
    wire = encode_frame(Frame(FrameType.RELIABLE, 0, 0, payload))
    return {
        "name": "board_info_old",
        "direction": "device->host",
        "note": "the transcript's board_info as a board without identity sends it (unknown "
        "identity: the host connects, shows and warns nothing)",
        "hex": wire.hex(" "),
        "frame": _describe(wire),
    }


def build_vectors() -> dict[str, Any]:
    return {
        "description": (
            "Golden frames of the hwbridge native protocol, Part 2 (sessions). 'transcript' is "
            "one scripted exchange on a clean link between a host (session 0x12345678) and a "
            "board (session 0xcafef00d, DeviceConfig defaults: mtu 64, max_message 64, window "
            "1); both ISNs are 0; the board's clock reads host monotonic time + 10 s and the "
            "host's epoch offset is 1.7e9 s. Each entry: the wire bytes ('hex', a leading 00 "
            "is the optional delimiter HELLO frames carry), the decoded header and, for "
            "control messages, the decoded fields. Checked by "
            "tests/protocols/test_native_session.py; see protocols/PROTOCOL.md, Part 2."
        ),
        "protocol_version": ctl.PROTOCOL_VERSION,
        "transcript": build_transcript(),
        "extra": [
            _sack_vector(),
            _old_board_info_vector(),
            *_ack_in_data_vectors(),
            *_service_channel_vectors(),
            *_short_call_vectors(),
        ],
    }


def test_golden_vectors_match_the_code() -> None:
    """The checked-in vectors are exactly what the sessions produce."""
    stored = json.loads(VECTORS.read_text())
    assert stored == json.loads(json.dumps(build_vectors()))


def test_golden_vectors_decode_and_reencode() -> None:
    """Each vector's bytes decode to its stated meaning, and that meaning encodes to its bytes."""
    stored = json.loads(VECTORS.read_text())
    names = set()
    for vec in stored["transcript"] + stored["extra"]:
        names.add(vec["name"].split("[")[0])
        wire = bytes.fromhex(vec["hex"])
        (frame,) = [f for f in FrameDecoder(4096).feed(wire) if isinstance(f, Frame)]
        meta = vec["frame"]
        rebuilt = Frame(
            FrameType[meta["type"]],
            meta["channel"],
            meta["seq"],
            bytes.fromhex(meta["payload"]),
            Frag[meta["frag"]],
            meta.get("ack"),
        )
        assert frame == rebuilt
        assert encode_frame(rebuilt, lead=wire.startswith(b"\x00")) == wire
        if "control" in meta:
            msg = decode_control(frame.payload)
            assert {"opcode": msg.OPCODE.name, **_jsonable(msg)} == meta["control"]
            assert msg.encode() == frame.payload
    for needed in (
        "hello_host",
        "hello_device",
        "topic_entry",
        "topic_data",
        "topic_data_fragments",
        "ack",
        "ack_selective",
        "service_request",
        "service_response",
        "param_get",
        "param_value",
        "param_not_found",
        "param_push",
        "log",
        "time_request",
        "time_response",
    ):
        assert needed in names


def test_protocol_md_examples_are_golden_vectors() -> None:
    """Every ``wire:`` line of PROTOCOL.md Part 2 is a vector, byte for byte."""
    text = (VECTORS.parents[1] / "PROTOCOL.md").read_text()
    part2 = text[text.index("## Part 2") :]
    quoted = [line[len("wire: ") :] for line in part2.splitlines() if line.startswith("wire: ")]
    stored = json.loads(VECTORS.read_text())
    known = {vec["hex"] for vec in stored["transcript"] + stored["extra"]}
    assert len(quoted) >= 30
    assert [q for q in quoted if q not in known] == []
    # ``payload:`` lines (hex, "strings", | separators) are the decoded frames' payloads
    payloads = {bytes.fromhex(v["frame"]["payload"]) for v in stored["transcript"]}
    checked = 0
    for line in part2.splitlines():
        if not line.startswith("payload: "):
            continue
        parts = re.split(r'("[^"]*")', line[len("payload: ") :])
        try:
            raw = b"".join(
                p[1:-1].encode() if p.startswith('"') else bytes.fromhex(p.replace("|", " "))
                for p in parts
            )
        except ValueError:
            continue  # an annotation line (field names under the bytes)
        assert raw in payloads, line
        checked += 1
    assert checked >= 15


def test_golden_transcript_is_accepted_by_fresh_sessions() -> None:
    """Replaying the board's frames into a fresh host yields the expected events."""
    stored = json.loads(VECTORS.read_text())
    host = HostSession(
        HostConfig(epoch_offset=1_700_000_000.0), session_id=HOST_ID, rng=_FixedRandom()
    )
    events: list[Event] = []
    host.tick(0.0)
    for vec in stored["transcript"]:
        if vec["direction"] == "device->host":
            events += host.receive_data(bytes.fromhex(vec["hex"]), 0.001)
    (connected,) = of_type(events, Connected)
    assert connected.device_session == DEVICE_ID
    assert connected.board.unique_id == bytes.fromhex("0102030405060708")
    assert messages(events, 1)[0] == b"\x05\x00\x00\x00hello"
    assert len(messages(events, 1)) == 2
    assert of_type(events, Log) == [Log(LogLevel.WARN, "low battery")]
    assert [r.name for r in of_type(events, ParamRequest)] == ["rate", "missing"]
    assert not errors(events)
    assert connected.firmware == GOLDEN_IDENTITY
    assert connected.board.identity == GOLDEN_IDENTITY


def test_old_board_info_without_identity_connects() -> None:
    """The transcript with its BOARD_INFO in the old form (no identity items): the host connects
    as before and the identity is unknown."""
    stored = json.loads(VECTORS.read_text())
    (old,) = [v for v in stored["extra"] if v["name"] == "board_info_old"]
    host = HostSession(
        HostConfig(epoch_offset=1_700_000_000.0), session_id=HOST_ID, rng=_FixedRandom()
    )
    events: list[Event] = []
    host.tick(0.0)
    for vec in stored["transcript"]:
        if vec["direction"] == "device->host":
            wire = old["hex"] if vec["name"] == "board_info" else vec["hex"]
            events += host.receive_data(bytes.fromhex(wire), 0.001)
    (connected,) = of_type(events, Connected)
    assert connected.firmware == FirmwareIdentity(version="0.1.0")
    assert connected.firmware is not None and not connected.firmware.known
    assert host.describe()["firmware_version"] == "0.1.0"
    assert not errors(events)


if __name__ == "__main__":  # regenerate the vectors: python -m tests.protocols.test_native_session
    VECTORS.write_text(json.dumps(build_vectors(), indent=1, ensure_ascii=False) + "\n")


@SETTINGS
@given(steps=st.lists(st.floats(min_value=0.001, max_value=0.6), min_size=1, max_size=40))
def test_keepalive_sends_heartbeats_and_never_takes_unread_time_for_silence(
    steps: list[float],
) -> None:
    """``keepalive`` (the pump's timers while its thread is busy and does not read): whatever
    its spacing, the host never declares the link lost during it, and it keeps sending (a
    frame, a heartbeat if nothing else, whenever a heartbeat interval has passed). Once the host
    only ticks again (reading, and nothing comes: the board is cut off), the link is lost within
    the link timeout."""
    link = make_link(17)
    connect(link)
    host = link.host
    link.d2h.faults = Faults(cut=True)  # the board's bytes would sit unread anyway
    now = link.now
    for step in steps:
        now += step
        sent_before = host.stats.frames_sent
        events = host.keepalive(now)
        assert not of_type(events, Disconnected), events
        assert host.connected
        if step >= host.config.heartbeat_interval:  # a heartbeat, unless another frame went
            assert host.stats.frames_sent > sent_before
        host.chunks_to_send()
    resumed = now
    lost_at = None
    while lost_at is None and now < resumed + 5.0:
        now += 0.01
        if of_type(host.tick(now), Disconnected):
            lost_at = now
    assert lost_at is not None
    assert lost_at - resumed <= host.config.link_timeout + 0.02
