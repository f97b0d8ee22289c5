"""CAN.md version 3, chained transfers (§12): a message's best-effort fragments as one CAN
transfer. Golden vectors (protocols/vectors/can_chains.json), property tests (seeded, bounded:
round trips, loss, corruption, duplication, reordering of CAN frames; a chain is delivered whole
or not at all, never a wrong datagram), and two can:// links on python-can's virtual bus: each end
learns from the other's claims whether to chain, and a version-2 end is never sent a chain."""

from __future__ import annotations

import itertools
import json
import random
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge.links.can import CanLink
from hwbridge.protocols.can.transport import (
    CHAIN_MAX,
    CLASSIC_MTU,
    FD_MTU,
    FORMAT_2,
    Kind,
    TransferDecoder,
    TransferEncoder,
    chain_size_code,
    crc16,
    decode_id,
    encode_chain_id,
    frame_lengths,
)
from hwbridge.protocols.native.framing import FrameType, encode_datagram, fragment

VECTORS = json.loads(
    (Path(__file__).resolve().parents[2] / "protocols" / "vectors" / "can_chains.json").read_text()
)
PROPERTY = settings(max_examples=120, deadline=None, derandomize=True)
_names = itertools.count()


def _frames(vector: dict) -> list[tuple[int, bytes]]:
    return [(int(f["id"], 16), bytes.fromhex(f["data_hex"])) for f in vector["frames"]]


@pytest.mark.parametrize("vector", VECTORS["claims"], ids=lambda v: v["name"])
def test_claim_vectors(vector: dict) -> None:
    uid = bytes.fromhex(vector["uid_hex"])
    encoder = TransferEncoder(vector["source"])
    assert encoder.claim(uid, chains=vector["takes_chains"]) == _frames(vector)
    (can_id, data), *_ = _frames(vector)
    transfer = TransferDecoder(0 if vector["source"] else 1).feed(can_id, data, 0.0)
    assert transfer is not None and transfer.kind is Kind.NODE and transfer.payload == uid
    assert transfer.takes_chains == vector["takes_chains"]


@pytest.mark.parametrize("vector", VECTORS["ids"], ids=lambda v: v["name"])
def test_id_vectors(vector: dict) -> None:
    fields = vector["fields"]
    can_id = int(vector["id"], 16)
    assert encode_chain_id(**fields) == can_id
    decoded = decode_id(can_id)
    assert decoded is not None and decoded.format == FORMAT_2
    assert (decoded.priority, decoded.kind, decoded.channel) == (
        fields["priority"],
        fields["kind"],
        fields["channel"],
    )
    assert (decoded.destination, decoded.source) == (fields["destination"], fields["source"])
    assert (decoded.seq_high, decoded.frag, decoded.chain) == (
        fields["seq"] >> 5,
        1,
        fields["size"],
    )
    assert decoded.encode() == can_id


@pytest.mark.parametrize("vector", VECTORS["chains"], ids=lambda v: v["name"])
def test_chain_vectors(vector: dict) -> None:
    datagrams = [bytes.fromhex(d) for d in vector["datagrams_hex"]]
    encoder = TransferEncoder(vector["source"], vector["mtu"])
    sent = [f for d in datagrams for f in encoder.datagram(d, vector["destination"], chain=True)]
    assert sent == _frames(vector)
    decoder = TransferDecoder(vector["destination"])
    got: list[bytes] = []
    for can_id, data in sent:
        transfer = decoder.feed(can_id, data, 0.0)
        if transfer is not None:
            got.extend(transfer.datagrams)
    assert got == datagrams
    assert decoder.stats.dropped == 0 and decoder.pending == 0


