"""python-can's SLCAN interface, reading what the adapter sent in one call instead of a byte
at a time.

python-can's ``slcanBus._read`` takes each byte with its own ``read(1)`` (a ``select`` and a
``read`` system call, under the GIL in between) and waits in 1 ms reads while the line is idle.
Eight boards' heartbeats alone are some 8 kB/s of SLCAN text: about 17,000 system calls a second
in the bridge, enough to starve it of CPU on a busy two-core machine until its boards' sessions
timed out. :class:`BulkSlcanBus` reads everything waiting at once, keeps what follows the first
complete reply for the next call, and sleeps in ``select`` while nothing comes. The lines it
returns are python-can's: the text up to and including ``\\r`` (OK) or ``\\a`` (error).
"""

from __future__ import annotations

import select
import time
from typing import Any

from can.interfaces.slcan import slcanBus

__all__ = ["BulkSlcanBus"]

_ENDS = (0x0D, 0x07)
"""The bytes that end an SLCAN reply: carriage return (OK) and bell (error)."""


class BulkSlcanBus(slcanBus):
    def _read(self, timeout: float | None) -> str | None:
        port: Any = self.serialPortOrig
        buffer: bytearray = self._buffer
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            line = _take_line(buffer)
            if line is not None:
                return line
            waiting = port.in_waiting
            if waiting:
                buffer.extend(port.read(waiting))
                continue
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                return None
            try:
                fileno = port.fileno()
            except (AttributeError, OSError, ValueError):
                fileno = None  # not a file descriptor (a socket:// URL, ...): python-can's way
            if fileno is None:
                buffer.extend(port.read(1))
                continue
            readable, _, _ = select.select([fileno], [], [], remaining)
            if readable:  # what came (a port that hung up raises here, not in a spin)
                buffer.extend(port.read(max(1, port.in_waiting)))


def _take_line(buffer: bytearray) -> str | None:
    """The first complete reply in ``buffer`` (taken out of it), or None."""
    ends = [i for i in (buffer.find(end) for end in _ENDS) if i >= 0]
    if not ends:
        return None
    cut = min(ends) + 1
    line = buffer[:cut].decode()
    del buffer[:cut]
    return line
