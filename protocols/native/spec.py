"""The native protocol as the runtime starts it: :data:`PROTOCOL` (see ``protocols.registry``).

``new_session`` builds a :class:`HostSession` with the framing of the link's kind, host time for
time sync, and a type check against the host's message registry; :class:`NativeDetector`
recognises native frames in a board's first bytes on a stream link.
"""

from __future__ import annotations

import logging
from typing import Any

from hwbridge.protocols.calling import CALL_BURST
from hwbridge.protocols.errors import HwBridgeError
from hwbridge.protocols.native.framing import (
    BadFrame,
    BadFrameReason,
    Frame,
    FrameDecoder,
    NativeDatagramFraming,
    NativeStreamFraming,
)
from hwbridge.protocols.native.session import ExpectedType, HostConfig, HostSession, TopicEntry
from hwbridge.protocols.registry import ProtocolSpec, SessionContext

__all__ = ["PROTOCOL", "NativeDetector", "RegistryTypeCheck", "new_session"]

log = logging.getLogger("hwbridge.protocols.native")

_CRC_VALID = frozenset({BadFrameReason.VERSION, BadFrameReason.RESERVED_TYPE})
"""Rejections of frames whose CRC was valid: evidence of native all the same."""


class RegistryTypeCheck:
    """The host's :data:`~hwbridge.protocols.native.session.TypeCheck`: the md5 the message
    registry has for an announced entry's type. A type the registry does not know is accepted
    as announced (its bytes pass through; nothing on the host can decode them), with one
    warning per type."""

    def __init__(self, registry: Any) -> None:
        self.registry = registry
        self._warned: set[str] = set()

    def __call__(self, entry: TopicEntry) -> ExpectedType | None:
        try:
            if entry.is_service:
                md5 = self.registry.service(entry.type_name).md5
            else:
                md5 = self.registry.message(entry.type_name).md5
        except HwBridgeError:
            if entry.type_name not in self._warned:
                self._warned.add(entry.type_name)
                log.warning(
                    "%s has type %s, unknown here: bytes are forwarded, nothing can decode them "
                    "(add its .msg with --msg-path)",
                    entry.name,
                    entry.type_name,
                )
            return None
        return ExpectedType(entry.type_name, str(md5))


def new_session(ctx: SessionContext) -> HostSession:
    """A host session for one board: stream or datagram framing per ``ctx.datagram``; the
    first HELLO waits in ``chunks_to_send()`` at once, but with a ``start_delay`` (a board whose
    bootloader takes bytes as an upload) the host listens first: it answers the board's HELLOs
    and calls none to a board it does not hear. On a stream link it calls a silent board in
    bursts with pauses (:mod:`hwbridge.protocols.calling`), so that a Mega's bootloader that took
    a HELLO goes on to the sketch in a pause."""
    framing = NativeDatagramFraming() if ctx.datagram else NativeStreamFraming()
    return HostSession(
        HostConfig(
            epoch_offset=ctx.wall_offset,
            listen_first=ctx.start_delay > 0,
            call_burst=0.0 if ctx.datagram else CALL_BURST,
        ),
        type_check=RegistryTypeCheck(ctx.registry),
        framing=framing,
        now=ctx.now,
    )


class NativeDetector:
    """True once a CRC-valid native frame was seen in a stream (a frame of another version or
    of the reserved type counts too: its CRC is valid). Memory: one frame's worth of bytes."""

    __slots__ = ("_decoder", "found")

    def __init__(self) -> None:
        self._decoder = FrameDecoder()
        self.found = False

    def feed(self, data: bytes, /) -> bool:
        if self.found or not data:
            return self.found
        for event in self._decoder.feed(data):
            if isinstance(event, Frame) or (
                isinstance(event, BadFrame) and event.reason in _CRC_VALID
            ):
                self.found = True
                break
        return self.found


PROTOCOL = ProtocolSpec(
    name="native",
    summary="hwbridge's own protocol: COBS frames with CRC-16, reliable and best-effort streams",
    new_session=new_session,
    stream=True,
    datagram=True,
    detector=NativeDetector,
    probe=b"",
    session_per_peer=False,
)
