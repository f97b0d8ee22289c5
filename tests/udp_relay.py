"""A lossy UDP relay between a board and the bridge: drops and duplicates datagrams (seeded).

The board sends to :attr:`UdpRelay.port` (127.0.0.1); the relay forwards from a socket of its
own to ``upstream`` (the bridge's ``udp-listen://`` port) and sends what comes back to the
board's address, the last one it heard from. In each direction a datagram is dropped with
probability ``drop``, else sent twice with probability ``duplicate``, else sent once; the
decisions come from one ``random.Random(seed)``. With :attr:`blackhole` set, nothing passes
(a bridge that crashed says nothing more to the board). One thread; :meth:`close` stops it.
"""

from __future__ import annotations

import random
import selectors
import socket
import threading
from dataclasses import dataclass, field


@dataclass
class Direction:
    """What the relay did with the datagrams of one direction."""

    received: int = 0
    dropped: int = 0
    duplicated: int = 0
    sent: int = 0
    lost_sends: list[str] = field(default_factory=list)


class UdpRelay:
    """See the module docstring."""

    def __init__(
        self,
        upstream: tuple[str, int],
        *,
        drop: float = 0.0,
        duplicate: float = 0.0,
        seed: int = 1,
    ) -> None:
        self.upstream = upstream
        self.drop = drop
        self.duplicate = duplicate
        self.blackhole = False
        self.to_bridge = Direction()
        self.to_board = Direction()
        self._rng = random.Random(seed)
        self._board: tuple[str, int] | None = None
        self._down = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the board's side
        self._down.bind(("127.0.0.1", 0))
        self._up = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the bridge's side
        self._up.bind(("127.0.0.1", 0))
        self.port = int(self._down.getsockname()[1])
        self._wake_r, self._wake_w = socket.socketpair()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="udp-relay", daemon=True)
        self._thread.start()

    def _forward(self, data: bytes, sock: socket.socket, to: tuple[str, int], d: Direction) -> None:
        d.received += 1
        roll = self._rng.random()
        if self.blackhole or roll < self.drop:
            d.dropped += 1
            return
        copies = 2 if roll < self.drop + self.duplicate else 1
        d.duplicated += copies - 1
        for _ in range(copies):
            try:
                sock.sendto(data, to)
                d.sent += 1
            except OSError as exc:  # nobody listening (the bridge is restarting): lost, as UDP
                d.lost_sends.append(str(exc))

    def _receive(self, sock: socket.socket) -> tuple[bytes, tuple[str, int]] | None:
        try:
            data, address = sock.recvfrom(65535)
        except (BlockingIOError, ConnectionRefusedError):
            return None  # an ICMP error for an earlier send: no datagram
        return data, (str(address[0]), int(address[1]))

    def _run(self) -> None:
        with selectors.DefaultSelector() as selector:
            for sock in (self._down, self._up, self._wake_r):
                sock.setblocking(False)
                selector.register(sock, selectors.EVENT_READ)
            while not self._stop.is_set():
                for key, _ in selector.select(1.0):
                    if key.fileobj is self._wake_r:
                        continue
                    while (
                        got := self._receive(self._down if key.fileobj is self._down else self._up)
                    ) is not None:
                        data, address = got
                        if key.fileobj is self._down:
                            self._board = address
                            self._forward(data, self._up, self.upstream, self.to_bridge)
                        elif address == self.upstream and self._board is not None:
                            self._forward(data, self._down, self._board, self.to_board)

    def close(self) -> None:
        self._stop.set()
        self._wake_w.send(b"x")
        self._thread.join(5)
        for sock in (self._down, self._up, self._wake_r, self._wake_w):
            sock.close()
