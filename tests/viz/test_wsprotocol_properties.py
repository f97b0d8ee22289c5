"""Properties of ``hwbridge.viz.wsprotocol``, the Foxglove WebSocket protocol's messages sans I/O.

The frames here are built and decoded by the test itself, from the protocol's layout (as the npm
``@foxglove/ws-protocol`` client writes and parses it: a one-byte opcode, then little-endian
``uint32``/``uint64`` fields, then the payload; a service call carries its encoding name as a
``uint32`` byte count then UTF-8), never with the module's own ``struct`` formats:

- everything a client sends (binary client message data and service call requests, the JSON
  control messages) parses back to what was put in, and everything the server builds decodes
  to what was put in;
- arbitrary bytes, text and JSON values given to the client-side parsers raise the module's
  ``ProtocolError`` (an ``HwBridgeError``) or parse, never anything else, and whatever parses
  is exactly what the bytes say;
- valid binary frames cut at every length or with any byte changed do the same.
"""

from __future__ import annotations

import json
from typing import Any

from hypothesis import example, given
from hypothesis import strategies as st

from hwbridge.errors import HwBridgeError
from hwbridge.viz import wsprotocol as wsp
from tests.strategies import bounded

U32 = st.integers(0, 2**32 - 1)
U64 = st.integers(0, 2**64 - 1)
PAYLOADS = st.binary(max_size=64)
NAMES = st.text(max_size=16)  # st.text never makes lone surrogates: always UTF-8 encodable


# --- the wire layout, written here independently of the module ------------------------------


def u32(value: int) -> bytes:
    return value.to_bytes(4, "little")


def u64(value: int) -> bytes:
    return value.to_bytes(8, "little")


def client_message_frame(channel_id: int, payload: bytes) -> bytes:
    """What ``FoxgloveClient.sendMessage`` writes: 0x01, uint32 channel id, payload."""
    return b"\x01" + u32(channel_id) + payload


def service_call_frame(service_id: int, call_id: int, encoding: str, payload: bytes) -> bytes:
    """What ``FoxgloveClient.sendServiceCallRequest`` writes: 0x02, uint32 service id, uint32
    call id, uint32 encoding length (bytes, per the spec), the UTF-8 encoding name, payload."""
    name = encoding.encode()
    return b"\x02" + u32(service_id) + u32(call_id) + u32(len(name)) + name + payload


def encode_client(message: wsp.ClientMessage | wsp.ServiceCall) -> bytes:
    if isinstance(message, wsp.ClientMessage):
        return client_message_frame(message.channel_id, message.payload)
    return service_call_frame(
        message.service_id, message.call_id, message.encoding, message.payload
    )


def decode_server(frame: bytes) -> tuple[Any, ...]:
    """The server's binary frames as ``parseServerMessage`` reads them."""
    op = frame[0]
    if op == 0x01:
        assert len(frame) >= 13
        return (
            "message",
            int.from_bytes(frame[1:5], "little"),
            int.from_bytes(frame[5:13], "little"),
            frame[13:],
        )
    if op == 0x02:
        assert len(frame) == 9
        return ("time", int.from_bytes(frame[1:9], "little"))
    assert op == 0x03, op
    service_id, call_id, length = (int.from_bytes(frame[i : i + 4], "little") for i in (1, 5, 9))
    assert len(frame) >= 13 + length
    return ("response", service_id, call_id, frame[13 : 13 + length].decode(), frame[13 + length :])


def parses_or_refuses_binary(frame: bytes) -> wsp.ClientMessage | wsp.ServiceCall | None:
    """``parse_binary(frame)``: None for a ProtocolError, and what parses is what the bytes say
    (encoding it again by the layout gives back exactly ``frame``)."""
    try:
        message = wsp.parse_binary(frame)
    except wsp.ProtocolError:
        return None
    assert isinstance(message, wsp.ClientMessage | wsp.ServiceCall)
    assert isinstance(message.payload, bytes)
    assert encode_client(message) == frame
    return message


# --- round trips: what a client sends ----------------------------------------------------------


@bounded(200)
@given(channel_id=U32, payload=PAYLOADS)
@example(channel_id=2**32 - 1, payload=b"")
def test_client_message_data_parses_to_its_channel_and_payload(
    channel_id: int, payload: bytes
) -> None:
    frame = client_message_frame(channel_id, payload)
    assert wsp.parse_binary(frame) == wsp.ClientMessage(channel_id, payload)


