"""rosserial protocol v2 as the runtime starts it (:data:`PROTOCOL`, see
:mod:`hwbridge.protocols.registry`)."""

from __future__ import annotations

from typing import Any, Final

from hwbridge.protocols.calling import BOOTLOADER_QUIET, CALL_BURST
from hwbridge.protocols.errors import HwBridgeError
from hwbridge.protocols.registry import ProtocolSpec, SessionContext
from hwbridge.protocols.rosserial.framing import FrameParser, RosFrame
from hwbridge.protocols.rosserial.host import REQUEST_TOPICS, RosserialHost

__all__ = ["OPTIONS", "PROTOCOL", "RosserialDetector", "new_session"]

OPTIONS: Final = frozenset(
    {
        "start_delay",
        "settle_time",
        "sync_timeout",
        "request_retry",
        "request_retry_max",
        "max_payload",
        "fallback_input_buffer",
        "old_protocol_threshold",
        "call_burst",
        "call_pause",
    }
)
"""The board options a rosserial session takes (keyword arguments of :class:`RosserialHost`)."""


class RosserialDetector:
    """True once a rosserial v2 frame with both checksums right was seen (sticky)."""

    __slots__ = ("_parser", "found")

    def __init__(self) -> None:
        self._parser = FrameParser()
        self.found = False

    def feed(self, data: bytes, /) -> bool:
        if not self.found and data:
            self.found = any(isinstance(e, RosFrame) for e in self._parser.feed(data))
        return self.found


def new_session(ctx: SessionContext) -> RosserialHost:
    """A host session for one board (rosserial runs on stream links only)."""
    if ctx.datagram:
        raise HwBridgeError(
            "rosserial runs on stream links only (serial, TCP, pty), not on datagram links"
        )
    unknown = sorted(set(ctx.options) - OPTIONS)
    if unknown:
        raise HwBridgeError(
            f"unknown rosserial option(s) {', '.join(unknown)}; known: {', '.join(sorted(OPTIONS))}"
        )
    options: dict[str, Any] = {
        "start_delay": ctx.start_delay,
        "call_burst": CALL_BURST,
        **ctx.options,
    }
    if ctx.start_delay > 0 and not {"request_retry", "request_retry_max"} & ctx.options.keys():
        # A reset board in a bootloader that waits after each byte (a Mega's stk500v2) gets the
        # silence it needs to leave between two unanswered requests.
        options["request_retry"] = options["request_retry_max"] = BOOTLOADER_QUIET
    if ctx.board_spoke:
        options["start_delay"] = 0.0  # it is running: no bootloader to wait for
    return RosserialHost(ctx.registry, now=ctx.now, wall_offset=ctx.wall_offset, **options)


PROTOCOL: Final = ProtocolSpec(
    name="rosserial",
    summary="rosserial protocol v2 (hydro and later): unmodified rosserial_arduino sketches",
    new_session=new_session,
    stream=True,
    datagram=False,
    detector=RosserialDetector,
    probe=REQUEST_TOPICS,
    session_per_peer=True,
)
