"""The stall rule (PROTOCOL.md 2.9) in host builds of the C++ library.

A host build shares the CPU like the emulated boards the rule was written for: a board program
the scheduler leaves out (here: SIGSTOP for 2 s) must not, when it runs again, take its own
absence for the host's silence. The board is ``tools/bench/SoakBoard`` (the soak bench's board:
the HwBridge library built with ``hwbridge firmware build --board host``) on a TCP link; the host
is the bridge's own protocol code (a ``HostSession``) driven by this test over the socket, so that
the test decides exactly when the host speaks again.

1. Both ends stop for 2 s (a machine that stalls), the board resumes first: it must count a stall
   and keep the session (only 200 ms of its absence counts towards the 0.8 s link timeout), and
   so must the host, which hears the board's heartbeat when it runs again. Without the rule the
   board declares the link lost the moment it runs again (2 s of silence).
2. Only the board stops for 2 s while the host keeps running: the host was there to see the
   silence, so it declares the link lost (per spec); the board, back, counts a stall, not a link
   loss of its own, and follows the host's new session (a peer reset).
"""

from __future__ import annotations

import json
import os
import select
import shutil
import signal
import socket
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from hwbridge.protocols.native import session as ns
from tests.netutil import free_port

SKETCH = Path(__file__).resolve().parents[2] / "tools" / "bench" / "SoakBoard"
STOP_S = 2.0
"""How long the board (and in case 1 the host) is stopped: 2.5 link timeouts."""

pytestmark = pytest.mark.skipif(
    shutil.which("g++") is None, reason="g++ is not installed (Debian package g++)"
)


@pytest.fixture(scope="module")
def program(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from hwbridge.firmware.build import build_host_sketch

    return build_host_sketch(SKETCH, tmp_path_factory.mktemp("stall_build"))


class Host:
    """A HostSession on a TCP connection to the board, pumped by the test."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        self.sock.setblocking(False)
        self.session = ns.HostSession(ns.HostConfig(time_sync_interval=0))
        self.events: list[Any] = []
        self.heard = 0
        """Bytes received from the board so far."""

    def step(self, wait: float = 0.02) -> None:
        readable, _, _ = select.select([self.sock], [], [], wait)
        data = b""
        if readable:
            try:
                data = self.sock.recv(65536)
            except BlockingIOError:
                data = b""
        now = time.monotonic()
        if data:
            self.heard += len(data)
            self.events += self.session.receive_data(data, now)
        self.events += self.session.tick(now)
        for chunk in self.session.chunks_to_send():
            self.sock.sendall(chunk)

    def run_until(self, condition: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.step()
            if condition():
                return True
        return False

    def run_for(self, seconds: float) -> None:
        until = time.monotonic() + seconds
        while time.monotonic() < until:
            self.step()

    def ended(self) -> list[str]:
        return [e.reason for e in self.events if isinstance(e, ns.Disconnected)]

    def close(self) -> None:
        self.sock.close()


class Board:
    """The SoakBoard program on ``listen://127.0.0.1:PORT`` (by default one best-effort topic
    at 20 Hz; ``settings`` overrides its SOAK_* environment, such as ``SOAK_RELIABLE``)."""

    def __init__(self, program: Path, port: int, **settings: str) -> None:
        env = dict(os.environ, SOAK_INDEX="7", SOAK_TOPICS="1", SOAK_RELIABLE="0", SOAK_RATE="20")
        env.update(settings)
        self.process = subprocess.Popen(
            [str(program), f"listen://127.0.0.1:{port}"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=env,
        )
        assert self.line() == f"listen://127.0.0.1:{port}"
        assert self.line() == "ready"

    def line(self) -> str:
        assert self.process.stdout is not None
        return self.process.stdout.readline().strip()

    def ask(self, command: str) -> str:
        assert self.process.stdin is not None
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()
        return self.line()

    def counts(self) -> dict[str, Any]:
        """The board's counters (SoakBoard's ``stop``; it keeps its session)."""
        answer: dict[str, Any] = json.loads(self.ask("stop"))["boards"]["b07"]
        return answer

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGCONT)
            self.process.kill()
        self.process.wait(10)
        for stream in (self.process.stdin, self.process.stdout):
            if stream is not None:
                stream.close()


@pytest.fixture
def board_and_host(program: Path) -> Iterator[tuple[Board, Host]]:
    port = free_port()
    board = Board(program, port)
    host = Host(port)
    try:
        assert host.run_until(lambda: host.session.connected, 20), host.events
        assert board.ask("go") == "going"
        host.run_for(0.3)
        yield board, host
    finally:
        host.close()
        board.close()


def test_a_board_that_did_not_run_does_not_declare_the_link_lost(
    board_and_host: tuple[Board, Host],
) -> None:
    board, host = board_and_host
    # 1. the machine stalls: neither end runs for STOP_S, then the board runs first
    board.process.send_signal(signal.SIGSTOP)
    time.sleep(STOP_S)  # the host is not pumped meanwhile: it is stopped too
    heard = host.heard
    board.process.send_signal(signal.SIGCONT)
    # the host runs again once the board has spoken (it ran its timers after the stop); only
    # then may the host's bytes reach it, so that they cannot hide the board's misjudging
    deadline = time.monotonic() + 20
    while host.heard == heard and time.monotonic() < deadline:
        readable, _, _ = select.select([host.sock], [], [], 0.05)
        if readable:
            host.step(0)
    assert host.heard > heard, "the board said nothing after SIGCONT"
    host.run_for(1.0)
    counts = board.counts()
    assert counts["link_losses"] == 0, counts
    assert counts["peer_resets"] == 0, counts
    assert counts["stalls"] >= 1, counts
    assert host.ended() == []
    assert host.session.connected
    assert host.session.stats.stalls >= 1

    # 2. only the board stops: the host, running, declares the link lost (per spec); the board
    # back counts a stall, no link loss of its own, and follows the host's new session
    assert board.ask("go") == "going"
    board.process.send_signal(signal.SIGSTOP)
    host.run_for(STOP_S)
    assert [r for r in host.ended() if r.startswith("link lost")], host.ended()
    board.process.send_signal(signal.SIGCONT)
    assert host.run_until(lambda: host.session.connected, 20), host.events
    host.run_for(0.3)
    counts = board.counts()
    assert counts["link_losses"] == 0, counts
    assert counts["peer_resets"] == 1, counts
    assert counts["stalls"] >= 2, counts
    assert counts["sessions"] == 2, counts
