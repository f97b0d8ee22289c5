"""Golden rosserial frames (protocols/vectors/rosserial.json): encoding, decoding, replay.

The replays drive the real host and the device emulation with the vector frames and compare the
bytes they write with the vectors, so the file, the host and the emulation agree byte for byte.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

from hwbridge import msg
from hwbridge.protocols.base import (
    Connected,
    Log,
    Message,
    ParamRequest,
    ServiceRequest,
    ServiceResponse,
)
from hwbridge.protocols.msgtypes import BUNDLED_MSG_DIR
from hwbridge.protocols.rosserial.device import (
    ParamResult,
    Received,
    RosserialDevice,
    ServiceCalled,
    ServiceResult,
)
from hwbridge.protocols.rosserial.framing import (
    BadFrame,
    FrameParser,
    NonFrameBytes,
    OldProtocol,
    RosFrame,
    decode_frame,
    encode_frame,
)
from hwbridge.protocols.rosserial.host import REQUEST_TOPICS, TX_STOP, RosserialHost

VECTORS: dict[str, Any] = json.loads(
    (BUNDLED_MSG_DIR.parent / "vectors" / "rosserial.json").read_text(encoding="utf-8")
)
FRAMES: dict[str, dict[str, Any]] = {f["name"]: f for f in VECTORS["frames"]}
SPEC = Path(__file__).resolve().parents[3] / "shared" / "specs" / "ROSSERIAL.md"
REG = msg.registry()
WALL = 1700000000.25


def wire(name: str) -> bytes:
    return bytes.fromhex(FRAMES[name]["hex"])


def payload(name: str) -> bytes:
    return bytes.fromhex(FRAMES[name]["payload_hex"])


def test_vector_file_shape() -> None:
    assert VECTORS["protocol_version"] == 2
    assert len(FRAMES) == len(VECTORS["frames"]), "vector names must be unique"
    for frame in VECTORS["frames"]:
        assert frame["direction"] in {"host_to_device", "device_to_host"}
        assert frame["hex"] == frame["hex"].lower()
        assert set(frame) >= {"name", "direction", "hex", "topic_id", "payload_hex", "decoded"}
    kinds = {f["decoded"]["kind"] for f in VECTORS["frames"]}
    assert kinds >= {
        "request_topics",
        "time_request",
        "time",
        "topic_info",
        "message",
        "service_request",
        "service_response",
        "param_request",
        "param_response",
        "log",
        "tx_stop",
    }


@pytest.mark.parametrize("vector", VECTORS["frames"], ids=lambda v: v["name"])
def test_frame_vector(vector: dict[str, Any]) -> None:
    data = bytes.fromhex(vector["payload_hex"])
    assert encode_frame(vector["topic_id"], data).hex() == vector["hex"]
    assert decode_frame(bytes.fromhex(vector["hex"])) == RosFrame(vector["topic_id"], data)
    decoded = vector["decoded"]
    if "type" in decoded:
        fields = {name for name, _ in REG.fields(decoded["type"])}
        value = msg.to_dict(msg.decode(data, decoded["type"]))
        assert {k: v for k, v in value.items() if k in fields} == decoded["value"]
        assert msg.encode(msg.from_dict(decoded["type"], decoded["value"])) == data
    else:
        assert data == b""


def test_worked_example_literally() -> None:
    """The capture of ROSSERIAL.md, typed in from the spec, byte for byte."""
    assert REQUEST_TOPICS == bytes.fromhex("ff fe 00 00 ff 00 00 ff") == wire("request_topics")
    assert TX_STOP == bytes.fromhex("ff fe 00 00 ff 0b 00 f4") == wire("tx_stop")
    topic_info = (
        bytes.fromhex("ff fe 48 00 b7 00 00 7d 00 07000000")
        + b"chatter"
        + bytes.fromhex("0f000000")
        + b"std_msgs/String"
        + bytes.fromhex("20000000")
        + b"992ce8a1687cec8c8bd883ec73ca41d1"
        + bytes.fromhex("00020000 23")
    )
    assert wire("topic_info_publisher_chatter") == topic_info
    frame = decode_frame(topic_info)
    assert frame.topic_id == 0 and len(frame.payload) == 72
    info = REG.deserialize(frame.payload, "rosserial_msgs/TopicInfo")
    assert (info.topic_id, info.topic_name, info.message_type, info.buffer_size) == (
        125,
        "chatter",
        "std_msgs/String",
        512,
    )
    data = bytes.fromhex("ff fe 10 00 ef 7d 00 0c000000") + b"hello world!" + b"\xf9"
    assert wire("message_chatter") == data
    assert msg.to_dict(msg.decode(decode_frame(data).payload, "std_msgs/String")) == {
        "data": "hello world!"
    }


def _spec_bytes(text: str) -> bytes:
    """``ff fe | 07000000 "chatter" | 23`` as written in ROSSERIAL.md -> bytes."""
    out = bytearray()
    for token in re.findall(r'"[^"]*"|[0-9a-fA-F]+', text):
        out += token[1:-1].encode() if token.startswith('"') else bytes.fromhex(token)
    return bytes(out)


@pytest.mark.skipif(not SPEC.exists(), reason="shared/specs is not beside this checkout")
def test_worked_example_matches_the_spec_text() -> None:
    section = SPEC.read_text(encoding="utf-8").split("## Worked example", 1)[1]
    quoted = re.findall(r"`([^`]+)`", section.split("## ", 1)[0])
    assert _spec_bytes(quoted[0]) == wire("request_topics")
    assert _spec_bytes(quoted[1]) == wire("topic_info_publisher_chatter")
    assert _spec_bytes(quoted[2]) == wire("message_chatter")
    stop = SPEC.read_text(encoding="utf-8").split("## Stop", 1)[1]
    assert _spec_bytes(re.findall(r"`([^`]+)`", stop)[0]) == wire("tx_stop")


@pytest.mark.parametrize("vector", VECTORS["bad"], ids=lambda v: v["name"])
def test_bad_vector(vector: dict[str, Any]) -> None:
    parser = FrameParser(max_payload=vector.get("max_payload", 4096))
    events = parser.feed(bytes.fromhex(vector["hex"]))
    assert not [e for e in events if isinstance(e, RosFrame)]
    first = events[0]
    if vector["reason"] == "old_protocol":
        assert isinstance(first, OldProtocol)
    else:
        assert isinstance(first, BadFrame)
        assert first.reason.value == vector["reason"]


@pytest.mark.parametrize("vector", VECTORS["resync"], ids=lambda v: v["name"])
def test_resync_vector(vector: dict[str, Any]) -> None:
    events = FrameParser().feed(bytes.fromhex(vector["hex"]))
    frames = [e for e in events if isinstance(e, RosFrame)]
    assert frames == [decode_frame(wire(name)) for name in vector["frames"]]
    if "non_frame_hex" in vector:
        text = b"".join(e.data for e in events if isinstance(e, NonFrameBytes))
        assert text == bytes.fromhex(vector["non_frame_hex"])


# ---------------------------------------------------------------------------------- replays
TOPIC_INFOS = [n for n in FRAMES if n.startswith("topic_info_")]
PARAMS = [n.removeprefix("param_request_") for n in FRAMES if n.startswith("param_request_")]


def example_device() -> RosserialDevice:
    """The device the vectors describe, endpoints added in the vectors' order."""
    device = RosserialDevice(REG)
    device.advertise("chatter", "std_msgs/String")
    device.advertise_service(
        "toggle_led", "std_srvs/SetBool", lambda _request: payload("service_server_response")
    )
    device.subscribe("led", "std_msgs/Bool")
    device.service_client("trigger", "std_srvs/Trigger")
    return device


