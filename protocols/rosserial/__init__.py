"""rosserial protocol v2 compatibility: framing, the host session and a device emulation.

``framing`` encodes and parses frames (:class:`RosserialFraming` is the session's framing),
``host`` is the host side of a session (what rosserial_python's serial node does; its topic
table, request ids, parameter answers and counters live in ``table``, ``services``, ``params``
and ``stats``), ``device`` emulates the rosserial client library that runs on the board, for
tests, and ``spec`` registers the protocol with the runtime. All are pure state machines: no I/O,
no threads, no clock of their own.
"""

from __future__ import annotations

from hwbridge.protocols.rosserial.device import RosserialDevice
from hwbridge.protocols.rosserial.framing import (
    FrameParser,
    RosFrame,
    RosserialFraming,
    decode_frame,
    encode_frame,
)
from hwbridge.protocols.rosserial.host import REQUEST_TOPICS, TX_STOP, RosserialHost
from hwbridge.protocols.rosserial.ids import ReservedId

__all__ = [
    "REQUEST_TOPICS",
    "TX_STOP",
    "FrameParser",
    "ReservedId",
    "RosFrame",
    "RosserialDevice",
    "RosserialFraming",
    "RosserialHost",
    "decode_frame",
    "encode_frame",
]
