"""Boards on links that wait for them: ``tcp-listen://`` (WiFi boards dial in) and ``pty://``.

A real :class:`~hwbridge.bridge.Bridge` on a real Zenoh graph; the boards are real device
sessions (the rosserial client emulation, the native device session) in a
:class:`~hwbridge.pump.SessionPump` over ``socket://`` or over the pty's slave.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Iterator
from typing import Any

import pytest

from hwbridge.bridge import BoardSpec, Bridge
from hwbridge.graph import Graph
from hwbridge.links import TcpListenLink, open_link
from hwbridge.links.pseudoterminal import PtyLink
from hwbridge.pump import SansIOSession, SessionPump
from tests.boards import native_sketch, rosserial_sketch, wait_for
from tests.netutil import free_port

START_DELAY = 0.2
"""The bridge's start delay in these tests: far below the rosserial host's 15 s sync timeout,
the only other thing that would ask a silent rosserial client for its topics."""
PROMPT = 5.0
"""Seconds a board that attaches may take to be on the graph (it has START_DELAY plus a
negotiation to do; 15 s would mean it waited for the sync timeout)."""


@contextlib.contextmanager
def bridge_on(url: str, protocol: str, caplog: pytest.LogCaptureFixture) -> Iterator[Bridge]:
    caplog.set_level(logging.INFO, logger="hwbridge")
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="listening")
    bridge = Bridge(graph)
    try:
        bridge.add_board(BoardSpec(url, protocol=protocol, name="wifi", start_delay=START_DELAY))
        yield bridge
    finally:
        bridge.stop()
        graph.close()


@contextlib.contextmanager
def board_on(url: str, session: SansIOSession) -> Iterator[SessionPump]:
    """A board dialing ``url`` (or opening the pty slave) with ``session``; gone on exit."""
    link = open_link(url)
    pump = SessionPump(link, session, lambda _event: None, name="test-board").start()
    try:
        yield pump
    finally:
        pump.stop()
        link.close()


def serves(bridge: Bridge) -> Any:
    return bridge.boards["wifi"].info()["topics"].get("publishes", ())


def listener(bridge: Bridge) -> TcpListenLink:
    assert wait_for(lambda: isinstance(bridge.boards["wifi"].link, TcpListenLink), 10)
    link = bridge.boards["wifi"].link
    assert isinstance(link, TcpListenLink)
    return link


@pytest.mark.parametrize("protocol", ["rosserial", "auto"])
def test_a_rosserial_board_dialing_in_late_is_asked_for_its_topics_at_once(
    protocol: str, caplog: pytest.LogCaptureFixture
) -> None:
    """The board connects well after the start delay: its topics come promptly, not after the
    15 s sync timeout (a request sent while nobody was connected is lost), and the listener is
    never closed meanwhile (it would refuse the board while it reopens)."""
    port = free_port()
    with bridge_on(f"tcp-listen://127.0.0.1:{port}", protocol, caplog) as bridge:
        link = listener(bridge)
        time.sleep(START_DELAY * 5)
        assert bridge.boards["wifi"].state == "waiting"
        started = time.monotonic()
        with board_on(f"socket://127.0.0.1:{port}", rosserial_sketch()):
            assert wait_for(lambda: "/chatter" in serves(bridge), PROMPT), caplog.text
        assert time.monotonic() - started < PROMPT
        assert bridge.boards["wifi"].link is link
    assert "reconnecting" not in caplog.text


def test_each_rosserial_client_of_a_listener_gets_its_own_session(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A WiFi board that drops and dials in again (or another board taking its place) is a new
    rosserial client: it is asked for its topics at once, not after the old session's sync
    timeout, and the first board's topics left the graph when it went."""
    port = free_port()
    url = f"tcp-listen://127.0.0.1:{port}"
    with bridge_on(url, "rosserial", caplog) as bridge:
        link = listener(bridge)
        with board_on(f"socket://127.0.0.1:{port}", rosserial_sketch()):
            assert wait_for(lambda: "/chatter" in serves(bridge), PROMPT), caplog.text
        assert wait_for(lambda: "/chatter" not in serves(bridge), PROMPT)
        assert "board gone" in caplog.text
        second = rosserial_sketch()
        second.advertise("range", "sensor_msgs/Range")
        with board_on(f"socket://127.0.0.1:{port}", second):
            assert wait_for(lambda: "/range" in serves(bridge), PROMPT), caplog.text
        assert bridge.boards["wifi"].link is link  # the listener stayed open throughout


def test_a_pty_bridge_waits_for_its_board_without_making_new_ptys(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """``pty://`` with protocol detection and nobody on the slave: the bridge says where to
    attach and waits on that one pty (probing nobody would end the link and make a new pty,
    under another name, every start delay). A board that attaches later is served."""
    with bridge_on("pty://", "auto", caplog) as bridge:
        assert wait_for(lambda: isinstance(bridge.boards["wifi"].link, PtyLink), 10)
        link = bridge.boards["wifi"].link
        assert isinstance(link, PtyLink)
        path = link.slave_path
        assert path is not None
        time.sleep(START_DELAY * 8)
        assert bridge.boards["wifi"].link is link and link.slave_path == path
        waiting = [r for r in caplog.records if "waiting for a board on" in r.getMessage()]
        assert waiting and path in waiting[0].getMessage()
        assert waiting[0].levelno == logging.WARNING  # the user needs the path to attach
        with board_on(f"serial://{path}", native_sketch()):
            assert wait_for(lambda: "/chatter" in serves(bridge), PROMPT), caplog.text
        assert link.slave_path == path
    assert "reconnecting" not in caplog.text
