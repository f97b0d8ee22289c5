"""What is alive on the graph, kept up to date, for tools that wait for something to appear.

:meth:`Graph.snapshot` answers "what is alive now"; a tool that must wait for a publisher (a
bridge that started a moment ago announces its boards' topics as they connect) watches instead::

    live = LiveGraph(graph)
    if live.wait(lambda: "/diffbot/odom" in live.published(), timeout=2.0):
        ...

:func:`close_names` gives the did-you-mean suggestions of the CLI's errors.
"""

from __future__ import annotations

import difflib
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable

from hwbridge.graph.core import ANY_TYPE, Graph
from hwbridge.graph.snapshot import GraphEntity

__all__ = ["LiveGraph", "close_names", "did_you_mean"]


class LiveGraph:
    """The entities alive on a graph, from a liveliness watch (history included) that lives as
    long as the graph. Entities of this graph's own session are left out: a tool's own
    subscriber is not an answer to "does anybody publish this?"."""

    def __init__(self, graph: Graph) -> None:
        self._own = graph.zid
        self._alive: Counter[GraphEntity] = Counter()
        self._changed = threading.Condition()
        graph.watch(self._on_change)

    def _on_change(self, entity: GraphEntity, alive: bool) -> None:
        if entity.session == self._own:
            return
        with self._changed:
            if alive:
                self._alive[entity] += 1
            elif self._alive[entity] > 1:
                self._alive[entity] -= 1
            else:
                self._alive.pop(entity, None)
            self._changed.notify_all()

    def entities(self, kind: str | None = None) -> list[GraphEntity]:
        """Entities alive now (of ``kind``: ``pub``, ``sub``, ``srv``, ``node``, ``board``)."""
        with self._changed:
            return [e for e in self._alive if kind is None or e.kind == kind]

    def published(self) -> set[str]:
        """Names of topics something publishes now."""
        return {e.name for e in self.entities("pub")}

    def topics(self) -> set[str]:
        """Names of topics something publishes or subscribes now."""
        return {e.name for e in self.entities() if e.kind in ("pub", "sub")}

    def users(self, topic: str) -> list[GraphEntity]:
        """Publishers and subscribers of ``topic`` that declare a type (not ``ANY_TYPE``)."""
        return [
            e
            for e in self.entities()
            if e.kind in ("pub", "sub") and e.name == topic and e.type != ANY_TYPE
        ]

    def wait(self, condition: Callable[[], bool], timeout: float | None) -> bool:
        """Wait until ``condition()`` holds (checked at each discovery change, and at least
        every 0.1 s so Ctrl-C is felt); False if ``timeout`` seconds pass first. ``None``
        waits for ever."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._changed:
            while True:
                if condition():
                    return True
                left = 0.1 if deadline is None else min(0.1, deadline - time.monotonic())
                if left <= 0:
                    return False
                self._changed.wait(left)


def close_names(name: str, known: Iterable[str], limit: int = 3) -> list[str]:
    """Names in ``known`` close to ``name``, closest first: in the same namespace, a last
    segment spelt alike (``/diffbot/odom`` for ``/diffbot/odm``); elsewhere, the same last
    segment (``/diffbot/odom`` for ``/odom``) or a whole name spelt alike."""
    parent, _, last = name.rstrip("/").rpartition("/")
    scored: list[tuple[float, str]] = []
    for candidate in set(known) - {name}:
        other_parent, _, other_last = candidate.rpartition("/")
        if other_last == last:
            score = 1.0
        elif other_parent == parent:
            score = difflib.SequenceMatcher(None, last, other_last).ratio()
            score = score if score >= 0.6 else 0.0
        else:
            score = difflib.SequenceMatcher(None, name, candidate).ratio()
            score = score if score >= 0.8 else 0.0
        if score > 0:
            scored.append((-score, candidate))
    return [candidate for _score, candidate in sorted(scored)[:limit]]


def did_you_mean(name: str, known: Iterable[str]) -> str:
    """``"; did you mean /a, /b?"`` for the names close to ``name``, or ``""``."""
    found = close_names(name, known)
    return f"; did you mean {', '.join(found)}?" if found else ""
