"""The ``seq`` of a message's ``std_msgs/Header``, which a graph publisher fills in as rospy's
does: its count of messages (1, 2, ...), unless the message has a seq of its own (not 0)."""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Final

if TYPE_CHECKING:
    from hwbridge.msg import TypeRegistry

__all__ = ["starts_with_header", "with_seq"]

_HEADER: Final = ("header", (2, "std_msgs/msg/Header"))
"""The field descriptor of ``std_msgs/Header header`` (rosbags' Nodetype.NAME is 2)."""


@functools.lru_cache(maxsize=256)
def starts_with_header(registry: TypeRegistry, type_name: str) -> bool:
    """Whether ``type_name``'s ROS 1 bytes start with a ``std_msgs/Header`` (so with its seq)."""
    fields = registry.fields(type_name)
    return bool(fields) and tuple(fields[0]) == _HEADER


def with_seq(registry: TypeRegistry, type_name: str, data: bytes, seq: int) -> bytes:
    """``data`` (ROS 1 bytes of ``type_name``) with ``seq`` as its header's seq, if it starts
    with a header whose seq is 0; otherwise ``data`` as it is."""
    if data[:4] != b"\0\0\0\0" or not starts_with_header(registry, type_name):
        return data
    return (seq & 0xFFFFFFFF).to_bytes(4, "little") + data[4:]
