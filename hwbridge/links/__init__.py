"""Byte links opened by URL: serial ports, TCP, pseudo-terminals, in-memory pipes, spies.

::

    from hwbridge.links import open_link

    with open_link("serial:///dev/ttyACM0?baud=115200") as link:
        link.write(b"\\x00hello")
        data = link.read(timeout=0.5)      # b"" on timeout

=================================  ==========================================================
``serial:///dev/ttyACM0?baud=N``    a serial port through pyserial (also a bare path or COM3)
``socket://HOST:PORT``              a TCP client
``tcp-listen://HOST:PORT``          a TCP listener serving one client at a time (WiFi boards)
``pty://``                          a new pseudo-terminal; a board opens ``link.slave_path``
``memory://NAME``                   one end of an in-process pipe (see :func:`memory_pair`)
``spy+URL``                         any of these, hex-dumping the traffic
=================================  ==========================================================

More schemes come from the ``hwbridge.links`` entry-point group or :func:`register_scheme`.
Links are blocking and thread-friendly: one thread reads, any thread writes, ``close()`` from
any thread wakes them (see :class:`Link`). Importing this package loads no I/O library; each
link's module (and pyserial) is imported when a URL first needs it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hwbridge.errors import LinkError
from hwbridge.links.base import Link, LinkClosedError, LinkStats
from hwbridge.links.memory import MemoryLink, memory_pair
from hwbridge.links.registry import (
    ENTRY_POINT_GROUP,
    LinkFactory,
    create_link,
    open_link,
    register_scheme,
    schemes,
)

if TYPE_CHECKING:
    from hwbridge.links.pseudoterminal import PtyLink
    from hwbridge.links.serialport import SerialLink
    from hwbridge.links.spy import SpyLink
    from hwbridge.links.tcp import SocketLink, TcpListenLink

__all__ = [
    "ENTRY_POINT_GROUP",
    "Link",
    "LinkClosedError",
    "LinkError",
    "LinkFactory",
    "LinkStats",
    "MemoryLink",
    "PtyLink",
    "SerialLink",
    "SocketLink",
    "SpyLink",
    "TcpListenLink",
    "create_link",
    "memory_pair",
    "open_link",
    "register_scheme",
    "schemes",
]

_LAZY = {
    "PtyLink": "hwbridge.links.pseudoterminal",
    "SerialLink": "hwbridge.links.serialport",
    "SpyLink": "hwbridge.links.spy",
    "SocketLink": "hwbridge.links.tcp",
    "TcpListenLink": "hwbridge.links.tcp",
}


def __getattr__(name: str) -> Any:
    """Import the link classes on first access, so ``import hwbridge.links`` stays light."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(module), name)
