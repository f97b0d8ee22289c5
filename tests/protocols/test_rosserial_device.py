"""RosserialDevice: the behaviours of the rosserial client library it emulates."""

from __future__ import annotations

import itertools
from typing import Any

import pytest

from hwbridge import msg
from hwbridge.protocols.errors import ProtocolError
from hwbridge.protocols.rosserial.device import (
    Configured,
    Endpoint,
    InputOverrun,
    ParamResult,
    Received,
    RosserialDevice,
    ServiceEndpoint,
    ServiceResult,
    TimeSynced,
    Unconfigured,
)
from hwbridge.protocols.rosserial.framing import FrameParser, RosFrame, encode_frame
from hwbridge.protocols.rosserial.host import REQUEST_TOPICS, TX_STOP
from hwbridge.protocols.rosserial.ids import ReservedId

REG = msg.registry()
TIME_REQUEST = encode_frame(ReservedId.TIME, bytes(8))


def frames(data: bytes) -> list[RosFrame]:
    events = FrameParser(max_payload=4096).feed(data)
    assert all(isinstance(e, RosFrame) for e in events), events
    return events  # type: ignore[return-value]


def topic_infos(data: bytes) -> list[tuple[int, int, str, str, int]]:
    out = []
    for frame in frames(data):
        if frame.topic_id <= 5:
            info = REG.deserialize(frame.payload, "rosserial_msgs/TopicInfo")
            out.append(
                (frame.topic_id, info.topic_id, info.topic_name, info.md5sum, info.buffer_size)
            )
    return out


def time_reply(sec: int, nsec: int) -> bytes:
    stamp = msg.from_dict("std_msgs/Time", {"data": {"secs": sec, "nsecs": nsec}})
    return encode_frame(ReservedId.TIME, msg.encode(stamp))


def configured_device(**options: Any) -> RosserialDevice:
    device = RosserialDevice(REG, publishers=[Endpoint("chatter", "std_msgs/String")], **options)
    device.subscribe("led", "std_msgs/Bool")
    device.receive_data(REQUEST_TOPICS, 0.0)
    device.data_to_send()
    return device


def test_topic_numbering_and_topic_info_order() -> None:
    string, boolean = REG.md5("std_msgs/String"), REG.md5("std_msgs/Bool")
    setbool, trigger = REG.service("std_srvs/SetBool"), REG.service("std_srvs/Trigger")
    device = RosserialDevice(
        REG,
        publishers=[Endpoint("chatter", "std_msgs/String"), Endpoint("b", "std_msgs/String")],
        subscribers=[Endpoint("led", "std_msgs/Bool")],
        service_servers=[ServiceEndpoint("srv", "std_srvs/SetBool")],
        service_clients=[ServiceEndpoint("cli", "std_srvs/Trigger")],
        input_size=280,
        output_size=300,
    )
    assert device.topic_id("chatter") == 125
    assert device.topic_id("led", publisher=False) == 100
    assert device.receive_data(REQUEST_TOPICS, 1.0) == [Configured()]
    out = device.data_to_send()
    assert out.startswith(TIME_REQUEST)
    assert topic_infos(out) == [
        (0, 125, "chatter", string, 300),
        (0, 126, "b", string, 300),
        (2, 127, "srv", setbool.response.md5, 300),
        (4, 128, "cli", trigger.request.md5, 300),
        (1, 100, "led", boolean, 280),
        (3, 101, "srv", setbool.request.md5, 280),
        (5, 102, "cli", trigger.response.md5, 280),
    ]


def test_custom_slot_counts() -> None:
    device = RosserialDevice(REG, max_subscribers=2, max_publishers=1)
    assert device.advertise("a", "std_msgs/Empty") == 102
    assert device.subscribe("s", "std_msgs/Empty") == 100
    with pytest.raises(ProtocolError, match="publisher slot"):
        device.advertise("b", "std_msgs/Empty")
    with pytest.raises(ProtocolError, match="publisher slot"):
        device.advertise_service("srv", "std_srvs/Empty", None)
    device.subscribe("t", "std_msgs/Empty")
    with pytest.raises(ProtocolError, match="subscriber slot"):
        device.subscribe("u", "std_msgs/Empty")


def test_publications_dropped_until_configured() -> None:
    device = RosserialDevice(REG, publishers=[Endpoint("chatter", "std_msgs/String")])
    assert device.publish("chatter", b"\x00\x00\x00\x00") == 0
    device.log(1, "logs are not topics >= 100")
    assert frames(device.data_to_send())[0].topic_id == ReservedId.LOG
    assert device.stats.dropped_unconfigured == 1
    device.receive_data(REQUEST_TOPICS, 0.0)
    device.data_to_send()
    assert device.publish("chatter", b"\x00\x00\x00\x00") == 12
    assert frames(device.data_to_send()) == [RosFrame(125, b"\x00\x00\x00\x00")]
    with pytest.raises(KeyError):
        device.publish("nope", b"")


