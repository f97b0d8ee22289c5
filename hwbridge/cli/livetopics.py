"""Name arguments of ``hwbridge topic ...``, ``service ...``, ``param ...``, ``record`` and
``play``: resolved as graph names (:func:`name_argument`). Then topics against the live graph:
waiting for a publisher (with did-you-mean hints when none comes), ``TOPIC/FIELD`` paths, and
``topic pub``'s type (inferred from the graph, or checked against it)."""

from __future__ import annotations

import re
import sys
import time
from typing import Final, Literal

import typer

from hwbridge.errors import HwBridgeError, HwBridgeTimeoutError, MessageTypeError, UnknownTypeError
from hwbridge.graph import Graph, GraphEntity
from hwbridge.graph.discovery import LiveGraph, close_names, did_you_mean
from hwbridge.graph.names import GraphNameError, resolve_name

__all__ = [
    "GRACE",
    "TYPE_NAME",
    "NameKind",
    "await_publisher",
    "check_field",
    "echo_target",
    "live_type",
    "name_argument",
    "no_publisher",
    "note",
    "pub_arguments",
    "published_prefix",
    "refuse_other_type",
    "users_text",
]

GRACE: Final = 2.0
"""Seconds of discovery before a tool says nothing publishes its topic: a bridge that has just
started announces its boards' topics as they connect."""


def note(text: str) -> None:
    """One line on stderr, at once (the user is waiting)."""
    sys.stderr.write(text + "\n")
    sys.stderr.flush()


NameKind = Literal["topic", "service", "parameter"]
"""What a name on the command line names (for the words of its errors)."""


def name_argument(name: str, kind: NameKind = "topic", *, fields: bool = False) -> str:
    """A topic, service or parameter named on the command line, resolved as the graph resolves
    names (:func:`hwbridge.graph.names.resolve_name`; a relative name in the root namespace,
    where these tools' nodes are), before anything waits on it or asks the graph. A name the
    graph refuses is a GraphNameError (status 1) with the rule it breaks; one that ends in '/'
    names the one meant too (``/diffbot/odom/``: ``a topic name does not end with '/'; did you
    mean /diffbot/odom?``). With ``fields`` (``topic echo TOPIC/FIELD...``) the segments are a
    topic and a field path, list indexes among them, so only the start and the end of the name
    are checked here."""
    if name != "/" and name.endswith("/"):
        try:
            meant = f"; did you mean {name_argument(name.rstrip('/'), kind, fields=fields)}?"
        except GraphNameError:
            meant = ""
        raise GraphNameError(f"{name!r}: a {kind} name does not end with '/'{meant}")
    if fields and name.startswith("/"):
        return name
    if fields and name and not name.startswith("~"):
        return "/" + name  # resolved in the root namespace, as resolve_name does
    return resolve_name(name)


def no_publisher(topic: str, live: LiveGraph) -> str:
    return f"no publisher of {topic} yet{did_you_mean(topic, live.published())}"


def await_publisher(live: LiveGraph, topic: str, wait: bool) -> None:
    """Return once something publishes ``topic``. After GRACE seconds without: an error
    naming the close topics that are published, or with ``wait`` that note once and then
    waiting on, silently."""
    if live.wait(lambda: topic in live.published(), GRACE):
        return
    if not wait:
        raise HwBridgeError(f"{no_publisher(topic, live)} (--wait keeps waiting for one)")
    note(f"{no_publisher(topic, live)}; waiting for one (Ctrl-C stops)")
    live.wait(lambda: topic in live.published(), None)


def published_prefix(live: LiveGraph, topic: str) -> tuple[str, list[str]] | None:
    """(topic, field path) if ``topic`` or a name it starts with is published now: the topic
    itself first, then the longest published prefix (the rest is the field path)."""
    published = live.published()
    if topic in published:
        return topic, []
    parts = topic.strip("/").split("/")
    for cut in range(len(parts) - 1, 0, -1):
        prefix = "/" + "/".join(parts[:cut])
        if prefix in published:
            return prefix, parts[cut:]
    return None


