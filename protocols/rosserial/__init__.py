"""rosserial protocol v2 compatibility: framing, the host session and a device emulation.

``framing`` encodes and parses frames, ``host`` is the host side of a session (what
rosserial_python's serial node does), ``device`` emulates the rosserial client library that runs
on the board, for tests. All are pure state machines: no I/O, no threads, no clock of their own.
"""

from __future__ import annotations

from hwbridge.protocols.rosserial.device import RosserialDevice
from hwbridge.protocols.rosserial.framing import FrameParser, RosFrame, decode_frame, encode_frame
from hwbridge.protocols.rosserial.host import REQUEST_TOPICS, TX_STOP, RosserialHost
from hwbridge.protocols.rosserial.ids import ReservedId

__all__ = [
    "REQUEST_TOPICS",
    "TX_STOP",
    "FrameParser",
    "ReservedId",
    "RosFrame",
    "RosserialDevice",
    "RosserialHost",
    "decode_frame",
    "encode_frame",
]
