"""Tell a native hwbridge board from a rosserial one by the first bytes it sends (sans-I/O).

Evidence, first come first served in stream order:

- ``native``: a run between ``0x00`` delimiters that decodes as a native frame with a valid
  CRC-16 (a frame of another native version or of the reserved type counts too: its CRC is valid);
- ``rosserial``: a rosserial v2 frame with both checksums right.

Anything else (bootloader noise, debug text, truncated frames) is not evidence, so leading
garbage only delays the answer. A false decision needs a random run to pass a CRC-16 (native) or
a ``FF FE`` pair to pass two 8-bit checksums (rosserial).

Firmware speaking rosserial protocol v1 (pre-hydro) is not detected: its ``FF FF`` header is
too common in other data (a native payload of 0xFF bytes) to be evidence, and such a board does
not answer a v2 "request topics" anyway; the rosserial host reports it when it sees it.

Note for callers: a rosserial board says nothing until it hears "request topics"
(:data:`hwbridge.protocols.rosserial.host.REQUEST_TOPICS`), unless it is still configured from an
earlier session. If a board stays silent, send that frame and keep feeding what comes back; a
native decoder sees only invalid runs in those 8 bytes.
"""

from __future__ import annotations

import copy
from typing import Final, Literal, TypeAlias

from hwbridge.protocols.native.framing import BadFrame as NativeBadFrame
from hwbridge.protocols.native.framing import BadFrameReason as NativeReason
from hwbridge.protocols.native.framing import Frame as NativeFrame
from hwbridge.protocols.native.framing import FrameDecoder
from hwbridge.protocols.rosserial.framing import FrameParser, RosFrame

__all__ = ["Protocol", "ProtocolDetector", "detect_protocol"]

Protocol: TypeAlias = Literal["native", "rosserial"]

_NATIVE_CRC_VALID: Final = frozenset({NativeReason.VERSION, NativeReason.RESERVED_TYPE})


class ProtocolDetector:
    """Incremental detector: :meth:`feed` chunks until it returns a protocol.

    Memory is bounded by the two decoders' limits (one frame each); bytes fed after a decision
    are ignored and the decision stays.
    """

    __slots__ = ("_native", "_ros", "result")

    def __init__(self) -> None:
        self._native = FrameDecoder()
        self._ros = FrameParser()
        self.result: Protocol | None = None
        """The decision, once made."""

    def feed(self, data: bytes | bytearray | memoryview) -> Protocol | None:
        """Consume ``data``; return the protocol once there is evidence, else None."""
        if self.result is not None or not data:
            return self.result
        chunk = bytes(data)
        saved = (copy.deepcopy(self._native), copy.deepcopy(self._ros))
        native = self._native_evidence(chunk)
        ros = self._ros_evidence(chunk)
        if native and ros:
            # Both decided inside this chunk: replay it byte by byte to see which came first.
            self._native, self._ros = saved
            for i in range(len(chunk)):
                byte = chunk[i : i + 1]
                if self._native_evidence(byte):
                    self.result = "native"
                    break
                if self._ros_evidence(byte):
                    self.result = "rosserial"
                    break
        elif native:
            self.result = "native"
        elif ros:
            self.result = "rosserial"
        return self.result

    def _native_evidence(self, data: bytes) -> bool:
        for event in self._native.feed(data):
            if isinstance(event, NativeFrame):
                return True
            if isinstance(event, NativeBadFrame) and event.reason in _NATIVE_CRC_VALID:
                return True
        return False

    def _ros_evidence(self, data: bytes) -> bool:
        return any(isinstance(event, RosFrame) for event in self._ros.feed(data))


def detect_protocol(data: bytes | bytearray | memoryview) -> Protocol | None:
    """The protocol of a board whose first bytes are ``data``; None if there is no evidence yet."""
    return ProtocolDetector().feed(data)
