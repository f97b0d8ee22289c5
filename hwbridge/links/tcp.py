"""TCP links: ``socket://HOST:PORT`` (connect to a board) and ``tcp-listen://HOST:PORT`` (let
WiFi boards connect to the host).

``tcp-listen`` semantics, which the bridge can rely on:

* ``open()`` binds and listens, and does not wait for a client. ``port=0`` binds a free port
  (see :attr:`TcpListenLink.bound_address`); a reopen binds the same port again.
* ``read()`` serves one client at a time. With no client it waits (up to ``timeout``) for one to
  connect, accepts it and goes on reading from it; it returns ``b""`` while nobody has connected.
* When the client disconnects (or its connection is reset), ``read()`` raises
  :class:`~hwbridge.links.base.LinkClosedError` once for that session, and the link stays open
  (``is_open`` stays True): the next ``read()`` waits for the next client. ``open()`` is not needed.
* A second connection while a client is connected is refused (closed at once) and logged, so
  nobody on the network can replace a working board. With ``takeover=1`` a new connection
  replaces the current client instead: for a board that reboots and leaves a half-open
  connection behind, whose new connection must win. The old session ends with
  ``LinkClosedError`` from ``read()``, then the next ``read()`` serves the new client.
* ``allow=NETWORK[,NETWORK...]`` (``192.168.4.0/24``, ``10.0.0.7``, ``::1``) accepts clients
  from those addresses only; others are refused and logged. Without it any address may connect
  (``tcp-listen://:PORT`` listens on every interface: use ``allow`` or a host address on a
  network you do not control).
* ``write()`` with no client connected raises ``LinkClosedError``; writes go to the current client.
* :attr:`TcpListenLink.connected` and :attr:`TcpListenLink.client_address` tell whether a client
  is connected now.
"""

from __future__ import annotations

import contextlib
import errno
import ipaddress
import logging
import selectors
import socket
import threading
from ipaddress import IPv4Network, IPv6Network
from typing import Any, Final
from urllib.parse import SplitResult, urlsplit

from hwbridge.errors import LinkError
from hwbridge.links._io import Deadline, write_all
from hwbridge.links.base import (
    COMMON_OPTIONS,
    Link,
    LinkClosedError,
    Waker,
    opt_bool,
    opt_int,
    opt_optional_float,
    parse_options,
    split_query,
)

__all__ = ["SocketLink", "TcpListenLink"]

log = logging.getLogger("hwbridge.links")

_CLOSED_ERRORS: Final = (ConnectionResetError, ConnectionAbortedError, BrokenPipeError)

_SOCKET_OPTIONS: Final = {
    **COMMON_OPTIONS,
    "connect_timeout": opt_optional_float,
    "nodelay": opt_bool,
    "keepalive": opt_bool,
}


def _text(value: Any) -> str:
    return str(value)


_LISTEN_OPTIONS: Final = {
    **COMMON_OPTIONS,
    "nodelay": opt_bool,
    "keepalive": opt_bool,
    "takeover": opt_bool,
    "backlog": opt_int,
    "allow": _text,
}


def _host_port(url: str, *, need_host: bool, example: str) -> tuple[str, int, SplitResult]:
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        raise LinkError(
            f"bad port in {url!r}: use a number from 0 to 65535, as in {example}"
        ) from None
    if port is None:
        raise LinkError(f"{url!r} has no port: write it as {example}")
    host = parts.hostname or ""
    if need_host and not host:
        raise LinkError(f"{url!r} has no host: write it as {example}")
    if parts.path not in ("", "/"):
        raise LinkError(f"{url!r} has a path ({parts.path!r}), which TCP links do not take")
    return host, port, parts


def _networks(value: str | None, url: str) -> tuple[IPv4Network | IPv6Network, ...]:
    """The ``allow`` option's networks; LinkError naming a bad one."""
    if not value:
        return ()
    networks = []
    for item in value.split(","):
        try:
            networks.append(ipaddress.ip_network(item.strip(), strict=False))
        except ValueError as exc:
            raise LinkError(
                f"{url}: allow={value}: {item.strip()!r} is not an address or network "
                "(e.g. 192.168.4.0/24)"
            ) from exc
    return tuple(networks)


def _allowed(host: str, networks: tuple[IPv4Network | IPv6Network, ...]) -> bool:
    address = ipaddress.ip_address(host.split("%", 1)[0])
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        address = address.ipv4_mapped
    return any(address in network for network in networks)


def _configure(sock: socket.socket, *, nodelay: bool, keepalive: bool) -> None:
    sock.setblocking(False)
    if nodelay:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    if keepalive:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)


