"""The rosserial host as a protocols.base session: framing object, spec, unknown types, start-up.

Property tests (seeded, bounded) drive the wire path: the framing object's round trip, and
arbitrary or corrupted bytes into a fresh and a connected host, which must never raise.
"""

from __future__ import annotations

import ast
import logging
import random
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hwbridge import msg
from hwbridge.protocols import base
from hwbridge.protocols.base import (
    Connected,
    EntryKind,
    Error,
    Message,
    ServiceRequest,
    ServiceResponse,
)
from hwbridge.protocols.errors import HwBridgeError, ProtocolMismatchError
from hwbridge.protocols.msgtypes import BUNDLED_MSG_DIR, TypeRegistry
from hwbridge.protocols.registry import SessionContext, get_protocol
from hwbridge.protocols.rosserial.device import (
    Endpoint,
    Received,
    RosserialDevice,
    ServiceCalled,
    ServiceEndpoint,
)
from hwbridge.protocols.rosserial.framing import (
    MAX_PAYLOAD,
    FrameParser,
    RosFrame,
    RosserialFraming,
    encode_frame,
)
from hwbridge.protocols.rosserial.host import REQUEST_TOPICS, TX_STOP, RosserialHost
from hwbridge.protocols.rosserial.spec import PROTOCOL, RosserialDetector
from hwbridge.protocols.rosserial.table import UNKNOWN_SERVICE_MD5

REG = msg.registry()
SETTINGS = settings(
    max_examples=80,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
EVENT_TYPES = (
    base.Connected,
    base.Disconnected,
    base.TopicAnnounced,
    base.Message,
    base.ServiceRequest,
    base.ServiceResponse,
    base.ParamRequest,
    base.Log,
    base.TimeSynced,
    base.DebugOutput,
    base.Error,
)

frames = st.builds(RosFrame, st.integers(0, 0xFFFF), st.binary(max_size=200))


def run(
    host: RosserialHost,
    device: RosserialDevice,
    start: float,
    seconds: float,
    device_events: list[Any] | None = None,
) -> list[Any]:
    """Exchange bytes every 10 ms of virtual time; the host's events (the device's go to
    ``device_events``)."""
    events: list[Any] = []
    for i in range(round(seconds / 0.01)):
        now = start + (i + 1) * 0.01
        events += host.tick(now)
        got = device.receive_data(host.data_to_send(), now)
        if device_events is not None:
            device_events += got
        events += host.receive_data(device.data_to_send(), now)
    return events


# ---------------------------------------------------------------------------------- framing
def test_framing_object() -> None:
    framing = RosserialFraming(max_payload=64)
    assert framing.datagram is False
    assert framing.encode([], 0.0) == []
    chunk = framing.encode([RosFrame(0, b""), RosFrame(11, b"")], 0.0)
    assert chunk == [REQUEST_TOPICS + TX_STOP]
    assert framing.decode(encode_frame(125, bytes(64))) == [RosFrame(125, bytes(64))]
    framing.max_payload = 10
    assert framing.max_payload == framing.parser.max_payload == 10
    assert not [e for e in framing.decode(encode_frame(125, bytes(64))) if isinstance(e, RosFrame)]
    assert framing.stats.oversize == 1


@SETTINGS
@given(st.lists(frames, max_size=8), st.lists(st.integers(1, 300), max_size=10))
def test_framing_round_trip(items: list[RosFrame], cuts: list[int]) -> None:
    sender, receiver = RosserialFraming(), RosserialFraming(MAX_PAYLOAD)
    chunks = sender.encode(items, 0.0)
    assert len(chunks) == (1 if items else 0)
    stream = b"".join(chunks)
    got: list[Any] = []
    at = 0
    for cut in [*cuts, len(stream)]:
        got += receiver.decode(stream[at : at + cut])
        at += cut
    got += receiver.decode(stream[at:])
    assert got == items


def test_host_uses_the_framing_it_is_given() -> None:
    framing = RosserialFraming()
    host = RosserialHost(REG, now=0.0, framing=framing, max_payload=1000)
    assert host.framing is framing and framing.max_payload == 1000
    assert host.chunks_to_send() == [REQUEST_TOPICS]
    assert host.chunks_to_send() == []
    host.receive_data(b"noise", 0.01)
    assert host.counters().non_frame_bytes == 5 == framing.stats.non_frame_bytes


# ---------------------------------------------------------------------------------- robustness
def _connected_host() -> tuple[RosserialHost, RosserialDevice]:
    device = RosserialDevice(
        REG,
        publishers=[Endpoint("chatter", "std_msgs/String")],
        subscribers=[Endpoint("led", "std_msgs/Bool")],
        service_servers=[ServiceEndpoint("toggle", "std_srvs/SetBool", lambda r: r)],
        service_clients=[ServiceEndpoint("trigger", "std_srvs/Trigger")],
    )
    host = RosserialHost(REG, now=0.0, wall_offset=1e9)
    run(host, device, 0.0, 0.6)
    assert host.connected
    return host, device


@SETTINGS
@given(st.binary(max_size=400), st.lists(st.integers(1, 120), max_size=8), st.booleans())
def test_garbage_into_the_host_never_raises(data: bytes, cuts: list[int], connected: bool) -> None:
    host, _ = _connected_host() if connected else (RosserialHost(REG, now=0.0), None)
    now, at = 0.7, 0
    for cut in [*cuts, len(data)]:
        now += 0.05
        for event in [*host.receive_data(data[at : at + cut], now), *host.tick(now)]:
            assert isinstance(event, EVENT_TYPES)
            if isinstance(event, Error):
                assert isinstance(event.error, HwBridgeError)
        at += cut
        host.chunks_to_send()
    host.counters()
    host.describe()


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(1, 40))
def test_corrupted_device_stream_never_raises(seed: int, flips: int) -> None:
    """A real session's bytes with random bytes changed, fed to a fresh host."""
    rng = random.Random(seed)
    device = RosserialDevice(
        REG,
        publishers=[Endpoint("chatter", "std_msgs/String")],
        service_clients=[ServiceEndpoint("trigger", "std_srvs/Trigger")],
    )
    device.receive_data(REQUEST_TOPICS, 0.0)
    device.receive_data(encode_frame(10, bytes(8)), 0.0)
    device.publish("chatter", msg.encode(msg.from_dict("std_msgs/String", {"data": "hi"})))
    device.log(1, "hello")
    device.request_param("p", 0.0)
    device.call_service("trigger", b"")
    stream = bytearray(device.data_to_send())
    for _ in range(flips):
        stream[rng.randrange(len(stream))] = rng.randrange(256)
    host = RosserialHost(REG, now=0.0)
    events = [*host.receive_data(bytes(stream), 0.01), *host.tick(1.0), *host.tick(20.0)]
    assert all(isinstance(e, EVENT_TYPES) for e in events)
    host.close(21.0)


