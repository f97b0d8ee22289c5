"""One registry of named plugins, used for protocols and device types (link schemes keep their
own, which also resolves ``A+B`` wrapper schemes).

Names come from three places, first match wins: :meth:`NamedRegistry.register` calls, a
built-in table of ``"module:attr"`` strings imported on first use, and an entry-point group of
the installed distributions, read lazily and read again when a name is not found (a plugin
installed while the program runs is seen). What a name resolves to is checked and kept.
"""

from __future__ import annotations

import importlib
import threading
from collections.abc import Callable, Mapping
from importlib.metadata import EntryPoint, entry_points
from typing import Generic, TypeVar

from hwbridge.protocols.errors import HwBridgeError

__all__ = ["NamedRegistry"]

T = TypeVar("T")


class NamedRegistry(Generic[T]):
    """Plugins of one kind by name. ``make(loaded, name)`` turns what a name's target loads into
    the plugin (checking its kind; raising ``unknown`` when it is not one); ``unknown`` is the
    error class for names that resolve to nothing."""

    def __init__(
        self,
        what: str,
        group: str,
        builtin: Mapping[str, str],
        make: Callable[[object, str], T],
        unknown: type[HwBridgeError],
    ) -> None:
        self.what = what
        self.group = group
        self.builtin = builtin
        self._make = make
        self._unknown = unknown
        self._lock = threading.RLock()
        self._registered: dict[str, object] = {}
        self._resolved: dict[str, T] = {}
        self._entry_points: dict[str, EntryPoint] | None = None

    def register(self, name: str, target: object) -> None:
        """Make ``name`` resolve to ``target`` (a plugin, or ``"module:attr"`` naming one)."""
        with self._lock:
            self._registered[name] = target
            self._resolved.pop(name, None)

    def unregister(self, name: str) -> None:
        """Forget what :meth:`register` gave ``name`` (built-ins and entry points stay)."""
        with self._lock:
            self._registered.pop(name, None)
            self._resolved.pop(name, None)

    def _plugins(self, refresh: bool = False) -> dict[str, EntryPoint]:
        with self._lock:
            if self._entry_points is None or refresh:
                self._entry_points = {ep.name: ep for ep in entry_points(group=self.group)}
            return self._entry_points

    def refresh(self) -> None:
        """Read the entry points again and forget what was loaded (after ``sys.path`` changed)."""
        with self._lock:
            self._resolved.clear()
            self._plugins(refresh=True)

    def names(self) -> list[str]:
        """Every name known now, built-in first."""
        with self._lock:
            names = [*self.builtin, *self._registered, *self._plugins()]
        return list(dict.fromkeys(names))

    def get(self, name: str, choices: str = "") -> T:
        """The plugin called ``name``; ``unknown`` listing the known names (after ``choices``,
        extra names to offer, such as ``auto``)."""
        with self._lock:
            found = self._resolved.get(name)
            if found is not None:
                return found
            target: object = self._registered.get(name) or self.builtin.get(name)
            if target is None:
                target = self._plugins().get(name) or self._plugins(refresh=True).get(name)
            if target is None:
                known = ", ".join(filter(None, [choices, *self.names()]))
                raise self._unknown(f"unknown {self.what} {name!r}; use one of {known}")
            if isinstance(target, EntryPoint):
                target = target.load()
            elif isinstance(target, str):
                module, _, attr = target.partition(":")
                target = getattr(importlib.import_module(module), attr)
            plugin = self._make(target, name)
            self._resolved[name] = plugin
            return plugin
