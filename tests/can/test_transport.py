"""The CAN transport (protocols/can/transport.py) against the golden vectors of CAN.md, and
property tests (seeded, bounded): round trips, garbage, loss, corruption, duplication and
reordering never crash it, never deliver what was not sent, and count what they drop."""

from __future__ import annotations

import json
import random
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge.protocols.can.transport import (
    CLASSIC_MTU,
    FD_LENGTHS,
    FD_MTU,
    FORMAT_1,
    ConflictMonitor,
    Kind,
    TransferDecoder,
    TransferEncoder,
    crc16,
    decode_id,
    encode_id,
    frame_lengths,
    priority_of,
    queue_class,
    split_transfer,
)

VECTORS = json.loads(
    (Path(__file__).resolve().parents[2] / "protocols" / "vectors" / "can_frames.json").read_text()
)
PROPERTY = settings(max_examples=150, deadline=None, derandomize=True)
MTUS = st.sampled_from([CLASSIC_MTU, 12, 16, 32, FD_MTU])


def test_crc_check_value() -> None:
    check = VECTORS["crc_check"]
    assert f"{crc16(bytes.fromhex(check['input_hex'])):04x}" == check["crc16"]


@pytest.mark.parametrize("vector", VECTORS["ids"], ids=lambda v: v["name"])
def test_id_vectors(vector: dict) -> None:
    fields = vector["fields"]
    can_id = int(vector["id"], 16)
    assert encode_id(**fields) == can_id
    decoded = decode_id(can_id)
    assert decoded is not None
    assert (
        decoded.priority,
        decoded.kind,
        decoded.channel,
        decoded.destination,
        decoded.source,
    ) == tuple(fields.values())


@pytest.mark.parametrize("vector", VECTORS["transfers"], ids=lambda v: v["name"])
def test_transfer_vectors(vector: dict) -> None:
    payload = bytes.fromhex(vector["payload_hex"])
    frames = [bytes.fromhex(f) for f in vector["frames_hex"]]
    assert split_transfer(payload, vector["tid"], vector["mtu"]) == frames
    decoder = TransferDecoder(None)
    can_id = encode_id(4, Kind.RELIABLE, 1, 0, 9)
    results = [decoder.feed(can_id, frame, 0.0) for frame in frames]
    assert all(r is None for r in results[:-1])
    last = results[-1]
    assert last is not None
    assert last.payload == payload


@pytest.mark.parametrize("vector", VECTORS["datagrams"], ids=lambda v: v["name"])
def test_datagram_vectors(vector: dict) -> None:
    encoder = TransferEncoder(vector["source"], vector["mtu"])
    frames = encoder.datagram(
        bytes.fromhex(vector["datagram_hex"]), vector["destination"], format=FORMAT_1
    )
    assert [(f"{i:08x}", d.hex()) for i, d in frames] == [
        (f["id"], f["data_hex"]) for f in vector["frames"]
    ]
    decoder = TransferDecoder(vector["destination"])
    out = [
        decoder.feed(int(f["id"], 16), bytes.fromhex(f["data_hex"]), 0.0) for f in vector["frames"]
    ]
    assert out[-1] is not None
    assert out[-1].payload.hex() == vector["datagram_hex"]
    assert out[-1].source == vector["source"]


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
        ) or vector["expect"] in ("duplicate_transfers", "abandoned")
    counters = decoder.stats.as_dict()
    assert counters[vector["expect"]] == 1, counters
    others = {
        k: v for k, v in counters.items() if k not in ("frames", "transfers", vector["expect"])
    }
    assert not any(others.values()), others


def test_priorities_put_acks_and_control_first() -> None:
    order = [
        priority_of(Kind.ACK, 0),
        priority_of(Kind.BEST_EFFORT, 0),
        priority_of(Kind.NODE, 1),
        priority_of(Kind.RELIABLE, 7),
        priority_of(Kind.BEST_EFFORT, 7),
    ]
    assert order == sorted(order)
    assert len(set(order)) == len(order)


def test_never_ending_transfer_times_out() -> None:
    decoder = TransferDecoder(0, timeout=1.0)
    can_id = encode_id(5, Kind.BEST_EFFORT, 1, 0, 3)
    frames = split_transfer(bytes(40), 0, CLASSIC_MTU)
    for frame in frames[:-1]:
        assert decoder.feed(can_id, frame, 10.0) is None
    assert decoder.pending == 1
    assert decoder.expire(10.5) == 0
    assert decoder.expire(11.0) == 1
    assert decoder.stats.timeouts == 1
    assert decoder.pending == 0
    assert decoder.feed(can_id, frames[-1], 11.0) is None  # its end, too late
    assert decoder.stats.unexpected == 1
    # the next transfer on that id is fine
    again = split_transfer(b"next", 1, CLASSIC_MTU)
    result = decoder.feed(can_id, again[0], 11.1)
    assert result is not None
    assert result.payload == b"next"


def test_oversize_transfer_dropped() -> None:
    decoder = TransferDecoder(0, max_transfer=30)
    can_id = encode_id(5, Kind.BEST_EFFORT, 1, 0, 3)
    for frame in split_transfer(bytes(100), 0, CLASSIC_MTU):
        assert decoder.feed(can_id, frame, 0.0) is None
    assert decoder.stats.oversize == 1


def test_pending_transfers_bounded() -> None:
    decoder = TransferDecoder(None, max_pending=8)
    for source in range(1, 40):
        can_id = encode_id(5, Kind.BEST_EFFORT, 1, 0, source)
        decoder.feed(can_id, split_transfer(bytes(20), 0, CLASSIC_MTU)[0], float(source))
    assert decoder.pending == 8
    assert decoder.stats.abandoned == 39 - 8


