"""CAN links: many boards on one CAN bus through python-can (``pip install hwbridge[can]``).

``can://INTERFACE/CHANNEL/nodeN`` (or ``?node=N``) is the datagram link to the board with node
id N (1..127) on a python-can bus; every link of this process on the same bus shares one
python-can ``Bus`` (one adapter, one socket), so eight boards are eight links and eight sessions,
each on the graph under its own name (``nodeN`` unless named)::

    can://virtual/bench/node3                       python-can's in-process virtual bus
    can://udp_multicast/239.74.163.2/node3          python-can's bus over IP multicast
    can://slcan/dev/ttyACM0/node3?bitrate=1000000   a serial adapter (CANable, ...) speaking SLCAN
    can://socketcan/can0/node3?fd=1                 a Linux SocketCAN interface, CAN FD

Each datagram the session writes travels as one CAN transfer (``protocols/can/CAN.md``): the
id carries priority, kind, channel and the node ids, the tail byte sequences the frames. In
format 2 (CAN.md version 2, the default) the native header rides in the id and the tail byte and
the native CRC-16 stays home (CAN's own CRC covers a frame, the transfer CRC a multi-frame
transfer); each end speaks to a peer the format of the last claim it heard from that peer, so a
board with format-1 firmware is spoken to in format 1 (logged once). The best-effort fragments
of one message go as one chained transfer (CAN.md version 3, §12: one transfer CRC, frames
filled end to end) to a peer whose claims say it takes chains.
Frames go out by priority (first come, first served within one): ACKs and control traffic
overtake topic data when the bus is saturated, and best-effort data past ``tx_queue`` frames is
dropped (counted). Error frames, send failures (bus-off) and the recovery are counted and
logged; a bus that fails to read (an adapter unplugged) makes every link on it lost, and the
bridge reopens them. Options:

* ``node`` (the board, 1..127), ``local`` (this end's node id, default 0: the host);
* ``fd`` (CAN FD frames of up to 64 bytes), ``bitrate``, ``data_bitrate``;
* ``sleep_after_open`` (slcan: seconds to wait after opening the port), ``port`` (udp_multicast);
* ``pace`` (bits/s: space the frames this end sends as a bus of that rate would; 0 = no);
* ``tx_queue`` (frames waiting to be sent, 1024), ``rx_queue`` (datagrams per board, 256),
  ``transfer_timeout`` (seconds a transfer may take, 1.0);
* ``can_format`` (2; 1 makes this end a CAN.md version-1 node: format 1 only, format-2 frames
  dropped as malformed, as software that predates format 2 does);
* ``can_chain`` (1; 0 makes this end a CAN.md version-2 node: it neither sends nor takes chained
  transfers, and drops chained frames as malformed).
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import logging
import os
import re
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any, ClassVar, Final
from urllib.parse import urlsplit

from hwbridge.errors import LinkError
from hwbridge.links.base import (
    COMMON_OPTIONS,
    Link,
    LinkClosedError,
    opt_bool,
    opt_float,
    opt_int,
    parse_options,
    split_query,
)
from hwbridge.protocols.can.transport import (
    CLASSIC_MTU,
    FD_MTU,
    FORMAT_1,
    FORMAT_2,
    HOST_NODE,
    MAX_NODE,
    MIN_NODE,
    NODE_CLAIM,
    PRIORITY_RELIABLE,
    UID_SIZE,
    ConflictMonitor,
    Kind,
    TransferDecoder,
    TransferEncoder,
    queue_class,
)

__all__ = ["CLAIM_INTERVAL", "CanHub", "CanLink", "HubStats", "frame_bits"]

log = logging.getLogger("hwbridge.links.can")

CLAIM_INTERVAL: Final = 1.0
"""Seconds between two node-id claims of one end."""
_RECOVERY_DELAY: Final = 0.05
"""Seconds a sender waits after a failed send before trying the next frame (bus-off)."""
_NODE_SEGMENT: Final = re.compile(r"^node(\d+)$", re.IGNORECASE)
_WINDOWS_PORT: Final = re.compile(r"^COM\d+$", re.IGNORECASE)

_OPTIONS: Final = {
    **COMMON_OPTIONS,
    "node": opt_int,
    "local": opt_int,
    "fd": opt_bool,
    "bitrate": opt_int,
    "data_bitrate": opt_int,
    "sleep_after_open": opt_float,
    "port": opt_int,
    "pace": opt_int,
    "tx_queue": opt_int,
    "rx_queue": opt_int,
    "transfer_timeout": opt_float,
    "can_format": opt_int,
    "can_chain": opt_bool,
}


def frame_bits(data_length: int, *, fd: bool = False, worst_case: bool = True) -> int:
    """Bits one extended-id data frame takes on the bus (at the nominal rate), interframe space
    included; ``worst_case`` adds the most stuff bits the stuffed part can need (one per four
    bits after the first). CAN FD frames are counted at one rate (no bit-rate switch)."""
    data_bits = 8 * data_length
    if not fd:
        # SOF, 11-bit id, SRR, IDE, 18-bit id, RTR, r1, r0, DLC 4, data, CRC 15: stuffed.
        stuffed = 1 + 11 + 1 + 1 + 18 + 1 + 2 + 4 + data_bits + 15
        fixed = 1 + 1 + 1 + 7 + 3  # CRC delimiter, ACK slot, ACK delimiter, EOF, IFS
    else:
        crc = 17 if data_length <= 16 else 21
        # SOF, ids, SRR, IDE, RRS, FDF, res, BRS, ESI, DLC, data (stuffed); the stuff count
        # and CRC with their fixed stuff bits (one per 4 bits) follow.
        stuffed = 1 + 11 + 1 + 1 + 18 + 1 + 1 + 1 + 1 + 1 + 4 + data_bits
        fixed = 4 + crc + (4 + crc + 3) // 4 + 1 + 1 + 1 + 7 + 3
    stuff = (stuffed - 1) // 4 if worst_case else 0
    return stuffed + stuff + fixed


@dataclass
class HubStats:
    """Counters of one shared bus (they only grow)."""

    frames_in: int = 0
    frames_out: int = 0
    error_frames: int = 0
    """Error frames the interface reported."""
    send_errors: int = 0
    """Frames the interface refused (bus-off, buffer full, adapter error): dropped."""
    bus_off: int = 0
    """Times sending started failing (the bus went off, or the adapter stopped taking frames)."""
    recoveries: int = 0
    """Times sending worked again after failing."""
    tx_dropped: int = 0
    """Best-effort frames dropped because ``tx_queue`` frames were already waiting."""
    unrouted: int = 0
    """Transfers from nodes with no link open here."""
    rx_overflow: int = 0
    """Datagrams dropped because their board's link had ``rx_queue`` unread."""
    node_conflicts: int = 0
    """Node-id claims that contradicted another node's claim of the same id."""
    conflict_drops: int = 0
    """Datagrams dropped because their node id was claimed by two nodes."""
    format_changes: int = 0
    """Times a peer's claims changed the CAN.md format this end speaks to it."""
    chains_out: int = 0
    """Chained transfers begun (CAN.md §12: the fragments of one message as one transfer)."""
    chain_breaks: int = 0
    """Chains broken off by a datagram that did not continue them (the receiver drops them)."""
    tx_invalid: int = 0
    """Datagrams not sent because they were not valid native datagrams (format 2 needs the
    header and the CRC-16 right)."""

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class CanHub:
    """One python-can bus shared by the links of one process: a reader thread that turns frames
    into transfers for the links, a sender thread that sends frames highest priority first
    (first come, first served within a priority, so one stream's frames keep their order)."""

    def __init__(
        self,
        key: Any,
        open_bus: Any,
        *,
        local: int,
        fd: bool,
        pace: int = 0,
        tx_queue: int = 1024,
        transfer_timeout: float = 1.0,
        owns_bus: bool = True,
        uid: bytes | None = None,
        format: int = FORMAT_2,
        chains: bool = True,
    ) -> None:
        self.key = key
        self.local = local
        self.fd = fd
        self.pace = pace
        self.tx_limit = tx_queue
        self.owns_bus = owns_bus
        self.uid = uid if uid is not None else os.urandom(UID_SIZE)
        self.stats = HubStats()
        self.format = format
        """The CAN.md format this end claims in and speaks to peers not heard yet."""
        self.peer_formats: dict[int, int] = {}
        """The format each peer (node id) claimed in last: the one it is spoken to in."""
        self.chains = chains and format == FORMAT_2
        """This end sends and takes chained transfers (CAN.md version 3, §12)."""
        self.peer_chains: dict[int, bool] = {}
        """Whether each peer's last claim said it takes chained transfers."""
        self.encoder = TransferEncoder(local, FD_MTU if fd else CLASSIC_MTU)
        self.decoder = TransferDecoder(
            local, timeout=transfer_timeout, format_2=format == FORMAT_2, chains=self.chains
        )
        self.monitor = ConflictMonitor(window=3 * CLAIM_INTERVAL)
        self.links: dict[int, CanLink] = {}
        self.users = 0
        self.failed: LinkError | None = None
        self.sending = True
        """False between a failed send and the next one that works (bus-off)."""
        self._lock = threading.Lock()  # links, encoder
        self._tx: list[tuple[int, int, int, bytes]] = []
        self._tx_ready = threading.Condition(threading.Lock())
        self._order = itertools.count()
        self._stop = threading.Event()
        self._bus = open_bus()
        self._reader = threading.Thread(target=self._read_loop, name="can-rx", daemon=True)
        self._sender = threading.Thread(target=self._send_loop, name="can-tx", daemon=True)
        self._reader.start()
        self._sender.start()

    # ------------------------------------------------------------------ links
    def attach(self, node: int, link: CanLink) -> None:
        with self._lock:
            other = self.links.get(node)
            if other is not None and other is not link:
                raise LinkError(
                    f"{link.url}: node {node} is already open here as {other.url}; open each "
                    "board once"
                )
            self.links[node] = link

    def detach(self, node: int, link: CanLink) -> None:
        with self._lock:
            if self.links.get(node) is link:
                del self.links[node]

    def describe(self) -> dict[str, Any]:
        now = time.monotonic()
        return {
            **self.stats.as_dict(),
            **{f"rx_{k}": v for k, v in self.decoder.stats.as_dict().items()},
            "sending": self.sending,
            "claims": {node: uid.hex() for node, uid in self.monitor.claimed(now)},
            "format": self.format,
            "peer_formats": dict(self.peer_formats),
            "chains": self.chains,
            "peer_chains": dict(self.peer_chains),
        }

    # ------------------------------------------------------------------ sending
    def send(self, destination: int, datagram: bytes) -> None:
        """Queue one datagram's frames for ``destination`` (dropped, counted, when the queue is
        full and the datagram is best-effort data)."""
        if self.failed is not None:
            raise self.failed
        with self._lock:
            fmt = self.peer_formats.get(destination, self.format)
            chain = self.chains and fmt == FORMAT_2 and self.peer_chains.get(destination, False)
            encoder = self.encoder
            try:
                frames = encoder.datagram(datagram, destination, format=fmt, chain=chain)
            except ValueError as exc:
                self.stats.tx_invalid += 1
                log.warning("CAN bus %s: not sent to node %d: %s", self.key, destination, exc)
                return
            self.stats.chains_out = encoder.chains
            self.stats.chain_breaks = encoder.chain_breaks
        self._queue(frames)

    def _queue(self, frames: list[tuple[int, bytes]]) -> None:
        if not frames:
            return  # a chain's fragment that completed no frame yet
        # Queued by stream, not by the id's priority, which still wins arbitration.
        priority = queue_class(Kind((frames[0][0] >> 24) & 0x3))
        with self._tx_ready:
            if len(self._tx) + len(frames) > self.tx_limit and priority > PRIORITY_RELIABLE:
                self.stats.tx_dropped += len(frames)
                return
            for can_id, data in frames:
                heapq.heappush(self._tx, (priority, next(self._order), can_id, data))
            self._tx_ready.notify()

    def _send_loop(self) -> None:
        import can

        bus = self._bus
        next_slot = time.monotonic()
        while not self._stop.is_set():
            with self._tx_ready:
                while not self._tx and not self._stop.is_set():
                    self._tx_ready.wait(0.5)
                if self._stop.is_set():
                    return
                _, _, can_id, data = heapq.heappop(self._tx)
            if self.pace:
                delay = next_slot - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                bits = frame_bits(len(data), fd=self.fd)
                next_slot = max(next_slot, time.monotonic()) + bits / self.pace
            message = can.Message(
                arbitration_id=can_id,
                is_extended_id=True,
                data=data,
                is_fd=self.fd,
                bitrate_switch=False,
            )
            try:
                bus.send(message, timeout=0.2)
            except (can.CanError, OSError, ValueError) as exc:
                self.stats.send_errors += 1
                if self.sending:
                    self.sending = False
                    self.stats.bus_off += 1
                    log.warning("CAN bus %s: sending fails (%s); frames are dropped", self.key, exc)
                self._stop.wait(_RECOVERY_DELAY)
                continue
            self.stats.frames_out += 1
            if not self.sending:
                self.sending = True
                self.stats.recoveries += 1
                log.warning("CAN bus %s: sending works again", self.key)

    # ------------------------------------------------------------------ receiving
    def _read_loop(self) -> None:
        import can

        bus = self._bus
        next_claim = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_claim:
                next_claim = now + CLAIM_INTERVAL
                with self._lock:
                    frames = self.encoder.claim(self.uid, format=self.format, chains=self.chains)
                self._queue(frames)
                self.decoder.expire(now)
            try:
                message = bus.recv(0.05)
            except (can.CanError, OSError, ValueError) as exc:
                if self._stop.is_set():
                    return
                self._fail(LinkError(f"CAN bus {self.key} failed: {exc}"))
                return
            if message is None:
                continue
            self.stats.frames_in += 1
            if message.is_error_frame:
                self.stats.error_frames += 1
                continue
            if message.is_remote_frame:
                self.decoder.stats.malformed += 1
                continue
            transfer = self.decoder.feed(
                message.arbitration_id,
                bytes(message.data),
                time.monotonic(),
                extended=message.is_extended_id,
            )
            if transfer is None:
                continue
            if transfer.kind is Kind.NODE:
                self._on_node(transfer.source, transfer.channel, transfer.payload)
                if (
                    transfer.channel == NODE_CLAIM
                    and transfer.source != self.local
                    and self.format == FORMAT_2
                    and HOST_NODE in (self.local, transfer.source)  # a board talks to the host
                ):
                    self._learn_format(transfer.source, transfer.format)
                    if self.chains:
                        with self._lock:
                            self.peer_chains[transfer.source] = transfer.takes_chains
                continue
            with self._lock:
                link = self.links.get(transfer.source)
            if link is None:
                self.stats.unrouted += 1
            elif self.monitor.in_conflict(transfer.source, time.monotonic()):
                self.stats.conflict_drops += 1
            else:
                for datagram in transfer.datagrams:
                    if not link.deliver(datagram):
                        self.stats.rx_overflow += 1

    def _on_node(self, source: int, opcode: int, payload: bytes) -> None:
        if opcode != NODE_CLAIM or len(payload) != UID_SIZE:
            self.decoder.stats.malformed += 1
            return
        if source == self.local and payload == self.uid:
            return  # our own claim, looped back (udp_multicast)
        now = time.monotonic()
        if source == self.local:
            self.stats.node_conflicts += 1
            log.error(
                "CAN bus %s: another node (unique id %s) uses this end's node id %d",
                self.key,
                payload.hex(),
                source,
            )
        elif self.monitor.claim(source, payload, now):
            self.stats.node_conflicts += 1
            log.error(
                "CAN bus %s: node id %d is claimed by two nodes (unique ids %s and another); "
                "its traffic is dropped until one goes: give each board its own node id",
                self.key,
                source,
                payload.hex(),
            )

    def _learn_format(self, node: int, fmt: int) -> None:
        """Speak to ``node`` the format of its last claim (CAN.md §11)."""
        with self._lock:
            before = self.peer_formats.get(node, self.format)
            self.peer_formats[node] = fmt
        if before == fmt:
            return
        self.stats.format_changes += 1
        if fmt < self.format:
            log.warning(
                "CAN bus %s: node %d claims in CAN.md format %d (older firmware) where this end "
                "speaks format %d; talking format %d to it (update its firmware for the "
                "shorter frames of format %d)",
                self.key,
                node,
                fmt,
                self.format,
                fmt,
                self.format,
            )
        else:
            log.info("CAN bus %s: node %d now claims in CAN.md format %d", self.key, node, fmt)

    def _fail(self, error: LinkError) -> None:
        log.warning("%s", error)
        self.failed = error
        _forget(self)
        with self._lock:
            links = list(self.links.values())
        for link in links:
            link.wake_reader()

    # ------------------------------------------------------------------ end
    def shutdown(self) -> None:
        self._stop.set()
        with self._tx_ready:
            self._tx_ready.notify_all()
        for thread in (self._reader, self._sender):
            if thread is not threading.current_thread():
                thread.join(2)
        if self.owns_bus:
            with contextlib.suppress(Exception):
                self._bus.shutdown()


