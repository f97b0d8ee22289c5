"""A small ROS 1 client in pure Python: the master and slave XML-RPC APIs and TCPROS.

Enough for a gateway that moves serialized bytes: publications and subscriptions of any type
(the md5 and type travel in the connection header, the bytes are never decoded), service servers
and calls, parameters. Facts from the ROS 1 wiki pages "ROS/Master_API", "ROS/Slave_API",
"ROS/TCPROS" and "ROS/Connection Header".

Every XML-RPC call to the master goes through :class:`MasterProxy`, which raises
:class:`MasterDown` when the master cannot be reached, so the gateway can wait and register again.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import struct
import threading
import xmlrpc.client
from collections.abc import Callable
from socketserver import ThreadingMixIn
from typing import Any, Final
from urllib.parse import urlparse
from xmlrpc.server import SimpleXMLRPCRequestHandler, SimpleXMLRPCServer

from hwbridge.errors import HwBridgeError

__all__ = [
    "MasterDown",
    "MasterProxy",
    "SlaveServer",
    "TcprosError",
    "call_service",
    "encode_header",
    "local_host",
    "probe_service",
    "read_frame",
    "read_header",
]

log = logging.getLogger("hwbridge.gateway.ros1")

_LEN: Final = struct.Struct("<I")
MAX_FRAME: Final = 256 * 1024 * 1024
"""A length prefix above this is taken as a broken stream, not a message."""


class TcprosError(HwBridgeError):
    """A TCPROS peer refused a connection or broke the protocol."""


class MasterDown(HwBridgeError):
    """The ROS master cannot be reached."""


# ---------------------------------------------------------------------- framing
def encode_header(fields: dict[str, str]) -> bytes:
    """A connection header: length-prefixed ``key=value`` fields, the whole length-prefixed."""
    body = b"".join(
        _LEN.pack(len(item)) + item
        for item in (f"{key}={value}".encode() for key, value in fields.items())
    )
    return _LEN.pack(len(body)) + body


def _read_exactly(sock: socket.socket, size: int) -> bytes:
    chunks: list[bytes] = []
    left = size
    while left:
        chunk = sock.recv(min(left, 1 << 20))
        if not chunk:
            raise ConnectionError("connection closed by the peer")
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


def read_frame(sock: socket.socket) -> bytes:
    """One length-prefixed block (a header or a message)."""
    (size,) = _LEN.unpack(_read_exactly(sock, 4))
    if size > MAX_FRAME:
        raise TcprosError(f"a TCPROS block of {size} bytes: the stream is broken")
    return _read_exactly(sock, size)


def parse_header(data: bytes) -> dict[str, str]:
    fields: dict[str, str] = {}
    pos = 0
    while pos + 4 <= len(data):
        (size,) = _LEN.unpack_from(data, pos)
        pos += 4
        key, _, value = data[pos : pos + size].decode("utf-8", "replace").partition("=")
        fields[key] = value
        pos += size
    return fields


def read_header(sock: socket.socket) -> dict[str, str]:
    return parse_header(read_frame(sock))


def send_frame(sock: socket.socket, data: bytes) -> None:
    sock.sendall(_LEN.pack(len(data)) + data)


# ---------------------------------------------------------------------- addresses
def local_host(master_uri: str) -> str:
    """The host name other ROS nodes reach this process by: ROS_IP, ROS_HOSTNAME, loopback
    for a master on this machine, else this machine's name."""
    for name in ("ROS_IP", "ROS_HOSTNAME"):
        value = os.environ.get(name)
        if value:
            return value
    host = urlparse(master_uri).hostname or "localhost"
    if host in ("localhost", "::1") or host.startswith("127."):
        return "127.0.0.1"
    return socket.gethostname()


def _bind_host(host: str) -> str:
    return "127.0.0.1" if host.startswith("127.") else "0.0.0.0"


class _Transport(xmlrpc.client.Transport):
    def __init__(self, timeout: float) -> None:
        super().__init__()
        self._timeout = timeout

    def make_connection(self, host: Any) -> Any:
        connection = super().make_connection(host)
        connection.timeout = self._timeout
        return connection


