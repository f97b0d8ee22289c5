"""The native protocol's fast paths agree with the slow, general code they shortcut.

Each hot path (precompiled structs for the service messages, objects built by filling their
slots, cached encodings of bare ACKs, the decoder's cache of bare frames, the session's cached
link values) is checked against the general code or an independent reference, on the edge cases
and on random input. All property tests are derandomized.
"""

from __future__ import annotations

import dataclasses
import random
import struct
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hwbridge.protocols.errors import FramingError, ProtocolError
from hwbridge.protocols.native import _hotpath, cobs, control, reliable
from hwbridge.protocols.native.control import (
    Features,
    ServiceRequestMsg,
    ServiceResponseMsg,
    ServiceStatus,
    decode_control,
    encode_service_request,
    encode_service_response,
)
from hwbridge.protocols.native.framing import (
    BadFrame,
    Frag,
    Frame,
    FrameDecoder,
    FrameType,
    encode_frame,
    make_frame,
)
from hwbridge.protocols.native.reliable import (
    Delivery,
    ReliableReceiver,
    RttEstimator,
    SequenceStats,
)
from hwbridge.protocols.native.session import (
    DeviceConfig,
    HostConfig,
    Message,
    NativeStreamFraming,
    ServiceRequest,
)
from tests.protocols.test_native_framing import ref_body, ref_cobs_encode
from tests.protocols.test_native_session import CH_CHATTER, CH_RESET, connect, make_link

SETTINGS = settings(
    max_examples=300,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)


def assert_same_object(fast: Any, slow: Any) -> None:
    """Two frozen dataclass instances that nothing can tell apart but their identity."""
    assert type(fast) is type(slow)
    assert fast == slow
    assert hash(fast) == hash(slow)
    assert repr(fast) == repr(slow)
    names = [field.name for field in dataclasses.fields(fast)]
    assert [getattr(fast, name) for name in names] == [getattr(slow, name) for name in names]
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.channel = 1


# --- service messages ----------------------------------------------------------------------


@SETTINGS
@given(st.integers(0, 255), st.integers(0, 0xFFFF), st.binary(max_size=40))
def test_service_encoders_match_the_messages(channel: int, request_id: int, body: bytes) -> None:
    request = encode_service_request(channel, request_id, body)
    assert request == struct.pack("<BBH", 0x20, channel, request_id) + body
    assert request == ServiceRequestMsg(channel, request_id, body).encode()
    for status in ServiceStatus:
        response = encode_service_response(channel, request_id, status, body)
        assert response == struct.pack("<BBHB", 0x21, channel, request_id, status) + body
        assert response == ServiceResponseMsg(channel, request_id, status, body).encode()


def test_service_messages_still_check_their_ranges() -> None:
    with pytest.raises(ValueError, match="channel 256 does not fit in 8 unsigned bits"):
        ServiceRequestMsg(256, 1, b"").encode()
    with pytest.raises(ValueError, match="request id 65536 does not fit in 16 unsigned bits"):
        ServiceResponseMsg(1, 0x10000, ServiceStatus.OK, b"").encode()


def ref_decode_service(payload: bytes) -> ServiceRequestMsg | ServiceResponseMsg:
    """The service messages decoded field by field from PROTOCOL.md, with the reader's errors."""
    if payload[0] == 0x20:
        if len(payload) < 4:
            raise ProtocolError(
                "SERVICE_REQUEST too short: channel, request id needs 3 bytes at offset 1, "
                f"payload has {len(payload)}"
            )
        channel, request_id = struct.unpack_from("<BH", payload, 1)
        return ServiceRequestMsg(channel, request_id, payload[4:])
    if len(payload) < 5:
        raise ProtocolError(
            "SERVICE_RESPONSE too short: channel, request id, status needs 4 bytes at offset 1, "
            f"payload has {len(payload)}"
        )
    channel, request_id, status = struct.unpack_from("<BHB", payload, 1)
    if status > 2:
        raise ProtocolError(f"SERVICE_RESPONSE request {request_id}: unknown status {status}")
    return ServiceResponseMsg(channel, request_id, ServiceStatus(status), payload[5:])


