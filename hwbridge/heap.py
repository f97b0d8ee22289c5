"""Giving freed heap memory back to the operating system in long-running processes.

glibc's malloc keeps up to eight arenas per core, and a thread that allocates takes one of them.
Memory a thread frees goes back to its arena, not to the system, so a bridge whose Zenoh and
link threads buffer a burst (a board flooding, a slow subscriber) keeps the burst's peak
resident for ever after: at 32 boards the bridge's RSS grew by a fifth over ten minutes while
the memory in use stayed flat (``tools/bench/soak.py``). ``malloc_trim(0)`` returns every
whole free page of every arena; it takes a few tens of milliseconds at that load.

:func:`release_free_memory` does that where the C library is glibc and nothing elsewhere (musl,
macOS); :func:`hwbridge.cli.stopping.wait_for_stop`, the steady state of every long-running
command, calls it every :data:`RELEASE_EVERY` seconds.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
from collections.abc import Callable
from typing import Final

__all__ = ["RELEASE_EVERY", "release_free_memory"]

RELEASE_EVERY: Final = 30.0
"""Seconds between two releases in a command's steady state."""


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        libc = ctypes.CDLL(name)
        trim = libc.malloc_trim  # glibc only
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def release_free_memory() -> bool | None:
    """Return the free pages of the C heap to the system. True when some were returned, False
    when none could be, None when the C library has no way to (not glibc)."""
    trim = _malloc_trim()
    if trim is None:
        return None
    return bool(trim(0))
