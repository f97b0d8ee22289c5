"""The scheme registry: which class opens ``serial://``, ``socket://``, ``spy+...`` and friends.

One table, looked up by the URL's scheme, filled from three places (first match wins):

1. :func:`register_scheme` calls (tests, applications);
2. the built-in table below, as ``"module:Class"`` strings imported on first use, so that
   ``import hwbridge.links`` loads neither pyserial nor anything else it does not need;
3. the ``hwbridge.links`` entry-point group of installed distributions, read lazily (and read
   again when a scheme is not found, so a plugin installed at run time is seen).

A scheme written ``A+B`` (``spy+serial``) is looked up as a whole first, then by its prefix ``A``,
whose factory receives the whole URL and opens the rest itself (the spy wrapper does that).
A string without ``://`` is a serial port path (``/dev/ttyUSB0``, ``COM3``).
"""

from __future__ import annotations

import importlib
import logging
import re
import threading
from collections.abc import Callable
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Final, cast

from hwbridge.errors import LinkError
from hwbridge.links.base import Link, closest

__all__ = [
    "BUILTIN_SCHEMES",
    "ENTRY_POINT_GROUP",
    "LinkFactory",
    "create_link",
    "open_link",
    "register_scheme",
    "scheme_of",
    "schemes",
]

log = logging.getLogger("hwbridge.links")

LinkFactory = Callable[..., Link]
"""Called as ``factory(url, **options)``; returns a Link that is not open yet (a Link subclass
itself is a factory)."""

ENTRY_POINT_GROUP: Final = "hwbridge.links"

BUILTIN_SCHEMES: Final[dict[str, str]] = {
    "serial": "hwbridge.links.serialport:SerialLink",
    "socket": "hwbridge.links.tcp:SocketLink",
    "tcp-listen": "hwbridge.links.tcp:TcpListenLink",
    "memory": "hwbridge.links.memory:MemoryLink",
    "pty": "hwbridge.links.pseudoterminal:PtyLink",
    "spy": "hwbridge.links.spy:SpyLink",
    "udp": "hwbridge.links.udp:UdpLink",
    "udp-listen": "hwbridge.links.udp:UdpListenLink",
}

_EXAMPLES: Final = (
    "serial:///dev/ttyACM0?baud=115200, /dev/ttyUSB0, COM3, socket://192.168.4.1:11411, "
    "tcp-listen://:11411, pty://, memory://NAME, udp://192.168.4.1:2324, udp-listen://:2324, "
    "can://slcan/dev/ttyACM0/node1?bitrate=1000000, mavlink:///dev/ttyACM0?baud=57600, spy+serial:///dev/ttyACM0"
)
_HINTS: Final[dict[str, str]] = {
    "tcp": "socket://HOST:PORT to connect, or tcp-listen://:PORT to wait for a board",
    "tcp-server": "tcp-listen://:PORT",
    "tcp-client": "socket://HOST:PORT",
    "file": "serial:///PATH for a device file",
    "loop": "memory://NAME (two ends of an in-process pipe)",
}

_SCHEME_RE: Final = re.compile(r"^([A-Za-z][A-Za-z0-9+.\-]*)://")
_WRAPPER_RE: Final = re.compile(r"^([A-Za-z][A-Za-z0-9.\-]*)\+")
_VALID_SCHEME: Final = re.compile(r"^[a-z][a-z0-9+.\-]*$")

_lock = threading.RLock()  # reentrant: a plugin may register schemes as it is imported
_registered: dict[str, LinkFactory | str] = {}
_resolved: dict[str, LinkFactory] = {}
_entry_points: dict[str, EntryPoint] | None = None


def register_scheme(scheme: str, factory: LinkFactory | str) -> None:
    """Make ``scheme://...`` URLs open with ``factory`` (a callable or a ``"module:attr"``).

    Overrides a built-in or plugin scheme of the same name (logged at debug level).
    """
    name = scheme.strip().lower()
    if not _VALID_SCHEME.match(name):
        raise ValueError(
            f"invalid scheme {scheme!r}: use letters, digits, '+', '-' or '.', starting with a "
            "letter"
        )
    if not callable(factory) and not (isinstance(factory, str) and ":" in factory):
        raise TypeError(f"factory for {name!r} must be callable or a 'module:attr' string")
    with _lock:
        if name in BUILTIN_SCHEMES or name in _registered:
            log.debug("scheme %r re-registered to %r", name, factory)
        _registered[name] = factory
        _resolved.pop(name, None)


def schemes() -> dict[str, str]:
    """Every known scheme and where it comes from (``"module:attr"``), sorted by scheme."""
    with _lock:
        plugins = _load_entry_points(refresh=False)
        table: dict[str, str] = {name: ep.value for name, ep in plugins.items()}
        table.update(BUILTIN_SCHEMES)
        table.update({name: _describe(target) for name, target in _registered.items()})
    return dict(sorted(table.items()))


