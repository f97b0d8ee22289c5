"""Compiled copies of the modules on a message's path, used only while they match their source.

A service call through the bridge runs a few hundred Python lines between the graph and the
link (the query callback, the pump, the session, framing, the link's read and write), each time
with the process's caches cold: the three processes of a call take turns on the cores. Compiled
with Cython, those lines cost about half as much (issue 29, ``tools/bench/bridge.py``). They stay
plain Python in the tree; a compiled copy is an optimisation that can always be missing:

* ``python -m hwbridge.compiled build`` compiles each module of :data:`MODULES` with Cython (the
  ``fast`` extra) and a C compiler into ``~/.cache/hwbridge/compiled/<Python tag>/<digest>/``,
  the digest being that of the module's source. It says what it does and why it cannot (no
  Cython, no compiler, no Python headers) and exits 1 then; nothing else depends on it.
* :func:`install` (run by ``import hwbridge``) puts a finder first on ``sys.meta_path``. For a
  module of :data:`MODULES` it hashes the source file the normal import would load and loads the
  compiled copy of that digest if there is one, else the source. An edited module runs as edited
  until it is built again: a stale copy is never used.
* ``HWBRIDGE_COMPILED=0`` in the environment turns the finder off; :func:`active` says which
  modules of a process are compiled (the benches print it).

Only this module's standard-library imports run before the finder is in place.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Final

__all__ = [
    "ENV",
    "MODULES",
    "active",
    "available",
    "cache_root",
    "compiled_path",
    "digest",
    "install",
    "source_of",
]

ENV: Final = "HWBRIDGE_COMPILED"
"""``0``: never load a compiled module (the finder is not installed)."""

MODULES: Final = (
    "hwbridge.pump",
    "hwbridge.links.base",
    "hwbridge.links.serialport",
    "hwbridge.links.pseudoterminal",
    "hwbridge.graph.core",
    "hwbridge.bridge.adapter",
    "hwbridge.bridge.board",
    "hwbridge.bridge.endpoints",
    "hwbridge.protocols.native.cobs",
    "hwbridge.protocols.native._hotpath",
    "hwbridge.protocols.native.reliable",
    "hwbridge.protocols.native._framing.encoder",
    "hwbridge.protocols.native._framing.decoder",
    "hwbridge.protocols.native._framing.links",
    "hwbridge.protocols.native._control.calls",
    "hwbridge.protocols.native._session.core",
    "hwbridge.protocols.native._session.services",
    "hwbridge.protocols.native._session.receive",
    "hwbridge.protocols.native._session.topics",
    "hwbridge.protocols.native._session.host",
    "hwbridge.protocols.rosserial.framing",
    "hwbridge.protocols.rosserial.services",
    "hwbridge.protocols.rosserial.host",
)
"""The modules a message or a call runs through on the host (and, for the sessions and framing,
on an emulated board)."""

RECIPE: Final = b"hwbridge-compiled-2"
"""Part of every digest: changed when the way modules are compiled changes (the directives)."""

DIRECTIVES: Final = {
    "language_level": 3,
    # Python's semantics, not C's: annotations are not turned into C types or checks (an
    # ``int`` annotation would refuse an IntEnum's subclass, say), and nothing is inferred to a
    # C type that could behave differently.
    "annotation_typing": False,
    "infer_types": None,
    "binding": True,
    "always_allow_keywords": True,
}

_SUFFIX: Final = importlib.machinery.EXTENSION_SUFFIXES[0]


def cache_root() -> Path:
    """Where compiled modules live: ``$XDG_CACHE_HOME`` (or ``~/.cache``)
    ``/hwbridge/compiled/<implementation tag>``."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    tag = sys.implementation.cache_tag or sys.implementation.name
    return Path(base) / "hwbridge" / "compiled" / tag


def digest(source: bytes) -> str:
    """The name of the folder of a compiled module whose source is ``source``."""
    import hashlib  # (here: ``import hwbridge`` need not load OpenSSL's)

    return hashlib.sha256(RECIPE + b"\0" + _SUFFIX.encode() + b"\0" + source).hexdigest()[:24]


def compiled_path(name: str, source: bytes, root: Path | None = None) -> Path:
    """The file the compiled copy of module ``name`` with source ``source`` has (or would have)."""
    return (root or cache_root()) / digest(source) / (name.rpartition(".")[2] + _SUFFIX)


class _Finder(importlib.abc.MetaPathFinder):
    """Finds the compiled copy of a module of :data:`MODULES` that matches its source."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.names = frozenset(MODULES)

    def find_spec(
        self,
        fullname: str,
        path: Sequence[str] | None,
        target: ModuleType | None = None,
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname not in self.names:
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path)
        origin = spec.origin if spec is not None else None
        if origin is None or not origin.endswith(".py"):
            return None
        try:
            source = Path(origin).read_bytes()
        except OSError:
            return None
        compiled = compiled_path(fullname, source, self.root)
        if not compiled.is_file():
            return None
        loader = importlib.machinery.ExtensionFileLoader(fullname, str(compiled))
        return importlib.util.spec_from_file_location(fullname, compiled, loader=loader)


def install() -> None:
    """Put the finder first on ``sys.meta_path`` (once), unless ``HWBRIDGE_COMPILED=0``."""
    if os.environ.get(ENV) == "0":
        return
    if any(isinstance(finder, _Finder) for finder in sys.meta_path):
        return
    sys.meta_path.insert(0, _Finder(cache_root()))


def active() -> list[str]:
    """The modules of :data:`MODULES` this process has imported compiled."""
    return [
        name
        for name in MODULES
        if isinstance(
            getattr(sys.modules.get(name), "__loader__", None),
            importlib.machinery.ExtensionFileLoader,
        )
    ]


def source_of(name: str) -> Path:
    """The source file of module ``name`` (its packages are imported to find it)."""
    spec = importlib.machinery.PathFinder.find_spec(name, _parent_path(name))
    if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
        raise ImportError(f"{name}: no Python source found", name=name)
    return Path(spec.origin)


def _parent_path(name: str) -> list[str] | None:
    parent = name.rpartition(".")[0]
    if not parent:
        return None
    package = importlib.import_module(parent)
    return list(getattr(package, "__path__", []))


def available(root: Path | None = None) -> list[str]:
    """The modules of :data:`MODULES` whose current source has a compiled copy in ``root`` (the
    cache by default), whether or not this process would load it."""
    root = root or cache_root()
    return [
        name
        for name in MODULES
        if compiled_path(name, source_of(name).read_bytes(), root).is_file()
    ]
