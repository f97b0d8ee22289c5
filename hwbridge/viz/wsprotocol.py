"""The Foxglove WebSocket protocol's messages, without I/O: what the server sends, built as text
or bytes, and what clients send, parsed and checked.

Two subprotocol names carry the same protocol: ``foxglove.websocket.v1`` (the published
specification's name, offered by ``@foxglove/ws-protocol`` and the viewers built on it, such as
Lichtblick) and ``foxglove.sdk.v1`` (what Foxglove's current app and SDK offer). JSON text frames
carry control messages (each with an ``op``); binary frames start with a one-byte opcode and carry
little-endian integers then a payload.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

from hwbridge.errors import HwBridgeError

__all__ = [
    "SUBPROTOCOLS",
    "ClientChannel",
    "ClientMessage",
    "ProtocolError",
    "ServiceCall",
    "advertise",
    "advertise_services",
    "client_channel",
    "ints",
    "message_data",
    "objects",
    "parse_binary",
    "parse_text",
    "server_info",
    "service_call_failure",
    "service_call_response",
    "status",
    "time_frame",
    "unadvertise",
    "unadvertise_services",
]

SUBPROTOCOLS: Final = ("foxglove.websocket.v1", "foxglove.sdk.v1")
"""Accepted subprotocol names, one protocol: the spec's name first, then the SDK's."""

# Server -> client binary opcodes.
OP_MESSAGE_DATA: Final = 0x01
OP_TIME: Final = 0x02
OP_SERVICE_CALL_RESPONSE: Final = 0x03
# Client -> server binary opcodes.
OP_CLIENT_MESSAGE_DATA: Final = 0x01
OP_SERVICE_CALL_REQUEST: Final = 0x02

STATUS_INFO: Final = 0
STATUS_WARNING: Final = 1
STATUS_ERROR: Final = 2

_MESSAGE_HEADER: Final = struct.Struct("<BIQ")  # opcode, subscription id, log time (ns)
_TIME: Final = struct.Struct("<BQ")
_CALL_HEADER: Final = struct.Struct("<BIII")  # opcode, service id, call id, encoding length
_CLIENT_DATA_HEADER: Final = struct.Struct("<BI")  # opcode, client channel id
_UINT32_MAX: Final = 2**32 - 1


class ProtocolError(HwBridgeError):
    """A client sent something the protocol does not allow (the text says what)."""


# ---------------------------------------------------------------------------------- server side
def _text(message: Mapping[str, Any]) -> str:
    return json.dumps(message, separators=(",", ":"))


def server_info(
    name: str,
    capabilities: Iterable[str],
    supported_encodings: Iterable[str],
    session_id: str,
    metadata: Mapping[str, str] | None = None,
) -> str:
    return _text(
        {
            "op": "serverInfo",
            "name": name,
            "capabilities": list(capabilities),
            "supportedEncodings": list(supported_encodings),
            "metadata": dict(metadata or {}),
            "sessionId": session_id,
        }
    )


def advertise(channels: Iterable[Mapping[str, Any]]) -> str:
    """``channels``: dicts with id, topic, encoding, schemaName, schema, schemaEncoding."""
    return _text({"op": "advertise", "channels": list(channels)})


def unadvertise(channel_ids: Iterable[int]) -> str:
    return _text({"op": "unadvertise", "channelIds": list(channel_ids)})


def advertise_services(services: Iterable[Mapping[str, Any]]) -> str:
    return _text({"op": "advertiseServices", "services": list(services)})


def unadvertise_services(service_ids: Iterable[int]) -> str:
    return _text({"op": "unadvertiseServices", "serviceIds": list(service_ids)})


def status(level: int, message: str, status_id: str | None = None) -> str:
    out: dict[str, Any] = {"op": "status", "level": level, "message": message}
    if status_id is not None:
        out["id"] = status_id
    return _text(out)


def service_call_failure(service_id: int, call_id: int, message: str) -> str:
    return _text(
        {"op": "serviceCallFailure", "serviceId": service_id, "callId": call_id, "message": message}
    )


def message_data(subscription_id: int, log_time_ns: int, payload: bytes) -> bytes:
    return _MESSAGE_HEADER.pack(OP_MESSAGE_DATA, subscription_id, log_time_ns) + payload


def time_frame(time_ns: int) -> bytes:
    return _TIME.pack(OP_TIME, time_ns)


def service_call_response(service_id: int, call_id: int, encoding: str, payload: bytes) -> bytes:
    name = encoding.encode()
    return (
        _CALL_HEADER.pack(OP_SERVICE_CALL_RESPONSE, service_id, call_id, len(name)) + name + payload
    )


# ---------------------------------------------------------------------------------- client side
@dataclass(frozen=True, slots=True)
class ClientChannel:
    """A channel a client advertised to publish on."""

    id: int
    topic: str
    encoding: str
    schema_name: str
    schema: str = ""
    schema_encoding: str = ""


@dataclass(frozen=True, slots=True)
class ClientMessage:
    """Binary opcode 1 from a client: a message on one of its channels."""

    channel_id: int
    payload: bytes


@dataclass(frozen=True, slots=True)
class ServiceCall:
    """Binary opcode 2 from a client: a service call request."""

    service_id: int
    call_id: int
    encoding: str
    payload: bytes


def parse_binary(frame: bytes) -> ClientMessage | ServiceCall:
    """A client's binary frame; ProtocolError when it is not one the protocol defines."""
    if not frame:
        raise ProtocolError("empty binary message")
    opcode = frame[0]
    if opcode == OP_CLIENT_MESSAGE_DATA:
        if len(frame) < _CLIENT_DATA_HEADER.size:
            raise ProtocolError(f"message data of {len(frame)} bytes: shorter than its header")
        _, channel_id = _CLIENT_DATA_HEADER.unpack_from(frame)
        return ClientMessage(channel_id, frame[_CLIENT_DATA_HEADER.size :])
    if opcode == OP_SERVICE_CALL_REQUEST:
        if len(frame) < _CALL_HEADER.size:
            raise ProtocolError(f"service call request of {len(frame)} bytes: no room for header")
        _, service_id, call_id, length = _CALL_HEADER.unpack_from(frame)
        start = _CALL_HEADER.size
        if len(frame) < start + length:
            raise ProtocolError(f"service call request: encoding name of {length} bytes cut short")
        try:
            encoding = frame[start : start + length].decode()
        except UnicodeDecodeError:
            raise ProtocolError("service call request: encoding name is not UTF-8") from None
        return ServiceCall(service_id, call_id, encoding, frame[start + length :])
    raise ProtocolError(f"unknown binary opcode 0x{opcode:02x}")