def scheme_of(url: str) -> str:
    """The scheme that opens ``url`` (lower case); ``serial`` for a bare device path."""
    match = _SCHEME_RE.match(url)
    if match:
        return match.group(1).lower()
    match = _WRAPPER_RE.match(url)  # a wrapper over a bare path: spy+/dev/ttyUSB0
    if match and match.group(1).lower() in schemes():
        return match.group(1).lower()
    return "serial"


def create_link(url: str, **options: Any) -> Link:
    """Make the link for ``url`` without opening it (the bridge opens and reopens it).

    ``options`` override the URL's query string (``baud=115200``...). Raises LinkError for an
    unknown scheme (naming the closest one), a malformed URL or an unknown option.
    """
    if not isinstance(url, str) or not url.strip():
        raise LinkError(f"empty link URL; give one such as {_EXAMPLES}")
    url = url.strip()
    scheme = scheme_of(url)
    factory = _lookup(scheme, url)
    try:
        link = factory(url, **options)
    except ValueError as exc:  # urllib's own refusals ("Invalid IPv6 URL"...)
        raise LinkError(f"{url!r} is not a valid link URL: {exc}") from exc
    if not isinstance(link, Link):
        raise LinkError(
            f"the factory for {scheme!r} returned {type(link).__name__}, not a Link; "
            "fix the plugin that registers it"
        )
    return link


def open_link(url: str, **options: Any) -> Link:
    """Make the link for ``url`` and open it (see :func:`create_link` for the arguments)."""
    link = create_link(url, **options)
    link.open()
    return link


# ------------------------------------------------------------------------------------ internals


def _describe(target: LinkFactory | str) -> str:
    if isinstance(target, str):
        return target
    module = getattr(target, "__module__", "?")
    name = getattr(target, "__qualname__", type(target).__name__)
    return f"{module}:{name}"


def _lookup(scheme: str, url: str) -> LinkFactory:
    candidates = [scheme]
    if "+" in scheme:
        candidates.append(scheme.split("+", 1)[0])
    with _lock:
        for refresh in (False, True):
            plugins = _load_entry_points(refresh=refresh)
            for name in candidates:
                factory = _find(name, plugins)
                if factory is not None:
                    return factory
        known = set(plugins) | set(BUILTIN_SCHEMES) | set(_registered)
    raise LinkError(_unknown_scheme_message(scheme, url, known))


def _find(name: str, plugins: dict[str, EntryPoint]) -> LinkFactory | None:
    """The factory for ``name`` (lock held), importing it on first use; None if unknown."""
    cached = _resolved.get(name)
    if cached is not None:
        return cached
    target: LinkFactory | str | EntryPoint
    if name in _registered:
        target = _registered[name]
    elif name in BUILTIN_SCHEMES:
        target = BUILTIN_SCHEMES[name]
    elif name in plugins:
        target = plugins[name]
    else:
        return None
    factory = _resolve(name, target)
    _resolved[name] = factory
    return factory


def _resolve(name: str, target: LinkFactory | str | EntryPoint) -> LinkFactory:
    if not isinstance(target, (str, EntryPoint)):
        return target
    where = target if isinstance(target, str) else f"{target.value} (entry point)"
    try:
        if isinstance(target, EntryPoint):
            loaded = target.load()
        else:
            module_name, _, attr = target.partition(":")
            loaded = importlib.import_module(module_name)
            for part in attr.split("."):
                loaded = getattr(loaded, part)
    except (ImportError, AttributeError) as exc:
        raise LinkError(
            f"the link scheme {name!r} is provided by {where}, which failed to load: {exc}; "
            "reinstall the package that provides it"
        ) from exc
    if not callable(loaded):
        raise LinkError(f"the link scheme {name!r} points at {where}, which is not callable")
    return cast("LinkFactory", loaded)


def _load_entry_points(*, refresh: bool) -> dict[str, EntryPoint]:
    """The plugin schemes (lock held); read once, or again when ``refresh`` is set."""
    global _entry_points  # noqa: PLW0603 (a lazily filled module cache)
    if _entry_points is not None and not refresh:
        return _entry_points
    found: dict[str, EntryPoint] = {}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        name = ep.name.strip().lower()
        if name in found and found[name].value != ep.value:
            log.warning(
                "link scheme %r is declared twice (%s and %s); using the first",
                name,
                found[name].value,
                ep.value,
            )
            continue
        if name in BUILTIN_SCHEMES and ep.value != BUILTIN_SCHEMES[name]:
            log.warning(
                "entry point %s = %s cannot replace the built-in scheme; ignored", name, ep.value
            )
        found.setdefault(name, ep)
    _entry_points = found
    return found


def _unknown_scheme_message(scheme: str, url: str, known: set[str]) -> str:
    hint = _HINTS.get(scheme)
    if hint is None:
        near = closest(scheme, known)
        if near is None and "+" in scheme:
            near = closest(scheme.split("+", 1)[0], known)
        hint = f"{near}://" if near else None
    did_you_mean = f"; did you mean {hint}?" if hint else ""
    return (
        f"unknown link scheme {scheme!r} in {url!r}{did_you_mean} Known schemes: "
        f"{', '.join(sorted(known))} (packages add more through the {ENTRY_POINT_GROUP!r} "
        f"entry-point group). Examples: {_EXAMPLES}"
    )