service_payloads = st.builds(
    lambda opcode, rest: bytes([opcode]) + rest,
    st.sampled_from([0x20, 0x21]),
    st.one_of(
        st.binary(max_size=8),
        st.binary(min_size=4, max_size=40),
        st.tuples(st.binary(min_size=3, max_size=3), st.integers(0, 255), st.binary()).map(
            lambda t: t[0] + bytes([t[1]]) + t[2]
        ),
    ),
)


@SETTINGS
@given(service_payloads)
def test_service_decoders_match_the_reference(payload: bytes) -> None:
    try:
        expected = ref_decode_service(payload)
    except ProtocolError as exc:
        with pytest.raises(ProtocolError) as raised:
            decode_control(payload)
        assert str(raised.value) == str(exc)
        return
    decoded = decode_control(payload)
    assert_same_object(decoded, expected)
    if isinstance(decoded, ServiceResponseMsg):
        assert isinstance(expected, ServiceResponseMsg)
        assert decoded.status is expected.status


# --- objects built by filling their slots ----------------------------------------------------


def test_fast_built_objects_equal_the_constructed_ones() -> None:
    assert_same_object(make_frame(FrameType.ACK, 3, 4, b"x"), Frame(FrameType.ACK, 3, 4, b"x"))
    assert_same_object(reliable._delivery(5, b"ab", 9), Delivery(5, b"ab", 9))
    assert_same_object(_hotpath.message(1, b"hi", 2), Message(1, b"hi", 2))


data_frames = st.builds(
    Frame,
    st.sampled_from([FrameType.BEST_EFFORT, FrameType.RELIABLE]),
    st.integers(0, 255),
    st.integers(0, 255),
    st.binary(max_size=40),
    st.sampled_from(list(Frag)),
)


@SETTINGS
@given(data_frames, st.integers(0, 255))
def test_with_ack_is_replace(frame: Frame, ack: int) -> None:
    """The carried ACK's copy of a data frame (ACK_IN_DATA) is ``dataclasses.replace`` of it,
    slot for slot, and leaves the frame the reliable sender keeps untouched."""
    copy = _hotpath.with_ack(frame, ack)
    assert_same_object(copy, dataclasses.replace(frame, ack=ack))
    assert frame.ack is None


def test_bare_acks_are_the_acks_built_in_place() -> None:
    receiver = ReliableReceiver(SequenceStats(), isn=200, window=4, max_message=100)
    for seq in range(200, 200 + 300):
        frame = Frame(FrameType.RELIABLE, 1, seq & 0xFF, b"m")
        assert receiver.receive(frame)
        assert_same_object(receiver.ack_frame(), Frame(FrameType.ACK, 0, seq & 0xFF, b""))
    assert receiver.stats.acks_sent == 300


# --- COBS and frame encoding -----------------------------------------------------------------


@SETTINGS
@given(
    st.one_of(
        st.binary(max_size=253),
        st.lists(st.sampled_from([0, 0, 1, 0xFF]), max_size=253).map(bytes),
    )
)
def test_cobs_encode_short_matches_the_reference(data: bytes) -> None:
    assert cobs.encode_short(data) == ref_cobs_encode(data) == cobs.encode(data)
    assert cobs.decode(cobs.encode_short(data)) == data


frame_fields = st.tuples(
    st.sampled_from(FrameType),
    st.integers(0, 255),
    st.integers(0, 255),
    st.one_of(st.just(b""), st.binary(max_size=300)),
    st.sampled_from(Frag),
    st.booleans(),
)


@SETTINGS
@given(frame_fields)
def test_encode_frame_matches_the_reference(fields: tuple[Any, ...]) -> None:
    ftype, channel, seq, payload, frag, lead = fields
    frame = Frame(ftype, channel, seq, payload, frag)
    expected = (b"\x00" if lead else b"") + ref_cobs_encode(ref_body(frame)) + b"\x00"
    assert encode_frame(frame, lead=lead) == expected
    assert encode_frame(frame, lead=lead) == expected  # a second time: cached for bare ACKs


