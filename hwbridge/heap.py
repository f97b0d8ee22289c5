"""The C heap of a long-running process: large blocks go back to the system when freed.

glibc's malloc serves a request of at least ``M_MMAP_THRESHOLD`` bytes (128 KiB at first) with a
mapping of its own, returned to the system by ``free``. But the threshold moves: each time such
a block is freed, glibc raises it to that block's size (up to 32 MiB) and the heap's trim
threshold to twice that. After the first burst, a bridge's large buffers (a flood from a board,
Zenoh's batches for a subscriber that fell behind) are carved from the heaps of the threads'
arenas instead, between small blocks that stay in use, and a freed one stays resident. At 32
boards (``tools/bench/soak.py``) the bridge's RSS grew by a fifth over ten minutes that way
while the memory in use stayed flat, the arenas holding some 50 MB free.

:func:`keep_the_heap_small` fixes the thresholds at glibc's starting values, which turns the
moving off: blocks from 64 KiB up are mapped and unmapped, and free memory at the top of a heap
goes back once it passes 128 KiB. :func:`hwbridge.cli.main` calls it first thing. Elsewhere
than glibc (musl, macOS) it does nothing.
"""

from __future__ import annotations

import ctypes
from typing import Final

__all__ = ["MMAP_THRESHOLD", "TRIM_THRESHOLD", "keep_the_heap_small"]

MMAP_THRESHOLD: Final = 64 * 1024
"""Blocks of at least this many bytes get a mapping of their own."""
TRIM_THRESHOLD: Final = 128 * 1024
"""Free memory at the top of a heap beyond this many bytes is given back."""

_M_TRIM_THRESHOLD: Final = -1  # mallopt parameters, from glibc's malloc.h
_M_MMAP_THRESHOLD: Final = -3


def keep_the_heap_small() -> bool:
    """Fix glibc's mmap and trim thresholds (see the module); whether it could (glibc)."""
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library the process runs with
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    )
