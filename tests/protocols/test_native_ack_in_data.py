"""ACK_IN_DATA (PROTOCOL.md 1.4, 2.4): data frames that carry the cumulative ACK of the other
direction, on the wire (framing round trips, against the reference encoding) and in sessions
(a service exchange with no ACK frame; old and new ends; loss, duplication and reordering)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hwbridge.protocols.can.transport import TransferDecoder, TransferEncoder
from hwbridge.protocols.errors import FramingError
from hwbridge.protocols.native import control as ctl
from hwbridge.protocols.native.control import Features
from hwbridge.protocols.native.framing import (
    Frag,
    Frame,
    FrameDecoder,
    FrameType,
    NativeDatagramFraming,
    cobs_encode,
    decode_frame,
    encode_datagram,
    encode_frame,
)
from hwbridge.protocols.native.session import (
    DeviceConfig,
    HostConfig,
    ServiceRequest,
    ServiceResponse,
)
from tests.protocols.test_native_framing import ref_body, ref_cobs_encode
from tests.protocols.test_native_session import (
    CH_GET_TIME,
    CH_RESET,
    PATIENT,
    SETTINGS,
    Event,
    _quiet_link,
    _serve_device,
    answer_then_ack_alone,
    connect,
    lossy,
    make_link,
    of_type,
)
from tests.strategies import bounded


@bounded(300)
@given(
    ftype=st.sampled_from([FrameType.BEST_EFFORT, FrameType.RELIABLE]),
    frag=st.sampled_from(list(Frag)),
    channel=st.integers(0, 255),
    seq=st.integers(0, 255),
    ack=st.integers(0, 255),
    payload=st.binary(max_size=300),
    garbage=st.binary(max_size=40),
)
def test_frame_with_ack_round_trip(
    ftype: FrameType, frag: Frag, channel: int, seq: int, ack: int, payload: bytes, garbage: bytes
) -> None:
    """A data frame carrying an ACK (ACK_IN_DATA, PROTOCOL.md 1.4) encodes as the reference
    says and decodes back whole, on streams (after any garbage and a delimiter) and datagrams;
    the ACK byte counts towards the payload MTU."""
    frame = Frame(ftype, channel, seq, payload, frag, ack)
    wire = encode_frame(frame)
    assert wire == ref_cobs_encode(ref_body(frame)) + b"\x00"
    events = FrameDecoder(max_payload=len(payload) + 1).feed(garbage + b"\x00" + wire)
    assert events[-1] == frame
    assert decode_frame(wire) == frame
    assert NativeDatagramFraming(max_payload=len(payload) + 1).decode(encode_datagram(frame)) == [
        frame
    ]
    (bad,) = FrameDecoder(max_payload=len(payload)).feed(b"\x00" + wire)
    assert not isinstance(bad, Frame)  # oversize (or text, for a printable frame)


def test_ack_only_in_data_frames() -> None:
    """An ACK frame cannot carry an ACK byte, nor can an ACK be outside 0..255."""
    with pytest.raises(FramingError, match="only BEST_EFFORT"):
        encode_frame(Frame(FrameType.ACK, 0, 1, b"", Frag.WHOLE, 2))
    for ack in (256, -1):  # (-1 would index the last byte value, were it not checked)
        for encode in (encode_frame, encode_datagram):
            with pytest.raises(FramingError, match="only BEST_EFFORT"):
                encode(Frame(FrameType.RELIABLE, 0, 1, b"", Frag.WHOLE, ack))


@pytest.mark.parametrize(
    "features",
    [ctl.ALL_FEATURES, ctl.ALL_FEATURES & ~Features.SERVICE_CHANNELS],
    ids=["service channels", "SERVICE_REQUEST"],
)
@pytest.mark.parametrize("window", [1, 3, 8])
def test_acks_ride_in_data_frames_with_ack_in_data(window: int, features: Features) -> None:
    """Both ends with ACK_IN_DATA, any window, either form of service calls: a service
    exchange sends no ACK frame. The board's answer carries the ACK of the request, the host's
    next request the ACK of the answer; with nothing to carry it, a held ACK goes alone after
    ack_delay."""
    link = _quiet_link(window, features=features)
    host, device = link.host, link.device
    t = link.now
    acks_before = host.stats.acks_sent, device.stats.acks_sent
    carried_before = host.stats.acks_carried, device.stats.acks_carried
    host.call_service(CH_RESET, b"ping", now=t)
    (call,) = of_type(device.receive_data(host.data_to_send(), link.device_time(t)), ServiceRequest)
    assert device.data_to_send() == b""  # the ACK waits for the answer ...
    device.respond_service(call.channel, call.request_id, b"pong")
    (answer,) = [f for f in FrameDecoder(4096).feed(device.data_to_send()) if isinstance(f, Frame)]
    assert answer.type is FrameType.RELIABLE and answer.ack is not None  # ... and rides in it
    assert answer.channel == (CH_RESET if features & Features.SERVICE_CHANNELS else 0)
    (response,) = of_type(host.receive_data(encode_frame(answer), t), ServiceResponse)
    assert response.ok and response.payload == b"pong"
    assert host.data_to_send() == b""
    t += 0.001
    host.call_service(CH_RESET, b"again", now=t)
    (request,) = [f for f in FrameDecoder(4096).feed(host.data_to_send()) if isinstance(f, Frame)]
    assert request.type is FrameType.RELIABLE and request.ack == answer.seq
    (call,) = of_type(
        device.receive_data(encode_frame(request), link.device_time(t)), ServiceRequest
    )
    answer_then_ack_alone(link, call, t)
    assert host.stats.acks_sent - acks_before[0] == 2  # one carried, one alone
    assert device.stats.acks_sent - acks_before[1] == 2  # both carried
    assert host.stats.acks_carried - carried_before[0] == 1
    assert device.stats.acks_carried - carried_before[1] == 2
    assert host.stats.retransmits == device.stats.retransmits == 0


def test_old_and_new_ends_do_not_carry_acks() -> None:
    """One end without ACK_IN_DATA: the feature is off, every ACK is a frame of its own."""
    link = make_link(12, dev_cfg=DeviceConfig(features=Features.TIME_SYNC | Features.PARAM_PUSH))
    connect(link)
    assert link.host.link is not None and not link.host.link.features & Features.ACK_IN_DATA
    _serve_device(link, lambda p: p)
    ids = [link.host.call_service(CH_RESET, bytes([i])) for i in range(5)]
    assert link.run(5.0, until=lambda: len(of_type(link.host_events, ServiceResponse)) == 5)
    assert sorted(r.request_id for r in of_type(link.host_events, ServiceResponse)) == ids
    assert link.host.stats.acks_carried == link.device.stats.acks_carried == 0
    assert link.host.stats.acks_sent >= 5 and link.device.stats.acks_sent >= 5


@SETTINGS
@given(
    window=st.sampled_from([1, 2, 4]),
    seed=st.integers(0, 2**16),
    loss=st.floats(0.0, 0.3),
    reorder=st.floats(0.0, 0.3),
    duplicate=st.floats(0.0, 0.2),
)
def test_services_with_acks_in_data_survive_a_bad_link(
    seed: int, loss: float, duplicate: float, reorder: float, window: int
) -> None:
    """ACK_IN_DATA on both ends, loss, duplication and reordering both ways: every call in
    both directions is answered exactly once, and ACKs did ride in data frames."""
    link = make_link(
        seed,
        host_cfg=HostConfig(**PATIENT),
        dev_cfg=DeviceConfig(window=window, max_message=128, **PATIENT),
        h2d=lossy(loss, duplicate=duplicate, reorder=reorder, max_chunk=11),
        d2h=lossy(loss, duplicate=duplicate, reorder=reorder, max_chunk=11),
    )
    connect(link, 60.0)
    assert link.host.link is not None and link.host.link.features & Features.ACK_IN_DATA

    def on_host(event: Event) -> None:
        if isinstance(event, ServiceRequest):
            link.host.respond_service(event.channel, event.request_id, b"t" + event.payload)

    _serve_device(link, lambda p: b"r" + p)
    link.on_host = on_host
    host_ids = [link.host.call_service(CH_RESET, bytes([i])) for i in range(6)]
    dev_ids = [link.device.call_service(CH_GET_TIME, bytes([i])) for i in range(6)]
    link.flush()

    def done() -> bool:
        return (
            len(of_type(link.host_events, ServiceResponse)) >= 6
            and len(of_type(link.device_events, ServiceResponse)) >= 6
        )

    assert link.run(300.0, until=done)
    for events, ids in ((link.host_events, host_ids), (link.device_events, dev_ids)):
        responses = of_type(events, ServiceResponse)
        assert sorted(r.request_id for r in responses) == sorted(ids)
        assert all(r.ok for r in responses)
    assert link.host.stats.acks_carried + link.device.stats.acks_carried > 0


@bounded(100)
@given(
    ftype=st.sampled_from([FrameType.BEST_EFFORT, FrameType.RELIABLE]),
    seq=st.integers(0, 255),
    ack=st.integers(0, 255),
    payload=st.binary(max_size=40),
)
def test_can_format_2_sends_a_carried_ack_as_an_ack_frame(
    ftype: FrameType, seq: int, ack: int, payload: bytes
) -> None:
    """CAN format 2 carries a frame's header in the id, where flag bit 0 has no room: a frame
    with an ACK goes as the frame without it, then an ACK frame (CAN.md), nothing lost."""
    frame = Frame(ftype, 3, seq, payload, Frag.WHOLE, ack)
    encoder, decoder = TransferEncoder(4), TransferDecoder(0)
    got = []
    for can_id, data in encoder.datagram(encode_datagram(frame), 0):
        transfer = decoder.feed(can_id, data, 0.0)
        if transfer is not None:
            got.append(decode_frame(cobs_encode(transfer.payload) + b"\x00"))
    assert got == [Frame(ftype, 3, seq, payload), Frame(FrameType.ACK, 0, ack, b"")]
