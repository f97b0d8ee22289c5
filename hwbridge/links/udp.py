"""UDP links: datagram links for boards on a network (an ESP32, a board behind a gateway).

A datagram link carries whole frames: each :meth:`~hwbridge.links.Link.read` returns exactly one
datagram and each :meth:`~hwbridge.links.Link.write` sends one, so the protocol uses its datagram
framing (no COBS, no delimiters: PROTOCOL.md, Part 1) and no protocol detection is attempted.

* ``udp://HOST:PORT``: the board listens at HOST:PORT; the host sends there from a port of its
  own and takes datagrams from that address only.
* ``udp-listen://[HOST]:PORT``: the host listens; the board sends first, and its address is
  where the host's datagrams go. Until a board is heard, ``connected`` is False. The link keeps
  to one board: while the board it follows was heard within :data:`PEER_HOLD`, datagrams from
  other addresses are dropped (counted in ``transport_stats()["udp"]["foreign_datagrams"]``,
  each new address logged once); after that silence the next address heard is the board (a
  board that rebooted onto another port, a bridge that restarted). A board with
  ``UdpHardware`` and no host configured finds this link by broadcasting its HELLOs to the
  port (PROTOCOL.md 1.14): the answer comes from here.

UDP has no connection: a board that goes away is noticed by the protocol's own timeouts.
"""

from __future__ import annotations

import logging
import selectors
import socket
import time
from typing import Any, ClassVar, Final
from urllib.parse import urlsplit

from hwbridge.errors import LinkError
from hwbridge.links._io import Deadline
from hwbridge.links.base import Link, LinkClosedError, Waker

__all__ = ["MAX_DATAGRAM", "PEER_HOLD", "UdpLink", "UdpListenLink"]

log = logging.getLogger(__name__)

MAX_DATAGRAM: Final = 65507
"""The largest UDP payload over IPv4."""
PEER_HOLD: Final = 1.0
"""Seconds a ``udp-listen://`` link keeps to the board it follows after last hearing it (a
board's heartbeats come every 0.1 s, its HELLOs at most 0.25 s apart; its link timeout is 0.8 s)."""


def _host_port(url: str, *, need_host: bool, example: str) -> tuple[str, int]:
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError as exc:
        raise LinkError(f"{url}: the port must be a number 0-65535, as in {example}") from exc
    host = parts.hostname or ""
    if port is None or (need_host and not host):
        raise LinkError(f"{url}: give a host and a port, as in {example}")
    return host, port


class _UdpBase(Link):
    datagram: ClassVar[bool] = True

    def __init__(self, url: str) -> None:
        super().__init__(url)
        self._sock: socket.socket | None = None
        self._waker: Waker | None = None
        self._selector: selectors.BaseSelector | None = None
        self._peer: tuple[str, int] | None = None

    def _setup(self, sock: socket.socket) -> None:
        sock.setblocking(False)
        self._sock = sock
        self._waker = Waker()
        self._selector = selectors.DefaultSelector()
        self._selector.register(sock, selectors.EVENT_READ)
        self._selector.register(self._waker, selectors.EVENT_READ)

    def _accept_from(self, address: tuple[str, int]) -> bool:
        """True if a datagram from ``address`` is for this link (and note the peer)."""
        raise NotImplementedError

    def _read(self, max_bytes: int, timeout: float | None) -> bytes:
        sock, waker, selector = self._sock, self._waker, self._selector
        if sock is None or waker is None or selector is None:
            raise LinkClosedError(f"{self.url} is closed", local=True)
        deadline = Deadline(timeout)
        while True:
            try:
                data, address = sock.recvfrom(max(max_bytes, MAX_DATAGRAM))
            except (BlockingIOError, InterruptedError):
                pass
            except ConnectionRefusedError:
                pass  # an ICMP "port unreachable" for an earlier send: nobody there yet
            except OSError as exc:
                raise LinkError(f"receive on {self.url} failed: {exc.strerror or exc}") from exc
            else:
                if data and self._accept_from(address[:2]):
                    return data[:max_bytes]
                continue
            if waker.woken or deadline.expired():
                return b""
            if not selector.select(deadline.remaining()) and deadline.expired():
                return b""

    def _write(self, data: memoryview) -> None:
        sock, peer = self._sock, self._peer
        if sock is None:
            raise LinkClosedError(f"{self.url} is closed", local=True)
        if peer is None:
            raise LinkClosedError(f"{self.url}: no board has sent anything yet")
        if len(data) > MAX_DATAGRAM:
            raise LinkError(
                f"{self.url}: a datagram of {len(data)} bytes is over UDP's {MAX_DATAGRAM}"
            )
        try:
            sock.sendto(data, peer)
        except (BlockingIOError, ConnectionRefusedError):
            pass  # lost, as UDP may lose any datagram; the protocol resends what matters
        except OSError as exc:
            raise LinkError(f"send on {self.url} failed: {exc.strerror or exc}") from exc

    def _survives_peer_loss(self) -> bool:
        return True  # no connection to lose: writing before a board is heard just fails

    def _wake(self) -> None:
        if self._waker is not None:
            self._waker.wake()

    def _close(self) -> None:
        if self._selector is not None:
            self._selector.close()
        if self._sock is not None:
            self._sock.close()
        if self._waker is not None:
            self._waker.close()
        self._sock = self._waker = self._selector = None


