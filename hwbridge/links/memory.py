"""``memory://NAME``: the two ends of an in-process byte pipe, for tests and emulated boards.

Two links opened on the same name are connected like the two ends of a cable. Each end has a
bounded inbound buffer (``buffer_size`` bytes, default 64 KiB): a write waits while the other end's
buffer is full. Bytes written before the other end is open wait in its buffer.

Closing an end discards what it had not read; the other end then reads what is left in its own
buffer and after that gets :class:`~hwbridge.links.base.LinkClosedError` (from reads and writes),
as with a socket. To talk again, open both ends again (``open()`` on the end that saw the error).
A name is forgotten when both of its ends are closed.
"""

from __future__ import annotations

import itertools
import threading
import time
from typing import Any, Final
from urllib.parse import urlsplit

from hwbridge.errors import LinkError
from hwbridge.links.base import (
    COMMON_OPTIONS,
    Link,
    LinkClosedError,
    opt_int,
    parse_options,
    split_query,
)

__all__ = ["DEFAULT_BUFFER_SIZE", "MemoryLink", "memory_pair"]

DEFAULT_BUFFER_SIZE: Final = 64 * 1024


def _end(value: Any) -> int | None:
    if value is None or (isinstance(value, str) and value.strip().lower() in ("", "any")):
        return None
    end = opt_int(value)
    if end not in (0, 1):
        raise ValueError("expected 0 or 1 (or any)")
    return end


def _size(value: Any) -> int:
    size = opt_int(value)
    if size < 1:
        raise ValueError("expected a positive number of bytes")
    return size


_OPTIONS: Final = {**COMMON_OPTIONS, "buffer_size": _size, "end": _end}


class _Channel:
    """The shared state of one name: two slots, each with its inbound buffer."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.inbound = (bytearray(), bytearray())
        self.capacity = [DEFAULT_BUFFER_SIZE, DEFAULT_BUFFER_SIZE]
        self.owners: list[MemoryLink | None] = [None, None]
        self.peer_gone = [False, False]


_channels: dict[str, _Channel] = {}
_channels_lock = threading.Lock()  # taken before a channel's condition, never after
_pair_names = itertools.count(1)


class MemoryLink(Link):
    """One end of the in-process pipe named by ``memory://NAME``.

    Options: ``buffer_size`` (bytes this end can hold unread), ``end`` (0 or 1 to pick a side;
    default: the first free one), ``write_timeout`` (seconds; default none: wait).
    """

    scheme = "memory"

    def __init__(self, url: str, **options: Any) -> None:
        super().__init__(url)
        parts = urlsplit(url)
        self.name = parts.netloc + parts.path
        if not self.name:
            raise LinkError(f"{url!r} has no name: write memory://NAME (any text) for both ends")
        opts = parse_options(url, _OPTIONS, split_query(parts.query, url), options)
        self.buffer_size: int = opts.get("buffer_size", DEFAULT_BUFFER_SIZE)
        self.end: int | None = opts.get("end")
        self.write_timeout: float | None = opts.get("write_timeout")
        self._channel: _Channel | None = None
        self._slot = 0
        self._woken = False

    @property
    def connected(self) -> bool:
        """True when the other end is open too."""
        channel = self._channel
        if channel is None or not self.is_open:
            return False
        with channel.cond:
            return channel.owners[1 - self._slot] is not None and not channel.peer_gone[self._slot]

    def _open(self) -> None:
        with _channels_lock:
            channel = _channels.setdefault(self.name, _Channel())
            with channel.cond:
                free = [i for i in (0, 1) if channel.owners[i] is None]
                if self.end is not None:
                    if self.end not in free:
                        raise LinkError(
                            f"end {self.end} of memory://{self.name} is already open; close it "
                            f"first or open the other end (end={1 - self.end})"
                        )
                    slot = self.end
                elif free:
                    slot = free[0]
                else:
                    raise LinkError(
                        f"memory://{self.name} already has both ends open; close one of them or "
                        "use another name"
                    )
                channel.owners[slot] = self
                channel.capacity[slot] = self.buffer_size
                channel.peer_gone[slot] = False
        self._channel = channel
        self._slot = slot
        self._woken = False

    def _read(self, max_bytes: int, timeout: float | None) -> bytes:
        channel, slot = self._require_channel(), self._slot
        deadline = None if timeout is None else time.monotonic() + timeout
        with channel.cond:
            while True:
                buffer = channel.inbound[slot]
                if buffer:
                    data = bytes(buffer[:max_bytes])
                    del buffer[:max_bytes]
                    channel.cond.notify_all()
                    return data
                if self._woken:
                    return b""
                if channel.peer_gone[slot]:
                    raise LinkClosedError(f"the other end of memory://{self.name} was closed")
                if deadline is None:
                    channel.cond.wait()
                else:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        return b""
                    channel.cond.wait(remaining)

    def _write(self, data: memoryview) -> None:
        channel, slot = self._require_channel(), self._slot
        peer = 1 - slot
        deadline = None if self.write_timeout is None else time.monotonic() + self.write_timeout
        sent = 0
        with channel.cond:
            while sent < len(data):
                if self._woken:
                    raise self._closed_error("write to")
                if channel.peer_gone[slot]:
                    raise LinkClosedError(
                        f"the other end of memory://{self.name} was closed "
                        f"({sent} of {len(data)} bytes sent)"
                    )
                space = channel.capacity[peer] - len(channel.inbound[peer])
                if space > 0:
                    chunk = data[sent : sent + space]
                    channel.inbound[peer].extend(chunk)
                    sent += len(chunk)
                    channel.cond.notify_all()
                    continue
                if deadline is None:
                    channel.cond.wait()
                    continue
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise LinkError(
                        f"write to {self.url} timed out after {self.write_timeout} s with {sent} "
                        f"of {len(data)} bytes sent: the other end does not read"
                    )
                channel.cond.wait(remaining)

    def _wake(self) -> None:
        channel = self._channel
        if channel is None:
            return
        with channel.cond:
            self._woken = True
            channel.cond.notify_all()

    def _close(self) -> None:
        channel, slot = self._require_channel(), self._slot
        with _channels_lock, channel.cond:
            channel.owners[slot] = None
            channel.inbound[slot].clear()
            peer = 1 - slot
            # Tell the peer only if this end was still connected to it: an end that already saw
            # the peer go must not end the session of a peer that reopened since.
            if channel.owners[peer] is not None and not channel.peer_gone[slot]:
                channel.peer_gone[peer] = True
            channel.peer_gone[slot] = False
            channel.cond.notify_all()
            if channel.owners[peer] is None and _channels.get(self.name) is channel:
                del _channels[self.name]
        self._channel = None

    def _require_channel(self) -> _Channel:
        if self._channel is None:  # the base class only calls hooks on an open link
            raise LinkClosedError(f"{self.url} is not open", local=True)
        return self._channel


def memory_pair(name: str | None = None, **options: Any) -> tuple[MemoryLink, MemoryLink]:
    """Open both ends of ``memory://NAME`` (a fresh unique name by default): ``(end 0, end 1)``."""
    if name is None:
        with _channels_lock:
            while True:
                name = f"pair-{next(_pair_names)}"
                if name not in _channels:
                    break
    first = MemoryLink(f"memory://{name}", end=0, **options)
    second = MemoryLink(f"memory://{name}", end=1, **options)
    first.open()
    try:
        second.open()
    except LinkError:
        first.close()
        raise
    return first, second