@pytest.mark.parametrize("vector", VECTORS["bad"], ids=lambda v: v["name"])
def test_bad_vectors(vector: dict) -> None:
    decoder = TransferDecoder(vector["local"], chains=vector["chains"])
    for frame in vector["frames"]:
        assert (
            decoder.feed(int(frame["id"], 16), bytes.fromhex(frame["data_hex"]), 0.0, extended=True)
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


def test_size_codes() -> None:
    assert [chain_size_code(32 << c) for c in range(8)] == list(range(8))
    for size in (0, 16, 24, 48, 63, 65, 100, 8192):
        assert chain_size_code(size) is None


def test_chains_need_a_peer_that_takes_them_and_sizes_that_code() -> None:
    """Without ``chain`` (a peer whose claims do not say it takes chains), at a fragment size
    that is no power of two, for reliable fragments and past CHAIN_MAX, every fragment is its
    own transfer, as in version 2."""
    message = bytes(range(200))
    plain = [encode_datagram(f) for f in fragment(FrameType.BEST_EFFORT, 1, 0, message, 64)]
    encoder = TransferEncoder(5)
    ids = {i for d in plain for i, _ in encoder.datagram(d, 0)}
    assert all(not decode_id(i).chain for i in ids)  # type: ignore[union-attr]
    for frame_type, size, length in (
        (FrameType.BEST_EFFORT, 48, 200),
        (FrameType.RELIABLE, 64, 200),
        (FrameType.BEST_EFFORT, 64, CHAIN_MAX + 1),
    ):
        datagrams = [encode_datagram(f) for f in fragment(frame_type, 1, 0, bytes(length), size)]
        frames = [f for d in datagrams for f in encoder.datagram(d, 0, chain=True)]
        assert len(frames) == sum(len(frame_lengths(len(d) - 5, CLASSIC_MTU)) for d in datagrams)
        assert all(not decode_id(i).chain for i, _ in frames)  # type: ignore[union-attr]
    assert encoder.chains == 0


def test_reliable_and_ack_datagrams_go_beside_a_chain() -> None:
    """An ACK and a reliable datagram written between two fragments are their own transfers on
    other ids: the chain goes on, and the receiver gets all of it."""
    encoder = TransferEncoder(5)
    decoder = TransferDecoder(0)
    chain = [encode_datagram(f) for f in fragment(FrameType.BEST_EFFORT, 1, 40, bytes(150), 64)]
    ack_body = bytes((0x60, 0, 3, 7, 0))  # an ACK datagram's header and payload
    ack = ack_body + crc16(ack_body).to_bytes(2, "little")
    reliable = encode_datagram(fragment(FrameType.RELIABLE, 2, 9, b"abc", 64)[0])
    got: list[bytes] = []
    for d in [chain[0], ack, chain[1], reliable, chain[2]]:
        for can_id, data in encoder.datagram(d, 0, chain=True):
            transfer = decoder.feed(can_id, data, 0.0)
            if transfer is not None:
                got.extend(transfer.datagrams)
    assert got == [ack, reliable, *chain]
    assert encoder.chains == 1 and encoder.chain_breaks == 0 and decoder.stats.dropped == 0


def test_a_broken_chain_is_dropped_and_the_next_message_goes() -> None:
    """A FIRST fragment that comes before the LAST of the chain in progress (the session gave
    up on a message) breaks the chain off: the receiver never delivers the part it got."""
    encoder = TransferEncoder(5)
    decoder = TransferDecoder(0)
    first = [encode_datagram(f) for f in fragment(FrameType.BEST_EFFORT, 1, 10, bytes(150), 64)]
    second = [
        encode_datagram(f) for f in fragment(FrameType.BEST_EFFORT, 1, 12, bytes(range(150)), 64)
    ]
    got: list[bytes] = []
    for d in [*first[:2], *second]:
        for can_id, data in encoder.datagram(d, 0, chain=True):
            transfer = decoder.feed(can_id, data, 0.0)
            if transfer is not None:
                got.extend(transfer.datagrams)
    decoder.expire(10.0)
    assert got == second
    assert encoder.chain_breaks == 1 and encoder.chains == 2
    # the first chain's part, never finished: the second's start on the same id (seq 10 and 12
    # share bits 7..5) abandons it
    assert decoder.stats.abandoned == 1 and decoder.stats.dropped == 1


# ----------------------------------------------------------------------------- properties

_MESSAGE = st.tuples(
    st.sampled_from([FrameType.BEST_EFFORT, FrameType.BEST_EFFORT, FrameType.RELIABLE]),
    st.integers(0, 255),  # channel
    st.integers(0, 700),  # length
)


def _stream(
    items: list[tuple[FrameType, int, int]], size: int, salt: int
) -> tuple[list[bytes], list[list[bytes]]]:
    """The native datagrams of these messages at fragment size ``size``, numbered as a session
    does (one sequence space per type), and the datagrams of each message."""
    seqs = {FrameType.BEST_EFFORT: salt & 0xFF, FrameType.RELIABLE: 0}
    flat: list[bytes] = []
    messages: list[list[bytes]] = []
    for index, (frame_type, channel, length) in enumerate(items):
        body = bytes((index * 31 + salt + i) & 0xFF for i in range(length))
        frames = fragment(frame_type, channel, seqs[frame_type], body, size)
        seqs[frame_type] = (seqs[frame_type] + len(frames)) & 0xFF
        datagrams = [encode_datagram(f) for f in frames]
        messages.append(datagrams)
        flat.extend(datagrams)
    return flat, messages


@PROPERTY
@given(
    st.lists(_MESSAGE, max_size=6),
    st.sampled_from([32, 48, 64, 128]),
    st.sampled_from([CLASSIC_MTU, 12, 32, FD_MTU]),
    st.integers(1, 127),
)
def test_round_trip(
    items: list[tuple[FrameType, int, int]], size: int, mtu: int, node: int
) -> None:
    sent, messages = _stream(items, size, node)
    for source, destination in ((node, 0), (0, node)):
        encoder = TransferEncoder(source, mtu)
        decoder = TransferDecoder(destination)
        frames = [f for d in sent for f in encoder.datagram(d, destination, chain=True)]
        got: list[bytes] = []
        for can_id, data in frames:
            transfer = decoder.feed(can_id, data, 0.0)
            if transfer is not None:
                got.extend(transfer.datagrams)
        assert got == sent
        assert decoder.stats.dropped == 0 and decoder.pending == 0
        assert encoder.chain_breaks == 0
        # a chained message takes the frames of one transfer of its bytes: Cyphal's count
        chained = [
            m
            for m, (kind, _, length) in zip(messages, items, strict=True)
            if kind is FrameType.BEST_EFFORT and len(m) > 1 and size in (32, 64, 128)
        ]
        assert encoder.chains == len(chained)
        expected = sum(
            len(frame_lengths(length, mtu))
            if m in chained
            else sum(len(frame_lengths(len(d) - 5, mtu)) for d in m)
            for m, (_, _, length) in zip(messages, items, strict=True)
        )
        assert len(frames) == expected


@PROPERTY
@given(
    st.lists(st.lists(_MESSAGE, min_size=1, max_size=4), min_size=1, max_size=3),
    st.sampled_from([32, 64]),
    st.sampled_from([CLASSIC_MTU, FD_MTU]),
    st.integers(0, 2**32 - 1),
    st.sampled_from(["none", "loss", "duplicate", "reorder", "corrupt"]),
)
def test_interleaved_nodes_with_faults(
    per_node: list[list[tuple[FrameType, int, int]]], size: int, mtu: int, seed: int, fault: str
) -> None:
    """Several boards' chains and transfers interleaved frame by frame on one bus, then damaged
    (corruption: of data bytes, not tail bytes, in frames that are not whole transfers, as CAN's
    own CRC catches the rest): every datagram delivered was sent, each message's datagrams come
    whole, in order, and nothing else; without faults everything arrives."""
    rng = random.Random(seed)
    sent: dict[int, list[bytes]] = {}
    messages: dict[int, list[list[bytes]]] = {}
    queues: list[list[tuple[int, bytes]]] = []
    for index, items in enumerate(per_node):
        node = index + 1
        encoder = TransferEncoder(node, mtu)
        sent[node], messages[node] = _stream(items, size, node)
        queues.append([f for d in sent[node] for f in encoder.datagram(d, 0, chain=True)])
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
        if fault == "corrupt" and roll < 0.3 and len(data) > 1 and data[-1] & 0xC0 != 0xC0:
            bit = rng.randrange((len(data) - 1) * 8)
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
            got[transfer.source].extend(transfer.datagrams)
    decoder.expire(1e9)
    assert decoder.pending == 0
    for node, datagrams in sent.items():
        received = got[node]
        assert all(d in datagrams for d in received), "a datagram that was never sent"
        if fault == "none":
            assert received == datagrams
        if fault in ("none", "loss", "corrupt"):
            # whole messages' datagrams in order: a chain is never delivered in part
            for message in messages[node]:
                if len(message) > 1 and message[0] in received and decode_chained(message):
                    start = received.index(message[0])
                    assert received[start : start + len(message)] == message
        if fault == "loss":
            it = iter(datagrams)
            assert all(d in it for d in received)


def decode_chained(message: list[bytes]) -> bool:
    """Whether a message's datagrams went as a chain (best-effort, fragmented)."""
    return (message[0][0] >> 4) & 3 == 0 and (message[0][0] >> 2) & 3 == 1


# ----------------------------------------------------------------------------- links


def wait_for(condition: Callable[[], object], timeout: float = 15.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return bool(condition())


@pytest.fixture
def opened() -> Iterator[list[CanLink]]:
    links: list[CanLink] = []
    yield links
    for link in links:
        link.close()


def _open(opened: list[CanLink], url: str) -> CanLink:
    link = CanLink(url)
    link.open()
    opened.append(link)
    return link


def _read(link: CanLink, count: int) -> list[bytes]:
    got: list[bytes] = []
    deadline = time.monotonic() + 15
    while len(got) < count and time.monotonic() < deadline:
        datagram = link.read(4096, 0.5)
        if datagram:
            got.append(datagram)
    return got


@pytest.mark.parametrize(
    ("host_query", "board_query", "chained"),
    [("", "", True), ("?can_chain=0", "", False), ("", "&can_chain=0", False)],
    ids=["both version 3", "version-2 host", "version-2 board"],
)
def test_links_chain_only_between_ends_that_take_chains(
    opened: list[CanLink], host_query: str, board_query: str, chained: bool
) -> None:
    channel = f"chain{next(_names)}"
    sniffer = can.Bus(interface="virtual", channel=channel)
    try:
        host = _open(opened, f"can://virtual/{channel}/node4{host_query}")
        board = _open(opened, f"can://virtual/{channel}?node=0&local=4{board_query}")
        board_hub, host_hub = board.hub, host.hub
        assert board_hub is not None and host_hub is not None
        # each end hears the other's claim: what it says decides
        assert wait_for(lambda: 0 in board_hub.peer_chains or not board_hub.chains)
        assert wait_for(lambda: 4 in host_hub.peer_chains or not host_hub.chains)
        message = bytes((i * 13) & 0xFF for i in range(320))  # a sensor_msgs/Imu's length
        up = [encode_datagram(f) for f in fragment(FrameType.BEST_EFFORT, 3, 7, message, 64)]
        down = [encode_datagram(f) for f in fragment(FrameType.BEST_EFFORT, 2, 90, message, 64)]
        for datagram in up:
            board.write(datagram)
        for datagram in down:
            host.write(datagram)
        assert _read(host, len(up)) == up
        assert _read(board, len(down)) == down
        frames = []
        while (frame := sniffer.recv(0.3)) is not None:
            if (frame.arbitration_id >> 24) & 3 != Kind.NODE:
                frames.append(frame)
        chains = [f for f in frames if decode_id(f.arbitration_id).chain]  # type: ignore[union-attr]
        if chained:
            # 320 bytes and the transfer CRC in 46 full frames each way, as Cyphal/CAN
            assert len(frames) == len(chains) == 2 * 46
            assert board_hub.stats.chains_out == host_hub.stats.chains_out == 1
        else:
            assert not chains and len(frames) == 2 * 51
        for hub in (board_hub, host_hub):
            assert hub.decoder.stats.dropped == 0, hub.describe()
    finally:
        sniffer.shutdown()
