"""Noise on a line the bridge is still detecting (a wrong baud rate, a board printing binary)
costs bounded memory and is reported (issue 19 item 1)."""

from __future__ import annotations

import logging
import random
import resource
import threading
import time
from pathlib import Path

import pytest

from hwbridge.bridge import BoardSpec, Bridge
from hwbridge.bridge.board import DETECT_BUFFER
from hwbridge.graph import Graph
from hwbridge.links import LinkError, open_link
from tests.netutil import free_port, wait_until

NOISE_BYTES = 50 * 1024 * 1024
MEMORY_BOUND = 20 * 1024 * 1024
"""The bridge may grow by at most this much while the 50 MB of noise arrives (it keeps
DETECT_BUFFER, 64 KiB, of it; the rest is the interpreter's own churn)."""


def _max_rss() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: KiB


def test_fifty_megabytes_of_noise_in_detection(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    assert DETECT_BUFFER <= 64 * 1024
    rng = random.Random(7)
    block = bytes(rng.randrange(1, 0xFE) for _ in range(65536))  # no 0x00, no FF FE: no frames
    path = tmp_path / "ttyNOISE"
    link = open_link(f"pty://?symlink={path}")
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="noise")
    bridge = Bridge(graph)
    sent = [0]
    stop = threading.Event()

    def spew() -> None:
        while not stop.is_set() and sent[0] < NOISE_BYTES:
            try:
                link.write(block)
            except LinkError:
                time.sleep(0.01)  # nobody has opened the pty yet
                continue
            sent[0] += len(block)

    caplog.set_level(logging.WARNING, logger="hwbridge.board")
    before = _max_rss()
    writer = threading.Thread(target=spew, daemon=True)
    try:
        connection = bridge.add_board(BoardSpec(str(path), name="noisy"))
        writer.start()
        assert wait_until(lambda: sent[0] >= NOISE_BYTES, 120, step=0.1), sent[0]

        def reported() -> bool:
            return any("wrong baud rate?" in r.getMessage() for r in caplog.records)

        assert wait_until(reported, 15), [r.getMessage() for r in caplog.records]
        assert connection.state == "detecting"
        grown = _max_rss() - before
        assert grown < MEMORY_BOUND, f"grew by {grown / 1e6:.1f} MB"
    finally:
        stop.set()
        bridge.stop()
        graph.close()
        link.close()
        writer.join(5)