def test_periodic_time_requests_and_sync_timeout() -> None:
    device = configured_device()
    sent = []
    now = 0.0
    for step in range(1, 1001):  # 10 s, answering every time request
        now = step / 100
        device.tick(now)
        for frame in frames(device.data_to_send()):
            sent.append((now, frame.topic_id))
            device.receive_data(time_reply(1000, 0), now)
    times = [t for t, topic in sent if topic == ReservedId.TIME]
    assert len(times) == 3 and all(2.5 < b - a < 2.55 for a, b in itertools.pairwise(times))
    assert device.configured
    # no more replies: unconfigured once 11 s passed since the last one
    last = times[-1]
    events = []
    step = 0
    for step in range(1, 1300):
        events += device.tick(last + step / 100)
        if events:
            break
    assert events == [Unconfigured("sync_timeout")]
    assert 11.0 < step / 100 <= 11.02


def test_time_arithmetic() -> None:
    device = configured_device()
    # the time request went out at t=0; the reply comes 0.25 s later
    events = device.receive_data(time_reply(1_700_000_000, 900_000_000), 0.25)
    assert events == [TimeSynced(1_700_000_001, 150_000_000)]
    assert device.ros_time(10.25) == (1_700_000_011, 150_000_000)


def test_split_frame_is_dropped_after_20_ms() -> None:
    device = configured_device()
    frame = encode_frame(100, b"\x01")
    assert device.receive_data(frame[:4], 1.0) == []
    assert device.receive_data(frame[4:], 1.015) == [Received("led", b"\x01")]
    assert device.receive_data(frame[:4], 2.0) == []
    assert device.receive_data(frame[4:], 2.03) == []
    assert device.stats.timed_out_frames == 1


def test_no_rescan_after_a_bad_frame() -> None:
    """Unlike the host parser, the library loses a frame hidden in a truncated one."""
    device = configured_device()
    frame = encode_frame(100, b"\x01")
    assert device.receive_data(frame[:5] + frame, 1.0) == []
    assert device.stats.checksum_errors == 1
    bad_length = b"\xff\xfe\x01\x00\x00"
    assert device.receive_data(bad_length + frame, 1.1) == [Received("led", b"\x01")]
    assert device.stats.length_checksum_errors == 1


def test_version_mismatch_makes_an_unconfigured_device_ask_for_time() -> None:
    device = RosserialDevice(REG)
    device.receive_data(b"\xff\xff", 0.0)
    assert device.data_to_send() == TIME_REQUEST
    device.receive_data(REQUEST_TOPICS, 0.1)
    device.data_to_send()
    device.receive_data(b"\xff\x01", 0.2)
    assert device.data_to_send() == b"", "a configured device stays quiet"


def test_input_overrun_is_reported_not_dispatched() -> None:
    device = configured_device(input_size=16)
    assert device.receive_data(encode_frame(100, bytes(17)), 1.0) == [InputOverrun(100, 17)]
    assert device.receive_data(encode_frame(100, bytes(16)), 1.0) == [Received("led", bytes(16))]
    assert device.stats.input_overruns == 1


def test_output_larger_than_buffer_is_dropped_with_an_error_log() -> None:
    device = configured_device(output_size=100)
    assert device.publish("chatter", bytes(93)) == -1
    (log,) = frames(device.data_to_send())
    record = REG.deserialize(log.payload, "rosserial_msgs/Log")
    assert (log.topic_id, record.level) == (ReservedId.LOG, 3)
    assert device.publish("chatter", bytes(92)) == 100
    tiny = configured_device(output_size=20)
    assert tiny.publish("chatter", bytes(13)) == -1
    assert tiny.data_to_send() == b"", "the error log does not fit either: dropped too"


def test_bytes_after_request_topics_wait_for_the_next_spin() -> None:
    device = RosserialDevice(REG, subscribers=[Endpoint("led", "std_msgs/Bool")])
    led = encode_frame(100, b"\x01")
    assert device.receive_data(REQUEST_TOPICS + led, 0.0) == [Configured()]
    assert device.tick(0.001) == [Received("led", b"\x01")]


def test_tx_stop_and_reset() -> None:
    device = configured_device()
    device.service_client("cli", "std_srvs/Trigger")
    device.receive_data(REQUEST_TOPICS, 0.5)
    device.data_to_send()
    assert device.call_service("cli", b"")
    with pytest.raises(ProtocolError, match="still waiting"):
        device.call_service("cli", b"")
    events = device.receive_data(TX_STOP, 1.0)
    assert events == [Unconfigured("tx_stop"), ServiceResult("cli", None)]
    assert not device.call_service("cli", b""), "a call while unconfigured returns at once"
    device.receive_data(REQUEST_TOPICS, 2.0)
    assert device.configured
    device.reset()
    assert device.tick(2.1) == [Unconfigured("reset")]
    assert not device.configured


def test_param_request_waits_one_second() -> None:
    device = configured_device()
    device.request_param("rate", 1.0)
    with pytest.raises(ProtocolError, match="still being requested"):
        device.request_param("other", 1.0)
    assert device.tick(2.0) == []
    (result,) = device.tick(2.001)
    assert result == ParamResult("rate", False)
    device.request_param("rate", 3.0, timeout=0.1)
    answer = msg.from_dict(
        "rosserial_msgs/RequestParamResponse", {"ints": [5], "floats": [], "strings": []}
    )
    frame = encode_frame(ReservedId.PARAMETER_REQUEST, msg.encode(answer))
    assert device.receive_data(frame, 3.05) == [ParamResult("rate", True, (5,))]