def _address(addr: Any) -> str:
    host, port = addr[0], addr[1]
    return f"[{host}]:{port}" if ":" in str(host) else f"{host}:{port}"


class SocketLink(Link):
    """A TCP client: ``socket://HOST:PORT`` (TCP_NODELAY and keep-alive on by default).

    Options: ``connect_timeout`` (seconds, default 5), ``write_timeout``, ``nodelay``,
    ``keepalive``. The peer closing or resetting the connection ends it: ``read``/``write`` raise
    LinkClosedError and ``open()`` connects again.
    """

    scheme = "socket"

    def __init__(self, url: str, **options: Any) -> None:
        super().__init__(url)
        self.host, self.port, parts = _host_port(
            url, need_host=True, example="socket://HOST:PORT (socket://192.168.4.1:11411)"
        )
        opts = parse_options(url, _SOCKET_OPTIONS, split_query(parts.query, url), options)
        self.connect_timeout: float | None = opts.get("connect_timeout", 5.0)
        self.write_timeout: float | None = opts.get("write_timeout")
        self.nodelay: bool = opts.get("nodelay", True)
        self.keepalive: bool = opts.get("keepalive", True)
        self._sock: socket.socket | None = None
        self._waker: Waker | None = None
        self._selector: selectors.BaseSelector | None = None

    def _open(self) -> None:
        where = f"{self.host}:{self.port}"
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
        except ConnectionRefusedError as exc:
            raise LinkError(
                f"connection refused by {where} ({self.url}): nothing is listening on that port; "
                "check that the board or server is running and the port number is right"
            ) from exc
        except socket.gaierror as exc:
            raise LinkError(
                f"cannot resolve host {self.host!r} ({self.url}): {exc.strerror}; check the name "
                "or use an IP address"
            ) from exc
        except TimeoutError as exc:
            raise LinkError(
                f"no answer from {where} within {self.connect_timeout} s ({self.url}); check the "
                "address, that the board is on the network, or raise connect_timeout"
            ) from exc
        except OSError as exc:
            raise LinkError(
                f"cannot connect to {where} ({self.url}): {exc.strerror or exc}; check the "
                "address and the network"
            ) from exc
        try:
            _configure(sock, nodelay=self.nodelay, keepalive=self.keepalive)
        except OSError as exc:
            sock.close()
            raise LinkError(f"cannot set up the socket to {where}: {exc}") from exc
        self._sock = sock
        self._waker = Waker()
        self._selector = selectors.DefaultSelector()
        self._selector.register(sock, selectors.EVENT_READ)
        self._selector.register(self._waker, selectors.EVENT_READ)

    def _read(self, max_bytes: int, timeout: float | None) -> bytes:
        sock, waker, selector = self._parts()
        deadline = Deadline(timeout)
        while True:
            try:
                data = sock.recv(max_bytes)
            except (BlockingIOError, InterruptedError):
                pass
            except _CLOSED_ERRORS as exc:
                raise self._lost(f"connection reset ({exc.strerror or exc})") from exc
            except OSError as exc:  # e.g. ETIMEDOUT from keep-alive: the connection is dead
                raise self._lost(f"connection failed ({exc.strerror or exc})") from exc
            else:
                if not data:
                    raise self._lost("the peer closed the connection")
                return data
            if waker.woken or deadline.expired():
                return b""
            if not selector.select(deadline.remaining()) and deadline.expired():
                return b""

    def _write(self, data: memoryview) -> None:
        sock, waker, _ = self._parts()
        try:
            write_all(sock.send, sock, data, waker, self.write_timeout, self.url)
        except _CLOSED_ERRORS as exc:
            raise self._lost(f"connection reset while writing ({exc.strerror or exc})") from exc
        except OSError as exc:
            raise self._lost(f"connection failed while writing ({exc.strerror or exc})") from exc

    def _wake(self) -> None:
        if self._waker is not None:
            self._waker.wake()

    def _close(self) -> None:
        if self._selector is not None:
            self._selector.close()
        if self._waker is not None:
            self._waker.close()
        if self._sock is not None:
            self._sock.close()
        self._sock = self._waker = self._selector = None

    def _lost(self, what: str) -> LinkClosedError:
        return LinkClosedError(
            f"{self.url}: {what}; open() the link again to reconnect when the peer is back"
        )

    def _parts(self) -> tuple[socket.socket, Waker, selectors.BaseSelector]:
        if self._sock is None or self._waker is None or self._selector is None:
            raise LinkClosedError(f"{self.url} is not open", local=True)
        return self._sock, self._waker, self._selector


