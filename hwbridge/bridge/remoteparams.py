"""Parameters a bridge reads from another process's server (a shard of ``hwbridge up``).

A bridge normally hosts the graph's parameter server (:class:`~hwbridge.graph.ParamServer`) and
its boards read from it directly. When ``hwbridge up`` shares a robot's boards out over several
bridge processes, only the parent hosts the server; each shard's boards read through
:class:`RemoteParams`, which asks that server over the graph and hears its changes on the
``param_update`` topic, with the same two calls a board uses of a local server.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from hwbridge.errors import HwBridgeTimeoutError
from hwbridge.graph.params import ParamClient, ParamError, ParamHost, UpdateListeners

__all__ = ["ParamSource", "RemoteParams"]


class ParamSource(Protocol):
    """What a bridge's boards use of a parameter server: a value (ParamError if missing) and
    the changes while a session lives."""

    def get(self, name: str) -> Any: ...

    def on_update(self, callback: Callable[[str, Any], None]) -> Callable[[], None]: ...


class RemoteParams:
    """The graph's parameter server, seen from a process that does not host it."""

    def __init__(self, graph: ParamHost, timeout: float = 5.0) -> None:
        self._client = ParamClient(graph, timeout)
        self._listeners = UpdateListeners()
        self._client.on_update(self._listeners.call)  # one subscription for every board

    def get(self, name: str) -> Any:
        """The value at ``name``; ParamError when it is missing or no server answers."""
        try:
            return self._client.get(name)
        except HwBridgeTimeoutError as exc:
            raise ParamError(f"parameter {name}: {exc}") from exc

    def on_update(self, callback: Callable[[str, Any], None]) -> Callable[[], None]:
        """Call ``callback(name, value)`` on every change, until the returned function runs."""
        return self._listeners.add(callback)

    @property
    def listener_count(self) -> int:
        return self._listeners.count
