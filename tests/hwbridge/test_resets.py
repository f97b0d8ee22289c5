"""What a board's resets leave behind in the bridge: nothing.

A real :class:`~hwbridge.bridge.Bridge` on a real Zenoh graph; the boards are the rosserial
client emulation in a :class:`~hwbridge.pump.SessionPump`, dialing a ``tcp-listen://`` link (each
connection is a new session, as a WiFi board that reboots makes) or on a pty (a board whose
session survives its reset, as on a USB cable).
"""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from hwbridge.bridge import BoardSpec, Bridge
from hwbridge.bridge.adapter import SessionAdapter
from hwbridge.errors import HwBridgeError
from hwbridge.graph import Graph
from hwbridge.protocols.rosserial import RosserialDevice
from tests.boards import PtyBoard, chatter, rosserial_sketch, wait_for
from tests.hwbridge.test_listening_links import PROMPT, board_on, bridge_on, listener, serves
from tests.netutil import free_port

SESSIONS = 6
"""Board sessions in a row in the listener test (each adapter used to leave one behind, so the
second session already shows a leak; tools/bench/resets.py runs 1,000)."""


def test_parameter_listeners_do_not_pile_up_across_board_sessions(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Every board session's adapter listens for parameter changes (to push them to the
    board); a session that ends stops listening, so a bridge whose board reconnects all day
    keeps one listener, and a parameter change reaches only the live session."""
    port = free_port()
    with bridge_on(f"tcp-listen://127.0.0.1:{port}", "rosserial", caplog) as bridge:
        listener(bridge)  # listening before the first board dials
        params = bridge.params
        for _ in range(SESSIONS):
            with board_on(f"socket://127.0.0.1:{port}", rosserial_sketch()):
                assert wait_for(lambda: "/chatter" in serves(bridge), PROMPT), caplog.text
                assert params.listener_count == 1
            assert wait_for(lambda: bridge.boards["wifi"].adapter is None, PROMPT)
            assert params.listener_count == 0
        params.set("/speed", 1.5)  # nobody listens: no dead adapter tries to push it
    assert "cannot push parameter" not in caplog.text


def test_a_session_ends_its_parameter_listener_even_if_its_adapter_forgets_to(
    caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The adapter listens through its port, and the board's connection closes the port when
    the session ends: an adapter whose close leaves its port open (a regression of the kind
    that leaked a listener per session) still leaves no listener behind."""

    def forgetful_close(adapter: SessionAdapter, reason: HwBridgeError) -> list[bytes]:
        adapter.endpoints.close(reason)
        return []

    monkeypatch.setattr(SessionAdapter, "close", forgetful_close)
    port = free_port()
    with bridge_on(f"tcp-listen://127.0.0.1:{port}", "rosserial", caplog) as bridge:
        listener(bridge)
        params = bridge.params
        for _ in range(3):
            with board_on(f"socket://127.0.0.1:{port}", rosserial_sketch()):
                assert wait_for(lambda: "/chatter" in serves(bridge), PROMPT), caplog.text
                assert params.listener_count == 1
            assert wait_for(lambda: params.listener_count == 0, PROMPT), params.listener_count


def test_a_rosserial_board_reflashed_with_other_topics_leaves_no_stale_topic(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A rosserial board on a cable keeps its session through a reset (the host asks the silent
    board for its topics again); when it comes back with another table, the topics it no longer
    has leave the graph and the log names the change."""
    caplog.set_level(logging.INFO, logger="hwbridge")
    path = tmp_path / "ttyROSSERIAL"
    board = PtyBoard(path, rosserial_sketch(), name="sketch").start()
    count = [0]
    board.every(0.05, lambda device: device.configured and chatter(count)(device))
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="resets")
    bridge = Bridge(graph)
    try:
        bridge.add_board(BoardSpec(str(path), protocol="rosserial", name="uno", start_delay=0.2))
        topics = lambda: bridge.boards["uno"].info()["topics"]  # noqa: E731
        assert wait_for(lambda: "/chatter" in topics().get("publishes", ()), 20), caplog.text

        def reflash(device: RosserialDevice) -> None:
            device.reflash()
            device.advertise("status", "std_msgs/String")

        board.pump.call(reflash)
        assert wait_for(lambda: "/status" in topics().get("publishes", ()), 30), caplog.text
        now = topics()
        assert "/chatter" not in now["publishes"]
        assert "/led" not in now["subscribes"] and "/reset" not in now["serves"]
        assert "another table" in caplog.text and "gone /chatter, /led, /reset" in caplog.text
        assert "new /status" in caplog.text
        assert bridge.boards["uno"].connects == 1  # the same session: no reconnect hid it
    finally:
        bridge.stop()
        graph.close()
        board.stop()
