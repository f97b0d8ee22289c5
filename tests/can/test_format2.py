"""CAN.md format 2 (the native header in the id and the tail byte, no native CRC-16) against its
golden vectors (protocols/vectors/can_frames_v2.json), and property tests (seeded, bounded):
round trips of native datagrams, garbage, loss, duplication, reordering across interleaved
transfers of several nodes, corruption."""

from __future__ import annotations

import json
import random
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge.protocols.can.transport import (
    CLASSIC_MTU,
    FD_MTU,
    FORMAT_1,
    FORMAT_2,
    Kind,
    TransferDecoder,
    TransferEncoder,
    acceptance_filters,
    crc16,
    decode_id,
    encode_id,
    encode_id2,
    frame_lengths,
)

VECTORS = json.loads(
    (
        Path(__file__).resolve().parents[2] / "protocols" / "vectors" / "can_frames_v2.json"
    ).read_text()
)
PROPERTY = settings(max_examples=150, deadline=None, derandomize=True)
MTUS = st.sampled_from([CLASSIC_MTU, 12, 16, 32, FD_MTU])


def datagram(frame_type: int, frag: int, channel: int, seq: int, payload: bytes) -> bytes:
    """A native datagram (PROTOCOL.md §1.13): header, payload, CRC-16 little-endian."""
    body = bytes((0x40 | frame_type << 4 | frag << 2, channel, seq)) + payload
    return body + crc16(body).to_bytes(2, "little")


@pytest.mark.parametrize("vector", VECTORS["ids"], ids=lambda v: v["name"])
def test_id_vectors(vector: dict) -> None:
    fields = vector["fields"]
    can_id = int(vector["id"], 16)
    assert encode_id2(**fields) == can_id
    decoded = decode_id(can_id)
    assert decoded is not None and decoded.format == FORMAT_2
    assert (
        decoded.priority,
        decoded.kind,
        decoded.channel,
        decoded.destination,
        decoded.source,
        decoded.seq_high,
        decoded.frag,
    ) == (
        fields["priority"],
        fields["kind"],
        fields["channel"],
        fields["destination"],
        fields["source"],
        fields["seq"] >> 5,
        fields["frag"],
    )
    assert decoded.encode() == can_id


@pytest.mark.parametrize("vector", VECTORS["datagrams"], ids=lambda v: v["name"])
def test_datagram_vectors(vector: dict) -> None:
    sent = bytes.fromhex(vector["datagram_hex"])
    encoder = TransferEncoder(vector["source"], vector["mtu"])
    frames = encoder.datagram(sent, vector["destination"])
    assert [(f"{i:08x}", d.hex()) for i, d in frames] == [
        (f["id"], f["data_hex"]) for f in vector["frames"]
    ]
    # neither the native header nor its CRC-16 travels: the frames carry the payload (and a
    # transfer CRC when there are several), the tail bytes
    carried = sum(len(d) - 1 for _, d in frames)
    assert carried == len(sent) - 5 + (2 if len(frames) > 1 else 0)
    decoder = TransferDecoder(vector["destination"])
    out = [
        decoder.feed(int(f["id"], 16), bytes.fromhex(f["data_hex"]), 0.0) for f in vector["frames"]
    ]
    assert all(o is None for o in out[:-1])
    last = out[-1]
    assert last is not None
    assert last.payload == sent  # rebuilt whole, header and CRC-16
    assert (last.source, last.destination, last.format) == (
        vector["source"],
        vector["destination"],
        FORMAT_2,
    )


@pytest.mark.parametrize("vector", VECTORS["bad"], ids=lambda v: v["name"])
def test_bad_vectors(vector: dict) -> None:
    decoder = TransferDecoder(vector["local"])
    for frame in vector["frames"]:
        assert (
            decoder.feed(
                int(frame["id"], 16),
                bytes.fromhex(frame["data_hex"]),
                0.0,
                extended=frame["extended"],
            )
            is None
        )
    counters = decoder.stats.as_dict()
    assert counters[vector["expect"]] == 1, counters
    others = {
        k: v
        for k, v in counters.items()
        if k not in ("frames", "transfers", "foreign", vector["expect"])
    }
    assert not any(others.values()), others


