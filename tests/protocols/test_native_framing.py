"""Tests of the native protocol's framing layer (PROTOCOL.md, Part 1).

Reference implementations written byte by byte from the specification (COBS, CRC) check the
fast ones; the golden vectors are checked in both directions; hypothesis drives the decoder
with garbage, corruption, text and arbitrary chunking. All property tests are derandomized.
"""

from __future__ import annotations

import itertools
import json
import random
import re
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hwbridge.protocols.errors import FramingError, HwBridgeError
from hwbridge.protocols.native import cobs
from hwbridge.protocols.native.framing import (
    DEFAULT_MAX_PAYLOAD,
    BadFrame,
    BadFrameReason,
    Frag,
    Frame,
    FrameDecoder,
    FrameEvent,
    FrameType,
    NonFrameBytes,
    Reassembler,
    crc16,
    decode_frame,
    encode_frame,
    fragment,
    frame_overhead,
    max_run_size,
    wire_size,
)
from tests.strategies import bounded

ROOT = Path(__file__).resolve().parents[2]
VECTORS = json.loads((ROOT / "protocols" / "vectors" / "native_frames.json").read_text())
PROTOCOL_MD = (ROOT / "protocols" / "PROTOCOL.md").read_text()


# --- independent reference implementations -----------------------------------------------