def test_device_replay() -> None:
    device = example_device()
    assert device.receive_data(wire("request_topics"), 1.0)
    expected = wire("time_request") + b"".join(wire(n) for n in TOPIC_INFOS)
    assert device.data_to_send() == expected

    device.receive_data(wire("time_reply"), 1.01)
    assert device.publish("chatter", payload("message_chatter")) > 0
    assert device.data_to_send() == wire("message_chatter")

    assert device.receive_data(wire("message_led"), 1.02) == [
        Received("led", payload("message_led"))
    ]
    events = device.receive_data(wire("service_server_request"), 1.03)
    assert events == [ServiceCalled("toggle_led", payload("service_server_request"))]
    assert device.data_to_send() == wire("service_server_response")

    assert device.call_service("trigger", payload("service_client_request"))
    assert device.data_to_send() == wire("service_client_request")
    assert device.receive_data(wire("service_client_response"), 1.04) == [
        ServiceResult("trigger", payload("service_client_response"))
    ]
    for name in PARAMS:
        device.request_param(name, 1.05)
        assert device.data_to_send() == wire(f"param_request_{name}")
        (result,) = device.receive_data(wire(f"param_response_{name}"), 1.06)
        arrays = FRAMES[f"param_response_{name}"]["decoded"]["value"]
        assert result == ParamResult(
            name,
            True,
            tuple(arrays["ints"]),
            tuple(arrays["floats"]),
            tuple(arrays["strings"]),
        )
    device.log(1, "hello from the board")
    assert device.data_to_send() == wire("log_info")
    assert device.publish("chatter", bytes(600)) == -1  # larger than the 512-byte buffer
    assert device.data_to_send() == wire("log_error_dropped")
    device.receive_data(wire("tx_stop"), 1.07)
    assert not device.configured


