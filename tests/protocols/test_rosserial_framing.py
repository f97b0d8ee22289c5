"""rosserial v2 framing: encoder, stream parser (resync, bounds, chunking), reserved ids."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge.protocols.errors import FramingError, HwBridgeError
from hwbridge.protocols.msgtypes import TypeRegistry
from hwbridge.protocols.rosserial.framing import (
    FRAME_OVERHEAD,
    MAX_PAYLOAD,
    BadFrame,
    BadFrameReason,
    FrameParser,
    NonFrameBytes,
    OldProtocol,
    ParserEvent,
    RosFrame,
    checksum,
    decode_frame,
    encode_frame,
)
from hwbridge.protocols.rosserial.ids import TOPIC_INFO_TYPE, ReservedId

SETTINGS = settings(max_examples=150, deadline=None, derandomize=True)
CHATTER = bytes.fromhex("fffe1000ef7d000c00000068656c6c6f20776f726c6421f9")

topic_ids = st.integers(0, 0xFFFF)
payloads = st.binary(max_size=300)
frames = st.builds(RosFrame, topic_ids, payloads)


def merged(events: list[ParserEvent]) -> list[ParserEvent]:
    """Join adjacent NonFrameBytes (the only thing chunking may split differently)."""
    out: list[ParserEvent] = []
    for event in events:
        if isinstance(event, NonFrameBytes) and out and isinstance(out[-1], NonFrameBytes):
            out[-1] = NonFrameBytes(out[-1].data + event.data)
        else:
            out.append(event)
    return out


def feed_chunks(parser: FrameParser, data: bytes, cuts: list[int]) -> list[ParserEvent]:
    events: list[ParserEvent] = []
    start = 0
    for cut in [*sorted({c % (len(data) + 1) for c in cuts}), len(data)]:
        events += parser.feed(data[start:cut])
        start = max(start, cut)
    return events


def reassemble(events: list[ParserEvent]) -> bytes:
    """The bytes each event stands for, in order."""
    out = bytearray()
    for event in events:
        if isinstance(event, RosFrame):
            out += event.encode()
        elif isinstance(event, BadFrame | NonFrameBytes):
            out += event.data
        else:
            out += b"\xff\xff"
    return bytes(out)


def test_reserved_ids_are_the_topicinfo_constants() -> None:
    constants = {name: int(value) for name, _, value in TypeRegistry().constants(TOPIC_INFO_TYPE)}
    assert {f"ID_{m.name}": int(m) for m in ReservedId} == constants


def test_encode_known_frames() -> None:
    assert encode_frame(0) == bytes.fromhex("fffe0000ff0000ff")
    assert encode_frame(11, b"") == bytes.fromhex("fffe0000ff0b00f4")
    assert encode_frame(125, b"\x0c\x00\x00\x00hello world!") == CHATTER
    assert checksum(b"\x7d\x00") == 255 - 125


def test_encode_refuses_out_of_range() -> None:
    with pytest.raises(FramingError, match="uint16"):
        encode_frame(0x10000, b"")
    with pytest.raises(FramingError, match="uint16"):
        encode_frame(-1, b"")
    with pytest.raises(FramingError, match="65535"):
        encode_frame(1, bytes(MAX_PAYLOAD + 1))


def test_decode_frame_exactly_one() -> None:
    assert decode_frame(CHATTER) == RosFrame(125, b"\x0c\x00\x00\x00hello world!")
    for bad in (CHATTER[:-1], CHATTER + b"x", b"x" + CHATTER, CHATTER[:-1] + b"\x00"):
        with pytest.raises(FramingError):
            decode_frame(bad)


@SETTINGS
@given(frames)
def test_round_trip(frame: RosFrame) -> None:
    wire = frame.encode()
    assert len(wire) == len(frame.payload) + FRAME_OVERHEAD
    parser = FrameParser()
    assert parser.feed(wire) == [frame]
    assert parser.buffered == 0
    assert parser.stats.frames == 1
    assert parser.stats.frame_bytes == len(wire)


@settings(max_examples=12, deadline=None, derandomize=True)
@given(topic_ids, st.integers(0, MAX_PAYLOAD), st.binary(min_size=1, max_size=64))
def test_round_trip_up_to_64k(topic_id: int, size: int, pattern: bytes) -> None:
    payload = (pattern * (size // len(pattern) + 1))[:size]
    parser = FrameParser(max_payload=MAX_PAYLOAD)
    assert parser.feed(encode_frame(topic_id, payload)) == [RosFrame(topic_id, payload)]


def test_largest_payload_with_ff_fe_inside() -> None:
    payload = b"\xff\xfe" * (MAX_PAYLOAD // 2) + b"\xff"
    parser = FrameParser(max_payload=MAX_PAYLOAD)
    wire = encode_frame(0xFFFF, payload)
    assert parser.feed(wire[:1000]) == []
    assert parser.feed(wire[1000:]) == [RosFrame(0xFFFF, payload)]


@SETTINGS
@given(st.lists(frames, min_size=1, max_size=6), st.lists(st.integers(0, 4000), max_size=12))
def test_chunking_gives_the_same_events(items: list[RosFrame], cuts: list[int]) -> None:
    stream = b"".join(f.encode() for f in items)
    assert feed_chunks(FrameParser(), stream, cuts) == items


@SETTINGS
@given(st.binary(max_size=600), st.lists(st.integers(0, 700), max_size=10))
def test_arbitrary_bytes_chunked_like_one_feed(data: bytes, cuts: list[int]) -> None:
    whole = FrameParser(max_payload=64)
    chunked = FrameParser(max_payload=64)
    expected = whole.feed(data)
    got = feed_chunks(chunked, data, cuts)
    assert merged(got) == merged(expected)
    assert chunked.buffered == whole.buffered
    assert chunked.stats == whole.stats


@SETTINGS
@given(st.binary(max_size=2000), st.integers(0, 300))
def test_arbitrary_bytes_never_raise_and_stay_bounded(data: bytes, max_payload: int) -> None:
    parser = FrameParser(max_payload=max_payload)
    events: list[ParserEvent] = []
    for i in range(0, len(data), 37):
        events += parser.feed(data[i : i + 37])
        assert parser.buffered <= max_payload + FRAME_OVERHEAD
    # every byte is reported exactly once, apart from an unfinished candidate at the end
    assert reassemble(events) + data[len(data) - parser.buffered :] == data
    stats = parser.stats
    accounted = (
        stats.frame_bytes + stats.bad_frame_bytes + stats.non_frame_bytes + 2 * stats.old_protocol
    )
    assert accounted + parser.buffered == stats.bytes == len(data)


@SETTINGS
@given(st.binary(max_size=400), frames)
def test_valid_frame_after_garbage_is_decoded(garbage: bytes, frame: RosFrame) -> None:
    parser = FrameParser(max_payload=400)
    events = parser.feed(garbage + frame.encode())
    # garbage ending in the middle of a plausible header can make the frame wait for more
    # bytes; once enough arrive to settle that candidate, the frame comes out
    events += parser.feed(b"\x00" * 410)
    assert frame in [e for e in events if isinstance(e, RosFrame)]


@SETTINGS
@given(frames, frames, st.integers(1, 40))
def test_truncated_frame_does_not_swallow_the_next(
    first: RosFrame, second: RosFrame, keep: int
) -> None:
    cut = first.encode()[: min(keep, len(first.encode()) - 1)]
    parser = FrameParser(max_payload=400)
    events = parser.feed(cut + second.encode()) + parser.feed(b"\x00" * 420)
    assert second in [e for e in events if isinstance(e, RosFrame)]


def test_bad_length_checksum_then_frame() -> None:
    parser = FrameParser()
    events = parser.feed(b"\xff\xfe\x10\x00\xee" + CHATTER)
    assert events == [
        BadFrame(BadFrameReason.LENGTH_CHECKSUM, b"\xff\xfe\x10\x00\xee"),
        RosFrame(125, CHATTER[7:-1]),
    ]
    assert parser.stats.length_checksum_errors == 1


def test_bad_checksum_is_reported_and_counted() -> None:
    parser = FrameParser()
    bad = CHATTER[:-1] + b"\xf8"
    assert parser.feed(bad) == [BadFrame(BadFrameReason.CHECKSUM, bad)]
    assert parser.stats.checksum_errors == 1
    assert parser.stats.frames == 0


def test_oversize_is_refused_then_rescanned() -> None:
    parser = FrameParser(max_payload=16)
    header = b"\xff\xfe\x58\x02\xa5\x7d\x00"  # announces 600 bytes
    events = parser.feed(header + CHATTER)
    assert events == [BadFrame(BadFrameReason.OVERSIZE, header), RosFrame(125, CHATTER[7:-1])]
    assert parser.stats.oversize == 1
    parser.max_payload = 15  # the chatter payload is 16 bytes
    assert parser.feed(CHATTER) == [
        BadFrame(BadFrameReason.OVERSIZE, CHATTER[:7]),
        NonFrameBytes(CHATTER[7:]),
    ]
    assert parser.stats.oversize == 2


def test_old_protocol_and_stray_ff() -> None:
    parser = FrameParser()
    assert parser.feed(b"\xff\xff\x7d\x00") == [OldProtocol(), NonFrameBytes(b"\x7d\x00")]
    # FF FF FE: the first FF is a stray byte and a v2 frame starts at the second
    assert parser.feed(b"\xff" + CHATTER) == [NonFrameBytes(b"\xff"), RosFrame(125, CHATTER[7:-1])]
    assert parser.feed(b"\xff\xfd") == [NonFrameBytes(b"\xff\xfd")]
    assert parser.stats.old_protocol == 1


def test_debug_text_between_frames() -> None:
    parser = FrameParser()
    events = parser.feed(b"boot ok\r\n" + CHATTER + b"x=1\n" + CHATTER)
    assert events == [
        NonFrameBytes(b"boot ok\r\n"),
        RosFrame(125, CHATTER[7:-1]),
        NonFrameBytes(b"x=1\n"),
        RosFrame(125, CHATTER[7:-1]),
    ]
    assert parser.stats.non_frame_bytes == 13


def test_reset_and_limits() -> None:
    parser = FrameParser()
    assert parser.feed(CHATTER[:10]) == []
    assert parser.buffered == 10
    parser.reset()
    assert parser.buffered == 0
    with pytest.raises(ValueError, match="max_payload"):
        FrameParser(max_payload=MAX_PAYLOAD + 1)
    with pytest.raises(ValueError, match="max_payload"):
        parser.max_payload = -1
    assert issubclass(FramingError, HwBridgeError)
