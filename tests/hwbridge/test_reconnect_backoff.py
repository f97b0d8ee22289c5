"""Two clients of one TCP board that kick each other off: the bridge backs off and says why,
instead of reconnecting thousands of times a second (issue 19 item 5)."""

from __future__ import annotations

import logging
import socket
import threading
import time

import pytest

from hwbridge.bridge import BoardSpec, Bridge
from hwbridge.graph import Graph
from tests.netutil import free_port, wait_until


class KickingServer:
    """A WiFi serial bridge that serves one client: a new connection closes the older one."""

    def __init__(self) -> None:
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.accepted: list[tuple[str, int]] = []
        self._current: socket.socket | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self.sock.settimeout(0.1)
        while not self._stop.is_set():
            try:
                client, address = self.sock.accept()
            except TimeoutError:
                continue
            self.accepted.append(address[:2])
            if self._current is not None:
                self._current.close()
            self._current = client

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.sock.close()
        if self._current is not None:
            self._current.close()


def test_a_fight_over_a_tcp_board_backs_off_and_is_explained(
    caplog: pytest.LogCaptureFixture,
) -> None:
    server = KickingServer()
    stop = threading.Event()
    rival_ports: set[int] = set()

    def rival() -> None:  # another program that reconnects at once whenever it is kicked off
        while not stop.is_set():
            with socket.create_connection(("127.0.0.1", server.port)) as sock:
                rival_ports.add(sock.getsockname()[1])
                sock.settimeout(0.5)
                try:
                    while not stop.is_set() and sock.recv(100):
                        pass
                except OSError:
                    pass

    thread = threading.Thread(target=rival, daemon=True)
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="fight")
    bridge = Bridge(graph)
    caplog.set_level(logging.WARNING, logger="hwbridge.board")
    try:
        thread.start()
        bridge.add_board(
            BoardSpec(f"socket://127.0.0.1:{server.port}", protocol="native", name="esp")
        )
        assert wait_until(
            lambda: any(
                "keeps closing right after it opens" in r.getMessage() for r in caplog.records
            ),
            15,
        ), [r.getMessage() for r in caplog.records]
        time.sleep(3.0)
        ours = [a for a in server.accepted if a[1] not in rival_ports]
        # With backoff the bridge reconnects a handful of times in these seconds (0.2, 0.4,
        # 0.8 ... s apart); without it, hundreds to thousands of times.
        assert len(ours) < 40, len(ours)
    finally:
        stop.set()
        bridge.stop()
        graph.close()
        server.close()
        thread.join(3)
