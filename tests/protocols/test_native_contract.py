"""Native on the shared contract (protocols.base): datagram framing, events, spec, start-up."""

from __future__ import annotations

import dataclasses
import itertools
import json
import logging
import random
from binascii import crc_hqx
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hwbridge import msg
from hwbridge.protocols import base
from hwbridge.protocols.base import BoardSession, SessionStats
from hwbridge.protocols.errors import FramingError
from hwbridge.protocols.native import control, session
from hwbridge.protocols.native.cobs import encode as cobs_encode
from hwbridge.protocols.native.framing import (
    BadFrame,
    BadFrameReason,
    Frag,
    Frame,
    FrameType,
    NativeDatagramFraming,
    NativeStreamFraming,
    decode_datagram,
    encode_datagram,
    encode_frame,
)
from hwbridge.protocols.native.reliable import SequenceStats
from hwbridge.protocols.native.session import (
    Connected,
    DeviceConfig,
    DeviceSession,
    HostConfig,
    HostSession,
    ServiceRequest,
    ServiceResponse,
    SessionCounters,
    TopicEntry,
)
from hwbridge.protocols.native.spec import PROTOCOL, NativeDetector
from hwbridge.protocols.registry import SessionContext
from tests.protocols.lossy import Faults, SimLink
from tests.protocols.test_native_session import (
    BOARD,
    CH_CHATTER,
    CH_CONFIG,
    CH_RESET,
    CH_STATUS,
    MD5_STRING,
    PATIENT,
    TOPICS,
    connect,
    messages,
    of_type,
)

SETTINGS = settings(
    max_examples=200,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)


def _check(s: HostSession) -> BoardSession:
    """mypy: a HostSession is a BoardSession."""
    return s


# --- datagram framing ------------------------------------------------------------------------

frames = st.builds(
    Frame,
    st.sampled_from(FrameType),
    st.integers(0, 255),
    st.integers(0, 255),
    st.binary(max_size=300),
    st.sampled_from(Frag),
)


@SETTINGS
@given(frames)
def test_datagram_framing_round_trips(frame: Frame) -> None:
    framing = NativeDatagramFraming(max_payload=300)
    (datagram,) = framing.encode([frame], 0.0)
    assert datagram == encode_datagram(frame)
    assert len(datagram) == len(frame.payload) + 5  # header and CRC, no COBS, no delimiter
    assert encode_frame(frame).rstrip(b"\x00") != datagram or not frame.payload
    assert framing.decode(datagram) == [frame]
    assert decode_datagram(datagram) == frame
    assert framing.stats.frames == 1 and framing.stats.bytes == len(datagram)