def parse_text(frame: str) -> dict[str, Any]:
    """A client's JSON message as a dict with a string ``op``; ProtocolError otherwise."""
    try:
        message = json.loads(frame)
    except (ValueError, RecursionError) as exc:
        # ValueError: JSONDecodeError, or an integer of more digits than int() converts;
        # RecursionError: arrays or objects nested deeper than the decoder recurses.
        raise ProtocolError(f"not JSON: {str(exc)[:200]}") from None
    if not isinstance(message, dict) or not isinstance(message.get("op"), str):
        raise ProtocolError("a JSON message must be an object with an 'op' string")
    return message


def ints(message: Mapping[str, Any], key: str) -> list[int]:
    """``message[key]`` as a list of integers; ProtocolError when it is not one."""
    value = message.get(key)
    if not isinstance(value, list) or not all(
        isinstance(v, int) and not isinstance(v, bool) for v in value
    ):
        raise ProtocolError(f"{message.get('op')}: '{key}' must be a list of integers")
    return value


def objects(message: Mapping[str, Any], key: str) -> Sequence[Mapping[str, Any]]:
    """``message[key]`` as a list of JSON objects; ProtocolError when it is not one."""
    value = message.get(key)
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise ProtocolError(f"{message.get('op')}: '{key}' must be a list of objects")
    return value


def client_channel(item: Mapping[str, Any]) -> ClientChannel:
    """One channel of a client's ``advertise``; ProtocolError naming a missing field."""
    channel_id = item.get("id")
    # Binary client messages name the channel by a uint32; JSON true is no id.
    if not isinstance(channel_id, int) or isinstance(channel_id, bool):
        raise ProtocolError("advertise: a channel needs 'id' (int)")
    if not 0 <= channel_id <= _UINT32_MAX:
        raise ProtocolError(f"advertise: channel id {channel_id} is not a uint32")
    for key, kind in (("topic", str), ("encoding", str), ("schemaName", str)):
        if not isinstance(item.get(key), kind):
            raise ProtocolError(f"advertise: a channel needs '{key}' ({kind.__name__})")
    schema = item.get("schema")
    schema_encoding = item.get("schemaEncoding")
    return ClientChannel(
        id=channel_id,
        topic=str(item["topic"]),
        encoding=str(item["encoding"]),
        schema_name=str(item["schemaName"]),
        schema=schema if isinstance(schema, str) else "",
        schema_encoding=schema_encoding if isinstance(schema_encoding, str) else "",
    )
