"""The rosserial host's topic table: what a device announced, checked and joined (sans-I/O).

A device announces each endpoint in a ``rosserial_msgs/TopicInfo`` on a reserved id (see
:mod:`hwbridge.protocols.rosserial.ids`). :func:`check_info` compares it with the host's type of
the same name; :func:`build_table` joins the accepted ones into a :class:`TopicTable` (service
halves joined by name) and :func:`endpoints` lists them as the shared
:class:`~hwbridge.protocols.base.Endpoint` records the bridge works with.

Channels (the keys of events and actions) are topic ids: a publisher's or subscriber's own id; for
a service the id its *requests* travel on (the device's subscriber half for a server, its
publisher half for a client).

Types the host does not know pass through: the endpoint is accepted with the device's own type
name and md5 (a node that has the definition decodes the bytes), reported once per type as a
warning. A known type whose md5 differs from the device's is refused.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Final

from hwbridge.protocols.base import Endpoint, EntryKind
from hwbridge.protocols.errors import (
    HwBridgeError,
    ProtocolError,
    ProtocolMismatchError,
    UnknownTypeError,
)
from hwbridge.protocols.msgtypes import TypeRegistry
from hwbridge.protocols.rosserial.ids import ReservedId

__all__ = [
    "UNKNOWN_SERVICE_MD5",
    "BuiltTable",
    "Info",
    "Service",
    "Topic",
    "TopicTable",
    "build_table",
    "check_info",
    "endpoints",
]

_log = logging.getLogger("hwbridge.protocols.rosserial")

UNKNOWN_SERVICE_MD5: Final = "*"
"""The combined md5 given for a service of a type the host does not know: it is the md5 of the
two halves' text, which the device does not send (only the md5 of each half); ``*`` is ROS 1's
"any md5"."""

_ROLE: Final = {
    ReservedId.PUBLISHER: "publisher",
    ReservedId.SUBSCRIBER: "subscriber",
    ReservedId.SERVICE_SERVER: "service server (response half)",
    ReservedId.SERVICE_SERVER + 1: "service server (request half)",
    ReservedId.SERVICE_CLIENT: "service client (request half)",
    ReservedId.SERVICE_CLIENT + 1: "service client (response half)",
}
TOPIC_INFO_IDS: Final = frozenset(range(ReservedId.PUBLISHER, ReservedId.SERVICE_CLIENT + 2))
"""The reserved ids TopicInfos arrive on."""
DEVICE_OUTPUT_KINDS: Final = frozenset(
    {ReservedId.PUBLISHER, ReservedId.SERVICE_SERVER, ReservedId.SERVICE_CLIENT}
)
"""TopicInfo ids whose endpoint the device writes to (their buffer_size is its output buffer)."""
DEVICE_INPUT_KINDS: Final = frozenset(
    {ReservedId.SUBSCRIBER, ReservedId.SERVICE_SERVER + 1, ReservedId.SERVICE_CLIENT + 1}
)


@dataclass(frozen=True)
class Topic:
    """One device publisher or subscriber, as the device announced it (md5 checked)."""

    name: str
    type: str
    md5: str
    topic_id: int
    buffer_size: int
    """Device output buffer (publishers) or input buffer (subscribers), in bytes."""
    known: bool = True
    """The host knows the type (False: it passes through unchecked)."""


@dataclass(frozen=True)
class Service:
    """A device service server or client, joined from its two announced halves."""

    name: str
    type: str
    request_topic_id: int
    """Topic id the Request travels on (host -> device for servers, device -> host for clients);
    the service's channel."""
    response_topic_id: int
    """Topic id the Response travels on."""
    request_md5: str
    response_md5: str
    input_buffer: int
    """The device's input buffer for what the host sends to this service."""
    md5: str = UNKNOWN_SERVICE_MD5
    """The combined service md5 (:data:`UNKNOWN_SERVICE_MD5` for a type the host lacks)."""
    known: bool = True


