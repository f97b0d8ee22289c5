"""``mavlink://`` link URLs: pymavlink's connection strings, opened with hwbridge's own links.

A flight controller's connection is written as pymavlink (and MAVProxy, QGroundControl's
users) write it, after ``mavlink://``; the bytes then travel over the matching hwbridge link,
which brings its reconnection, counters and error messages:

=================================  ======================================  =====================
``mavlink://...``                  what it is                              hwbridge link
=================================  ======================================  =====================
``udpin:0.0.0.0:14550``            listen for a vehicle's UDP packets      ``udp-listen://``
``udp:0.0.0.0:14550``              the same (pymavlink's default input)    ``udp-listen://``
``udpout:192.168.4.1:14550``       send to a vehicle that listens          ``udp://``
``tcp:127.0.0.1:5760``             connect to a vehicle (SITL, a telemetry ``socket://``
                                   radio's TCP bridge)
``tcpin:0.0.0.0:5760``             wait for a vehicle to connect           ``tcp-listen://``
``/dev/ttyACM0?baud=115200``       a serial port (or ``serial:PATH``,      ``serial://``
                                   ``COM3``)
=================================  ======================================  =====================

Query options (``?baud=57600``) go to the hwbridge link. The ``mavlink_vehicle`` host device
(:mod:`hwbridge.mavlink.plugin`) reads MAVLink from whatever link its robot file names, so a
plain hwbridge URL (``pty://``, ``socket://``) works there too.
"""

from __future__ import annotations

from typing import Any, Final

from hwbridge.errors import LinkError
from hwbridge.links.base import Link

__all__ = ["EXAMPLES", "mavlink_link", "translate"]

EXAMPLES: Final = (
    "mavlink://udpin:0.0.0.0:14550, mavlink://udpout:192.168.4.1:14550, "
    "mavlink://tcp:127.0.0.1:5760, mavlink://tcpin:0.0.0.0:5760, "
    "mavlink:///dev/ttyACM0?baud=115200"
)
_SCHEMES: Final[dict[str, str]] = {
    "udpin": "udp-listen",
    "udp": "udp-listen",
    "udpout": "udp",
    "tcp": "socket",
    "tcpin": "tcp-listen",
}


def translate(url: str) -> str:
    """The hwbridge link URL for a ``mavlink://`` URL; LinkError naming the accepted forms."""
    prefix = "mavlink://"
    if not url.lower().startswith(prefix):
        raise LinkError(f"{url!r} is not a mavlink:// URL; examples: {EXAMPLES}")
    rest = url[len(prefix) :]
    device, sep, query = rest.partition("?")
    suffix = f"?{query}" if sep else ""
    if not device:
        raise LinkError(f"{url!r}: give a connection after mavlink://, e.g. {EXAMPLES}")
    kind, colon, address = device.partition(":")
    if colon and kind.lower() in _SCHEMES:
        host, _, port = address.rpartition(":")
        if not port.isdigit() or (kind.lower() not in ("udpin", "udp", "tcpin") and not host):
            raise LinkError(f"{url!r}: write {kind}:HOST:PORT, e.g. {EXAMPLES}")
        return f"{_SCHEMES[kind.lower()]}://{host}:{port}{suffix}"
    if colon and kind.lower() == "serial":
        device = address
    elif colon and not (len(kind) == 1 and kind.isalpha()):  # not a Windows drive letter
        raise LinkError(
            f"{url!r}: unknown MAVLink connection {kind!r}; use udpin, udpout, tcp, tcpin or a "
            f"serial port, e.g. {EXAMPLES}"
        )
    return f"serial://{device}{suffix}"


def mavlink_link(url: str, **options: Any) -> Link:
    """The link factory of the ``mavlink`` scheme (see the module's table)."""
    from hwbridge.links import create_link

    return create_link(translate(url), **options)
