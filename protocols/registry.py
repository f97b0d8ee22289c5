"""The protocol registry: which protocols a board may speak, and how to start each one.

Like the link registry (``hwbridge.links``), one table filled from three places, first match
wins: :func:`register_protocol` calls, the built-in table (``"module:attr"`` strings imported on
first use), and the ``hwbridge.protocols`` entry-point group of installed distributions, read
lazily and read again when a name is not found. An entry point names a :class:`ProtocolSpec`.

A spec says everything the runtime needs, so the bridge never branches on a protocol's name:
how to build a host session (with the framing for the link's kind), whether the protocol can run
on stream and on datagram links, how to recognise it in a stream (detection) and what to write to
a silent stream board to make it speak (the probe).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Final, Protocol

from hwbridge.protocols.base import BoardSession
from hwbridge.protocols.calling import BOOTLOADER_QUIET
from hwbridge.protocols.errors import HwBridgeError
from hwbridge.protocols.plugins import NamedRegistry

__all__ = [
    "BOOTLOADER_QUIET",
    "BUILTIN_PROTOCOLS",
    "ENTRY_POINT_GROUP",
    "Detector",
    "ProtocolSpec",
    "SessionContext",
    "UnknownProtocolError",
    "get_protocol",
    "protocol_names",
    "refresh",
    "register_protocol",
]

ENTRY_POINT_GROUP: Final = "hwbridge.protocols"

BUILTIN_PROTOCOLS: Final[dict[str, str]] = {
    "native": "hwbridge.protocols.native.spec:PROTOCOL",
    "rosserial": "hwbridge.protocols.rosserial.spec:PROTOCOL",
}


class UnknownProtocolError(HwBridgeError):
    """No protocol of that name is registered."""


class Detector(Protocol):
    """Looks for evidence of one protocol in a board's first bytes on a stream link."""

    def feed(self, data: bytes, /) -> bool:
        """Consume ``data``; True once the bytes seen so far prove the protocol."""
        ...


@dataclass(frozen=True)
class SessionContext:
    """What a protocol gets to build a host session for one board."""

    registry: Any
    """The message type registry (:class:`hwbridge.protocols.msgtypes.TypeRegistry`)."""
    datagram: bool
    """The link carries datagrams (use the datagram framing) rather than a byte stream."""
    now: float
    """The monotonic clock's time now (seconds)."""
    wall_offset: float
    """Wall-clock time minus monotonic time (for time sync answers), seconds."""
    board_spoke: bool = False
    """The board already sent something (no start-up wait is needed)."""
    start_delay: float = 0.0
    """Seconds the user wants the board left alone after the link opens (a board whose
    bootloader dislikes bytes); a protocol that writes first waits this long, unless
    ``board_spoke``. Above 0 it also says the board resets into such a bootloader (a Mega's
    stk500v2), where every byte keeps it waiting: the session must never keep talking to a board
    that does not answer, or a board reset under it stays in its bootloader for good. A native
    host then listens first (it answers the board's HELLOs and calls none of its own while the
    board is silent); a rosserial host leaves :data:`BOOTLOADER_QUIET` between unanswered
    requests."""
    options: dict[str, Any] = field(default_factory=dict)
    """Protocol options from the board's configuration."""


@dataclass(frozen=True)
class ProtocolSpec:
    """One protocol, as the runtime starts it."""

    name: str
    summary: str
    new_session: Callable[[SessionContext], BoardSession]
    stream: bool = True
    """Runs on stream links (serial, TCP, pty)."""
    datagram: bool = False
    """Runs on datagram links (CAN, UDP, tunnels)."""
    detector: Callable[[], Detector] | None = None
    """Recognises the protocol in a stream (None: only chosen by name)."""
    probe: bytes = b""
    """Written to a silent stream board while detecting (rosserial's "request topics")."""
    session_per_peer: bool = False
    """A listening link (tcp-listen://, pty://) gives each new peer a new session."""


def _spec(loaded: object, name: str) -> ProtocolSpec:
    if not isinstance(loaded, ProtocolSpec):
        raise UnknownProtocolError(
            f"protocol {name!r} is registered as {loaded!r}, which is not a ProtocolSpec"
        )
    return loaded


_REGISTRY: Final = NamedRegistry(
    "protocol", ENTRY_POINT_GROUP, BUILTIN_PROTOCOLS, _spec, UnknownProtocolError
)


def register_protocol(spec: ProtocolSpec | str, name: str | None = None) -> None:
    """Make ``spec`` (or ``"module:attr"`` naming one) available under its name."""
    key = name if name is not None else spec.name if isinstance(spec, ProtocolSpec) else None
    if not key:
        raise ValueError("a protocol given as 'module:attr' needs a name")
    _REGISTRY.register(key, spec)


def refresh() -> None:
    """Read the entry points again and forget loaded specs (after ``sys.path`` changed)."""
    _REGISTRY.refresh()


def protocol_names() -> list[str]:
    """Every protocol name known now, built-in first."""
    return _REGISTRY.names()


def get_protocol(name: str) -> ProtocolSpec:
    """The spec registered as ``name``; :class:`UnknownProtocolError` listing the known ones."""
    return _REGISTRY.get(name, choices="auto")