def test_conflict_monitor() -> None:
    monitor = ConflictMonitor(window=3.0)
    assert not monitor.claim(5, b"aaaaaa", 0.0)
    assert not monitor.claim(5, b"aaaaaa", 1.0)
    assert not monitor.claim(6, b"bbbbbb", 1.0)
    assert monitor.claim(5, b"cccccc", 1.5)
    assert monitor.in_conflict(5, 2.0)
    assert not monitor.in_conflict(6, 2.0)
    assert not monitor.in_conflict(5, 5.0)
    assert monitor.conflicts == 1
    assert dict(monitor.claimed(2.0)) == {5: b"cccccc", 6: b"bbbbbb"}


@pytest.mark.parametrize("mtu", [CLASSIC_MTU, *FD_LENGTHS[9:]])
def test_frame_lengths_use_valid_lengths_only(mtu: int) -> None:
    for size in range(0, 300):
        lengths = frame_lengths(size, mtu)
        assert all(length in FD_LENGTHS and 1 <= length <= mtu for length in lengths)
        carried = sum(length - 1 for length in lengths)
        assert carried == (size if len(lengths) == 1 else size + 2)


# ----------------------------------------------------------------------------- properties


def _sent(payloads: list[bytes], mtu: int, source: int = 7) -> list[tuple[int, bytes]]:
    encoder = TransferEncoder(source, mtu)
    frames: list[tuple[int, bytes]] = []
    for payload in payloads:
        frames += encoder.transfer(encode_id(4, Kind.RELIABLE, 2, 0, source), payload)
    return frames


def _received(frames: list[tuple[int, bytes]], decoder: TransferDecoder) -> list[bytes]:
    out: list[bytes] = []
    for index, (can_id, data) in enumerate(frames):
        transfer = decoder.feed(can_id, data, index * 1e-3)
        if transfer is not None:
            out.append(transfer.payload)
    return out


@PROPERTY
@given(st.lists(st.binary(max_size=200), max_size=12), MTUS)
def test_round_trip(payloads: list[bytes], mtu: int) -> None:
    decoder = TransferDecoder(0)
    assert _received(_sent(payloads, mtu), decoder) == payloads
    assert decoder.stats.dropped == 0
    assert decoder.pending == 0


@PROPERTY
@given(
    st.lists(
        st.tuples(st.integers(0, (1 << 29) - 1), st.binary(max_size=64), st.booleans()),
        max_size=200,
    )
)
def test_garbage_is_counted_never_raises(frames: list[tuple[int, bytes, bool]]) -> None:
    decoder = TransferDecoder(0, max_pending=16, max_transfer=256)
    for index, (can_id, data, extended) in enumerate(frames):
        decoder.feed(can_id, data, index * 0.01, extended=extended)
        assert decoder.pending <= 16
    decoder.expire(1e9)
    stats = decoder.stats
    assert stats.frames == len(frames)
    assert decoder.pending == 0


@PROPERTY
@given(
    st.lists(st.binary(min_size=1, max_size=120), min_size=1, max_size=10),
    MTUS,
    st.integers(0, 2**32 - 1),
    st.sampled_from(["loss", "duplicate", "reorder", "corrupt"]),
)
def test_faults_never_deliver_what_was_not_sent(
    payloads: list[bytes], mtu: int, seed: int, fault: str
) -> None:
    # Distinct payloads (a prefix with the index) so that a delivered one names its transfer.
    payloads = [bytes([i]) + p for i, p in enumerate(payloads)]
    frames = _sent(payloads, mtu)
    rng = random.Random(seed)
    damaged: list[tuple[int, bytes]] = []
    for can_id, sent in frames:
        data = sent
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
    received = _received(damaged, decoder)
    decoder.expire(1e9)
    stats = decoder.stats
    if fault == "corrupt":
        # A corrupted single-frame transfer has no CRC of its own (CAN's CRC and the native
        # datagram's catch it); multi-frame transfers must come out intact or not at all.
        multi = {p for p in payloads if len(frame_lengths(len(p), mtu)) > 1}
        assert all(p in payloads for p in received if p in multi or len(p) > mtu)
        return
    assert all(p in payloads for p in received)
    if fault == "duplicate":
        assert received == payloads
        assert stats.duplicate_frames + stats.duplicate_transfers > 0 or len(damaged) == len(frames)
    else:
        assert len(set(received)) == len(received)  # each transfer at most once
        if fault == "loss":  # what arrives keeps its order; a transfer that lost some of its
            # frames but not all is counted (a whole lost transfer is the native layer's to count)
            it = iter(payloads)
            assert all(p in it for p in received)
            assert (
                len(received) == len(payloads)
                or stats.dropped + decoder.pending > 0
                or (len(damaged) < len(frames))
            )


def test_a_stream_keeps_one_queue_class_whatever_its_channel() -> None:
    """Control datagrams (channel 0) have a higher id priority than data, but the same queue
    class as their stream, so a sender never lets them overtake that stream's queued data."""
    for kind in (Kind.BEST_EFFORT, Kind.RELIABLE):
        assert priority_of(kind, 0) < priority_of(kind, 1)
        assert queue_class(kind) == priority_of(kind, 1)
    order = [queue_class(k) for k in (Kind.ACK, Kind.NODE, Kind.RELIABLE, Kind.BEST_EFFORT)]
    assert order == sorted(order) and len(set(order)) == 4