_hubs: dict[Any, CanHub] = {}
_hubs_lock = threading.Lock()


def _forget(hub: CanHub) -> None:
    with _hubs_lock:
        if _hubs.get(hub.key) is hub:
            del _hubs[hub.key]


def _python_can() -> Any:
    try:
        import can
    except ImportError as exc:
        raise LinkError(
            "CAN links need python-can: pip install 'hwbridge[can]' (or python-can)"
        ) from exc
    return can


class CanLink(Link):
    """``can://INTERFACE/CHANNEL/nodeN``: one board on a shared CAN bus (module docstring).

    ``bus`` (keyword only) runs the link on a python-can bus object given by the caller (an
    emulator's, a test's), shared with every link given the same object and never shut down.
    """

    scheme: ClassVar[str] = "can"
    datagram: ClassVar[bool] = True

    def __init__(self, url: str, *, bus: Any = None, **options: Any) -> None:
        super().__init__(url)
        parts = urlsplit(url)
        self.interface = parts.netloc.lower()
        if not self.interface:
            raise LinkError(
                f"{url}: name the python-can interface, as in can://virtual/bench/node1 or "
                "can://slcan/dev/ttyACM0/node1?bitrate=1000000"
            )
        segments = parts.path.split("/")
        path_node: int | None = None
        if segments and _NODE_SEGMENT.match(segments[-1]):
            path_node = int(segments.pop()[4:])
        channel = "/".join(segments)
        channel = channel[1:] if channel.startswith("/") else channel
        if self.interface == "slcan" and channel and not _WINDOWS_PORT.match(channel):
            channel = "/" + channel.lstrip("/")
        if not channel:
            raise LinkError(
                f"{url}: give the bus channel after the interface: can://{self.interface}/CHANNEL/nodeN"
            )
        self.channel = channel
        opts = parse_options(url, _OPTIONS, split_query(parts.query, url), options)
        node = opts.get("node", path_node)
        if node is None:
            raise LinkError(
                f"{url}: give the board's node id: {url.split('?', maxsplit=1)[0]}/node1 or ?node=1"
            )
        self.local = opts.get("local", HOST_NODE)
        low_node = MIN_NODE if self.local == HOST_NODE else HOST_NODE
        for what, value, low in (("node", node, low_node), ("local", self.local, 0)):
            if not low <= value <= MAX_NODE:
                raise LinkError(f"{url}: {what} must be a node id {low}..{MAX_NODE}, not {value}")
        if node == self.local:
            raise LinkError(f"{url}: the board's node id {node} is this end's own")
        self.node: int = node
        self.fd: bool = opts.get("fd", False)
        self.pace: int = opts.get("pace", 0)
        self.tx_queue: int = max(16, opts.get("tx_queue", 1024))
        self.rx_queue: int = max(1, opts.get("rx_queue", 256))
        self.transfer_timeout: float = opts.get("transfer_timeout", 1.0)
        self.can_format: int = opts.get("can_format", FORMAT_2)
        if self.can_format not in (FORMAT_1, FORMAT_2):
            raise LinkError(f"{url}: can_format must be 1 or 2, not {self.can_format}")
        self.can_chain: bool = opts.get("can_chain", True)
        if self.pace < 0 or self.transfer_timeout <= 0:
            raise LinkError(f"{url}: pace must be >= 0 bits/s and transfer_timeout above 0 s")
        self._bus_options: dict[str, Any] = {
            key: opts[key]
            for key in ("bitrate", "data_bitrate", "sleep_after_open", "port")
            if key in opts
        }
        self._given_bus = bus
        self._hub: CanHub | None = None
        self._inbox: deque[bytes] = deque()
        self._ready = threading.Condition(threading.Lock())

    # ------------------------------------------------------------------ hub
    @property
    def hub(self) -> CanHub | None:
        """The shared bus this link is on (None while closed)."""
        return self._hub

    def can_stats(self) -> dict[str, Any]:
        """The shared bus's counters (frames, errors, bus-off, drops, node claims)."""
        hub = self._hub
        return hub.describe() if hub is not None else {}

    def transport_stats(self) -> dict[str, Any]:
        return {"can": self.can_stats()}

    def _key(self) -> tuple[Any, ...]:
        if self._given_bus is not None:
            return (
                "bus",
                id(self._given_bus),
                self.local,
                self.fd,
                self.can_format,
                self.can_chain,
            )
        return (
            self.interface,
            self.channel,
            self.local,
            self.fd,
            self.can_format,
            self.can_chain,
            tuple(sorted(self._bus_options.items())),
        )

    def _open_bus(self) -> Any:
        if self._given_bus is not None:
            return self._given_bus
        can = _python_can()
        kwargs: dict[str, Any] = {"interface": self.interface, "channel": self.channel}
        if self.fd:
            kwargs["fd"] = True
        kwargs.update(self._bus_options)
        try:
            if self.interface == "slcan":  # python-can's, reading in bulk (links/slcan.py)
                from hwbridge.links.slcan import BulkSlcanBus

                del kwargs["interface"]
                return BulkSlcanBus(**kwargs)
            return can.Bus(**kwargs)
        except (can.CanError, OSError, ValueError, ImportError, TypeError) as exc:
            raise LinkError(f"cannot open the CAN bus of {self.url}: {exc}") from exc

    def _open(self) -> None:
        key = self._key()
        with _hubs_lock:
            hub = _hubs.get(key)
            if hub is None:
                hub = CanHub(
                    key,
                    self._open_bus,
                    local=self.local,
                    fd=self.fd,
                    pace=self.pace,
                    tx_queue=self.tx_queue,
                    transfer_timeout=self.transfer_timeout,
                    owns_bus=self._given_bus is None,
                    format=self.can_format,
                    chains=self.can_chain,
                )
                _hubs[key] = hub
            hub.users += 1
        with self._ready:
            self._inbox.clear()
        self._hub = hub
        try:
            hub.attach(self.node, self)
        except LinkError:
            self._hub = None
            self._release(hub)
            raise

    def _release(self, hub: CanHub) -> None:
        with _hubs_lock:
            hub.users -= 1
            last = hub.users <= 0
            if last and _hubs.get(hub.key) is hub:
                del _hubs[hub.key]
        if last:
            hub.shutdown()

    def _close(self) -> None:
        hub, self._hub = self._hub, None
        if hub is not None:
            hub.detach(self.node, self)
            self._release(hub)

    def _wake(self) -> None:
        self.wake_reader()

    def wake_reader(self) -> None:
        """Make a blocked read look again (closing, or the bus failed)."""
        with self._ready:
            self._ready.notify_all()

    def deliver(self, datagram: bytes) -> bool:
        """Hand a received datagram to the reader (the hub's thread); False when full."""
        with self._ready:
            if len(self._inbox) >= self.rx_queue:
                return False
            self._inbox.append(datagram)
            self._ready.notify()
        return True

    # ------------------------------------------------------------------ I/O
    def _read(self, max_bytes: int, timeout: float | None) -> bytes:
        hub = self._hub
        if hub is None:
            raise LinkClosedError(f"{self.url} is closed", local=True)
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._ready:
            while not self._inbox:
                if hub.failed is not None:
                    raise LinkClosedError(str(hub.failed))
                if self._stopping:
                    return b""
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return b""
                self._ready.wait(remaining if remaining is not None else 0.5)
            return self._inbox.popleft()[:max_bytes]

    def _write(self, data: memoryview) -> None:
        hub = self._hub
        if hub is None:
            raise LinkClosedError(f"{self.url} is closed", local=True)
        if hub.failed is not None:
            raise LinkClosedError(str(hub.failed))
        hub.send(self.node, bytes(data))