@bounded(200)
@given(service_id=U32, call_id=U32, encoding=NAMES, payload=PAYLOADS)
@example(service_id=2**32 - 1, call_id=2**32 - 1, encoding="", payload=b"")
@example(service_id=0, call_id=0, encoding="ros1", payload=b"\x00\x01")
@example(service_id=1, call_id=2, encoding="jsön✓", payload=b"{}")
def test_service_call_request_parses_to_its_ids_encoding_and_payload(
    service_id: int, call_id: int, encoding: str, payload: bytes
) -> None:
    frame = service_call_frame(service_id, call_id, encoding, payload)
    assert wsp.parse_binary(frame) == wsp.ServiceCall(service_id, call_id, encoding, payload)


def _json_text(message: dict[str, Any], ascii_only: bool) -> str:
    # JSON.stringify's compact form, or Python's spaced, \u-escaping one: JSON either way.
    if ascii_only:
        return json.dumps(message)
    return json.dumps(message, separators=(",", ":"), ensure_ascii=False)


CHANNELS = st.fixed_dictionaries(
    {"id": U32, "topic": NAMES, "encoding": NAMES, "schemaName": NAMES},
    optional={"schema": NAMES, "schemaEncoding": NAMES},
)


@bounded(100)
@given(
    subscriptions=st.lists(st.fixed_dictionaries({"id": U32, "channelId": U32}), max_size=4),
    subscription_ids=st.lists(U32, max_size=4),
    channels=st.lists(CHANNELS, max_size=4),
    channel_ids=st.lists(U32, max_size=4),
    ascii_only=st.booleans(),
)
def test_client_control_messages_parse_back_to_their_fields(
    subscriptions: list[dict[str, int]],
    subscription_ids: list[int],
    channels: list[dict[str, Any]],
    channel_ids: list[int],
    ascii_only: bool,
) -> None:
    def parsed(message: dict[str, Any]) -> dict[str, Any]:
        out = wsp.parse_text(_json_text(message, ascii_only))
        assert out == message
        return out

    sub = parsed({"op": "subscribe", "subscriptions": subscriptions})
    assert list(wsp.objects(sub, "subscriptions")) == subscriptions
    unsub = parsed({"op": "unsubscribe", "subscriptionIds": subscription_ids})
    assert wsp.ints(unsub, "subscriptionIds") == subscription_ids
    adv = parsed({"op": "advertise", "channels": channels})
    assert [wsp.client_channel(item) for item in wsp.objects(adv, "channels")] == [
        wsp.ClientChannel(
            id=c["id"],
            topic=c["topic"],
            encoding=c["encoding"],
            schema_name=c["schemaName"],
            schema=c.get("schema", ""),
            schema_encoding=c.get("schemaEncoding", ""),
        )
        for c in channels
    ]
    unadv = parsed({"op": "unadvertise", "channelIds": channel_ids})
    assert wsp.ints(unadv, "channelIds") == channel_ids


CLIENT_OPS = (
    "getParameters",
    "setParameters",
    "subscribeParameterUpdates",
    "unsubscribeParameterUpdates",
    "subscribeConnectionGraph",
    "unsubscribeConnectionGraph",
    "fetchAsset",
)


@bounded(100)
@given(
    op=st.sampled_from(CLIENT_OPS) | NAMES,
    fields=st.dictionaries(NAMES.filter(lambda k: k != "op"), st.integers() | NAMES, max_size=3),
    ascii_only=st.booleans(),
)
def test_any_op_string_parses_to_the_whole_object(
    op: str, fields: dict[str, Any], ascii_only: bool
) -> None:
    message = {"op": op, **fields}
    assert wsp.parse_text(_json_text(message, ascii_only)) == message


# --- round trips: what the server builds -------------------------------------------------------


@bounded(200)
@given(subscription_id=U32, log_time=U64, payload=PAYLOADS)
@example(subscription_id=2**32 - 1, log_time=2**64 - 1, payload=b"")
def test_message_data_decodes_to_what_was_put_in(
    subscription_id: int, log_time: int, payload: bytes
) -> None:
    frame = wsp.message_data(subscription_id, log_time, payload)
    assert decode_server(frame) == ("message", subscription_id, log_time, payload)


@bounded(100)
@given(time_ns=U64)
@example(time_ns=2**64 - 1)
def test_time_frame_decodes_to_its_time(time_ns: int) -> None:
    assert decode_server(wsp.time_frame(time_ns)) == ("time", time_ns)


@bounded(200)
@given(service_id=U32, call_id=U32, encoding=NAMES, payload=PAYLOADS)
@example(service_id=1, call_id=2, encoding="jsön✓", payload=b"{}")
def test_service_call_response_decodes_to_what_was_put_in(
    service_id: int, call_id: int, encoding: str, payload: bytes
) -> None:
    frame = wsp.service_call_response(service_id, call_id, encoding, payload)
    assert decode_server(frame) == ("response", service_id, call_id, encoding, payload)