@dataclass(frozen=True)
class TopicTable:
    """Everything a device announced and the host accepted, by name."""

    publishers: dict[str, Topic] = field(default_factory=dict)
    """Topics the device publishes (the host receives them as ``Message`` events)."""
    subscribers: dict[str, Topic] = field(default_factory=dict)
    """Topics the device subscribes to (the host sends with ``RosserialHost.publish``)."""
    service_servers: dict[str, Service] = field(default_factory=dict)
    """Services the device serves (called with ``RosserialHost.call_service``)."""
    service_clients: dict[str, Service] = field(default_factory=dict)
    """Services the device calls (answered with ``RosserialHost.respond_service``)."""

    def __len__(self) -> int:
        return sum(
            len(d)
            for d in (self.publishers, self.subscribers, self.service_servers, self.service_clients)
        )


@dataclass(frozen=True)
class Info:
    """One accepted TopicInfo: the reserved id it came on and its fields."""

    kind: int
    topic_id: int
    name: str
    type: str
    md5: str
    buffer_size: int
    known: bool = True
    """The host knows the type and checked the md5."""


def role(kind: int) -> str:
    """What a TopicInfo on reserved id ``kind`` announces, for messages."""
    return _ROLE.get(kind, f"endpoint (id {kind})")


def check_info(registry: TypeRegistry, info: Info, warned: set[str]) -> Info | HwBridgeError:
    """``info`` as accepted (``known`` False for a type the host lacks) or why it is refused.

    An unknown type is logged as a warning once per type name in ``warned`` (which is updated).
    """
    where = f"device {role(info.kind)} {info.name!r} (topic id {info.topic_id})"
    is_message = info.kind in (ReservedId.PUBLISHER, ReservedId.SUBSCRIBER)
    try:
        if is_message:
            host_type = registry.message(info.type)
            half = ""
        else:
            service = registry.service(info.type)
            is_request = info.kind in (ReservedId.SERVICE_SERVER + 1, ReservedId.SERVICE_CLIENT)
            host_type = service.request if is_request else service.response
            half = " request" if is_request else " response"
    except UnknownTypeError:
        if info.type not in warned:
            warned.add(info.type)
            ext = ".msg" if is_message else ".srv"
            _log.warning(
                "%s has %s type %s, which hwbridge does not know: its %s pass through "
                "unchecked with the device's md5 %s (a node that has the definition decodes "
                "them). Add its %s file with --msg-path DIR to check and decode it.",
                where,
                "message" if is_message else "service",
                info.type,
                "messages" if is_message else "requests and responses",
                info.md5,
                ext,
            )
        return Info(
            info.kind, info.topic_id, info.name, info.type, info.md5, info.buffer_size, False
        )
    if info.md5 != host_type.md5:
        return ProtocolMismatchError(
            f"md5 mismatch on {where}: the device's {info.type}{half} has md5 {info.md5}, "
            f"hwbridge's {host_type.name} (from {host_type.source}) has md5 "
            f"{host_type.md5}. Build both from the same definition (regenerate the "
            "sketch's ros_lib, or fix hwbridge's .msg). This endpoint is left out; the "
            "others keep working."
        )
    return info


@dataclass(frozen=True)
class BuiltTable:
    """A :class:`TopicTable` and the lookups the host needs, by topic id."""

    table: TopicTable
    subscribers: dict[int, Topic]
    """Device subscribers by topic id (the channel the host publishes on)."""
    servers: dict[int, Service]
    """Device service servers by request topic id (their channel)."""
    clients: dict[int, Service]
    """Device service clients by request topic id (their channel)."""
    rx: dict[int, tuple[str, int]]
    """What a frame received on a topic id is: (``RX_*`` kind, channel)."""
    endpoints: tuple[Endpoint, ...]
    input_buffer: int | None
    """The smallest device input buffer announced (else the smallest buffer, else None)."""
    output_buffer: int | None
    """The largest device output buffer announced (None if none)."""


RX_MESSAGE: Final = "message"
RX_SERVER_RESPONSE: Final = "server_response"
RX_CLIENT_REQUEST: Final = "client_request"


