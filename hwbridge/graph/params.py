"""Parameters: a server (hosted by the bridge) and a client any process can use.

Values are what YAML and JSON hold: bool, int, float, str, lists of them, and dicts. Names are
graph names (``/diffbot/wheel_radius``); a dict set at a name sets every leaf under it, and getting
a namespace returns the dict of what is below it, as ``rosparam`` does.

Wire: one Zenoh queryable at ``hwbridge/<domain>/param`` taking JSON requests
``{"op": "get"|"set"|"delete"|"list", "name": ..., "value": ...}`` and answering JSON; every
change is published as ``{"name", "value"}`` (``value`` null when deleted) on
``hwbridge/<domain>/param_update``.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from hwbridge.errors import HwBridgeError, HwBridgeTimeoutError
from hwbridge.graph.guard import call_guarded
from hwbridge.graph.names import resolve_name

if TYPE_CHECKING:
    import zenoh

__all__ = ["ParamClient", "ParamError", "ParamHost", "ParamServer", "UpdateListeners", "flatten"]


class ParamHost(Protocol):
    """What parameters need of a graph; :class:`hwbridge.graph.Graph` is one.

    (A protocol rather than the Graph class itself, so that this module does not import
    :mod:`hwbridge.graph.core`, which imports this one for ``Graph.params``.)
    """

    @property
    def prefix(self) -> str: ...

    @property
    def session(self) -> zenoh.Session: ...

    def keep(self, declaration: Any) -> Any: ...

    def announce(self, kind: str, node: str, name: str = "", type_name: str = "") -> Any: ...


class ParamError(HwBridgeError, KeyError):
    """A parameter does not exist, or a request to the parameter server failed."""

    def __str__(self) -> str:
        return str(self.args[0])


def flatten(name: str, value: Any) -> dict[str, Any]:
    """``("/a", {"b": 1, "c": {"d": 2}})`` -> ``{"/a/b": 1, "/a/c/d": 2}``."""
    if isinstance(value, dict) and value:
        out: dict[str, Any] = {}
        for key, sub in value.items():
            out.update(flatten(resolve_name(str(key), name), sub))
        return out
    _check_value(name, value)
    return {name: value}


def _check_value(name: str, value: Any) -> None:
    if isinstance(value, (bool, int, float, str)) or value == {}:
        return
    if isinstance(value, list):
        for index, item in enumerate(value):
            _check_value(f"{name}[{index}]", item)
        return
    raise ParamError(f"parameter {name}: {value!r} is not a bool, int, float, str, list or dict")


class UpdateListeners:
    """The callbacks that hear parameter changes, each until the function :meth:`add` returned
    is called; an exception in one is logged and the others still hear the change."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._callbacks: list[Callable[[str, Any], None]] = []

    def add(self, callback: Callable[[str, Any], None]) -> Callable[[], None]:
        with self._lock:
            self._callbacks.append(callback)

        def remove() -> None:
            with self._lock:
                if callback in self._callbacks:
                    self._callbacks.remove(callback)

        return remove

    @property
    def count(self) -> int:
        with self._lock:
            return len(self._callbacks)

    def call(self, name: str, value: Any) -> None:
        with self._lock:
            callbacks = list(self._callbacks)
        for callback in callbacks:
            call_guarded(callback, name, value)