def xmlrpc_proxy(uri: str, timeout: float = 3.0) -> xmlrpc.client.ServerProxy:
    return xmlrpc.client.ServerProxy(uri, transport=_Transport(timeout), allow_none=False)


class MasterProxy:
    """Calls to the master's XML-RPC API; :class:`MasterDown` when it does not answer."""

    def __init__(self, uri: str, caller_id: str, timeout: float = 3.0) -> None:
        self.uri = uri
        self.caller_id = caller_id
        self.timeout = timeout

    def call(self, method: str, *args: Any) -> Any:
        """``method(caller_id, *args)``; the value of a successful ``[code, text, value]``."""
        proxy = xmlrpc_proxy(self.uri, self.timeout)
        try:
            code, text, value = getattr(proxy, method)(self.caller_id, *args)
        except (OSError, xmlrpc.client.ProtocolError, xmlrpc.client.Fault) as exc:
            raise MasterDown(f"ROS master {self.uri} does not answer: {exc}") from exc
        if code != 1:
            raise HwBridgeError(f"ROS master {self.uri}: {method} failed: {text}")
        return value


# ---------------------------------------------------------------------- slave API
_SHUTDOWN_POLL: Final = 0.05
"""Seconds between the XML-RPC server's checks for shutdown."""
_CLOSE_WAIT: Final = 0.5
"""Longest wait for one of the slave server's threads to end on close."""


class _Server(ThreadingMixIn, SimpleXMLRPCServer):
    daemon_threads = True