# ---------------------------------------------------------------------------------- types
def test_unknown_types_pass_through(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Types only the device knows: accepted with its name and md5, one warning per type."""
    (tmp_path / "foo_msgs" / "msg").mkdir(parents=True)
    (tmp_path / "foo_msgs" / "msg" / "Bar.msg").write_text("int32 x\nstring label\n")
    (tmp_path / "foo_msgs" / "srv").mkdir()
    (tmp_path / "foo_msgs" / "srv" / "Echo.srv").write_text("string a\n---\nstring b\n")
    device_types = TypeRegistry([tmp_path])
    bar_md5 = device_types.md5("foo_msgs/Bar")
    device = RosserialDevice(
        device_types,
        publishers=[Endpoint("bar_out", "foo_msgs/Bar"), Endpoint("bar_2", "foo_msgs/Bar")],
        subscribers=[Endpoint("bar_in", "foo_msgs/Bar")],
        service_servers=[ServiceEndpoint("echo", "foo_msgs/Echo", lambda r: r)],
    )
    host = RosserialHost(REG, now=0.0, wall_offset=0.0)
    with caplog.at_level(logging.WARNING, logger="hwbridge.protocols.rosserial"):
        events = run(host, device, 0.0, 0.6)
    assert not [e for e in events if isinstance(e, Error)]
    (connected,) = [e for e in events if isinstance(e, Connected)]
    by_name = {e.name: e for e in connected.endpoints}
    assert set(by_name) == {"bar_out", "bar_2", "bar_in", "echo"}
    assert (by_name["bar_out"].type_name, by_name["bar_out"].md5) == ("foo_msgs/Bar", bar_md5)
    assert by_name["bar_in"].kind == EntryKind.SUBSCRIBER
    assert by_name["echo"].kind == EntryKind.SERVICE_SERVER
    assert by_name["echo"].md5 == UNKNOWN_SERVICE_MD5
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 2, warnings  # once per type
    assert any("foo_msgs/Bar" in w and "--msg-path" in w for w in warnings)
    assert any("foo_msgs/Echo" in w and "--msg-path" in w for w in warnings)
    assert host.stats.unknown_types == 5  # TopicInfos: 3 topics and 2 service halves
    assert host.describe()["unknown_types"] == ["foo_msgs/Bar", "foo_msgs/Echo"]

    payload = device_types.serialize(
        device_types.message_class("foo_msgs/Bar")(x=7, label="seven"), "foo_msgs/Bar"
    )
    device.publish("bar_out", payload)
    assert host.publish(by_name["bar_in"].channel, payload)
    request_id = host.call_service(by_name["echo"].channel, b"\x01\x00\x00\x00z", now=0.7)
    seen: list[Any] = []
    later = run(host, device, 0.7, 0.05, seen)
    assert Message(by_name["bar_out"].channel, payload, 0) in later
    assert ServiceResponse(by_name["echo"].channel, request_id, b"\x01\x00\x00\x00z") in later
    assert Received("bar_in", payload) in seen


def test_a_known_type_with_another_md5_is_still_refused() -> None:
    device = RosserialDevice(REG, publishers=[Endpoint("n", "std_msgs/Int32", "a" * 32)])
    host = RosserialHost(REG, now=0.0)
    events = run(host, device, 0.0, 0.6)
    (error,) = [e for e in events if isinstance(e, Error)]
    assert isinstance(error.error, ProtocolMismatchError)
    (connected,) = [e for e in events if isinstance(e, Connected)]
    assert connected.endpoints == ()


def test_rosserial_arduino_types() -> None:
    """The bundled definitions give the md5s of rosserial_arduino's generated ros_lib."""
    root = BUNDLED_MSG_DIR / "rosserial_arduino"
    assert (root / "msg" / "Adc.msg").read_text() == "".join(f"uint16 adc{i}\n" for i in range(6))
    assert (root / "srv" / "Test.srv").read_text() == "string input\n---\nstring output\n"
    assert REG.md5("rosserial_arduino/Adc") == "6d7853a614e2e821319068311f2af25b"
    test = REG.service("rosserial_arduino/Test")
    assert test.request.md5 == "39e92f1778057359c64c7b8a7d7b19de"  # TestRequest in ros_lib
    assert test.response.md5 == "0825d95fdfa2c8f4bbb4e9c74bccd3fd"  # TestResponse in ros_lib
    assert test.md5 == "c63e85f503b805d84df783e71c6bb0d2"  # md5("string input" "string output")
    adc = msg.from_dict("rosserial_arduino/Adc", {f"adc{i}": i * 100 for i in range(6)})
    assert len(msg.encode(adc)) == 12


def test_rosserial_arduino_sketch_connects() -> None:
    """The ADC and service examples of rosserial_arduino, against the host."""
    device = RosserialDevice(
        REG,
        publishers=[Endpoint("adc", "rosserial_arduino/Adc")],
        service_servers=[ServiceEndpoint("test_srv", "rosserial_arduino/Test", lambda r: r)],
    )
    host = RosserialHost(REG, now=0.0)
    events = run(host, device, 0.0, 0.6)
    assert not [e for e in events if isinstance(e, Error)]
    (connected,) = [e for e in events if isinstance(e, Connected)]
    assert {(e.name, e.type_name) for e in connected.endpoints} == {
        ("adc", "rosserial_arduino/Adc"),
        ("test_srv", "rosserial_arduino/Test"),
    }
    server = next(e for e in connected.endpoints if e.name == "test_srv")
    assert server.md5 == "c63e85f503b805d84df783e71c6bb0d2"
    request = msg.encode(msg.from_dict("rosserial_arduino/TestRequest", {"input": "ping"}))
    request_id = host.call_service(server.channel, request, now=0.6)
    later = run(host, device, 0.6, 0.05)
    assert ServiceResponse(server.channel, request_id, request) in later


# ---------------------------------------------------------------------------------- start-up
def test_connected_within_the_settle_time_of_a_running_board() -> None:
    """No start delay: a board that is running is connected one settle time after it answers."""
    device = RosserialDevice(
        REG,
        publishers=[Endpoint(f"p{i}", "std_msgs/String") for i in range(10)],
        subscribers=[Endpoint(f"s{i}", "std_msgs/Bool") for i in range(10)],
    )
    host = RosserialHost(REG, now=0.0)
    t, connected_at = 0.0, None
    while connected_at is None and t < 5.0:
        t += 0.001
        events = host.tick(t)
        device.receive_data(host.data_to_send(), t)
        events += host.receive_data(device.data_to_send(), t)
        if any(isinstance(e, Connected) for e in events):
            connected_at = t
    assert connected_at is not None and connected_at <= 0.5 + 0.002
    assert host.stats.topic_requests == 1


def test_device_service_client_via_channel() -> None:
    host, device = _connected_host()
    channel = next(
        s.request_topic_id
        for s in host.topics.service_clients.values()  # type: ignore[union-attr]
    )
    device.call_service("trigger", b"")
    (request,) = [e for e in run(host, device, 0.6, 0.02) if isinstance(e, ServiceRequest)]
    assert request.channel == channel
    assert host.respond_service(channel, request.request_id, b"\x01\x00\x00\x00\x00")
    run(host, device, 0.62, 0.02)


def test_device_service_server_via_channel() -> None:
    host, device = _connected_host()
    channel = host.topics.service_servers["toggle"].request_topic_id  # type: ignore[union-attr]
    request_id = host.call_service(channel, b"\x01", now=0.6)
    seen: list[Any] = []
    events = run(host, device, 0.6, 0.03, seen)
    assert ServiceResponse(channel, request_id, b"\x01") in events
    assert ServiceCalled("toggle", b"\x01") in seen


# ---------------------------------------------------------------------------------- spec
def test_protocol_spec() -> None:
    assert get_protocol("rosserial") is PROTOCOL
    assert (PROTOCOL.name, PROTOCOL.stream, PROTOCOL.datagram) == ("rosserial", True, False)
    assert PROTOCOL.probe == REQUEST_TOPICS and PROTOCOL.session_per_peer
    assert PROTOCOL.summary


def test_new_session() -> None:
    ctx = SessionContext(registry=REG, datagram=False, now=5.0, wall_offset=1000.25)
    host = PROTOCOL.new_session(ctx)
    assert isinstance(host, RosserialHost)
    assert host.chunks_to_send() == [REQUEST_TOPICS], "no start delay"
    host.receive_data(encode_frame(10, bytes(8)), 5.05)
    reply = FrameParser().feed(host.data_to_send())
    assert reply == [
        RosFrame(10, (1005).to_bytes(4, "little") + (300_000_000).to_bytes(4, "little"))
    ]
    delayed = PROTOCOL.new_session(
        SessionContext(REG, datagram=False, now=0.0, wall_offset=0.0, options={"start_delay": 2.0})
    )
    assert delayed.chunks_to_send() == []
    spoke = PROTOCOL.new_session(
        SessionContext(
            REG,
            datagram=False,
            now=0.0,
            wall_offset=0.0,
            board_spoke=True,
            options={"start_delay": 2.0},
        )
    )
    assert spoke.chunks_to_send() == [REQUEST_TOPICS]
    with pytest.raises(HwBridgeError, match="stream"):
        PROTOCOL.new_session(SessionContext(REG, datagram=True, now=0.0, wall_offset=0.0))
    with pytest.raises(HwBridgeError, match="baud"):
        PROTOCOL.new_session(
            SessionContext(REG, datagram=False, now=0.0, wall_offset=0.0, options={"baud": 1})
        )


def test_detector() -> None:
    assert PROTOCOL.detector is RosserialDetector
    detector = RosserialDetector()
    chatter = encode_frame(125, b"\x02\x00\x00\x00hi")
    assert not detector.feed(b"boot noise \xff\xfe\x13")
    assert not detector.feed(b"\xff\xff\x0a\x00\x08\x00" + bytes(8) + b"\xeb")  # v1: no
    assert not detector.feed(chatter[:-1] + bytes([chatter[-1] ^ 1]))  # bad checksum
    assert not detector.feed(chatter[:5])
    assert detector.feed(chatter[5:] + b"more")
    assert detector.feed(b"anything"), "the decision stays"


@SETTINGS
@given(st.binary(max_size=300), st.binary(max_size=300))
def test_detector_finds_a_frame_after_any_garbage(before: bytes, after: bytes) -> None:
    detector = RosserialDetector()
    detector.feed(before)
    detector.feed(after)
    # garbage may end in a header claiming a payload of up to 4096 bytes: frames are found once
    # that candidate is complete and fails its checksum
    assert detector.feed(encode_frame(10, bytes(8)) * 300)


# ---------------------------------------------------------------------------------- start-up cost
def test_no_module_level_numpy_import() -> None:
    for path in (BUNDLED_MSG_DIR.parent / "rosserial").glob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in tree.body:
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            assert not [n for n in names if n.split(".")[0] == "numpy"], path
