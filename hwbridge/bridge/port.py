"""What a session adapter may use of the board it serves: a :class:`BoardPort`.

The adapter (:mod:`hwbridge.bridge.adapter`) mirrors one session of a board onto the graph. It
never sees the :class:`~hwbridge.bridge.board.BoardConnection` that owns it, only this port,
which the connection builds for each session: the board's name, logger, node and service
timeout, a way to call into the session under its pump's lock, the board's name resolution, its
state, and the bridge's parameters. The port also owns the session's parameter listeners: the
connection closes the port when the session ends, however it ends, and that removes them.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

from hwbridge.graph import Node
from hwbridge.protocols.base import BoardSession, FirmwareIdentity

__all__ = ["BoardPort", "ParamListener", "SessionCall", "SetState"]

T = TypeVar("T")

ParamListener = Callable[[str, Any], None]
"""``listener(name, value)``: a parameter changed (``value`` None: it was deleted)."""


class SessionCall(Protocol):
    """Runs ``action(session)`` under the session's pump lock, dispatches the events it returns
    and writes the bytes it produced; its result. HwBridgeError when the session is not (or no
    longer) the board's live one."""

    def __call__(self, action: Callable[[BoardSession], T], /) -> T: ...


class SetState(Protocol):
    """Sets the board's state as ``hwbridge board info`` shows it (and the details with it)."""

    def __call__(self, state: str, **detail: Any) -> None: ...


def _ignore_firmware(identity: FirmwareIdentity | None) -> None:
    """A port that checks no firmware (a test's)."""


@dataclass(eq=False)
class BoardPort:
    """The board as one session's adapter sees it (one port per session).

    ``on_param_update(listener)`` registers a parameter listener and returns what removes it
    (:meth:`hwbridge.graph.ParamServer.on_update`); the adapter does not call it, but
    :meth:`listen_params`, so that :meth:`close` removes every listener of the session.
    """

    name: str
    log: logging.Logger
    node: Node
    service_timeout: float
    call: SessionCall
    resolve: Callable[[str], str]
    """A name the board uses (topic, service, parameter) in the board's namespace."""
    set_state: SetState
    get_param: Callable[[str], Any]
    """A parameter's value (ParamError if missing)."""
    on_param_update: Callable[[ParamListener], Callable[[], None]]
    on_firmware: Callable[[FirmwareIdentity | None], None] = _ignore_firmware
    """The session connected with this firmware identity (None: its protocol does not say);
    the board's connection checks it (:class:`hwbridge.bridge.identity.FirmwareCheck`)."""
    _removers: list[Callable[[], None]] = field(default_factory=list, init=False, repr=False)
    _closed: bool = field(default=False, init=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, init=False, repr=False)

    @property
    def closed(self) -> bool:
        """True once the session ended (:meth:`close`)."""
        return self._closed

    @property
    def listeners(self) -> int:
        """Parameter listeners registered through this port and not removed yet."""
        with self._lock:
            return len(self._removers)

    def listen_params(self, listener: ParamListener) -> None:
        """Call ``listener(name, value)`` on every parameter change until the session ends
        (:meth:`close`); nothing once it has ended, not even for a change announced just before
        (the parameter server calls its listeners outside its lock). A closed port registers
        nothing."""

        def guarded(name: str, value: Any) -> None:
            if not self._closed:
                listener(name, value)

        with self._lock:
            if not self._closed:
                self._removers.append(self.on_param_update(guarded))

    def close(self) -> None:
        """End the session's ties to the bridge: remove its parameter listeners (idempotent)."""
        with self._lock:
            self._closed = True
            removers, self._removers = self._removers, []
        for remove in removers:
            remove()