class _Quiet(SimpleXMLRPCRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:
        pass


class SlaveServer:
    """The node's XML-RPC API (what the master and other nodes call) and its TCPROS listener.

    ``requestTopic`` answers with the TCPROS listener for topics in ``publications``;
    ``publisherUpdate`` and ``paramUpdate`` go to the callbacks.
    """

    def __init__(
        self,
        host: str,
        master_uri: str,
        publications: Callable[[], list[list[str]]],
        subscriptions: Callable[[], list[list[str]]],
        on_publisher_update: Callable[[str, list[str]], None],
        on_param_update: Callable[[str, Any], None],
        on_tcpros: Callable[[socket.socket, dict[str, str]], None],
    ) -> None:
        self.host = host
        self.master_uri = master_uri
        self._publications = publications
        self._subscriptions = subscriptions
        self._on_publisher_update = on_publisher_update
        self._on_param_update = on_param_update
        self._on_tcpros = on_tcpros
        bind = _bind_host(host)
        self._xmlrpc = _Server((bind, 0), requestHandler=_Quiet, logRequests=False)
        self._xmlrpc.register_instance(self)
        self.uri = f"http://{host}:{self._xmlrpc.server_address[1]}/"
        self._listener = socket.create_server((bind, 0))
        self.tcpros_port: int = self._listener.getsockname()[1]
        self._closed = False
        self._started = False
        self._threads = [
            threading.Thread(target=self._serve_xmlrpc, name="ros1-xmlrpc", daemon=True),
            threading.Thread(target=self._accept, name="ros1-tcpros", daemon=True),
        ]

    def start(self) -> SlaveServer:
        self._started = True
        for thread in self._threads:
            thread.start()
        return self

    def _serve_xmlrpc(self) -> None:
        # socketserver polls for shutdown every 0.5 s by default: too slow for Ctrl-C's 2 s.
        self._xmlrpc.serve_forever(poll_interval=_SHUTDOWN_POLL)

    def close(self) -> None:
        """Stop serving (returns within about a poll interval; every wait is bounded)."""
        if self._closed:
            return
        self._closed = True
        if self._started:
            # shutdown() waits for serve_forever to notice; never called before start(), whose
            # serve_forever would not have begun (it would then wait for ever).
            stopper = threading.Thread(target=self._xmlrpc.shutdown, daemon=True)
            stopper.start()
            stopper.join(_CLOSE_WAIT)
        self._xmlrpc.server_close()
        with contextlib.suppress(OSError):
            self._listener.shutdown(socket.SHUT_RDWR)
        self._listener.close()
        for thread in self._threads:
            if thread.is_alive():
                thread.join(_CLOSE_WAIT)

    def _accept(self) -> None:
        while not self._closed:
            try:
                conn, _ = self._listener.accept()
            except OSError:
                return
            threading.Thread(
                target=self._serve_connection, args=(conn,), name="ros1-conn", daemon=True
            ).start()

    def _serve_connection(self, conn: socket.socket) -> None:
        try:
            conn.settimeout(10)
            header = read_header(conn)
            conn.settimeout(None)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._on_tcpros(conn, header)
        except (OSError, HwBridgeError) as exc:
            log.debug("TCPROS connection dropped: %s", exc)
            with contextlib.suppress(OSError):
                conn.close()

    # The slave API (names as ROS defines them).
    def getBusStats(self, _caller: str) -> list[Any]:
        return [1, "", [[], [], []]]

    def getBusInfo(self, _caller: str) -> list[Any]:
        return [1, "", []]

    def getMasterUri(self, _caller: str) -> list[Any]:
        return [1, "", self.master_uri]

    def shutdown(self, _caller: str, _reason: str = "") -> list[Any]:
        return [1, "", 0]  # the gateway stops on its own signal, not on a remote request

    def getPid(self, _caller: str) -> list[Any]:
        return [1, "", os.getpid()]

    def getSubscriptions(self, _caller: str) -> list[Any]:
        return [1, "", self._subscriptions()]

    def getPublications(self, _caller: str) -> list[Any]:
        return [1, "", self._publications()]

    def paramUpdate(self, _caller: str, key: str, value: Any) -> list[Any]:
        self._on_param_update(key, value)
        return [1, "", 0]

    def publisherUpdate(self, _caller: str, topic: str, publishers: list[str]) -> list[Any]:
        self._on_publisher_update(topic, list(publishers))
        return [1, "", 0]

    def requestTopic(self, _caller: str, topic: str, protocols: list[Any]) -> list[Any]:
        if not any(p and p[0] == "TCPROS" for p in protocols):
            return [0, "only TCPROS is supported", []]
        if topic not in {t for t, _ in self._publications()}:
            return [0, f"not a publisher of {topic}", []]
        return [1, "", ["TCPROS", self.host, self.tcpros_port]]


# ---------------------------------------------------------------------- service calls
def _service_socket(uri: str, timeout: float) -> socket.socket:
    parsed = urlparse(uri)  # rosrpc://host:port
    if parsed.hostname is None or parsed.port is None:
        raise TcprosError(f"bad service URI {uri!r}")
    sock = socket.create_connection((parsed.hostname, parsed.port), timeout=timeout)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def probe_service(uri: str, service: str, caller_id: str, timeout: float = 3.0) -> dict[str, str]:
    """The header a service server answers a probe with (``type``, ``md5sum``)."""
    with _service_socket(uri, timeout) as sock:
        sock.sendall(
            encode_header({"callerid": caller_id, "service": service, "md5sum": "*", "probe": "1"})
        )
        header = read_header(sock)
    if "error" in header:
        raise TcprosError(f"service {service}: {header['error']}")
    return header


def call_service(
    uri: str, service: str, md5: str, request: bytes, caller_id: str, timeout: float = 5.0
) -> bytes:
    """One call: request bytes in, response bytes out; TcprosError if the server refuses."""
    with _service_socket(uri, timeout) as sock:
        sock.sendall(
            encode_header(
                {"callerid": caller_id, "service": service, "md5sum": md5, "persistent": "0"}
            )
        )
        header = read_header(sock)
        if "error" in header:
            raise TcprosError(f"service {service}: {header['error']}")
        send_frame(sock, request)
        ok = _read_exactly(sock, 1)
        body = read_frame(sock)
    if ok != b"\x01":
        raise TcprosError(f"service {service} failed: {body.decode('utf-8', 'replace')}")
    return body