@bounded(100)
@given(
    name=NAMES,
    capabilities=st.lists(NAMES, max_size=3),
    encodings=st.lists(NAMES, max_size=3),
    session=NAMES,
    metadata=st.none() | st.dictionaries(NAMES, NAMES, max_size=3),
    channels=st.lists(st.dictionaries(NAMES, st.integers() | NAMES, max_size=3), max_size=3),
    ids=st.lists(U32, max_size=4),
    level=st.sampled_from((wsp.STATUS_INFO, wsp.STATUS_WARNING, wsp.STATUS_ERROR)),
    text=NAMES,
    status_id=st.none() | NAMES,
    service_id=U32,
    call_id=U32,
)
def test_server_text_messages_decode_to_what_was_put_in(
    name: str,
    capabilities: list[str],
    encodings: list[str],
    session: str,
    metadata: dict[str, str] | None,
    channels: list[dict[str, Any]],
    ids: list[int],
    level: int,
    text: str,
    status_id: str | None,
    service_id: int,
    call_id: int,
) -> None:
    info = json.loads(wsp.server_info(name, iter(capabilities), iter(encodings), session, metadata))
    assert info == {
        "op": "serverInfo",
        "name": name,
        "capabilities": capabilities,
        "supportedEncodings": encodings,
        "metadata": metadata or {},
        "sessionId": session,
    }
    assert json.loads(wsp.advertise(iter(channels))) == {"op": "advertise", "channels": channels}
    assert json.loads(wsp.unadvertise(iter(ids))) == {"op": "unadvertise", "channelIds": ids}
    assert json.loads(wsp.advertise_services(iter(channels))) == {
        "op": "advertiseServices",
        "services": channels,
    }
    assert json.loads(wsp.unadvertise_services(iter(ids))) == {
        "op": "unadvertiseServices",
        "serviceIds": ids,
    }
    expected: dict[str, Any] = {"op": "status", "level": level, "message": text}
    if status_id is not None:
        expected["id"] = status_id
    assert json.loads(wsp.status(level, text, status_id)) == expected
    assert json.loads(wsp.service_call_failure(service_id, call_id, text)) == {
        "op": "serviceCallFailure",
        "serviceId": service_id,
        "callId": call_id,
        "message": text,
    }


# --- garbage, truncation, corruption: binary -------------------------------------------------


@bounded(500)
@given(
    frame=st.binary(max_size=40)
    | st.tuples(st.sampled_from(b"\x00\x01\x02\x03\xff"), st.binary(max_size=40)).map(
        lambda t: bytes([t[0]]) + t[1]
    )
)
@example(frame=b"")
@example(frame=b"\x02" + u32(0) + u32(0) + u32(2**32 - 1))
@example(frame=b"\x02" + u32(0) + u32(0) + u32(2) + b"\xc3\x28")
@example(frame=b"\x02" + u32(0) + u32(0) + u32(3) + b"\xed\xa0\x80")  # an encoded surrogate
def test_arbitrary_bytes_parse_or_raise_protocol_error_only(frame: bytes) -> None:
    parses_or_refuses_binary(frame)


def _valid_frames() -> st.SearchStrategy[bytes]:
    return st.builds(client_message_frame, U32, PAYLOADS) | st.builds(
        service_call_frame, U32, U32, NAMES, PAYLOADS
    )


@bounded(150)
@given(frame=_valid_frames())
def test_valid_frames_cut_at_every_length_are_refused_or_a_prefix(frame: bytes) -> None:
    whole = wsp.parse_binary(frame)
    header = 5 if isinstance(whole, wsp.ClientMessage) else 13 + len(whole.encoding.encode())
    for cut in range(len(frame)):
        message = parses_or_refuses_binary(frame[:cut])
        if cut < header:
            assert message is None, (cut, message)
        else:  # the layout has no payload length: a shorter payload is all a cut can be
            assert message is not None
            assert encode_client(message) == frame[:cut]
            assert message.payload == whole.payload[: cut - header]


@bounded(300)
@given(frame=_valid_frames(), data=st.data())
def test_valid_frames_with_a_byte_changed_parse_or_raise_protocol_error_only(
    frame: bytes, data: st.DataObject
) -> None:
    index = data.draw(st.integers(0, len(frame) - 1), label="index")
    value = data.draw(st.integers(0, 255), label="value")
    parses_or_refuses_binary(frame[:index] + bytes([value]) + frame[index + 1 :])


# --- garbage: text and JSON ------------------------------------------------------------------

JSON_TOKENS = st.sampled_from(
    [
        "[",
        "]",
        "{",
        "}",
        ",",
        ":",
        '"',
        '"op"',
        '"a"',
        "0",
        "-1",
        "1e999",
        "1.5",
        "true",
        "false",
        "null",
        "NaN",
        "Infinity",
        "\\u",
        "\\ud800",
        " ",
        "\n",
        "é",
        "\x00",
    ]
)


