"""Small helpers for links built on file descriptors and sockets (deadlines, blocking sends)."""

from __future__ import annotations

import selectors
import time
from collections.abc import Callable
from typing import Any

from hwbridge.errors import LinkError
from hwbridge.links.base import LinkClosedError, Waker

__all__ = ["Deadline", "write_all"]


class Deadline:
    """A point in monotonic time, or none (wait forever)."""

    def __init__(self, timeout: float | None) -> None:
        self._end = None if timeout is None else time.monotonic() + timeout

    def remaining(self) -> float | None:
        """Seconds left (never negative), or None without a limit."""
        if self._end is None:
            return None
        return max(0.0, self._end - time.monotonic())

    def expired(self) -> bool:
        """True once the time is up (never for no limit)."""
        return self._end is not None and time.monotonic() >= self._end


def write_all(
    send: Callable[[memoryview], int],
    fileobj: Any,
    data: memoryview,
    waker: Waker,
    timeout: float | None,
    url: str,
) -> None:
    """Call ``send`` (non-blocking) until every byte is out, waiting for room when it would block.

    Returns early only by raising: :class:`LinkClosedError` (``local``) when ``waker`` fires,
    :class:`LinkError` when ``timeout`` expires; ``OSError`` from ``send`` is left to the caller.
    """
    try:
        sent = send(data)
    except (BlockingIOError, InterruptedError):
        sent = 0
    if sent == len(data):  # the common case: the buffer had room
        return
    deadline = Deadline(timeout)
    selector: selectors.BaseSelector | None = None
    try:
        while sent < len(data):
            try:
                sent += send(data[sent:])
                continue
            except (BlockingIOError, InterruptedError):
                pass
            if waker.woken:
                raise LinkClosedError(f"{url} was closed while writing", local=True)
            if selector is None:
                selector = selectors.DefaultSelector()
                selector.register(fileobj, selectors.EVENT_WRITE)
                selector.register(waker, selectors.EVENT_READ)
            ready = selector.select(deadline.remaining())
            if any(key.fileobj is waker for key, _ in ready):
                raise LinkClosedError(f"{url} was closed while writing", local=True)
            if not ready and deadline.expired():
                raise LinkError(
                    f"write to {url} timed out after {timeout} s with {sent} of {len(data)} "
                    "bytes sent: the other side does not read (flow control, a stalled board, "
                    "or a full network buffer)"
                )
    finally:
        if selector is not None:
            selector.close()
