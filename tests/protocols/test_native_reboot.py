"""A board that reboots with the session id it had: session ids are new per boot, but a port
that seeds them from the clock and an analog pin alone (with a steady voltage on it), without the
library's boot count (firmware ``hwbridge/boot_count.h``), gets the same id again. Its
best-effort sequence numbers start over all the same: once the host's session ended, it must
take the board's HELLOs rather than drop them as late frames."""

from __future__ import annotations

import random

import pytest

from hwbridge.protocols.native.session import DeviceSession, HostSession
from tests.protocols.lossy import SimLink
from tests.protocols.test_native_session import BOARD, CH_CHATTER, TOPICS


@pytest.mark.parametrize("published", [0, 60, 200])
def test_a_board_rebooted_with_its_old_session_id_connects_at_once(published: int) -> None:
    board_id = 0x2468ACE1
    host = HostSession(rng=random.Random(1))
    board = DeviceSession(BOARD, TOPICS, session_id=board_id, rng=random.Random(2))
    link = SimLink(host, board)
    assert link.run(5.0, until=lambda: host.connected and board.connected)
    for _ in range(published):  # best-effort messages move the host's expected seq on
        board.publish(CH_CHATTER, b"x")
        link.run(0.005)
    rebooted = DeviceSession(BOARD, TOPICS, session_id=board_id, rng=random.Random(3))
    link.reset_device(rebooted)
    rebooted_at = link.now
    assert link.run(10.0, until=lambda: host.connected and rebooted.connected)
    # the host notices within its link timeout (0.8 s: the board's HELLOs, under the id of the
    # session, are late frames until then) and the handshake takes a few HELLOs
    assert link.now - rebooted_at < host.config.link_timeout + 0.5