def ref_crc(data: bytes) -> int:
    """CRC-16/CCITT-FALSE bit by bit, as in PROTOCOL.md 1.5."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def ref_cobs_encode(data: bytes, *, trailing_group: bool = False) -> bytes:
    """COBS byte by byte (the C encoder of PROTOCOL.md 1.3); optionally the PacketSerial form."""
    out = bytearray([0])
    code_at = 0
    code = 1
    for index, byte in enumerate(data):
        if byte:
            out.append(byte)
            code += 1
        if byte == 0 or code == 0xFF:
            out[code_at] = code
            code = 1
            if byte and index + 1 == len(data) and not trailing_group:
                return bytes(out)
            code_at = len(out)
            out.append(0)
    out[code_at] = code
    return bytes(out)


def ref_body(frame: Frame) -> bytes:
    acked = frame.ack is not None
    header = bytes((0x40 | frame.type << 4 | frame.frag << 2 | acked, frame.channel, frame.seq))
    data = header + frame.payload + (bytes((frame.ack,)) if frame.ack is not None else b"")
    crc = ref_crc(data)
    return data + bytes((crc & 0xFF, crc >> 8))


# --- strategies ----------------------------------------------------------------------------

payloads = st.one_of(
    st.binary(max_size=300),
    st.lists(st.sampled_from([0x00, 0x01, 0xFF, 0x0A]), max_size=300).map(bytes),
    st.integers(0, 1100).map(lambda n: b"\x55" * n),
    st.integers(0, 600).map(bytes),
)
frames = st.builds(
    Frame,
    st.sampled_from(FrameType),
    st.integers(0, 255),
    st.integers(0, 255),
    payloads,
    st.sampled_from(Frag),
)
small_frames = st.builds(
    Frame,
    st.sampled_from(FrameType),
    st.integers(0, 255),
    st.integers(0, 255),
    st.binary(max_size=32),
    st.sampled_from(Frag),
)


def only_frames(events: list[FrameEvent]) -> list[Frame]:
    return [e for e in events if isinstance(e, Frame)]


# --- CRC -------------------------------------------------------------------------------------


def test_crc_check_value() -> None:
    assert crc16(b"123456789") == 0x29B1
    assert ref_crc(b"123456789") == 0x29B1


@bounded(100)
@given(st.binary(max_size=300))
def test_crc_matches_bitwise_reference(data: bytes) -> None:
    assert crc16(data) == ref_crc(data)


# --- COBS ------------------------------------------------------------------------------------

SEQ_1_254 = bytes(range(1, 255))


@pytest.mark.parametrize(
    ("raw", "encoded"),
    [
        (b"", b"\x01"),
        (b"\x00", b"\x01\x01"),
        (b"\x00\x00", b"\x01\x01\x01"),
        (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
        (b"\x11\x22\x33\x44", b"\x05\x11\x22\x33\x44"),
        (b"\x11\x00\x00\x00", b"\x02\x11\x01\x01\x01"),
        (SEQ_1_254, b"\xff" + SEQ_1_254),
        (b"\x00" + SEQ_1_254, b"\x01\xff" + SEQ_1_254),
        (SEQ_1_254 + b"\xff", b"\xff" + SEQ_1_254 + b"\x02\xff"),
        (SEQ_1_254 + b"\x00", b"\xff" + SEQ_1_254 + b"\x01\x01"),
        (bytes(range(3, 256)) + b"\x00\x01", b"\xfe" + bytes(range(3, 256)) + b"\x02\x01"),
    ],
)
def test_cobs_known_encodings(raw: bytes, encoded: bytes) -> None:
    assert cobs.encode(raw) == encoded
    assert cobs.decode(encoded) == raw


cobs_inputs = st.one_of(
    st.binary(max_size=1200),
    st.lists(st.sampled_from([0, 1, 0xFF]), max_size=800).map(bytes),
    st.tuples(st.integers(0, 1100), st.integers(0, 3)).map(
        lambda t: b"\x07" * t[0] + b"\x00" * t[1]
    ),
)


@bounded(300)
@given(cobs_inputs)
def test_cobs_round_trip(data: bytes) -> None:
    encoded = cobs.encode(data)
    assert 0 not in encoded
    assert encoded == ref_cobs_encode(data)
    assert cobs.decode(encoded) == data
    # Longest canonical encoding, and the bound a decoder's buffer needs.
    assert len(encoded) <= len(data) + max(1, -(-len(data) // 254))
    lenient = ref_cobs_encode(data, trailing_group=True)
    assert len(lenient) <= cobs.max_encoded_size(len(data))
    assert cobs.decode(lenient) == data


@pytest.mark.parametrize("bad", [b"", b"\x00", b"\x01\x00", b"\x05\x01", b"\x02\x41\x03\x42"])
def test_cobs_decode_rejects_invalid(bad: bytes) -> None:
    with pytest.raises(FramingError):
        cobs.decode(bad)


@bounded(200)
@given(st.binary(min_size=1, max_size=600).filter(lambda b: 0 not in b))
def test_cobs_decode_of_any_run_is_none_or_consistent(run: bytes) -> None:
    decoded = cobs.decode_or_none(run)
    if decoded is not None:
        # Whatever decodes must encode back to the run (canonical) or to the run minus the
        # empty final group that lenient encoders add.
        assert cobs.encode(decoded) in (run, run[:-1])


# --- frames ----------------------------------------------------------------------------------


def test_header_byte0_table() -> None:
    expected = {
        FrameType.BEST_EFFORT: [0x40, 0x44, 0x48, 0x4C],
        FrameType.RELIABLE: [0x50, 0x54, 0x58, 0x5C],
        FrameType.ACK: [0x60, 0x64, 0x68, 0x6C],
    }
    for ftype, row in expected.items():
        for frag, byte0 in zip(Frag, row, strict=True):
            body = cobs.decode(encode_frame(Frame(ftype, 1, 2, b"", frag))[:-1])
            assert body[0] == byte0
            assert f"`{byte0:02X}`" in PROTOCOL_MD or ftype is FrameType.ACK


@bounded(250)
@given(frames)
def test_frame_round_trip(frame: Frame) -> None:
    wire = encode_frame(frame)
    assert wire.endswith(b"\x00")
    assert 0 not in wire[:-1]
    assert wire == ref_cobs_encode(ref_body(frame)) + b"\x00"
    assert len(wire) <= wire_size(len(frame.payload))
    if 0 not in ref_body(frame):
        assert len(wire) == wire_size(len(frame.payload))
    assert decode_frame(wire) == frame
    decoder = FrameDecoder(max_payload=len(frame.payload))
    assert decoder.feed(wire) == [frame]
    assert decoder.feed(encode_frame(frame, lead=True)) == [frame]
    assert decoder.stats.frames == 2
    assert decoder.buffered == 0


@pytest.mark.parametrize(
    "frame",
    [
        Frame(FrameType.BEST_EFFORT, 256, 0, b""),
        Frame(FrameType.BEST_EFFORT, -1, 0, b""),
        Frame(FrameType.BEST_EFFORT, 0, 256, b""),
        Frame(3, 0, 0, b""),  # type: ignore[arg-type]
        Frame(FrameType.ACK, 0, 0, b"", 4),  # type: ignore[arg-type]
    ],
)
def test_encode_rejects_out_of_range_fields(frame: Frame) -> None:
    with pytest.raises(FramingError):
        encode_frame(frame)


def test_framing_error_is_a_hwbridge_error() -> None:
    with pytest.raises(HwBridgeError, match=r"0\.\.255"):
        encode_frame(Frame(FrameType.RELIABLE, 300, 0, b""))


@pytest.mark.parametrize(
    ("payload", "overhead"),
    [(0, 7), (16, 7), (200, 7), (249, 7), (250, 8), (254, 8), (503, 8), (504, 9), (1000, 10)],
)
def test_overhead(payload: int, overhead: int) -> None:
    assert frame_overhead(payload) == overhead
    # Worst case on the wire: a body without zeros (header and CRC chosen non-zero).
    for seq in range(1, 256):
        frame = Frame(FrameType.BEST_EFFORT, 1, seq, b"\x55" * payload)
        if 0 not in ref_body(frame):
            assert len(encode_frame(frame)) - payload == overhead
            return
    pytest.fail("no zero-free body found")


@bounded(150)
@given(st.integers(0, 254), payloads.map(lambda p: p[:254]), st.integers(0, 255))
def test_overhead_is_at_most_8_up_to_254_bytes(size: int, pattern: bytes, seq: int) -> None:
    payload = (pattern + b"\x55" * size)[:size]
    assert len(encode_frame(Frame(FrameType.RELIABLE, 9, seq, payload))) - size <= 8


def test_overhead_table_in_protocol_md_is_right() -> None:
    table = PROTOCOL_MD.split("<!-- overhead-table")[1].split("\n\n")[0]
    rows = [line for line in table.splitlines() if re.match(r"\| \d", line)]
    assert len(rows) == 6
    for row in rows:
        cells = [cell.strip() for cell in row.strip("|").split("|")]
        size = int(cells[0].split()[0])
        mtu = int(m.group(1)) if (m := re.search(r"MTU (\d+):", cells[0])) else size
        parts = fragment(FrameType.BEST_EFFORT, 1, 0, b"\x55" * size, mtu)
        bodies = [len(f.payload) + 5 for f in parts]
        wire = sum(wire_size(len(f.payload)) for f in parts)
        assert int(cells[1]) == sum(bodies), row
        assert int(cells[2]) == sum(max(1, -(-b // 254)) for b in bodies), row
        assert int(cells[3]) == wire, row
        assert int(cells[4]) == wire - size, row
        assert cells[5] == (f"{wire / size:.3f}" if size else "—"), row


def test_worked_examples_in_protocol_md_match() -> None:
    def doc_hex(frame: Frame) -> str:
        return encode_frame(frame).hex(" ").upper()

    assert doc_hex(Frame(FrameType.RELIABLE, 5, 7, bytes.fromhex("020000006869"))) in (PROTOCOL_MD)
    assert doc_hex(Frame(FrameType.ACK, 5, 7, b"")) in PROTOCOL_MD
    for part in fragment(FrameType.BEST_EFFORT, 4, 20, bytes(range(0x30, 0x3A)), 8):
        assert doc_hex(part) in PROTOCOL_MD
    assert f"{max_run_size(DEFAULT_MAX_PAYLOAD)} bytes for hwbridge's default" in PROTOCOL_MD


# --- golden vectors --------------------------------------------------------------------------


def vector_frame(spec: dict[str, Any]) -> Frame:
    return Frame(
        FrameType[spec["type"]],
        spec["channel"],
        spec["seq"],
        bytes.fromhex(spec["payload_hex"]),
        Frag[spec["frag"]],
        spec.get("ack"),
    )


@pytest.mark.parametrize("vector", VECTORS["vectors"], ids=lambda v: v["name"])
def test_golden_vector(vector: dict[str, Any]) -> None:
    frame = vector_frame(vector["frame"])
    wire = bytes.fromhex(vector["hex"])
    assert encode_frame(frame) == wire
    assert ref_cobs_encode(ref_body(frame)) + b"\x00" == wire
    assert FrameDecoder().feed(wire) == [frame]


@pytest.mark.parametrize("vector", VECTORS["decode_only"], ids=lambda v: v["name"])
def test_golden_decode_only(vector: dict[str, Any]) -> None:
    frame = vector_frame(vector["frame"])
    wire = bytes.fromhex(vector["hex"])
    assert encode_frame(frame) != wire
    assert FrameDecoder().feed(wire) == [frame]


@pytest.mark.parametrize("case", VECTORS["fragmentation"], ids=lambda v: v["name"])
def test_golden_fragmentation(case: dict[str, Any]) -> None:
    message = bytes.fromhex(case["message_hex"])
    ftype = FrameType[case["type"]]
    parts = fragment(ftype, case["channel"], case["first_seq"], message, case["max_payload"])
    assert [encode_frame(f).hex() for f in parts] == case["frames_hex"]
    decoder = FrameDecoder(max_payload=case["max_payload"])
    decoded = only_frames(decoder.feed(bytes.fromhex("".join(case["frames_hex"]))))
    assert decoded == parts
    reassembler = Reassembler(max_message=len(message))
    out = [reassembler.feed(f) for f in decoded]
    assert out[-1] == message
    assert all(m is None for m in out[:-1])


@pytest.mark.parametrize("case", VECTORS["bad"], ids=lambda v: v["name"])
def test_golden_bad(case: dict[str, Any]) -> None:
    decoder = FrameDecoder(max_payload=case.get("max_payload", DEFAULT_MAX_PAYLOAD))
    wire = bytes.fromhex(case["hex"])
    events = decoder.feed(wire)
    assert len(events) == 1
    if case["expect"] == "text":
        assert events == [NonFrameBytes(wire[:-1])]
        assert decoder.stats.non_frame_bytes == len(wire) - 1
    else:
        # An over-long run is reported by its head (at most max_buffer bytes).
        reason = BadFrameReason(case["expect"])
        assert events == [BadFrame(reason, wire[:-1][: decoder.max_buffer])]
        counters = decoder.stats.as_dict()
        assert sum(v for k, v in counters.items() if k != "bytes") == 1
    assert decoder.stats.frames == 0


def test_golden_vectors_cover_the_format() -> None:
    kinds = {(v["frame"]["type"], v["frame"]["frag"]) for v in VECTORS["vectors"]}
    for ftype in ("BEST_EFFORT", "RELIABLE"):
        for frag in Frag:
            assert (ftype, frag.name) in kinds
    assert ("ACK", "WHOLE") in kinds
    expects = {case["expect"] for case in VECTORS["bad"]}
    assert expects == {reason.value for reason in BadFrameReason} | {"text"}
    wires = [bytes.fromhex(v["hex"]) for v in VECTORS["vectors"]]
    assert any(w[0] == 0xFF for w in wires)  # a full 254-byte COBS group
    assert any(len(v["frame"]["payload_hex"]) == 0 for v in VECTORS["vectors"])


# --- decoder robustness ----------------------------------------------------------------------


def split_at(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({0, len(data), *(c % (len(data) + 1) for c in cuts)})
    return [data[a:b] for a, b in itertools.pairwise(points)]


@bounded(200)
@given(
    st.binary(max_size=3000),
    st.lists(st.integers(0, 3000), max_size=8),
    small_frames,
)
def test_garbage_never_raises_and_frame_after_delimiter_decodes(
    garbage: bytes, cuts: list[int], frame: Frame
) -> None:
    decoder = FrameDecoder(max_payload=32)
    for chunk in split_at(garbage, cuts):
        for event in decoder.feed(chunk):
            assert isinstance(event, Frame | NonFrameBytes | BadFrame)
        assert decoder.buffered <= decoder.max_buffer
    events = decoder.feed(b"\x00" + encode_frame(frame))
    assert events[-1] == frame
    assert decoder.buffered == 0


@bounded(100)
@given(st.binary(min_size=1, max_size=1 << 16), st.integers(1, 4096))
def test_memory_stays_bounded(garbage: bytes, chunk_size: int) -> None:
    decoder = FrameDecoder(max_payload=16)
    for start in range(0, len(garbage), chunk_size):
        decoder.feed(garbage[start : start + chunk_size])
        assert decoder.buffered <= decoder.max_buffer
    assert decoder.stats.bytes == len(garbage)


def test_oversize_binary_run_is_reported_once_and_dropped() -> None:
    decoder = FrameDecoder(max_payload=64)
    noise = bytes(random.Random(7).randrange(0x80, 0x100) for _ in range(100_000))
    events = []
    for start in range(0, len(noise), 1000):
        events += decoder.feed(noise[start : start + 1000])
        assert decoder.buffered <= decoder.max_buffer
    assert events == [BadFrame(BadFrameReason.OVERSIZE, noise[: decoder.max_buffer])]
    frame = Frame(FrameType.RELIABLE, 3, 4, b"after")
    assert decoder.feed(b"\x00" + encode_frame(frame)) == [frame]
    assert decoder.stats.oversize == 1


def test_payload_above_max_payload_is_oversize() -> None:
    decoder = FrameDecoder(max_payload=300)
    payload = bytes(150) + b"\x01" * 151  # zeros keep the run within max_frame
    wire = encode_frame(Frame(FrameType.BEST_EFFORT, 1, 1, payload))
    assert len(wire) - 1 <= decoder.max_frame
    assert decoder.feed(wire) == [BadFrame(BadFrameReason.OVERSIZE, wire[:-1])]
    decoder.max_payload = 301
    assert decoder.feed(wire) == [Frame(FrameType.BEST_EFFORT, 1, 1, payload)]
    assert decoder.stats.oversize == 1


def test_empty_runs_are_ignored_and_input_types() -> None:
    decoder = FrameDecoder()
    assert decoder.feed(b"") == []
    assert decoder.feed(b"\x00" * 10) == []
    frame = Frame(FrameType.ACK, 0, 255, b"")
    wire = encode_frame(frame)
    assert decoder.feed(bytearray(wire)) == [frame]
    assert decoder.feed(memoryview(b"\x00\x00" + wire)) == [frame]
    assert decoder.stats.bytes == 10 + 2 * len(wire) + 2


def test_version_mismatch_is_reported_distinctly() -> None:
    body = bytes((0x80 | 0x10, 1, 2, 0x41))
    crc = crc16(body)
    wire = cobs.encode(body + bytes((crc & 0xFF, crc >> 8))) + b"\x00"
    decoder = FrameDecoder()
    [event] = decoder.feed(wire)
    assert event == BadFrame(BadFrameReason.VERSION, wire[:-1])
    assert isinstance(event, BadFrame)
    assert cobs.decode(event.data)[0] >> 6 == 2
    assert decoder.stats.version_errors == 1
    assert decoder.stats.crc_errors == 0


def test_decode_frame_rejects() -> None:
    good = encode_frame(Frame(FrameType.BEST_EFFORT, 1, 1, b"x"))
    assert decode_frame(good[:-1]) == Frame(FrameType.BEST_EFFORT, 1, 1, b"x")
    for bad in (b"", b"\x00", good + good, good[:-2] + b"\x00"):
        with pytest.raises(FramingError):
            decode_frame(bad)


def stream_parts() -> st.SearchStrategy[bytes]:
    frame_wire = small_frames.map(encode_frame)
    return st.one_of(
        frame_wire,
        frame_wire.map(lambda w: w[:-1] + b"\x37"),  # corrupted delimiter
        st.binary(max_size=120),
        st.just(b"debug: x=3\r\n"),
        st.just(b"T=21.5C "),
        st.integers(30, 400).map(lambda n: (b"log line\r\n" * n)[:n]),  # over max_buffer
        st.just(b"\x00"),
    )


@bounded(200)
@given(st.lists(stream_parts(), max_size=12), st.lists(st.integers(0, 4000), max_size=10))
def test_chunking_does_not_change_events(parts: list[bytes], cuts: list[int]) -> None:
    stream = b"".join(parts)
    whole = FrameDecoder(max_payload=32)
    chunked = FrameDecoder(max_payload=32)
    expected = whole.feed(stream)
    got = []
    for chunk in split_at(stream, cuts):
        got += chunked.feed(chunk)
    assert got == expected
    assert chunked.stats == whole.stats
    one_by_one = FrameDecoder(max_payload=32)
    assert [e for i in range(len(stream)) for e in one_by_one.feed(stream[i : i + 1])] == expected


@bounded(300)
@given(
    st.lists(st.builds(Frame, st.sampled_from(FrameType), st.integers(0, 255),
                       st.integers(0, 255), payloads.map(lambda p: p[:300]),
                       st.sampled_from(Frag)), min_size=1, max_size=8),
    st.integers(0, 1 << 20),
    st.integers(1, 255),
)  # fmt: skip
def test_single_byte_corruption_loses_at_most_its_frame(
    sent: list[Frame], where: int, flip: int
) -> None:
    wires = [encode_frame(f) for f in sent]
    stream = bytearray(b"".join(wires))
    position = where % len(stream)
    stream[position] ^= flip
    owner = 0
    offset = len(wires[0])
    while position >= offset:
        owner += 1
        offset += len(wires[owner])
    decoder = FrameDecoder(max_payload=300)
    got = only_frames(decoder.feed(bytes(stream)))
    assert got in (sent, sent[:owner] + sent[owner + 1 :])


def test_corrupted_delimiter_loses_nothing() -> None:
    first = Frame(FrameType.RELIABLE, 5, 7, b"\x02\x00\x00\x00hi")
    second = Frame(FrameType.BEST_EFFORT, 1, 9, bytes(range(1, 256)) * 2)
    stream = encode_frame(first)[:-1] + b"\x99" + encode_frame(second)
    decoder = FrameDecoder()
    assert decoder.feed(stream) == [first, second]


def test_corrupted_delimiter_before_a_long_frame_loses_nothing() -> None:
    # The glued run is longer than one frame can be: it is still split into its two frames.
    first = Frame(FrameType.BEST_EFFORT, 0, 0, bytes(2))
    second = Frame(FrameType.BEST_EFFORT, 0, 1, bytes(39) + b"\x01" * 261)
    stream = encode_frame(first)[:-1] + b"\x01" + encode_frame(second)
    decoder = FrameDecoder(max_payload=300)
    assert len(stream) - 1 > decoder.max_frame
    assert decoder.feed(stream) == [first, second]
    chunked = FrameDecoder(max_payload=300)
    assert [e for b in stream for e in chunked.feed(bytes((b,)))] == [first, second]


def test_damaged_frame_is_not_mistaken_for_a_shorter_one() -> None:
    # A frame with one damaged code byte, found by search: one of its COBS group boundaries
    # ends a prefix with a valid header and CRC. Only the check of the rest (as frame B of
    # ``A X B``) keeps the decoder from returning that truncated frame.
    run = bytes.fromhex(
        "044001310101010103010201024101034141010102020202010341020451024102010103410101030c26"
    )
    trap = [
        end
        for end in range(6, len(run))
        if (body := cobs.decode_or_none(run[:end])) is not None
        and len(body) >= 5
        and body[0] >> 6 == 1
        and crc16(body[:-2]) == int.from_bytes(body[-2:], "little")
    ]
    assert trap  # the weaker rule (a CRC-valid prefix is enough) would return a frame here
    decoder = FrameDecoder()
    events = decoder.feed(run + b"\x00")
    assert only_frames(events) == []
    assert decoder.stats.crc_errors + decoder.stats.cobs_errors == 1


# --- text on the line ------------------------------------------------------------------------

TEXT = b"debug: x=3\r\n"


@bounded(100)
@given(st.lists(small_frames, min_size=1, max_size=6), st.booleans())
def test_text_between_frames_is_reported_and_frames_decode(sent: list[Frame], lead: bool) -> None:
    stream = b"".join(TEXT + encode_frame(f, lead=lead) for f in sent)
    decoder = FrameDecoder(max_payload=32)
    events = decoder.feed(stream)
    assert only_frames(events) == sent
    assert [e for e in events if not isinstance(e, Frame)] == [NonFrameBytes(TEXT)] * len(sent)
    assert decoder.stats.non_frame_bytes == len(TEXT) * len(sent)
    assert decoder.stats.crc_errors + decoder.stats.cobs_errors == 0


def test_text_glued_to_frame_is_split_as_in_the_worked_example() -> None:
    ack = Frame(FrameType.ACK, 5, 7, b"")
    run = TEXT + encode_frame(ack)
    assert run[:-1].hex(" ").upper() in PROTOCOL_MD.replace("\n", " ")
    assert FrameDecoder().feed(run) == [NonFrameBytes(TEXT), ack]


def test_long_text_without_delimiter_is_reported_in_pieces() -> None:
    decoder = FrameDecoder(max_payload=16)
    text = b"".join(b"line %d of a long boot banner\r\n" % i for i in range(40))
    frame = Frame(FrameType.BEST_EFFORT, 2, 3, b"ok")
    events = decoder.feed(text + encode_frame(frame))
    assert b"".join(e.data for e in events if isinstance(e, NonFrameBytes)) == text
    assert events[-1] == frame
    assert all(len(e.data) <= decoder.max_buffer for e in events if isinstance(e, NonFrameBytes))


def test_text_without_newline_glued_to_frame_loses_that_frame_only() -> None:
    frame = Frame(FrameType.BEST_EFFORT, 2, 3, b"\x10\x20")
    decoder = FrameDecoder()
    events = decoder.feed(b"x=" + encode_frame(frame) + encode_frame(frame))
    assert only_frames(events) == [frame]
    assert len(events) == 2


def test_binary_garbage_is_a_bad_frame_not_text() -> None:
    decoder = FrameDecoder()
    [event] = decoder.feed(b"\x03\x81\x82\x83\x84\x85\x00")
    assert isinstance(event, BadFrame)
    assert event.reason in (BadFrameReason.COBS, BadFrameReason.CRC, BadFrameReason.TOO_SHORT)


# --- fragmentation ---------------------------------------------------------------------------

MTUS = [5, 6, 8, 64, 200, 254, 1024]


@bounded(40)
@given(
    st.one_of(st.integers(0, 300), st.integers(0, 1 << 16)),
    st.sampled_from(MTUS),
    st.sampled_from([FrameType.BEST_EFFORT, FrameType.RELIABLE]),
    st.integers(0, 255),
    st.integers(0, 255),
    st.randoms(use_true_random=False),
)
def test_fragment_and_reassemble_round_trip(
    size: int,
    mtu: int,
    ftype: FrameType,
    channel: int,
    first_seq: int,
    rnd: random.Random,
) -> None:
    message = rnd.randbytes(size)
    parts = fragment(ftype, channel, first_seq, message, mtu)
    if size <= mtu:
        assert parts == [Frame(ftype, channel, first_seq, message)]
    else:
        assert len(parts) == 1 + -(-(size - (mtu - 4)) // mtu)
        assert [p.frag for p in parts] == [Frag.FIRST] + [Frag.MIDDLE] * (len(parts) - 2) + [
            Frag.LAST
        ]
        assert int.from_bytes(parts[0].payload[:4], "little") == size
    assert [p.seq for p in parts] == [(first_seq + i) % 256 for i in range(len(parts))]
    assert all(len(p.payload) <= mtu and p.channel == channel for p in parts)
    decoder = FrameDecoder(max_payload=mtu)
    decoded = only_frames(decoder.feed(b"".join(encode_frame(p) for p in parts)))
    assert decoded == parts
    reassembler = Reassembler(max_message=size)
    results = [reassembler.feed(p) for p in decoded]
    assert results[-1] == message
    assert results[:-1] == [None] * (len(parts) - 1)
    assert reassembler.stats.as_dict() == {
        "messages": 1,
        "dropped_partial": 0,
        "oversize": 0,
        "orphans": 0,
        "malformed": 0,
        "duplicates": 0,
    }


def test_fragment_rejects_bad_requests() -> None:
    with pytest.raises(FramingError, match="ACK"):
        fragment(FrameType.ACK, 1, 0, b"x", 64)
    with pytest.raises(FramingError, match="at least 5"):
        fragment(FrameType.RELIABLE, 1, 0, b"123456", 4)
    assert len(fragment(FrameType.RELIABLE, 1, 0, b"1234", 4)) == 1


def message_frames(sizes: list[int], mtu: int) -> tuple[list[bytes], list[Frame], list[int]]:
    """Messages on alternating channels, fragmented in one BEST_EFFORT sequence space.

    Returns the messages, their frames in order, and the index of the message of each frame.
    """
    messages: list[bytes] = []
    frames_out: list[Frame] = []
    owners: list[int] = []
    seq = 250
    for index, size in enumerate(sizes):
        message = bytes((index * 37 + k) % 251 + 1 for k in range(size))
        parts = fragment(FrameType.BEST_EFFORT, 1 + index % 2, seq, message, mtu)
        seq += len(parts)
        messages.append(message)
        frames_out += parts
        owners += [index] * len(parts)
    return messages, frames_out, owners


@bounded(300)
@given(st.lists(st.integers(0, 60), min_size=1, max_size=6), st.data())
def test_reassembly_under_loss_duplication_reordering_never_yields_a_wrong_message(
    sizes: list[int], data: st.DataObject
) -> None:
    messages, sent, owners = message_frames(sizes, mtu=8)
    actions = data.draw(
        st.lists(st.sampled_from(["keep", "keep", "keep", "drop", "dup"]),
                 min_size=len(sent), max_size=len(sent))
    )  # fmt: skip
    received: list[tuple[int, Frame]] = []
    for owner, frame, action in zip(owners, sent, actions, strict=True):
        if action != "drop":
            received.append((owner, frame))
        if action == "dup":
            received.append((owner, frame))
    for swap in data.draw(st.lists(st.integers(0, max(0, len(received) - 2)), max_size=3)):
        if len(received) >= 2:
            received[swap], received[swap + 1] = received[swap + 1], received[swap]
    reassembler = Reassembler(max_message=60)
    delivered = []
    for _, frame in received:
        out = reassembler.feed(frame)
        assert reassembler.buffered <= 60
        if out is not None:
            delivered.append((frame.channel, out))
    reassembler.reset()
    originals = [(1 + i % 2, m) for i, m in enumerate(messages)]
    for item in delivered:
        assert item in originals  # never a wrong message
    if [f for _, f in received] == sent:
        assert delivered == originals
        assert reassembler.stats.dropped_partial == reassembler.stats.orphans == 0
    # Every fragment received whose message never came out left a counted trace.
    lost = {o for o, f in received if f.frag != Frag.WHOLE and originals[o] not in delivered}
    stats = reassembler.stats
    assert (stats.dropped_partial + stats.orphans + stats.malformed > 0) or not lost


def test_reassembly_counts_each_kind_of_drop() -> None:
    _, sent, _ = message_frames([20, 20], mtu=8)  # 3 frames each: seqs 250..252, 253..255
    first, middle, last, first2, middle2, last2 = sent

    r = Reassembler(max_message=100)
    assert [r.feed(f) for f in (first, last)] == [None, None]  # MIDDLE lost
    assert (r.stats.dropped_partial, r.stats.orphans) == (1, 1)
    assert not r.in_progress

    r = Reassembler(max_message=100)
    assert [r.feed(f) for f in (middle, last)] == [None, None]  # FIRST lost
    assert r.stats.orphans == 2

    r = Reassembler(max_message=100)
    out = [r.feed(f) for f in (first, first, middle, middle, last, last)]
    assert out[-2] is not None and out.count(None) == 5
    assert r.stats.duplicates == 3

    r = Reassembler(max_message=100)
    r.feed(first)
    r.feed(middle)
    assert r.feed(first2) is None  # new FIRST without LAST
    assert r.stats.dropped_partial == 1
    assert r.feed(middle2) is None
    assert r.feed(last2) is not None

    r = Reassembler(max_message=19)  # too small: refused before buffering, quietly skipped
    assert [r.feed(f) for f in sent] == [None] * 6
    assert r.stats.oversize == 2
    assert r.stats.orphans == 0
    assert r.buffered == 0

    r = Reassembler(max_message=100)
    wrong_length = Frame(FrameType.BEST_EFFORT, 1, 250, (21).to_bytes(4, "little") + b"abcd",
                         Frag.FIRST)  # fmt: skip
    assert [r.feed(f) for f in (wrong_length, middle, last)] == [None, None, None]
    assert r.stats.malformed == 1
    short_first = Frame(FrameType.BEST_EFFORT, 1, 0, b"\x01", Frag.FIRST)
    assert r.feed(short_first) is None
    assert r.stats.malformed == 2

    r = Reassembler(max_message=100)
    r.feed(first)
    r.reset()
    assert r.stats.dropped_partial == 1
    whole = Frame(FrameType.RELIABLE, 4, 1, b"w")
    assert r.feed(whole) == b"w"
    assert r.feed(whole) is None
    assert r.stats.duplicates == 1


def test_reassembly_rejects_fragment_from_another_channel() -> None:
    _, sent, _ = message_frames([20], mtu=8)
    first, middle, last = sent
    moved = Frame(middle.type, middle.channel + 1, middle.seq, middle.payload, middle.frag)
    r = Reassembler(max_message=100)
    assert [r.feed(f) for f in (first, moved, last)] == [None, None, None]
    assert r.stats.dropped_partial == 1