class ParamServer:
    """Holds parameters for the graph. One per graph (the bridge starts it)."""

    def __init__(self, graph: ParamHost, initial: dict[str, Any] | None = None) -> None:
        self.graph = graph
        self._values: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._listeners = UpdateListeners()
        self._update_pub = graph.keep(
            graph.session.declare_publisher(f"{graph.prefix}/param_update")
        )
        self._queryable = graph.keep(
            graph.session.declare_queryable(f"{graph.prefix}/param", self._on_query)
        )
        self._token = graph.announce("param_server", "/hwbridge_params")
        for name, value in (initial or {}).items():
            self.set(name, value)

    # local API (the bridge uses it directly)
    def get(self, name: str) -> Any:
        name = resolve_name(name)
        with self._lock:
            if name in self._values:
                return self._values[name]
            prefix = "/" if name == "/" else name + "/"
            below = {k: v for k, v in self._values.items() if k.startswith(prefix)}
        if not below:
            raise ParamError(f"no parameter {name}")
        return _nest(prefix, below)

    def set(self, name: str, value: Any) -> None:
        name = resolve_name(name)
        leaves = flatten(name, value)
        with self._lock:
            prefix = name + "/"
            for old in [k for k in self._values if k == name or k.startswith(prefix)]:
                del self._values[old]
            self._values.update(leaves)
        for leaf, leaf_value in leaves.items():
            self._announce(leaf, leaf_value)

    def delete(self, name: str) -> None:
        name = resolve_name(name)
        with self._lock:
            prefix = name + "/"
            gone = [k for k in self._values if k == name or k.startswith(prefix)]
            for key in gone:
                del self._values[key]
        if not gone:
            raise ParamError(f"no parameter {name}")
        for key in gone:
            self._announce(key, None)

    def names(self) -> list[str]:
        with self._lock:
            return sorted(self._values)

    def on_update(self, callback: Callable[[str, Any], None]) -> Callable[[], None]:
        """Call ``callback(name, value)`` on every change made through this server, until the
        returned function is called (each board session's adapter listens while it lives)."""
        return self._listeners.add(callback)

    @property
    def listener_count(self) -> int:
        """How many :meth:`on_update` callbacks are registered (flat across board resets)."""
        return self._listeners.count

    def _announce(self, name: str, value: Any) -> None:
        self._update_pub.put(json.dumps({"name": name, "value": value}).encode())
        self._listeners.call(name, value)

    def _on_query(self, query: zenoh.Query) -> None:
        try:
            request = json.loads(bytes(query.payload.to_bytes())) if query.payload else {}
            op = request.get("op")
            name = request.get("name", "/")
            result: Any
            if op == "get":
                result = self.get(name)
            elif op == "set":
                self.set(name, request.get("value"))
                result = True
            elif op == "delete":
                self.delete(name)
                result = True
            elif op == "list":
                result = self.names()
            else:
                raise ParamError(f"unknown parameter request {op!r}")
        except (HwBridgeError, ValueError) as exc:
            query.reply_err(str(exc))
            return
        query.reply(query.key_expr, json.dumps(result).encode())


def _nest(prefix: str, flat: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in sorted(flat.items()):
        parts = key[len(prefix) :].split("/")
        here = out
        for part in parts[:-1]:
            here = here.setdefault(part, {})
        here[parts[-1]] = value
    return out


class ParamClient:
    """Talks to the graph's parameter server from any process."""

    def __init__(self, graph: ParamHost, timeout: float = 2.0) -> None:
        self.graph = graph
        self.timeout = timeout

    def _request(self, **request: Any) -> Any:
        replies = self.graph.session.get(
            f"{self.graph.prefix}/param",
            payload=json.dumps(request).encode(),
            timeout=self.timeout,
        )
        for reply in replies:
            if reply.ok is not None:
                return json.loads(bytes(reply.ok.payload.to_bytes()))
            if reply.err is not None:
                raise ParamError(reply.err.payload.to_string())
        raise HwBridgeTimeoutError(
            f"no parameter server answered within {self.timeout:g} s (is a bridge running?)"
        )

    def get(self, name: str, default: Any = ...) -> Any:
        """Value at ``name`` (a dict for a namespace); ``default`` if given and it is missing."""
        try:
            return self._request(op="get", name=resolve_name(name))
        except ParamError:
            if default is ...:
                raise
            return default

    def set(self, name: str, value: Any) -> None:
        name = resolve_name(name)
        flatten(name, value)  # refuse bad values here, with the caller's names
        self._request(op="set", name=name, value=value)

    def delete(self, name: str) -> None:
        self._request(op="delete", name=resolve_name(name))

    def names(self) -> list[str]:
        result: list[str] = self._request(op="list")
        return result

    def on_update(self, callback: Callable[[str, Any], None]) -> Any:
        """Call ``callback(name, value)`` on every change (``value`` None when deleted)."""

        def on_sample(sample: zenoh.Sample) -> None:
            change = json.loads(bytes(sample.payload.to_bytes()))
            call_guarded(callback, change["name"], change["value"])

        return self.graph.keep(
            self.graph.session.declare_subscriber(f"{self.graph.prefix}/param_update", on_sample)
        )