def test_every_bare_ack_encodes_like_the_reference() -> None:
    for seq in range(256):
        for lead in (False, True):
            frame = make_frame(FrameType.ACK, 0, seq, b"")
            expected = (b"\x00" if lead else b"") + ref_cobs_encode(ref_body(frame)) + b"\x00"
            assert encode_frame(frame, lead=lead) == expected


@pytest.mark.parametrize(
    ("frame", "error", "message"),
    [
        (Frame(FrameType.ACK, 256, 0, b""), FramingError, "channel 256 seq 0: both are 0..255"),
        (Frame(FrameType.ACK, 0, -1, b""), FramingError, "channel 0 seq -1: both are 0..255"),
        (Frame(FrameType.RELIABLE, 0, 300, b"x"), FramingError, "seq 300: both are 0..255"),
        (Frame(FrameType.ACK, 0, 1.0, b""), TypeError, "'float' object cannot be interpreted"),  # type: ignore[arg-type]
        (Frame(FrameType.ACK, None, 1, b""), TypeError, "'NoneType' object cannot be interpreted"),  # type: ignore[arg-type]
        (Frame(FrameType.ACK, 0, 1, None), TypeError, "can't concat NoneType to bytes"),  # type: ignore[arg-type]
    ],
)
def test_encode_frame_errors_are_unchanged(
    frame: Frame, error: type[Exception], message: str
) -> None:
    for _ in range(2):  # nothing invalid is ever cached
        with pytest.raises(error, match=message):
            encode_frame(frame)


def test_encode_frame_accepts_bool_and_bytearray_fields_as_before() -> None:
    reference = encode_frame(Frame(FrameType.ACK, 1, 1, b""))
    assert encode_frame(Frame(FrameType.ACK, True, True, b"")) == reference
    assert encode_frame(Frame(FrameType.ACK, 1, 1, bytearray())) == reference  # type: ignore[arg-type]
    payload = encode_frame(Frame(FrameType.BEST_EFFORT, 1, 1, b"ab"))
    assert encode_frame(Frame(FrameType.BEST_EFFORT, 1, 1, bytearray(b"ab"))) == payload  # type: ignore[arg-type]


# --- the decoder's cache of frames without payload ---------------------------------------------


@SETTINGS
@given(
    st.sampled_from(FrameType),
    st.integers(0, 255),
    st.integers(0, 255),
    st.sampled_from(Frag),
    st.integers(0, 3),
)
def test_bare_frames_decode_the_same_from_the_cache(
    ftype: FrameType, channel: int, seq: int, frag: Frag, max_payload: int
) -> None:
    frame = Frame(ftype, channel, seq, b"", frag)
    wire = encode_frame(frame)
    assert len(wire) == 7  # a 6-byte run and its delimiter
    for _ in range(3):  # the first decode fills the cache, the others read it
        decoder = FrameDecoder(max_payload)
        assert decoder.feed(wire * 2) == [frame, frame]
        assert decoder.stats.frames == 2
        assert decoder.stats.bytes == 14


def test_damaged_bare_frames_are_not_taken_from_the_cache() -> None:
    wire = encode_frame(Frame(FrameType.ACK, 0, 7, b""))
    decoder = FrameDecoder()
    assert decoder.feed(wire) == [Frame(FrameType.ACK, 0, 7, b"")]
    damaged = bytearray(wire)
    damaged[3] ^= 0x40  # the seq, still not a zero
    events = decoder.feed(bytes(damaged))
    assert len(events) == 1
    assert isinstance(events[0], BadFrame)
    assert decoder.stats.crc_errors == 1
    assert decoder.stats.frames == 1


# --- the RTT estimator -------------------------------------------------------------------------


def ref_rtt(samples: list[float], rto: float, rto_min: float, rto_max: float) -> tuple[Any, ...]:
    """RFC 6298 written out, as the estimator did before it kept its state in locals."""
    srtt: float | None = None
    rttvar = 0.0
    for sample in samples:
        rtt = max(sample, 0.0)
        if srtt is None:
            srtt = rtt
            rttvar = rtt / 2
        else:
            rttvar = 0.75 * rttvar + 0.25 * abs(srtt - rtt)
            srtt = 0.875 * srtt + 0.125 * rtt
        rto = min(rto_max, max(rto_min, srtt + 4 * rttvar))
    return srtt, rttvar, rto


