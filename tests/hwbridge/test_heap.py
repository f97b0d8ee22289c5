"""hwbridge.heap: after a burst of large buffers is freed, the memory leaves the process.

Each case runs in a fresh interpreter (glibc's thresholds are process-wide and only move up):
a thread frees a first large block (which, untuned, raises glibc's mmap threshold past the
burst's size, as a bridge's first burst does), then allocates a burst of large buffers with a
small block in use after each (the heap stays fragmented), writes them, and frees the large
ones. The resident size that remains is compared with and without keep_the_heap_small().
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from hwbridge.heap import keep_the_heap_small

BURST = """
import ctypes, json, sys, threading
from pathlib import Path
from hwbridge.heap import keep_the_heap_small

def rss_kb():
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])

tuned = sys.argv[1] == "tuned" and keep_the_heap_small()
libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.malloc.argtypes = [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
figures = {"tuned": tuned}

def burst():
    libc.free(libc.malloc(4 << 20))  # a first large block, freed
    figures["before"] = rss_kb()
    large, small = [], []
    for _ in range(64):
        large.append(libc.malloc(512 << 10))
        small.append(libc.malloc(256))  # in use after the burst
    for block in large:
        ctypes.memset(block, 0xA5, 512 << 10)
    figures["peak"] = rss_kb()
    for block in large:
        libc.free(block)
    figures["after"] = rss_kb()

worker = threading.Thread(target=burst)
worker.start()
worker.join()
print(json.dumps(figures))
"""


def _burst(mode: str) -> dict[str, int]:
    done = subprocess.run(
        [sys.executable, "-c", BURST, mode], capture_output=True, text=True, timeout=60, check=True
    )
    figures: dict[str, int] = json.loads(done.stdout)
    return figures


def test_a_freed_burst_of_large_buffers_leaves_the_process() -> None:
    if not keep_the_heap_small():
        pytest.skip("the C library is not glibc: nothing to tune")
    burst_kb = 64 * 512
    untuned, tuned = _burst("untuned"), _burst("tuned")
    assert tuned["tuned"] and not untuned["tuned"]
    for figures in (untuned, tuned):
        assert figures["peak"] - figures["before"] > burst_kb * 0.9, figures  # it was resident
    # glibc's default keeps the freed burst; tuned, it is gone
    assert untuned["after"] - untuned["before"] > burst_kb * 0.9, untuned
    assert tuned["after"] - tuned["before"] < burst_kb * 0.1, tuned
