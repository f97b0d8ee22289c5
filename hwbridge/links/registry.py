"""The scheme registry: which class opens ``serial://``, ``socket://``, ``spy+...`` and friends.

A :class:`~hwbridge.protocols.plugins.NamedRegistry`, as protocols and device types use, looked
up by the URL's scheme and filled from three places (first match wins):

1. :func:`register_scheme` calls (tests, applications);
2. the built-in table below (the one place hwbridge's own schemes are declared), as
   ``"module:Class"`` strings imported on first use, so that ``import hwbridge.links`` loads
   neither pyserial nor anything else it does not need;
3. the ``hwbridge.links`` entry-point group of other installed distributions, read lazily (and
   read again when a scheme is not found, so a plugin installed at run time is seen).

A scheme written ``A+B`` (``spy+serial``) is looked up as a whole first, then by its prefix ``A``,
whose factory receives the whole URL and opens the rest itself (the spy wrapper does that).
A string without ``://`` is a serial port path (``/dev/ttyUSB0``, ``COM3``).
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable
from typing import Any, Final, cast

from hwbridge.errors import LinkError
from hwbridge.links.base import Link, closest
from hwbridge.protocols.plugins import NamedRegistry

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
    "can": "hwbridge.links.can:CanLink",
    "mavlink": "hwbridge.mavlink.link:mavlink_link",
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


def _factory(loaded: object, name: str) -> LinkFactory:
    if not callable(loaded):
        raise LinkError(f"the link scheme {name!r} resolves to {loaded!r}, which is not callable")
    return cast("LinkFactory", loaded)


_REGISTRY: Final = NamedRegistry(
    "link scheme", ENTRY_POINT_GROUP, BUILTIN_SCHEMES, _factory, LinkError, fold_case=True
)


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
    if name in _REGISTRY.names():
        log.debug("scheme %r re-registered to %r", name, factory)
    _REGISTRY.register(name, factory)


def schemes() -> dict[str, str]:
    """Every known scheme and where it comes from (``"module:attr"``), sorted by scheme."""
    return dict(sorted(_REGISTRY.sources().items()))


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


def _lookup(scheme: str, url: str) -> LinkFactory:
    """The factory for ``scheme``, else for the wrapper prefix of ``A+B``; the entry points are
    read again only when neither is known."""
    candidates = [scheme]
    if "+" in scheme:
        candidates.append(scheme.split("+", 1)[0])
    for reread in (False, True):
        for name in candidates:
            factory = _REGISTRY.find(name, reread=reread)
            if factory is not None:
                return factory
    raise LinkError(_unknown_scheme_message(scheme, url, set(_REGISTRY.names())))


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
