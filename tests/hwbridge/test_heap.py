"""hwbridge.heap: freed C-heap memory goes back to the system (glibc's malloc_trim)."""

from __future__ import annotations

import ctypes
import ctypes.util
import threading
from pathlib import Path

import pytest

from hwbridge.heap import release_free_memory

BLOCK = 4096
BLOCKS = 12_000  # about 48 MiB


def _rss_kb() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS in /proc/self/status")


def test_a_burst_freed_on_a_thread_leaves_the_process_once_released() -> None:
    if release_free_memory() is None:
        pytest.skip("the C library is not glibc: nothing to release")
    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    kept: list[int] = []
    figures: dict[str, int] = {}

    def burst() -> None:
        # a thread's burst, as a link or Zenoh thread buffering a flood: written to (resident),
        # then freed but for one block in 64 still in use (the heap stays fragmented, so glibc
        # cannot give it back by shrinking its top)
        blocks = [libc.malloc(BLOCK) for _ in range(BLOCKS)]
        assert all(blocks)
        for block in blocks:
            ctypes.memset(block, 0xA5, BLOCK)
        figures["peak"] = _rss_kb()
        for index, block in enumerate(blocks):
            if index % 64 == 63:
                kept.append(block)
            else:
                libc.free(block)

    worker = threading.Thread(target=burst)
    worker.start()
    worker.join()
    figures["freed"] = _rss_kb()
    assert release_free_memory() is True
    figures["released"] = _rss_kb()
    for block in kept:
        libc.free(block)
    burst_kb = BLOCK * BLOCKS // 1024
    # freeing alone keeps the burst resident; the release gives most of it back
    assert figures["freed"] - figures["released"] > burst_kb // 2, figures