@SETTINGS
@given(frames, st.data())
def test_a_corrupted_datagram_is_one_bad_frame(frame: Frame, data: st.DataObject) -> None:
    framing = NativeDatagramFraming(max_payload=300)
    datagram = bytearray(encode_datagram(frame))
    if data.draw(st.booleans(), label="flip"):
        bit = data.draw(st.integers(0, 8 * len(datagram) - 1), label="bit")
        datagram[bit // 8] ^= 1 << (bit % 8)
        expected = BadFrameReason.CRC  # CRC-16 catches every single-bit error
    else:
        cut = data.draw(st.integers(0, len(datagram) - 1), label="cut")
        del datagram[cut:]
        expected = BadFrameReason.TOO_SHORT if cut < 5 else BadFrameReason.CRC
    if not datagram:
        assert framing.decode(bytes(datagram)) == []
        return
    (event,) = framing.decode(bytes(datagram))
    assert isinstance(event, BadFrame) and event.reason is expected
    assert event.data == bytes(datagram)
    assert framing.stats.frames == 0
    with pytest.raises(FramingError):
        decode_datagram(bytes(datagram))


def test_datagram_header_and_size_checks() -> None:
    framing = NativeDatagramFraming(max_payload=4)
    big = encode_datagram(Frame(FrameType.BEST_EFFORT, 1, 0, b"12345"))
    other_version = bytearray(encode_datagram(Frame(FrameType.BEST_EFFORT, 1, 0, b"")))
    other_version[0] = 0x80
    body = bytes(other_version[:3])
    other_version = bytearray(body + crc_hqx(body, 0xFFFF).to_bytes(2, "little"))
    events = framing.decode(big) + framing.decode(bytes(other_version))
    reasons = [e.reason for e in events if isinstance(e, BadFrame)]
    assert reasons == [BadFrameReason.OVERSIZE, BadFrameReason.VERSION]
    assert (framing.stats.oversize, framing.stats.version_errors) == (1, 1)
    framing.max_payload = 5
    assert isinstance(framing.decode(big)[0], Frame)


def test_stream_framing_leads_the_first_chunk_idle_ones_and_hellos() -> None:
    framing = NativeStreamFraming()
    frame = Frame(FrameType.BEST_EFFORT, 1, 0, b"x")
    plain = encode_frame(frame)
    assert framing.encode([frame, frame], 0.0) == [b"\x00" + plain + plain]
    assert framing.encode([frame], 0.05) == [plain]
    assert framing.encode([frame], 0.2) == [b"\x00" + plain]  # idle for IDLE_LEAD
    framing.lead_next()
    assert framing.encode([frame], 0.21) == [b"\x00" + plain]
    assert framing.encode([], 5.0) == []


def _datagram_link(seed: int, h2d: Faults | None = None, d2h: Faults | None = None) -> SimLink:
    host = HostSession(
        HostConfig(**PATIENT), framing=NativeDatagramFraming(), rng=random.Random(seed)
    )
    device = DeviceSession(
        BOARD,
        TOPICS,
        DeviceConfig(window=4, max_message=256, tx_queue_limit=4096, **PATIENT),
        framing=NativeDatagramFraming(),
        rng=random.Random(seed + 1),
    )
    return SimLink(host, device, seed=seed, h2d=h2d, d2h=d2h, datagram=True)


def test_host_and_device_talk_over_datagrams() -> None:
    link = _datagram_link(1)
    connect(link)
    assert all(len(chunk) <= 64 + 5 for chunk in link.h2d_log)  # one frame per datagram
    link.device.publish(CH_CHATTER, b"hello")
    assert link.host.publish(CH_CONFIG, b"c" * 150)  # fragmented over the device's mtu 64
    request_id = link.host.call_service(CH_RESET, b"", timeout=5.0, now=link.now)

    def serve(event: object) -> None:
        if isinstance(event, ServiceRequest):
            link.device.respond_service(event.channel, event.request_id, b"ok")

    link.on_device = serve
    link.flush()
    assert link.run(2, until=lambda: bool(of_type(link.host_events, ServiceResponse)))
    (response,) = of_type(link.host_events, ServiceResponse)
    assert (response.request_id, response.payload, response.ok) == (request_id, b"ok", True)
    assert messages(link.host_events, CH_CHATTER) == [b"hello"]
    assert messages(link.device_events, CH_CONFIG) == [b"c" * 150]
    assert link.host.stats.bad_frames == 0 and link.host.stats.non_frame_bytes == 0


@settings(max_examples=6, deadline=None, derandomize=True)
@given(st.integers(0, 1000))
def test_datagram_sessions_survive_loss_duplication_and_reordering(seed: int) -> None:
    faults = Faults(drop=0.1, corrupt=0.05, duplicate=0.1, reorder=0.1)
    link = _datagram_link(seed, h2d=faults, d2h=Faults(**vars(faults)))
    connect(link, 60)
    sent = [bytes([i]) * 20 for i in range(40)]
    for payload in sent:
        assert link.device.publish(CH_STATUS, payload)  # reliable
    link.flush()
    assert link.run(60, until=lambda: len(messages(link.host_events, CH_STATUS)) == len(sent))
    assert messages(link.host_events, CH_STATUS) == sent
    assert link.host.stats.bad_frames == link.d2h.stats.corrupted or link.d2h.stats.corrupted


# --- events, entries and statistics are the shared ones --------------------------------------


def test_events_are_the_shared_classes() -> None:
    for name in (
        "Message",
        "ServiceRequest",
        "ServiceResponse",
        "Log",
        "DebugOutput",
        "Error",
        "Disconnected",
        "TopicAnnounced",
        "TimeSynced",
    ):
        assert getattr(session, name) is getattr(base, name), name
    assert issubclass(session.Connected, base.Connected)
    assert issubclass(session.ParamRequest, base.ParamRequest)
    assert control.EntryKind is base.EntryKind
    assert issubclass(TopicEntry, base.Endpoint)
    assert issubclass(session.NativeStats, SessionStats)


def test_connected_and_stats_carry_the_shared_fields() -> None:
    host = HostSession(rng=random.Random(3))
    link = SimLink(host, DeviceSession(BOARD, TOPICS, rng=random.Random(4)), seed=3)
    connect(link)
    (event,) = of_type(link.host_events, Connected)
    assert isinstance(event, base.Connected) and isinstance(event, Connected)
    assert event.endpoints == event.topics == TOPICS
    assert (event.board_name, event.board, event.resumed) == (BOARD.name, BOARD, False)
    stats = host.counters()
    assert isinstance(stats, SessionStats) and stats == host.stats
    assert stats.sessions == 1 and stats.frames_received > 0
    assert stats.as_dict()["hellos_sent"] == stats.hellos_sent
    info = host.describe()
    assert info["board"] == BOARD.name and info["unique_id"] == BOARD.unique_id.hex()
    assert info["mtu"] == host.link.mtu if host.link else False
    json.dumps(info)


def test_native_stats_list_each_counter_once_from_where_it_is_counted() -> None:
    """``as_dict()`` lists the shared counters, then the sequencing layer's and the session's
    own (each declared once, on the object that counts it), then the RTT estimate."""
    shared = [f.name for f in dataclasses.fields(SessionStats) if f.name != "detail"]
    counted = [f.name for f in dataclasses.fields(SequenceStats)]
    counted += [f.name for f in dataclasses.fields(SessionCounters) if f.name not in shared]
    stats = HostSession().stats
    assert list(stats.as_dict()) == [*shared, *counted, "rtt", "rto"]
    assert (stats.retransmits, stats.stalls, stats.rtt) == (0, 0, None)
    with pytest.raises(AttributeError, match="no attribute 'retransmit'"):
        getattr(stats, "retransmit")  # noqa: B009


# --- start-up --------------------------------------------------------------------------------


def test_first_hello_at_once_then_backing_off_to_hello_interval() -> None:
    host = HostSession(rng=random.Random(0), now=10.0)
    assert host.data_to_send()  # created with a time: the HELLO is already waiting
    sent = []
    t = 10.0
    while t < 11.5:
        host.tick(t)
        if host.data_to_send():
            sent.append(round(t - 10.0, 3))
        t = round(t + 0.001, 3)
    assert sent[:4] == [0.05, 0.15, 0.35, 0.6]  # 50 ms doubling up to hello_interval (0.25)
    assert all(round(b - a, 3) == 0.25 for a, b in itertools.pairwise(sent[3:]))
    device = DeviceSession(BOARD, TOPICS, now=0.0)
    (hello,) = [f for f in session.NativeStreamFraming().decode(device.data_to_send())]
    assert isinstance(hello, Frame) and hello.payload[0] == control.Opcode.HELLO


# --- the spec --------------------------------------------------------------------------------


def _context(datagram: bool = False) -> SessionContext:
    return SessionContext(registry=msg.registry(), datagram=datagram, now=5.0, wall_offset=1e9)


@pytest.mark.parametrize("datagram", [False, True])
def test_spec_builds_a_host_session_that_says_hello_at_once(datagram: bool) -> None:
    assert PROTOCOL.name == "native" and PROTOCOL.stream and PROTOCOL.datagram
    host = PROTOCOL.new_session(_context(datagram))
    assert isinstance(host, HostSession)
    assert host.framing.datagram is datagram
    assert isinstance(host.config, HostConfig) and host.config.epoch_offset == 1e9
    chunks = host.chunks_to_send()
    assert len(chunks) == 1
    framing = NativeDatagramFraming() if datagram else NativeStreamFraming()
    (hello,) = framing.decode(chunks[0])
    assert isinstance(hello, Frame) and hello.payload[0] == control.Opcode.HELLO


def test_spec_type_check_uses_the_registry(caplog: pytest.LogCaptureFixture) -> None:
    host = PROTOCOL.new_session(_context())
    assert isinstance(host, HostSession)
    topics = (
        TopicEntry(1, base.EntryKind.PUBLISHER, "/a", "std_msgs/String", MD5_STRING),
        TopicEntry(2, base.EntryKind.PUBLISHER, "/b", "std_msgs/Int32", MD5_STRING),
        TopicEntry(3, base.EntryKind.PUBLISHER, "/c", "nowhere_msgs/Thing", MD5_STRING),
        TopicEntry(4, base.EntryKind.PUBLISHER, "/d", "nowhere_msgs/Thing", MD5_STRING),
    )
    link = SimLink(host, DeviceSession(BOARD, topics, rng=random.Random(2)), seed=2)
    link.now = 5.0
    with caplog.at_level(logging.WARNING, logger="hwbridge.protocols.native"):
        connect(link)
    (event,) = of_type(link.host_events, Connected)
    assert [e.channel for e in event.endpoints] == [1, 3, 4]  # Int32 with String's md5: refused
    warned = [r for r in caplog.records if "nowhere_msgs/Thing" in r.getMessage()]
    assert len(warned) == 1  # once per type


def _device_bytes() -> bytes:
    device = DeviceSession(BOARD, TOPICS, rng=random.Random(0), now=0.0)
    return device.data_to_send()


@pytest.mark.parametrize("chunk", [1, 3, 64])
def test_detector_finds_native_frames_in_any_chunking(chunk: int) -> None:
    data = b"booting...\r\n\xff\xfe garbage" + _device_bytes()
    detector = PROTOCOL.detector() if PROTOCOL.detector else NativeDetector()
    results = [detector.feed(data[i : i + chunk]) for i in range(0, len(data), chunk)]
    assert results[-1] and (chunk > 30 or not results[0])
    assert detector.feed(b"more")  # stays decided


def test_detector_ignores_text_and_noise() -> None:
    detector = NativeDetector()
    rng = random.Random(7)
    noise: list[Any] = [b"hello world\r\n\x00", bytes(rng.getrandbits(8) for _ in range(200))]
    assert not any(detector.feed(chunk) for chunk in noise)
    # A CRC-valid frame of another version counts (its CRC is valid).
    body = bytes([0x80, 0, 0])
    frame = cobs_encode(body + crc_hqx(body, 0xFFFF).to_bytes(2, "little"))
    assert detector.feed(b"\0" + frame + b"\0")
