"""Dynamixel packet codecs: the spec's vectors byte for byte, round trips, stuffing, the parser."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import hwbridge.protocols
from hwbridge.devices.dynamixel import packets as p
from hwbridge.devices.dynamixel.packets import (
    CorruptPacket,
    InstructionPacket,
    PacketParser,
    StatusPacket,
)
from hwbridge.errors import FramingError

VECTORS: dict[str, Any] = json.loads(
    (Path(hwbridge.protocols.__file__).parent / "vectors" / "dynamixel.json").read_text()
)
ALL = VECTORS["vectors"] + VECTORS["stuffing"]
SPEC = [v for v in VECTORS["vectors"] if v["source"] == "DEVICES.md"]


def _packet(vector: dict[str, Any]) -> InstructionPacket | StatusPacket:
    params = bytes.fromhex(vector["params"])
    if vector["kind"] == "instruction":
        return InstructionPacket(vector["id"], vector["instruction"], params, vector["protocol"])
    return StatusPacket(vector["id"], vector["error"], params, vector["protocol"])


def _name(vector: dict[str, Any]) -> str:
    return f"p{vector['protocol']}-{vector['kind']}-{vector['name']}"


def test_the_spec_vectors_are_all_there() -> None:
    # DEVICES.md lists six Protocol 2.0 packets and five Protocol 1.0 ones.
    assert [v["protocol"] for v in SPEC].count(2) == 6
    assert [v["protocol"] for v in SPEC].count(1) == 5


@pytest.mark.parametrize("vector", ALL, ids=_name)
def test_vector_encodes_byte_for_byte_and_decodes_back(vector: dict[str, Any]) -> None:
    wire = bytes.fromhex(vector["bytes"])
    packet = _packet(vector)
    assert p.encode(packet) == wire
    assert p.decode(wire, vector["protocol"], vector["kind"]) == packet


@pytest.mark.parametrize("vector", [v for v in VECTORS["vectors"] if "decoded" in v], ids=_name)
def test_vector_parameters_decode_to_their_meaning(vector: dict[str, Any]) -> None:
    """The typed layouts (construct) read each vector's parameters as the spec explains them,
    and the packet builders make the same bytes from that meaning."""
    decoded = vector["decoded"]
    proto = vector["protocol"]
    params = bytes.fromhex(vector["params"])
    wire = bytes.fromhex(vector["bytes"])
    code = vector.get("instruction")
    if vector["kind"] == "status":
        if "model_number" in decoded:
            model, firmware = p.parse_ping_status(params)
            assert (model, firmware) == (decoded["model_number"], decoded["firmware"])
            assert (
                p.encode(StatusPacket(vector["id"], 0, p.ping_status_params(model, firmware)))
                == wire
            )
        else:
            assert int.from_bytes(params, "little") == decoded["value"]
        return
    if code == p.Instruction.READ:
        assert p.parse_read(proto, params) == (decoded["address"], decoded["length"])
        built = p.read_packet(proto, vector["id"], decoded["address"], decoded["length"])
    elif code in (p.Instruction.WRITE, p.Instruction.REG_WRITE):
        address, data = p.parse_write(proto, params)
        assert address == decoded["address"]
        if "value" in decoded:
            assert data == decoded["value"].to_bytes(decoded["size"], "little")
        else:
            assert data == bytes.fromhex(decoded["data"])
        built = p.write_packet(
            proto, vector["id"], address, data, registered=code == p.Instruction.REG_WRITE
        )
    elif code == p.Instruction.SYNC_WRITE:
        address, length, items = p.parse_sync_write(proto, params)
        assert (address, length) == (decoded["address"], decoded["length"])
        if "values" in decoded:
            assert {str(i): int.from_bytes(d, "little") for i, d in items} == decoded["values"]
        built = p.sync_write_packet(proto, address, length, items)
    elif code == p.Instruction.SYNC_READ:
        assert p.parse_sync_read(proto, params) == (
            decoded["address"],
            decoded["length"],
            decoded["ids"],
        )
        built = p.sync_read_packet(proto, decoded["address"], decoded["length"], decoded["ids"])
    elif code == p.Instruction.BULK_READ:
        reads = [(i[0], i[1], i[2]) for i in decoded["items"]]
        assert p.parse_bulk_read(proto, params) == reads
        built = p.bulk_read_packet(proto, reads)
    elif code == p.Instruction.FACTORY_RESET:
        built = p.factory_reset_packet(proto, vector["id"], decoded["option"])
    else:  # pragma: no cover - every vector with "decoded" is handled above
        raise AssertionError(vector)
    assert p.encode(built) == wire


def test_crc_and_checksum_of_known_frames() -> None:
    assert p.crc16(bytes.fromhex("FF FF FD 00 01 03 00 01")) == 0x4E19
    assert p.checksum(bytes.fromhex("01 05 03 0C 64 AA")) == 0xDC
    assert p.crc16(b"") == 0


def test_error_bits_are_named() -> None:
    assert p.error_names(2, 0x07) == ["Access Error"]
    assert p.error_names(2, 0x84) == [
        "Data Range Error",
        "Alert (hardware error, read Hardware Error Status)",
    ]
    assert p.error_names(1, 0x24) == ["Overheating Error", "Overload Error"]
    assert p.error_names(1, 0x48) == ["Range Error", "Instruction Error"]
    assert StatusPacket(1, 0x80).alert and not StatusPacket(1, 0x80, b"", 1).alert


# ----------------------------------------------------------------------------- round trips

ids2 = st.one_of(st.integers(0, 252), st.just(254))
ids1 = st.integers(0, 254)


@st.composite
def packets(draw: st.DrawFn, protocol: int | None = None) -> InstructionPacket | StatusPacket:
    proto = protocol or draw(st.sampled_from([1, 2]))
    status = draw(st.booleans())
    size = 253 if proto == 1 else 300
    params = draw(
        st.binary(max_size=size)
        | st.lists(st.sampled_from([b"\xff", b"\xfd", b"\x00", b"\xff\xff\xfd"]), max_size=40).map(
            b"".join
        )
    )
    if status:
        id_ = draw(st.integers(0, 252 if proto == 2 else 253))
        return StatusPacket(id_, draw(st.integers(0, 255)), params, proto)
    code = draw(st.integers(0, 255).filter(lambda c: proto == 1 or c != 0x55))
    return InstructionPacket(draw(ids2 if proto == 2 else ids1), code, params, proto)


def _kind(packet: InstructionPacket | StatusPacket) -> Any:
    return "status" if isinstance(packet, StatusPacket) else "instruction"


@settings(max_examples=300, deadline=None, derandomize=True)
@given(packets())
def test_any_packet_round_trips(packet: InstructionPacket | StatusPacket) -> None:
    wire = p.encode(packet)
    assert p.decode(wire, packet.protocol, _kind(packet)) == packet
    if packet.protocol == 2:
        assert wire[:4] == p.HEADER_2
        length = wire[5] | wire[6] << 8
        assert length == len(wire) - 7
        body = wire[7:-2]
        # After stuffing, every FF FF FD in the body is followed by FD.
        index = body.find(b"\xff\xff\xfd")
        while index >= 0:
            assert body[index + 3 : index + 4] == b"\xfd"
            index = body.find(b"\xff\xff\xfd", index + 4)
    else:
        assert wire[3] == len(packet.params) + 2


@pytest.mark.parametrize(
    "params",
    [
        b"\xff\xff\xfd" * 100,
        b"\xff\xff\xfd\xfd" * 50,
        b"\xff" * 60 + b"\xfd" * 60,
        b"\xff\xff" + b"\xfd" * 10,
        b"\x00\xff\xff\xfd",
    ],
    ids=["pattern-x100", "prestuffed-x50", "ff-then-fd", "one-pattern-at-start", "at-the-end"],
)
def test_stuffing_worst_cases(params: bytes) -> None:
    packet = InstructionPacket(1, p.Instruction.WRITE, params, 2)
    wire = p.encode(packet)
    patterns = params.count(b"\xff\xff\xfd")
    body = wire[7:-2]
    assert len(body) == 1 + len(params) + patterns
    assert wire[5] | wire[6] << 8 == len(params) + patterns + 3  # LEN counts the stuffed bytes
    assert p.unstuff(p.stuff(params)) == params
    assert p.decode(wire, 2, "instruction") == packet
    status = StatusPacket(3, 0, params, 2)
    assert p.decode(p.encode(status), 2) == status


def test_unstuffed_pattern_in_a_body_is_rejected() -> None:
    with pytest.raises(FramingError, match="not stuffed"):
        p.unstuff(b"\x03\xff\xff\xfd\x01")
    # A packet whose CRC is right but whose body breaks the stuffing rule is reported corrupt.
    frame = p.HEADER_2 + bytes((1, 8, 0, 3, 0xFF, 0xFF, 0xFD, 0x01, 0x02))
    crc = p.crc16(frame)
    frame += bytes((crc & 0xFF, crc >> 8))
    items = PacketParser(2).feed(frame)
    assert len(items) == 1 and isinstance(items[0], CorruptPacket)
    assert "not stuffed" in items[0].reason


def test_encoding_refuses_what_does_not_fit() -> None:
    with pytest.raises(ValueError, match="IDs are 0-252"):
        p.encode(InstructionPacket(253, 1, b"", 2))
    with pytest.raises(ValueError, match="IDs are 0-252"):
        p.encode(StatusPacket(254, 0, b"", 2))
    with pytest.raises(ValueError, match=r"do not fit a Protocol 1\.0 packet"):
        p.encode(InstructionPacket(1, 3, bytes(254), 1))
    with pytest.raises(ValueError, match="protocol must be 1 or 2"):
        p.encode(InstructionPacket(1, 1, b"", 3))
    with pytest.raises(ValueError, match="is 3 bytes, not 4"):
        p.sync_write_params(2, 116, 4, {1: b"\x00\x00\x00"})


def test_malformed_parameters_are_framing_errors() -> None:
    with pytest.raises(FramingError, match="READ takes 4"):
        p.parse_read(2, b"\x84\x00\x04")
    with pytest.raises(FramingError, match="do not split"):
        p.parse_sync_write(2, bytes.fromhex("74 00 04 00 01 96 00 00"))
    with pytest.raises(FramingError, match="malformed BULK_READ"):
        p.parse_bulk_read(2, bytes.fromhex("01 90 00 02"))
    with pytest.raises(FramingError, match="malformed BULK_READ"):
        p.parse_bulk_read(1, bytes.fromhex("01 02 01 1E"))  # must start with 0x00
    with pytest.raises(FramingError, match="malformed PING status"):
        p.parse_ping_status(b"\x06\x04")
    assert p.parse_bulk_write(p.bulk_write_params([(1, 116, b"\x01\x02"), (2, 65, b"\x01")])) == [
        (1, 116, b"\x01\x02"),
        (2, 65, b"\x01"),
    ]


def test_decode_says_what_is_wrong() -> None:
    wire = bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")
    with pytest.raises(FramingError, match=r"no complete Protocol 2\.0 packet"):
        p.decode(wire[:-1])
    with pytest.raises(FramingError, match="exactly one"):
        p.decode(wire + wire)
    with pytest.raises(FramingError, match="CRC 4E1A where 4E19 fits"):
        p.decode(wire[:-2] + b"\x1a\x4e")
    with pytest.raises(FramingError, match="checksum FA where FB fits"):
        p.decode(bytes.fromhex("FF FF 01 02 01 FA"), 1, "instruction")


# ----------------------------------------------------------------------------- the parser


def _chunks(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts})
    out, last = [], 0
    for point in [*points, len(data)]:
        out.append(data[last:point])
        last = point
    return out


@settings(max_examples=150, deadline=None, derandomize=True)
@given(
    st.sampled_from([1, 2]).flatmap(
        lambda proto: st.tuples(
            st.just(proto),
            st.lists(packets(proto), min_size=1, max_size=6),
            st.lists(
                st.binary(max_size=12).map(lambda b: b.replace(b"\xff", b"")),
                min_size=7,
                max_size=7,
            ),
            st.lists(st.integers(0, 10_000), max_size=12),
        )
    )
)
def test_parser_finds_every_packet_among_noise_in_any_chunks(case: Any) -> None:
    """Noise without FF bytes between packets, the stream cut anywhere: every packet comes out,
    in order, and nothing else (both protocols)."""
    proto, sent, noise, cuts = case
    kind: Literal["instruction", "status"] = (
        "status" if isinstance(sent[0], StatusPacket) else "instruction"
    )
    sent = [s for s in sent if _kind(s) == kind] if proto == 1 else sent
    stream = noise[0] + b"".join(p.encode(s) + n for s, n in zip(sent, noise[1:], strict=False))
    parser = PacketParser(proto, expect=kind)
    found: list[Any] = []
    for chunk in _chunks(stream, cuts):
        found += parser.feed(chunk)
    found += parser.flush()
    assert found == sent
    assert parser.stats.packets == len(sent)
    assert parser.stats.corrupt == 0


@settings(max_examples=150, deadline=None, derandomize=True)
@given(
    st.lists(packets(2), min_size=1, max_size=4),
    st.lists(
        st.binary(max_size=16)
        | st.sampled_from([b"\xff\xff\xfd\x00\x01\xff\x03", b"\xff\xff\xfd\x00", b"\xff\xff"]),
        min_size=5,
        max_size=5,
    ),
    st.lists(st.integers(0, 10_000), max_size=8),
)
def test_protocol_2_parser_survives_any_noise(
    sent: list[Any], noise: list[bytes], cuts: list[int]
) -> None:
    """Any noise, fake headers with long lengths included: every packet still comes out in
    order (a fake header that would swallow one is dropped when its CRC fails or at flush)."""
    stream = noise[0] + b"".join(p.encode(s) + n for s, n in zip(sent, noise[1:], strict=False))
    parser = PacketParser(2)
    found: list[Any] = []
    for chunk in _chunks(stream, cuts):
        found += parser.feed(chunk)
    found += parser.flush()
    good = iter(item for item in found if not isinstance(item, CorruptPacket))
    assert all(any(item == packet for item in good) for packet in sent)  # a subsequence


def test_a_fake_header_waits_for_its_length_then_the_real_packet_comes_out() -> None:
    real = p.encode(p.ping_packet(2, 1))
    fake = b"\xff\xff\xfd\x00\x05\x20\x00"  # claims 32 more bytes
    parser = PacketParser(2)
    assert parser.feed(fake + real) == []  # could still be a 32-byte packet
    items = parser.feed(bytes(40))  # now it is complete, its CRC fails
    assert isinstance(items[0], CorruptPacket) and items[0].id == 5
    assert items[1:] == [p.ping_packet(2, 1)]


def test_stale_partial_packets_are_dropped_after_a_gap() -> None:
    wire = p.encode(p.ping_packet(2, 1))
    parser = PacketParser(2, stale_after=0.05)
    assert parser.feed(wire[:5], now=1.0) == []
    assert parser.feed(wire[5:], now=1.01) == [p.ping_packet(2, 1)]  # no gap: joined
    assert parser.feed(wire[:5], now=2.0) == []
    assert parser.feed(wire[5:], now=2.2) == []  # too late: the start was dropped
    assert parser.stats.skipped_bytes >= 5
    assert parser.feed(wire, now=2.21) == [p.ping_packet(2, 1)]


def test_protocol_1_header_of_three_ff() -> None:
    wire = bytes.fromhex("FF FF 01 02 00 FC")
    assert PacketParser(1).feed(b"\xff" + wire) == [StatusPacket(1, 0, b"", 1)]


@settings(max_examples=300, deadline=None, derandomize=True)
@given(packets(), st.data())
def test_any_single_bit_error_after_the_length_is_detected(
    packet: InstructionPacket | StatusPacket, data: st.DataObject
) -> None:
    """CRC-16 and the 1.0 checksum catch every single-bit error in INST..CRC/CHK."""
    wire = bytearray(p.encode(packet))
    first = 7 if packet.protocol == 2 else 4
    index = data.draw(st.integers(first, len(wire) - 1))
    wire[index] ^= 1 << data.draw(st.integers(0, 7))
    parser = PacketParser(packet.protocol, expect=_kind(packet))
    items = parser.feed(bytes(wire)) + parser.flush()
    assert packet not in items
    assert isinstance(items[0], CorruptPacket)
    assert items[0].raw == bytes(wire)
    assert parser.stats.corrupt >= 1
    with pytest.raises(FramingError):
        p.decode(bytes(wire), packet.protocol, _kind(packet))