def echo_target(
    live: LiveGraph, topic: str, timeout: float | None, wait: bool, started: float
) -> tuple[str, list[str]]:
    """Where ``topic echo TOPIC`` listens, once something publishes it: see
    :func:`published_prefix`. Gives up after GRACE seconds, or ``timeout``, unless ``wait``."""
    found: list[tuple[str, list[str]]] = []

    def published() -> bool:
        target = published_prefix(live, topic)
        if target is not None:
            found.append(target)
        return target is not None

    def left() -> float | None:
        return None if timeout is None else timeout - (time.monotonic() - started)

    first = GRACE if timeout is None else min(GRACE, timeout)
    if live.wait(published, first):
        return found[-1]
    if not wait and timeout is None:
        raise HwBridgeError(f"{no_publisher(topic, live)} (--wait keeps waiting for one)")
    remaining = left()
    if remaining is None or remaining > 0:
        note(f"{no_publisher(topic, live)}; waiting for one (Ctrl-C stops)")
        if live.wait(published, remaining):
            return found[-1]
    raise HwBridgeTimeoutError(
        f"no message on {topic} within {timeout:g} s: {no_publisher(topic, live)}"
    )


def check_field(graph: Graph, live: LiveGraph, topic: str, field: list[str]) -> None:
    """MessageTypeError unless ``field`` is in the type(s) ``topic`` is published with."""
    from hwbridge import msg

    types = sorted({e.type for e in live.users(topic) if e.kind == "pub"})
    if not types:
        raise HwBridgeError(f"cannot select {'/'.join(field)} in {topic}: its type is unknown")
    for type_name in types:
        try:
            msg.check_field_path(type_name, field, graph.registry)
        except UnknownTypeError as exc:
            raise HwBridgeError(
                f"cannot select {'/'.join(field)} in {topic}: {exc} (add its package with "
                "--msg-path)"
            ) from exc
        except MessageTypeError as exc:
            raise MessageTypeError(f"{topic}: {exc}") from exc


TYPE_NAME: Final = re.compile(r"[A-Za-z][A-Za-z0-9_]*/[A-Za-z][A-Za-z0-9_]*")
"""A message type name as ``topic pub`` tells it from a YAML value: ``pkg/Type``."""


def pub_arguments(first: str | None, second: str | None) -> tuple[str | None, str | None]:
    """(type, values) from ``topic pub``'s arguments after the topic: ``TYPE [YAML]`` or
    ``YAML``. A type reads ``pkg/Type``; a message's YAML never does (it is a mapping)."""
    if second is not None:
        if first is None or not TYPE_NAME.fullmatch(first):
            raise typer.BadParameter(
                f"expected a message type (pkg/Type) before the values, got {first!r}",
                param_hint="TYPE",
            )
        return first, second
    if first is not None and TYPE_NAME.fullmatch(first.strip()):
        return first.strip(), None
    return None, first


def users_text(users: list[GraphEntity]) -> str:
    """``published by /a; subscribed by /b, /c`` for the nodes in ``users``."""
    parts = []
    for kind, verb in (("pub", "published"), ("sub", "subscribed")):
        nodes = sorted({e.node for e in users if e.kind == kind})
        if nodes:
            parts.append(f"{verb} by {', '.join(nodes)}")
    return "; ".join(parts)


def live_type(live: LiveGraph, topic: str) -> str:
    """The type ``topic`` has on the graph (waiting up to GRACE seconds for it to appear)."""
    live.wait(lambda: bool(live.users(topic)), GRACE)
    users = live.users(topic)
    types = sorted({e.type for e in users})
    if not types:
        close = close_names(topic, live.topics())
        hint = f" (did you mean {', '.join(close)}?)" if close else ""
        raise HwBridgeError(
            f"cannot tell the type of {topic}: nothing on the graph publishes or subscribes "
            f"it{hint}; give the type: hwbridge topic pub {topic} pkg/Type '{{...}}'"
        )
    if len(types) > 1:
        raise HwBridgeError(
            f"{topic} has several types on the graph ({users_text(users)}: "
            f"{', '.join(types)}): give the one to publish"
        )
    return types[0]


def refuse_other_type(topic: str, type_name: str, users: list[GraphEntity]) -> None:
    """HwBridgeError if ``topic`` is on the graph with a type other than ``type_name``."""
    others = [e for e in users if e.type != type_name]
    if not others:
        return
    types = ", ".join(sorted({e.type for e in others}))
    raise HwBridgeError(f"{topic} is {types} on the graph ({users_text(others)}), not {type_name}")
