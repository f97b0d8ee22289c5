"""Service calls to a board whose reliable window stays full (issue 25 item 5: the soak's
peer resets).

A board has one transmit buffer. A service request that arrives while a reliable message of its
own waits there for the window is taken back unacknowledged (PROTOCOL.md 2.8) and answered when
the host sends it again. The soak bench's boards publish a reliable message whenever the buffer
is free, and under load the bridge acknowledges late, so the buffer was full again at every
retransmission: the board never answered, the bridge's calls failed at their timeout and its
retry limit (2.4) ended the session, dropping what the board's reliable window held. A request
taken back now reserves the buffer for its answer.

The board is ``tools/bench/SoakBoard`` (the HwBridge library built for the host), publishing two
reliable topics at 200 Hz each; the host is the bridge's ``HostSession`` on a TCP connection,
reading the link only every 0.1 s (a bridge behind its graph), so the board's 16-frame window is
full whenever the host's bytes arrive.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from hwbridge.protocols.native import session as ns
from tests.firmware.test_host_stall import SKETCH, Board, Host
from tests.netutil import free_port

pytestmark = pytest.mark.skipif(
    shutil.which("g++") is None, reason="g++ is not installed (Debian package g++)"
)

CALLS = 12
"""Service calls, one a second: without the fix the retry limit ends the session within them."""
HOST_PERIOD = 0.1
"""Seconds between the host's reads of the link (a bridge behind its graph)."""


@pytest.fixture(scope="module")
def program(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from hwbridge.firmware.build import build_host_sketch

    return build_host_sketch(SKETCH, tmp_path_factory.mktemp("busy_build"))


@pytest.fixture
def busy_board(program: Path) -> Iterator[tuple[Board, Host, int]]:
    port = free_port()
    board = Board(program, port, SOAK_TOPICS="2", SOAK_RELIABLE="2", SOAK_RATE="200")
    host = Host(port)
    try:
        assert host.run_until(lambda: host.session.connected, 20), host.events
        connected = next(e for e in host.events if isinstance(e, ns.Connected))
        channel = next(t.channel for t in connected.topics if t.name.endswith("/trigger"))
        assert board.ask("go") == "going"
        yield board, host, channel
    finally:
        host.close()
        board.close()


def test_a_board_with_a_full_window_answers_every_call(
    busy_board: tuple[Board, Host, int],
) -> None:
    board, host, channel = busy_board
    answers: dict[int, Any] = {}
    asked: list[int] = []
    next_call = time.monotonic()
    # every call gets its answer or an error (a generous timeout: a loaded machine is slow)
    deadline = time.monotonic() + CALLS + 120
    while (len(asked) < CALLS or len(answers) < len(asked)) and time.monotonic() < deadline:
        now = time.monotonic()
        if len(asked) < CALLS and now >= next_call:
            asked.append(host.session.call_service(channel, b"", timeout=60, now=now))
            next_call = now + 1.0
        time.sleep(HOST_PERIOD)  # the host is busy elsewhere; the board's window fills
        host.step(0)
        for event in host.events:
            if isinstance(event, ns.ServiceResponse):
                answers[event.request_id] = event.error
        host.events = [e for e in host.events if not isinstance(e, ns.ServiceResponse)]
    counts = board.counts()
    assert host.ended() == [], host.ended()
    assert sorted(answers) == sorted(asked), (answers, asked)
    assert all(error is None for error in answers.values()), answers
    assert counts["served"] == CALLS, counts
    assert counts["peer_resets"] == 0 and counts["link_losses"] == 0, counts
    assert counts["sessions"] == 1, counts
    assert sum(counts["refused"]) > 0, counts  # the window was full: the case under test
