"""What the recorder and the player share: the MCAP encodings, the error, statistics."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Final

from hwbridge.errors import HwBridgeError

SCHEMA_ENCODING: Final = "ros1msg"
MESSAGE_ENCODING: Final = "ros1"


class RecordingError(HwBridgeError):
    """An MCAP file cannot be written, read or played."""


# ---------------------------------------------------------------------- statistics
@dataclass(frozen=True)
class ChannelStats:
    """Messages and payload bytes of one topic and type, recorded or played."""

    topic: str
    type: str
    md5: str
    messages: int = 0
    bytes: int = 0
    has_schema: bool = True
    """False when the type was not in the registry: bytes recorded, definition unknown."""


class _ChannelTotals:
    """Totals over ``channels`` (of a recording or a playback)."""

    channels: tuple[ChannelStats, ...]

    @property
    def messages(self) -> int:
        return sum(c.messages for c in self.channels)

    @property
    def bytes(self) -> int:
        return sum(c.bytes for c in self.channels)


@dataclass(frozen=True)
class RecorderStats(_ChannelTotals):
    """A snapshot of a recording in progress (or finished)."""

    path: Path
    elapsed: float
    """Seconds since :meth:`Recorder.start` (until :meth:`Recorder.stop` once stopped)."""
    channels: tuple[ChannelStats, ...] = ()
    dropped: int = 0
    """Messages lost because the write buffer was full (the disk could not keep up)."""


@dataclass(frozen=True)
class PlayerStats(_ChannelTotals):
    """A snapshot of a playback in progress (or finished)."""

    path: Path
    elapsed: float
    """Wall-clock seconds since :meth:`Player.run` began."""
    position: float = 0.0
    """Seconds into the recording of the last message published."""
    duration: float | None = 0.0
    """Length of the recording in seconds (first to last message); None while it is not known
    (a file without a summary, until a pass has read it to its end)."""
    loops: int = 0
    """Passes over the file completed."""
    channels: tuple[ChannelStats, ...] = ()


@dataclass
class ChannelCounter:
    """Running totals of one channel; :meth:`freeze` makes a :class:`ChannelStats`."""

    topic: str
    type: str
    md5: str
    has_schema: bool = True
    messages: int = 0
    bytes: int = 0

    def freeze(self) -> ChannelStats:
        """A snapshot of the totals."""
        return ChannelStats(
            self.topic, self.type, self.md5, self.messages, self.bytes, self.has_schema
        )


def describe(exc: BaseException) -> str:
    """``exc``'s message, or its type's name when it has none."""
    return str(exc) or type(exc).__name__