@SETTINGS
@given(st.lists(st.floats(-1.0, 5.0, allow_nan=False), max_size=20))
def test_rtt_estimator_matches_the_reference(samples: list[float]) -> None:
    estimator = RttEstimator(0.25, 0.05, 1.0)
    for sample in samples:
        estimator.sample(sample)
    assert (estimator.srtt, estimator.rttvar, estimator.rto) == ref_rtt(samples, 0.25, 0.05, 1.0)


# --- the session's cached link values ----------------------------------------------------------


@pytest.mark.parametrize("time_sync_interval", [0.0, 5.0])
@pytest.mark.parametrize("device_features", [Features.NONE, Features.TIME_SYNC])
def test_session_link_values_follow_the_link(
    time_sync_interval: float, device_features: Features
) -> None:
    link = make_link(
        3,
        host_cfg=HostConfig(max_message=5000, time_sync_interval=time_sync_interval),
        dev_cfg=DeviceConfig(max_message=48, features=device_features),
    )
    host, device = link.host, link.device
    for end in (host, device):
        assert (end._peer_max, end._time_sync) == (control.MIN_MTU, False)
    connect(link)
    assert (host._peer_max, device._peer_max) == (48, 5000)
    for end in (host, device):
        assert end.link is not None
        enabled = end.config.time_sync_interval > 0 and bool(end.link.features & Features.TIME_SYNC)
        assert end._time_sync == enabled
    device.close()
    link.run(1.0)
    assert not host.connected
    assert (host._peer_max, host._time_sync) == (control.MIN_MTU, False)


def test_next_deadline_is_the_earliest_timer() -> None:
    """next_deadline is exact: ticking just before it does nothing, ticking at it does."""
    link = make_link(5)
    connect(link)
    rng = random.Random(5)
    host = link.host
    for _ in range(200):
        link.run(rng.choice([0.001, 0.03, 0.2]))
        deadline = host.next_deadline()
        assert deadline is not None
        sent_before = host.stats.frames_sent
        heartbeats = host.stats.heartbeats_sent
        assert host.tick(deadline - 1e-9) == []
        assert host.stats.frames_sent == sent_before
        assert host.data_to_send() == b""
        host.tick(deadline)
        assert host.next_deadline() != deadline or host.stats.heartbeats_sent > heartbeats
        link.flush()


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), most=st.integers(1, 40))
def test_a_settled_read_leaves_next_deadline_as_it_was(seed: int, most: int) -> None:
    """``settled`` (a pump skips asking next_deadline again after such a read) is True exactly
    after a read that completed no frame, and then the deadline is the one before the read;
    the board's bytes come in chunks of 1 to ``most`` bytes while calls, messages and timers
    run both ways."""
    link = make_link(seed % 1000)
    connect(link)
    host, device = link.host, link.device
    rng = random.Random(seed)
    now, settled_reads = link.now, 0
    for step in range(60):
        now += rng.choice([0.0005, 0.004, 0.03, 0.12])
        host.tick(now)
        device.tick(now)
        if step % 3 == 0:
            host.call_service(CH_RESET, b"", now=now)
        if step % 4 == 1:
            device.publish(CH_CHATTER, b"\x05\x00\x00\x00hello")
        for event in device.receive_data(host.data_to_send(), now):
            if isinstance(event, ServiceRequest):
                device.respond_service(event.channel, event.request_id, b"\x01\x00\x00\x00\x00")
        wire = device.data_to_send()
        while wire:
            size = rng.randint(1, most)
            chunk, wire = wire[:size], wire[size:]
            framing = host.framing
            assert isinstance(framing, NativeStreamFraming)
            pending = framing.decoder.buffered
            before = host.next_deadline()
            host.receive_data(chunk, now)
            runs = chunk.split(b"\x00")[:-1]  # the runs a delimiter in the chunk ends
            completes = bool(runs) and (pending > 0 or any(runs))
            assert host.settled is (not completes)
            if host.settled:
                settled_reads += 1
                assert host.next_deadline() == before
        host.tick(now)
    assert host.connected and settled_reads > 0