def test_host_replay() -> None:
    host = RosserialHost(REG, now=0.0, wall_clock=lambda: WALL)
    assert host.tick(0.0) == []
    assert host.data_to_send() == wire("request_topics")
    host = RosserialHost(REG, now=0.0, wall_offset=WALL - 0.05)  # the same, by offset
    assert host.data_to_send() == wire("request_topics")

    host.receive_data(wire("time_request"), 0.05)  # before the request is repeated at 0.1
    assert host.data_to_send() == wire("time_reply")
    for name in TOPIC_INFOS:
        assert host.receive_data(wire(name), 0.05) == []
    assert host.data_to_send() == b""
    (connected,) = host.tick(1.0)
    assert isinstance(connected, Connected)
    table = host.topics
    assert table is not None
    assert table.publishers["chatter"].topic_id == 125
    assert table.subscribers["led"].topic_id == 101
    assert table.service_servers["toggle_led"].request_topic_id == 100
    assert table.service_servers["toggle_led"].response_topic_id == 126
    assert table.service_clients["trigger"].request_topic_id == 127
    assert table.service_clients["trigger"].response_topic_id == 102
    assert {(e.name, e.channel) for e in connected.endpoints} == {
        ("chatter", 125),
        ("led", 101),
        ("toggle_led", 100),
        ("trigger", 127),
    }

    assert host.receive_data(wire("message_chatter"), 1.1) == [
        Message(125, payload("message_chatter"), 0)
    ]
    assert host.publish(101, payload("message_led"))
    assert host.data_to_send() == wire("message_led")

    request_id = host.call_service(100, payload("service_server_request"), now=1.2)
    assert host.data_to_send() == wire("service_server_request")
    assert host.receive_data(wire("service_server_response"), 1.3) == [
        ServiceResponse(100, request_id, payload("service_server_response"))
    ]

    (request,) = host.receive_data(wire("service_client_request"), 1.4)
    assert isinstance(request, ServiceRequest)
    assert request == ServiceRequest(127, request.request_id, payload("service_client_request"))
    assert host.respond_service(127, request.request_id, payload("service_client_response"))
    assert host.data_to_send() == wire("service_client_response")

    for name in PARAMS:
        (asked,) = host.receive_data(wire(f"param_request_{name}"), 1.5)
        assert isinstance(asked, ParamRequest)
        assert asked == ParamRequest(asked.request_id, name)
        value = FRAMES[f"param_response_{name}"]["decoded"]["param_value"]
        assert host.answer_param(asked.request_id, value)
        assert host.data_to_send() == wire(f"param_response_{name}")

    assert host.receive_data(wire("log_info"), 1.6) == [Log(1, "hello from the board")]
    host.close(1.7)
    assert host.chunks_to_send() == [wire("tx_stop")]
    assert host.data_to_send() == b""