class TcpListenLink(Link):
    """A TCP listener serving one client at a time: ``tcp-listen://HOST:PORT``.

    ``tcp-listen://:11411`` listens on every IPv4 interface, ``tcp-listen://127.0.0.1:0`` on a free
    loopback port. Options: ``takeover`` (default 0), ``allow`` (source networks), ``nodelay``,
    ``keepalive``, ``backlog``, ``write_timeout``. See the module documentation for the session
    semantics.
    """

    scheme = "tcp-listen"

    def __init__(self, url: str, **options: Any) -> None:
        super().__init__(url)
        self.host, self.port, parts = _host_port(
            url,
            need_host=False,
            example="tcp-listen://:PORT (all interfaces) or tcp-listen://127.0.0.1:0 (a free port)",
        )
        opts = parse_options(url, _LISTEN_OPTIONS, split_query(parts.query, url), options)
        self.write_timeout: float | None = opts.get("write_timeout")
        self.nodelay: bool = opts.get("nodelay", True)
        self.keepalive: bool = opts.get("keepalive", True)
        self.takeover: bool = opts.get("takeover", False)
        self.allow = _networks(opts.get("allow"), url)
        """Source networks clients may connect from (empty: any)."""
        self.backlog: int = max(1, opts.get("backlog", 4))
        self._server: socket.socket | None = None
        self._client: socket.socket | None = None
        self._client_address: tuple[str, int] | None = None
        self._client_lock = threading.Lock()
        self._waker: Waker | None = None
        self._selector: selectors.BaseSelector | None = None
        self._bound: tuple[str, int] | None = None
        self._last_port: int | None = None

    @property
    def bound_address(self) -> tuple[str, int] | None:
        """``(host, port)`` the listener is bound to (the real port for ``port=0``); None when
        closed."""
        return self._bound

    @property
    def client_address(self) -> tuple[str, int] | None:
        """``(host, port)`` of the client being served, or None."""
        return self._client_address

    @property
    def connected(self) -> bool:
        """True while a client is connected."""
        return self.is_open and self._client is not None

    def _open(self) -> None:
        port = self.port
        if port == 0 and self._last_port is not None:
            port = self._last_port  # keep the address a client already knows across reopens
        try:
            server = self._bind(port)
        except OSError as exc:
            if port != self.port and exc.errno == errno.EADDRINUSE:
                log.warning("port %d is taken now; %s binds a new free port", port, self.url)
                server = self._bind_or_explain(self.port)
            else:
                raise self._bind_error(exc, port) from exc
        self._server = server
        host, bound_port = server.getsockname()[:2]
        self._bound = (str(host), int(bound_port))
        self._last_port = self._bound[1]
        self._waker = Waker()
        self._selector = selectors.DefaultSelector()
        self._selector.register(server, selectors.EVENT_READ)
        self._selector.register(self._waker, selectors.EVENT_READ)
        log.info("%s listening on %s", self.url, _address(self._bound))

    def _bind(self, port: int) -> socket.socket:
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        server = socket.create_server((self.host, port), family=family, backlog=self.backlog)
        server.setblocking(False)
        return server

    def _bind_or_explain(self, port: int) -> socket.socket:
        try:
            return self._bind(port)
        except OSError as exc:
            raise self._bind_error(exc, port) from exc

    def _bind_error(self, exc: OSError, port: int) -> LinkError:
        where = _address((self.host or "*", port))
        if exc.errno == errno.EADDRINUSE:
            todo = "another program (another hwbridge?) listens there; stop it or pick another port"
        elif exc.errno == errno.EACCES:
            todo = "ports below 1024 need privileges; use a port of 1024 or more"
        elif exc.errno == errno.EADDRNOTAVAIL:
            todo = f"{self.host} is not an address of this machine; use :PORT for all interfaces"
        else:
            todo = "check the address"
        return LinkError(f"cannot listen on {where} ({self.url}): {exc.strerror or exc}; {todo}")

    def _read(self, max_bytes: int, timeout: float | None) -> bytes:
        server, waker, selector = self._parts()
        deadline = Deadline(timeout)
        while True:
            client = self._client
            if client is not None:
                data = self._recv(client, max_bytes)
                if data:
                    return data
            if waker.woken:
                return b""
            ready = {key.fileobj for key, _ in selector.select(deadline.remaining())}
            if waker in ready:
                return b""
            if server in ready:
                self._accept(server)
            elif not ready and deadline.expired():
                return b""

    def _recv(self, client: socket.socket, max_bytes: int) -> bytes:
        try:
            data = client.recv(max_bytes)
        except (BlockingIOError, InterruptedError):
            return b""
        except _CLOSED_ERRORS as exc:
            address = self._drop_client()
            raise LinkClosedError(
                f"client {address} of {self.url} reset the connection ({exc.strerror or exc}); "
                "waiting for the next client"
            ) from exc
        except OSError as exc:
            address = self._drop_client()
            raise LinkClosedError(
                f"reading from client {address} of {self.url} failed ({exc}); dropped it"
            ) from exc
        if not data:
            address = self._drop_client()
            raise LinkClosedError(
                f"client {address} disconnected from {self.url}; waiting for the next client"
            )
        return data

    def _accept(self, server: socket.socket) -> None:
        try:
            sock, addr = server.accept()
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:  # e.g. ECONNABORTED, EMFILE: keep listening
            log.warning("%s failed to accept a connection: %s", self.url, exc)
            return
        if self.allow and not _allowed(addr[0], self.allow):
            log.warning(
                "%s refused a connection from %s: not in allow=%s",
                self.url,
                _address(addr),
                ",".join(map(str, self.allow)),
            )
            sock.close()
            return
        if self._client is not None and not self.takeover:
            log.warning(
                "%s refused a second connection from %s while %s is connected (add "
                "?takeover=1 to the URL if a new connection should replace the board's, as "
                "after a reboot)",
                self.url,
                _address(addr),
                _address(self._client_address) if self._client_address else "a client",
            )
            sock.close()
            return
        try:
            _configure(sock, nodelay=self.nodelay, keepalive=self.keepalive)
        except OSError as exc:
            log.warning("%s dropped the client %s: %s", self.url, _address(addr), exc)
            sock.close()
            return
        old_address = self._drop_client() if self._client is not None else None
        self._install_client(sock, (str(addr[0]), int(addr[1])))
        log.info("%s: client %s connected", self.url, _address(addr))
        if old_address is not None:
            raise LinkClosedError(
                f"client {old_address} of {self.url} was replaced by a new connection from "
                f"{_address(addr)} (takeover); the next read serves the new client"
            )

    def _install_client(self, sock: socket.socket, address: tuple[str, int]) -> None:
        _, _, selector = self._parts()
        with self._client_lock:
            self._client = sock
            self._client_address = address
        selector.register(sock, selectors.EVENT_READ)

    def _drop_client(self) -> str:
        """Forget the client and close its socket (reader thread); returns its address."""
        with self._client_lock:
            client, address = self._client, self._client_address
            self._client = self._client_address = None
        if client is None:
            return "?"
        if self._selector is not None:
            self._selector.unregister(client)
        with contextlib.suppress(OSError):  # makes a writer blocked on this socket return
            client.shutdown(socket.SHUT_RDWR)
        with self._write_lock:  # no writer uses the socket once we hold this
            client.close()
        text = _address(address) if address else "?"
        log.info("%s: client %s gone", self.url, text)
        return text

    def _write(self, data: memoryview) -> None:
        _, waker, _ = self._parts()
        with self._client_lock:
            client, address = self._client, self._client_address
        if client is None:
            raise LinkClosedError(
                f"no client is connected to {self.url} (listening on "
                f"{_address(self._bound or ('?', 0))}); wait until one connects"
            )
        try:
            write_all(client.send, client, data, waker, self.write_timeout, self.url)
        except _CLOSED_ERRORS as exc:
            raise LinkClosedError(
                f"client {_address(address or ('?', 0))} of {self.url} went away while writing "
                f"({exc.strerror or exc})"
            ) from exc
        except OSError as exc:
            raise LinkError(f"write to client of {self.url} failed: {exc}") from exc

    def _survives_peer_loss(self) -> bool:
        return True

    def _wake(self) -> None:
        if self._waker is not None:
            self._waker.wake()

    def _close(self) -> None:
        with self._client_lock:
            client = self._client
            self._client = self._client_address = None
        if client is not None:
            client.close()
        if self._selector is not None:
            self._selector.close()
        if self._waker is not None:
            self._waker.close()
        if self._server is not None:
            self._server.close()
        self._server = self._waker = self._selector = None
        self._bound = None

    def _parts(self) -> tuple[socket.socket, Waker, selectors.BaseSelector]:
        if self._server is None or self._waker is None or self._selector is None:
            raise LinkClosedError(f"{self.url} is not open", local=True)
        return self._server, self._waker, self._selector
