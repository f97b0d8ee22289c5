"""Small helpers the built-in devices share: a reading encoded as a board publishes it, the
usual ``rate`` setting, a message stamp in seconds."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hwbridge import msg
from hwbridge.robot.plugin import EmulatedBoard, Field

__all__ = ["RATE", "encode", "stamp_seconds"]

RATE = Field("rate", float, 50.0, "readings per second", minimum=0.1, maximum=1000.0)
"""The ``rate`` setting of a device read at up to 1 kHz (50 a second unless given)."""


def encode(board: EmulatedBoard, type_name: str, value: Mapping[str, Any]) -> bytes:
    """``value`` (a mapping of ``type_name``'s fields) serialized as the board publishes it."""
    return msg.encode(msg.from_dict(type_name, dict(value), board.registry))


def stamp_seconds(stamp: Any) -> float:
    """A message's time stamp (builtin_interfaces Time) in seconds."""
    return float(stamp.sec + stamp.nanosec * 1e-9)