class UdpLink(_UdpBase):
    """``udp://HOST:PORT``: a board listening at HOST:PORT (see the module docstring)."""

    scheme = "udp"

    def __init__(self, url: str, **_options: Any) -> None:
        super().__init__(url)
        self.host, self.port = _host_port(url, need_host=True, example="udp://192.168.4.1:2324")

    def _open(self) -> None:
        try:
            infos = socket.getaddrinfo(self.host, self.port, socket.AF_INET, socket.SOCK_DGRAM)
        except socket.gaierror as exc:
            raise LinkError(f"cannot resolve host {self.host!r} ({self.url}): {exc}") from exc
        address = infos[0][4]
        self._peer = (str(address[0]), int(address[1]))
        self._setup(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))

    def _accept_from(self, address: tuple[str, int]) -> bool:
        return address == self._peer


class UdpListenLink(_UdpBase):
    """``udp-listen://[HOST]:PORT``: waits for a board to send (see the module docstring)."""

    scheme = "udp-listen"

    def __init__(self, url: str, **_options: Any) -> None:
        super().__init__(url)
        self.host, self.port = _host_port(url, need_host=False, example="udp-listen://:2324")
        self._heard = 0.0
        self._foreign = 0
        self._foreign_seen: set[tuple[str, int]] = set()

    @property
    def connected(self) -> bool:
        return self.is_open and self._peer is not None

    def transport_stats(self) -> dict[str, Any]:
        return {"udp": {"board": self._peer_text(), "foreign_datagrams": self._foreign}}

    def _peer_text(self) -> str | None:
        peer = self._peer
        return f"{peer[0]}:{peer[1]}" if peer is not None else None

    def _open(self) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((self.host or "0.0.0.0", self.port))
        except OSError as exc:
            sock.close()
            raise LinkError(
                f"cannot listen on UDP port {self.port} ({self.url}): {exc.strerror or exc}"
            ) from exc
        self._peer = None
        self._setup(sock)

    def _accept_from(self, address: tuple[str, int]) -> bool:
        now = time.monotonic()
        if address != self._peer:
            if self._peer is not None and now - self._heard < PEER_HOLD:
                self._foreign += 1
                if address not in self._foreign_seen and len(self._foreign_seen) < 64:
                    self._foreign_seen.add(address)
                    log.warning(
                        "%s: datagrams from %s:%d dropped while the board at %s is heard "
                        "(one board per udp-listen port; a board that rebooted onto a new "
                        "port is taken after %.1f s of silence)",
                        self.url,
                        address[0],
                        address[1],
                        self._peer_text(),
                        PEER_HOLD,
                    )
                return False
            if self._peer is not None:
                log.info("%s: the board is now at %s:%d", self.url, address[0], address[1])
            self._peer = address
        self._heard = now
        return True
