"""Tell which protocol a board speaks on a stream link from the first bytes it sends (sans-I/O).

Each registered protocol that can be recognised gives a detector (:class:`~hwbridge.protocols.
registry.ProtocolSpec` ``detector``) that looks for *evidence*: bytes that only that protocol
produces, such as a native frame whose CRC-16 checks or a rosserial v2 frame with both checksums
right. The first evidence in stream order wins. Anything else (bootloader noise, debug text,
truncated frames) is not evidence, so leading garbage only delays the answer.

Detection is for stream links only: a datagram link (CAN, UDP) carries one protocol that the
board's configuration names, and nothing is written to probe it.

Memory is bounded by the detectors (each keeps at most one frame); the bytes themselves are kept
by the caller, who decides how many to hold (see ``hwbridge.bridge.board``).
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Iterable

from hwbridge.protocols.errors import HwBridgeError
from hwbridge.protocols.registry import Detector, ProtocolSpec, get_protocol, protocol_names

__all__ = ["ProtocolDetector", "detect_protocol", "detectable_protocols"]

_log = logging.getLogger("hwbridge.protocols")


def detectable_protocols() -> list[ProtocolSpec]:
    """The registered protocols that can be recognised in a stream, in registry order (one that
    fails to load is logged and left out: the others still work)."""
    specs: list[ProtocolSpec] = []
    for name in protocol_names():
        try:
            spec = get_protocol(name)
        except (HwBridgeError, ImportError, AttributeError) as exc:
            _log.error("protocol %s cannot be loaded, so it is not detected: %s", name, exc)
            continue
        if spec.stream and spec.detector is not None:
            specs.append(spec)
    return specs


class ProtocolDetector:
    """Incremental detector: :meth:`feed` chunks until it returns a protocol's name.

    Bytes fed after a decision are ignored and the decision stays. When several protocols find
    evidence in one chunk, the chunk is replayed byte by byte (on copies of the detectors taken
    before it) to see whose evidence came first.
    """

    __slots__ = ("_detectors", "result")

    def __init__(self, specs: Iterable[ProtocolSpec] | None = None) -> None:
        chosen = specs if specs is not None else detectable_protocols()
        self._detectors: list[tuple[str, Detector]] = [
            (spec.name, spec.detector()) for spec in chosen if spec.detector is not None
        ]
        self.result: str | None = None
        """The decision, once made."""

    def feed(self, data: bytes | bytearray | memoryview) -> str | None:
        """Consume ``data``; return the protocol's name once there is evidence, else None."""
        if self.result is not None or not data:
            return self.result
        chunk = bytes(data)
        before = copy.deepcopy(self._detectors) if len(self._detectors) > 1 else []
        found = [name for name, detector in self._detectors if detector.feed(chunk)]
        if len(found) == 1:
            self.result = found[0]
        elif found:
            self.result = _first_in(before, chunk)
        return self.result


def _first_in(detectors: list[tuple[str, Detector]], chunk: bytes) -> str:
    """The protocol whose evidence comes first in ``chunk`` (``detectors`` as before it)."""
    for i in range(len(chunk)):
        byte = chunk[i : i + 1]
        for name, detector in detectors:
            if detector.feed(byte):
                return name
    return detectors[0][0]  # unreachable: the whole chunk gave evidence above


def detect_protocol(data: bytes | bytearray | memoryview) -> str | None:
    """The protocol of a board whose first bytes are ``data``; None if there is no evidence yet."""
    return ProtocolDetector().feed(data)
