"""Graph names (``/robot1/odom``) and how they map onto Zenoh key expressions.

Names follow ROS 1 rules: segments of letters, digits and underscores that do not start with a
digit, joined by ``/``. A relative name is resolved in a namespace (``odom`` in ``/robot1`` is
``/robot1/odom``); ``~name`` is private to a node (``/robot1/driver/name``).

Key layout under ``hwbridge/<domain>``:

=========================  ===============================================
``.../t/<name>``           topic data (ROS 1 bytes; attachment: md5 + type)
``.../s/<name>``           service requests (a queryable per server)
``.../param``              the parameter server (a queryable; JSON requests)
``.../param_update``       parameter changes, published by the server
``.../@/<zid>/<kind>/...`` liveliness tokens: what is alive (discovery)
=========================  ===============================================
"""

from __future__ import annotations

import re
from typing import Final

from hwbridge.errors import HwBridgeError

__all__ = ["GraphNameError", "decode_segment", "encode_segment", "resolve_name"]

_SEGMENT: Final = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class GraphNameError(HwBridgeError, ValueError):
    """A topic, service, node or parameter name is not valid."""


def resolve_name(name: str, namespace: str = "/", node: str | None = None) -> str:
    """Absolute form of ``name``; raises GraphNameError with the rule that is broken."""
    if not name:
        raise GraphNameError("empty name")
    if name.startswith("~"):
        if node is None:
            raise GraphNameError(f"private name {name!r} needs a node")
        base = _join(namespace, node)
        name = base + "/" + name[1:].lstrip("/") if name[1:] else base
    elif not name.startswith("/"):
        name = _join(namespace, name)
    check_name(name)
    return name


def check_name(name: str) -> None:
    """Raise GraphNameError unless ``name`` is absolute and well formed."""
    if name == "/":
        return
    if not name.startswith("/") or name.endswith("/"):
        raise GraphNameError(f"{name!r}: a resolved name starts with '/' and does not end with one")
    for segment in name[1:].split("/"):
        if not _SEGMENT.match(segment):
            raise GraphNameError(
                f"{name!r}: segment {segment!r} must be letters, digits and '_', "
                "not starting with a digit"
            )


def _join(namespace: str, name: str) -> str:
    namespace = namespace if namespace.startswith("/") else "/" + namespace
    return namespace.rstrip("/") + "/" + name


def encode_segment(text: str) -> str:
    """Make any text one Zenoh key segment (escapes ``%``, ``/`` and Zenoh's special chars)."""
    out = []
    for char in text:
        if char.isalnum() or char in "_-.":
            out.append(char)
        else:
            out.append("".join(f"%{b:02X}" for b in char.encode()))
    return "".join(out) or "%00"


def decode_segment(segment: str) -> str:
    """Inverse of :func:`encode_segment`."""
    if segment == "%00":
        return ""
    data = bytearray()
    index = 0
    while index < len(segment):
        if segment[index] == "%":
            data.append(int(segment[index + 1 : index + 3], 16))
            index += 3
        else:
            data.extend(segment[index].encode())
            index += 1
    return data.decode()