def build_table(
    registry: TypeRegistry, infos: Iterable[Info], errors: list[HwBridgeError]
) -> BuiltTable:
    """Join accepted TopicInfos into a table; a service missing a half goes to ``errors``."""
    publishers: dict[str, Topic] = {}
    subscribers: dict[str, Topic] = {}
    servers: dict[str, Service] = {}
    clients: dict[str, Service] = {}
    halves: dict[tuple[int, str], dict[int, Info]] = {}
    rx: dict[int, tuple[str, int]] = {}
    every = list(infos)
    for info in every:
        topic = Topic(info.name, info.type, info.md5, info.topic_id, info.buffer_size, info.known)
        if info.kind == ReservedId.PUBLISHER:
            publishers[info.name] = topic
            rx[info.topic_id] = (RX_MESSAGE, info.topic_id)
        elif info.kind == ReservedId.SUBSCRIBER:
            subscribers[info.name] = topic
        else:
            base: int = ReservedId.SERVICE_SERVER if info.kind < 4 else ReservedId.SERVICE_CLIENT
            halves.setdefault((base, info.name), {})[info.kind - base] = info
    for (base, name), parts in halves.items():
        pub, sub = parts.get(0), parts.get(1)
        if pub is None or sub is None:
            kind = "service server" if base == ReservedId.SERVICE_SERVER else "service client"
            missing = "publisher" if pub is None else "subscriber"
            errors.append(
                ProtocolError(
                    f"device {kind} {name!r} announced no {missing} half "
                    f"(TopicInfo on id {base + (0 if pub is None else 1)}); it is left out"
                )
            )
            continue
        known = pub.known and sub.known
        md5 = registry.service(pub.type).md5 if known else UNKNOWN_SERVICE_MD5
        if base == ReservedId.SERVICE_SERVER:
            servers[name] = Service(
                name,
                sub.type,
                sub.topic_id,
                pub.topic_id,
                sub.md5,
                pub.md5,
                sub.buffer_size,
                md5,
                known,
            )
            rx[pub.topic_id] = (RX_SERVER_RESPONSE, sub.topic_id)
        else:
            clients[name] = Service(
                name,
                pub.type,
                pub.topic_id,
                sub.topic_id,
                pub.md5,
                sub.md5,
                sub.buffer_size,
                md5,
                known,
            )
            rx[pub.topic_id] = (RX_CLIENT_REQUEST, pub.topic_id)
    inputs = [i.buffer_size for i in every if i.kind in DEVICE_INPUT_KINDS]
    sizes = [i.buffer_size for i in every]
    outputs = [i.buffer_size for i in every if i.kind in DEVICE_OUTPUT_KINDS]
    table = TopicTable(publishers, subscribers, servers, clients)
    return BuiltTable(
        table,
        {t.topic_id: t for t in subscribers.values()},
        {s.request_topic_id: s for s in servers.values()},
        {s.request_topic_id: s for s in clients.values()},
        rx,
        endpoints(table),
        min(inputs) if inputs else (min(sizes) if sizes else None),
        max(outputs) if outputs else None,
    )


def endpoints(table: TopicTable) -> tuple[Endpoint, ...]:
    """The table as shared endpoint records, channels being topic ids (see the module doc)."""
    out = [
        Endpoint(t.topic_id, EntryKind.PUBLISHER, t.name, t.type, t.md5)
        for t in table.publishers.values()
    ]
    out += [
        Endpoint(t.topic_id, EntryKind.SUBSCRIBER, t.name, t.type, t.md5)
        for t in table.subscribers.values()
    ]
    out += [
        Endpoint(s.request_topic_id, EntryKind.SERVICE_SERVER, s.name, s.type, s.md5)
        for s in table.service_servers.values()
    ]
    out += [
        Endpoint(s.request_topic_id, EntryKind.SERVICE_CLIENT, s.name, s.type, s.md5)
        for s in table.service_clients.values()
    ]
    return tuple(out)
