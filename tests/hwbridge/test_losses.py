"""What a board's session drops reaches the log at WARNING, once per kind and interval."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from hwbridge.bridge import BoardSpec, Bridge
from hwbridge.bridge.adapter import LOSS_REPORT_INTERVAL
from hwbridge.graph import Graph
from tests.boards import PtyBoard, native_chatter, native_sketch, wait_for
from tests.netutil import free_port


def test_oversize_frames_are_logged_once_per_interval(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "ttyBIG"
    board = PtyBoard(path, native_sketch()).start()
    board.every(0.05, native_chatter([0]))
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="losses")
    bridge = Bridge(graph)
    caplog.set_level(logging.WARNING, logger="hwbridge.board")
    try:
        connection = bridge.add_board(BoardSpec(str(path), protocol="native", name="big"))
        assert wait_for(lambda: connection.state == "connected"), connection.info()
        huge = bytes([0x81]) * 5000 + b"\x00"  # binary, far longer than any frame allowed
        for _ in range(3):
            board.link.write(huge)

        def said() -> list[str]:
            return [r.getMessage() for r in caplog.records if "bad_frames" in r.getMessage()]

        assert wait_for(lambda: bool(said()), 10), connection.info()
        assert said()[0].startswith("big: ") and "rejected" in said()[0]
        assert connection.info()["stats"]["bad_frames"] >= 1
        board.link.write(huge)  # more of the same within the interval: counted, not said again
        assert LOSS_REPORT_INTERVAL >= 5
        assert not wait_for(lambda: len(said()) > 1, 1.5)
        assert connection.state == "connected"  # the session is kept
    finally:
        bridge.stop()
        graph.close()
        board.stop()
