"""One registry of named plugins, used for protocols, device types and link URL schemes.

Names come from three places, first match wins: :meth:`NamedRegistry.register` calls, a
built-in table of ``"module:attr"`` strings imported on first use, and an entry-point group of
the installed distributions, read lazily and read again when a name is not found (a plugin
installed while the program runs is seen). What a name resolves to is checked and kept.

The built-in table is the only place a built-in is declared: hwbridge's own ``pyproject.toml``
declares none of them as an entry point (a test checks it); the entry points are for other
packages' plugins (``mavlink_vehicle`` is one: it needs pymavlink, an optional extra).
"""

from __future__ import annotations

import importlib
import logging
import threading
from collections.abc import Callable, Mapping
from importlib.metadata import EntryPoint, entry_points
from typing import Generic, TypeVar

from hwbridge.protocols.errors import HwBridgeError

__all__ = ["NamedRegistry"]

T = TypeVar("T")

log = logging.getLogger("hwbridge.plugins")


class NamedRegistry(Generic[T]):
    """Plugins of one kind by name. ``make(loaded, name)`` turns what a name's target loads into
    the plugin (checking its kind; raising ``unknown`` when it is not one); ``unknown`` is the
    error class for names that resolve to nothing or whose target fails to import.
    ``fold_case`` makes names case-insensitive (entry-point names are lowered; callers give
    lower-case names)."""

    def __init__(
        self,
        what: str,
        group: str,
        builtin: Mapping[str, str],
        make: Callable[[object, str], T],
        unknown: type[HwBridgeError],
        *,
        fold_case: bool = False,
    ) -> None:
        self.what = what
        self.group = group
        self.builtin = builtin
        self._make = make
        self._unknown = unknown
        self._fold_case = fold_case
        self._lock = threading.RLock()  # reentrant: a plugin may register others as it loads
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
                self._entry_points = self._read_entry_points()
            return self._entry_points

    def _read_entry_points(self) -> dict[str, EntryPoint]:
        found: dict[str, EntryPoint] = {}
        for ep in entry_points(group=self.group):
            name = ep.name.strip().lower() if self._fold_case else ep.name.strip()
            if name in found and found[name].value != ep.value:
                log.warning(
                    "%s %r is declared twice (%s and %s); using the first",
                    self.what,
                    name,
                    found[name].value,
                    ep.value,
                )
            elif name in self.builtin and ep.value != self.builtin[name]:
                log.warning(
                    "entry point %s = %s cannot replace the built-in %s; ignored",
                    name,
                    ep.value,
                    self.what,
                )
            found.setdefault(name, ep)
        return found

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

    def sources(self) -> dict[str, str]:
        """Every name known now and what it resolves from (``"module:attr"``), built-in first."""
        with self._lock:
            table = {name: ep.value for name, ep in self._plugins().items()}
            table.update(self.builtin)
            table.update({name: _describe(target) for name, target in self._registered.items()})
        return {name: table[name] for name in self.names()}

    def get(self, name: str, choices: str = "") -> T:
        """The plugin called ``name``; ``unknown`` listing the known names (after ``choices``,
        extra names to offer, such as ``auto``)."""
        found = self.find(name)
        if found is None:
            known = ", ".join(filter(None, [choices, *self.names()]))
            raise self._unknown(f"unknown {self.what} {name!r}; use one of {known}")
        return found

    def find(self, name: str, *, reread: bool = True) -> T | None:
        """The plugin called ``name``, or None when no source has it (the entry points read
        again first, unless ``reread`` is False)."""
        with self._lock:
            found = self._resolved.get(name)
            if found is not None:
                return found
            target: object = self._registered.get(name) or self.builtin.get(name)
            if target is None:
                target = self._plugins().get(name)
                if target is None and reread:
                    target = self._plugins(refresh=True).get(name)
            if target is None:
                return None
            plugin = self._make(self._load(name, target), name)
            self._resolved[name] = plugin
            return plugin

    def _load(self, name: str, target: object) -> object:
        if not isinstance(target, (str, EntryPoint)):
            return target
        where = target if isinstance(target, str) else f"{target.value} (entry point)"
        try:
            if isinstance(target, EntryPoint):
                return target.load()
            module, _, attr = target.partition(":")
            loaded: object = importlib.import_module(module)
            for part in attr.split("."):
                loaded = getattr(loaded, part)
        except (ImportError, AttributeError) as exc:
            raise self._unknown(
                f"the {self.what} {name!r} is provided by {where}, which failed to load: {exc}; "
                "reinstall the package that provides it"
            ) from exc
        return loaded


def _describe(target: object) -> str:
    """``"module:attr"`` for what :meth:`NamedRegistry.register` was given."""
    if isinstance(target, str):
        return target
    module = getattr(target, "__module__", "?")
    name = getattr(target, "__qualname__", type(target).__name__)
    return f"{module}:{name}"