def test_format_1_decoder_path_keeps_refusing_format_2() -> None:
    """An old receiver drops every format-2 frame (bit 15 was reserved): the vectors of
    can_frames.json's 'reserved id bits set' cover the same bit; here, that every format-2 id
    has bit 15 set and every format-1 id has it clear."""
    for vector in VECTORS["ids"]:
        assert int(vector["id"], 16) & 0x8000
    assert not encode_id(7, 3, 255, 127, 127) & 0xC000


def test_bad_datagrams_are_refused_by_the_encoder() -> None:
    encoder = TransferEncoder(3)
    good = datagram(0, 0, 1, 5, b"abc")
    with pytest.raises(ValueError, match="CRC"):
        encoder.datagram(good[:-1] + bytes([good[-1] ^ 1]), 0)
    with pytest.raises(ValueError, match="at least 5"):
        encoder.datagram(good[:4], 0)
    with pytest.raises(ValueError, match="known type"):
        encoder.datagram(datagram(3, 0, 1, 5, b""), 0)
    with pytest.raises(ValueError, match="to or from the host"):
        TransferEncoder(3).datagram(good, 4)
    # format 1 carries whatever it is given, as before
    assert encoder.datagram(good[:4], 0, format=FORMAT_1)


def test_a_reliable_resend_gets_through() -> None:
    """Format 2 leaves repeats to the session: a resent reliable datagram (same seq, same
    content) must arrive again, or the receiver could never acknowledge it a second time."""
    encoder = TransferEncoder(4)
    decoder = TransferDecoder(0)
    sent = datagram(1, 0, 1, 17, b"0123456789abcdef")
    for attempt in range(3):
        out = [decoder.feed(i, d, attempt * 0.01) for i, d in encoder.datagram(sent, 0)]
        assert out[-1] is not None and out[-1].payload == sent
    assert decoder.stats.dropped == 0


@PROPERTY
@given(st.integers(1, 127), st.integers(0, 255), st.integers(0, 3))
def test_filters_take_own_format_2_transfers_only(node: int, seq: int, frag: int) -> None:
    def wanted(local: int, can_id: int) -> bool:
        return any((can_id ^ v) & m == 0 for v, m in acceptance_filters(local))

    to_node = encode_id2(4, Kind.RELIABLE, 9, node, 0, seq, frag)
    from_node = encode_id2(5, Kind.BEST_EFFORT, 9, 0, node, seq, frag)
    other = node % 127 + 1
    assert wanted(node, to_node) and not wanted(other, to_node)
    assert wanted(0, from_node) and not wanted(other, from_node)
    assert wanted(other, encode_id2(3, Kind.NODE, 1, 0, node))


# ----------------------------------------------------------------------------- properties

_NATIVE = st.tuples(
    st.sampled_from([0, 1, 2]),  # type
    st.integers(0, 3),  # frag
    st.integers(0, 255),  # channel
    st.binary(max_size=150),
)


def _datagrams(items: list[tuple[int, int, int, bytes]], salt: int = 0) -> list[bytes]:
    """Distinct datagrams (seq from the index, a prefix naming the datagram)."""
    return [
        datagram(t, f, c, (i + salt) & 0xFF, bytes([i, salt]) + p)
        for i, (t, f, c, p) in enumerate(items)
    ]


@PROPERTY
@given(st.lists(_NATIVE, max_size=12), MTUS, st.integers(1, 127))
def test_round_trip(items: list[tuple[int, int, int, bytes]], mtu: int, node: int) -> None:
    sent = _datagrams(items)
    for source, destination in ((node, 0), (0, node)):
        encoder = TransferEncoder(source, mtu)
        decoder = TransferDecoder(destination)
        got = []
        for d in sent:
            frames = encoder.datagram(d, destination)
            assert len(frames) == len(frame_lengths(len(d) - 5, mtu))
            for can_id, data in frames:
                transfer = decoder.feed(can_id, data, 0.0)
                if transfer is not None:
                    got.append(transfer.payload)
        assert got == sent
        assert decoder.stats.dropped == 0 and decoder.pending == 0