def _dispatch(message: dict[str, Any]) -> None:
    """What the server does with a parsed message (``foxglove.py``'s ``_on_text``), for every
    key whatever the op, so that each reader meets every kind of value."""
    for key in ("subscriptions", "channels"):
        try:
            items = wsp.objects(message, key)
        except wsp.ProtocolError:
            continue
        assert isinstance(items, list) and all(isinstance(i, dict) for i in items)
        for item in items:
            try:
                channel = wsp.client_channel(item)
            except wsp.ProtocolError:
                continue
            assert type(channel.id) is int and 0 <= channel.id < 2**32
            for text in (
                channel.topic,
                channel.encoding,
                channel.schema_name,
                channel.schema,
                channel.schema_encoding,
            ):
                assert type(text) is str
    for key in ("subscriptionIds", "channelIds"):
        try:
            values = wsp.ints(message, key)
        except wsp.ProtocolError:
            continue
        assert all(type(v) is int for v in values)


def _parses_or_refuses_text(frame: str) -> None:
    try:
        message = wsp.parse_text(frame)
    except wsp.ProtocolError as exc:
        assert isinstance(exc, HwBridgeError)
        return
    assert isinstance(message, dict) and isinstance(message["op"], str)
    _dispatch(message)


@bounded(300)
@given(frame=st.text(max_size=40) | st.lists(JSON_TOKENS, max_size=24).map("".join))
@example(frame="")
@example(frame='{"op": 1}')
@example(frame='{"op": "x"} trailing')
def test_arbitrary_text_parses_or_raises_protocol_error_only(frame: str) -> None:
    _parses_or_refuses_text(frame)


def test_deeply_nested_json_raises_protocol_error() -> None:
    # json's decoder recurses: past the recursion limit it raised RecursionError.
    for frame in ("[" * 100_000, '{"op":"x","a":' + "[" * 100_000, '{"a":' * 100_000):
        _parses_or_refuses_text(frame)


def test_json_integers_too_long_to_convert_raise_protocol_error() -> None:
    # int() of more than sys.get_int_max_str_digits() digits: it raised ValueError.
    for frame in ("1" * 5000, '{"op":"unsubscribe","subscriptionIds":[' + "9" * 5000 + "]}"):
        _parses_or_refuses_text(frame)


JSON_SCALARS = (
    st.none()
    | st.booleans()
    | st.integers(-(2**70), 2**70)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=6)
)
JSON_VALUES = st.recursive(
    JSON_SCALARS,
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=12,
)
CHANNEL_KEYS = ("id", "topic", "encoding", "schemaName", "schema", "schemaEncoding", "channelId")
CHANNELISH = st.dictionaries(st.sampled_from(CHANNEL_KEYS), JSON_VALUES, max_size=7)
FIELDS = ("subscriptions", "subscriptionIds", "channels", "channelIds")
MESSAGES = st.dictionaries(
    st.sampled_from(("op", *FIELDS)) | st.text(max_size=6),
    JSON_VALUES
    | st.lists(CHANNELISH | JSON_SCALARS, max_size=3)
    | st.sampled_from(("subscribe", "unsubscribe", "advertise", "unadvertise")),
    max_size=5,
)


@bounded(300)
@given(value=MESSAGES | JSON_VALUES)
@example(
    value={
        "op": "advertise",
        "channels": [
            {"id": True, "topic": "/t", "encoding": "json", "schemaName": "std_msgs/String"}
        ],
    }
)
@example(
    value={
        "op": "advertise",
        "channels": [
            {"id": -1, "topic": "/t", "encoding": "json", "schemaName": "std_msgs/String"}
        ],
    }
)
@example(
    value={
        "op": "advertise",
        "channels": [
            {"id": 2**32, "topic": "/t", "encoding": "json", "schemaName": "std_msgs/String"}
        ],
    }
)
@example(value={"op": "unsubscribe", "subscriptionIds": [True, 1]})
def test_arbitrary_json_values_parse_or_raise_protocol_error_only(value: Any) -> None:
    _parses_or_refuses_text(json.dumps(value))


def test_a_channel_id_must_be_a_uint32_not_a_boolean() -> None:
    channel = {"topic": "/t", "encoding": "json", "schemaName": "std_msgs/String"}
    for bad in (True, False, -1, 2**32, 1.0, "1", None):
        try:
            got = wsp.client_channel({**channel, "id": bad})
        except wsp.ProtocolError:
            continue
        raise AssertionError(f"id {bad!r} accepted as {got!r}")
    assert wsp.client_channel({**channel, "id": 2**32 - 1}).id == 2**32 - 1
