"""Framing of the native protocol: frames, decoders, encoders, fragmentation (sans-I/O).

A frame travels as ``COBS(header + payload + crc16) 0x00`` on a stream link and as
``header + payload + crc16`` alone in one datagram on a datagram link; PROTOCOL.md, Part 1, is
the specification and this package its reference implementation. Nothing here does I/O: feed
bytes to :class:`FrameDecoder` and get events back, turn :class:`Frame` objects into bytes with
:func:`encode_frame`, split and join messages with :func:`fragment` and :class:`Reassembler`.
Sessions use a framing object, :class:`NativeStreamFraming` or :class:`NativeDatagramFraming`.

The code lives in ``_framing/``: ``frames`` (types, header, sizes), ``encoder``, ``decoder``
(the stream decoder), ``fragment`` and ``links`` (the two framings); the per-frame fast paths
are described in :mod:`hwbridge.protocols.native._hotpath`.
"""

from __future__ import annotations

from hwbridge.protocols.native._framing.decoder import FrameDecoder
from hwbridge.protocols.native._framing.encoder import encode_datagram, encode_frame
from hwbridge.protocols.native._framing.fragment import Reassembler, ReassemblyStats, fragment
from hwbridge.protocols.native._framing.frames import (
    ACK_FLAG,
    CRC_INIT,
    CRC_SIZE,
    DEFAULT_MAX_PAYLOAD,
    DELIMITER,
    HEADER_SIZE,
    LENGTH_PREFIX_SIZE,
    MIN_FRAGMENT_PAYLOAD,
    VERSION,
    BadFrame,
    BadFrameReason,
    Frag,
    Frame,
    FrameEvent,
    FrameType,
    FramingStats,
    NonFrameBytes,
    crc16,
    decode_datagram,
    decode_frame,
    frame_overhead,
    max_run_size,
    wire_size,
)
from hwbridge.protocols.native._framing.links import (
    IDLE_LEAD,
    NativeDatagramFraming,
    NativeFraming,
    NativeStreamFraming,
)
from hwbridge.protocols.native._hotpath import make_frame, slot_setter
from hwbridge.protocols.native.cobs import decode as cobs_decode
from hwbridge.protocols.native.cobs import encode as cobs_encode

__all__ = [
    "ACK_FLAG",
    "CRC_INIT",
    "CRC_SIZE",
    "DEFAULT_MAX_PAYLOAD",
    "DELIMITER",
    "HEADER_SIZE",
    "IDLE_LEAD",
    "LENGTH_PREFIX_SIZE",
    "MIN_FRAGMENT_PAYLOAD",
    "VERSION",
    "BadFrame",
    "BadFrameReason",
    "Frag",
    "Frame",
    "FrameDecoder",
    "FrameEvent",
    "FrameType",
    "FramingStats",
    "NativeDatagramFraming",
    "NativeFraming",
    "NativeStreamFraming",
    "NonFrameBytes",
    "Reassembler",
    "ReassemblyStats",
    "cobs_decode",
    "cobs_encode",
    "crc16",
    "decode_datagram",
    "decode_frame",
    "encode_datagram",
    "encode_frame",
    "fragment",
    "frame_overhead",
    "make_frame",
    "max_run_size",
    "slot_setter",
    "wire_size",
]