@PROPERTY
@given(
    st.lists(
        st.tuples(
            st.integers(0, (1 << 29) - 1).map(lambda i: i | 0x8000),
            st.binary(max_size=64),
        ),
        max_size=200,
    )
)
def test_format_2_garbage_is_counted_never_raises(frames: list[tuple[int, bytes]]) -> None:
    decoder = TransferDecoder(None, max_pending=16, max_transfer=256)
    for index, (can_id, data) in enumerate(frames):
        transfer = decoder.feed(can_id, data, index * 0.01)
        if transfer is not None and transfer.kind is not Kind.NODE:
            # whatever garbage completes comes out as a well-formed native datagram
            assert crc16(transfer.payload[:-2]) == int.from_bytes(transfer.payload[-2:], "little")
        assert decoder.pending <= 16
    decoder.expire(1e9)
    assert decoder.stats.frames == len(frames)
    assert decoder.pending == 0


@PROPERTY
@given(
    st.lists(st.lists(_NATIVE, min_size=1, max_size=5), min_size=1, max_size=4),
    MTUS,
    st.integers(0, 2**32 - 1),
    st.sampled_from(["none", "loss", "duplicate", "reorder", "corrupt"]),
)
def test_interleaved_nodes_with_faults(
    per_node: list[list[tuple[int, int, int, bytes]]], mtu: int, seed: int, fault: str
) -> None:
    """Several boards' transfers interleaved frame by frame on one bus, then damaged: nothing
    is delivered that was not sent (a multi-frame transfer comes out whole or not at all), each
    node's datagrams keep their order, and without faults everything arrives."""
    rng = random.Random(seed)
    sent: dict[int, list[bytes]] = {}
    queues: list[list[tuple[int, bytes]]] = []
    for index, items in enumerate(per_node):
        node = index + 1
        encoder = TransferEncoder(node, mtu)
        sent[node] = _datagrams(items, salt=node)
        queues.append([f for d in sent[node] for f in encoder.datagram(d, 0)])
    bus: list[tuple[int, bytes]] = []
    while any(queues):
        queue = rng.choice([q for q in queues if q])
        bus.append(queue.pop(0))
    damaged: list[tuple[int, bytes]] = []
    for can_id, sent_data in bus:
        data = sent_data
        roll = rng.random()
        if fault == "loss" and roll < 0.2:
            continue
        if fault == "corrupt" and roll < 0.2:
            bit = rng.randrange(len(data) * 8)
            data = bytes(b ^ (1 << (bit % 8)) if i == bit // 8 else b for i, b in enumerate(data))
        damaged.append((can_id, data))
        if fault == "duplicate" and roll < 0.2:
            damaged.append((can_id, data))
    if fault == "reorder":
        for _ in range(max(1, len(damaged) // 5)):
            i, j = rng.randrange(len(damaged)), rng.randrange(len(damaged))
            damaged[i], damaged[j] = damaged[j], damaged[i]
    decoder = TransferDecoder(0)
    got: dict[int, list[bytes]] = {node: [] for node in sent}
    for index, (can_id, data) in enumerate(damaged):
        transfer = decoder.feed(can_id, data, index * 1e-3)
        if transfer is not None:
            assert transfer.format == FORMAT_2
            got[transfer.source].append(transfer.payload)
    decoder.expire(1e9)
    for node, datagrams in sent.items():
        received = got[node]
        if fault == "corrupt":
            # a corrupted single frame has only CAN's CRC (the bus's job); multi-frame
            # transfers come out intact or not at all
            multi = [d for d in datagrams if len(frame_lengths(len(d) - 5, mtu)) > 1]
            assert all(d in datagrams for d in received if len(d) - 5 >= mtu or d in multi)
            continue
        assert all(d in datagrams for d in received)
        if fault == "none":
            assert received == datagrams
        elif fault == "duplicate":
            # a repeated single frame is a repeated datagram (the session drops it by seq);
            # a repeated frame inside a multi-frame transfer is dropped here
            assert [d for i, d in enumerate(received) if i == 0 or d != received[i - 1]] == (
                datagrams
            )
        elif fault == "loss":
            it = iter(datagrams)
            assert all(d in it for d in received)
