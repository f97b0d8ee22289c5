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

import importlib
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Final, Protocol

from hwbridge.protocols.base import BoardSession
from hwbridge.protocols.errors import HwBridgeError

__all__ = [
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
    ``board_spoke``."""
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


_lock = threading.RLock()
_registered: dict[str, ProtocolSpec | str] = {}
_resolved: dict[str, ProtocolSpec] = {}
_entry_points: dict[str, EntryPoint] | None = None


def register_protocol(spec: ProtocolSpec | str, name: str | None = None) -> None:
    """Make ``spec`` (or ``"module:attr"`` naming one) available under its name."""
    key = name if name is not None else spec.name if isinstance(spec, ProtocolSpec) else None
    if not key:
        raise ValueError("a protocol given as 'module:attr' needs a name")
    with _lock:
        _registered[key] = spec
        _resolved.pop(key, None)


def _load_entry_points(refresh: bool = False) -> dict[str, EntryPoint]:
    global _entry_points  # noqa: PLW0603 - a lazily filled module cache
    with _lock:
        if _entry_points is None or refresh:
            _entry_points = {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}
        return _entry_points


def refresh() -> None:
    """Read the entry points again and forget loaded specs (after ``sys.path`` changed)."""
    with _lock:
        _resolved.clear()
        _load_entry_points(refresh=True)


def protocol_names() -> list[str]:
    """Every protocol name known now, built-in first."""
    with _lock:
        names = [*BUILTIN_PROTOCOLS, *_registered, *_load_entry_points()]
    return list(dict.fromkeys(names))


def _load(target: ProtocolSpec | str | EntryPoint, name: str) -> ProtocolSpec:
    if isinstance(target, ProtocolSpec):
        return target
    if isinstance(target, EntryPoint):
        loaded = target.load()
    else:
        module, _, attr = target.partition(":")
        loaded = getattr(importlib.import_module(module), attr)
    if not isinstance(loaded, ProtocolSpec):
        raise UnknownProtocolError(
            f"protocol {name!r} is registered as {target!r}, which is not a ProtocolSpec"
        )
    return loaded


def get_protocol(name: str) -> ProtocolSpec:
    """The spec registered as ``name``; :class:`UnknownProtocolError` listing the known ones."""
    with _lock:
        found = _resolved.get(name)
        if found is not None:
            return found
        target: ProtocolSpec | str | EntryPoint | None = _registered.get(name)
        if target is None:
            target = BUILTIN_PROTOCOLS.get(name)
        if target is None:
            target = _load_entry_points().get(name) or _load_entry_points(refresh=True).get(name)
        if target is None:
            known = ", ".join(["auto", *protocol_names()])
            raise UnknownProtocolError(f"unknown protocol {name!r}; use one of {known}")
        spec = _load(target, name)
        _resolved[name] = spec
        return spec
