"""Emulated boards on a python-can ``udp_multicast`` bus, sharing one socket.

Every python-can ``udp_multicast`` bus object has its own socket and decodes every frame any
node sends to the group (msgpack, a ``can.Message``) before its filters drop it. Eight emulated
boards in one process so decoded each frame eight times: the emulator took 40 % of a core with
eight boards at one Odometry a second each, and on a busy two-core machine it fell behind far
enough that its boards went unheard for the bridge's link timeout (0.8 s). A real CAN controller
filters in hardware and the other nodes' frames cost its CPU nothing.

:class:`MulticastGateway` puts the boards on an in-process bus (``shared_virtual_bus``, which
hands each frame only to the boards whose acceptance filters take it) and carries frames between
that bus and the multicast group through one socket: each frame from the group is decoded once.
The group loops back what the gateway sends; those echoes are recognised (same identifier and
data, sent within ``ECHO_WINDOW`` seconds) and not delivered to the boards a second time.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import deque
from typing import Any

from hwbridge.emulator.virtual_bus import Relay, shared_virtual_bus

__all__ = ["ECHO_WINDOW", "MulticastGateway"]

log = logging.getLogger("hwbridge.emulator.can")

ECHO_WINDOW = 2.0
"""Seconds a sent frame waits for its echo from the group before it is forgotten."""

_Key = tuple[int, bool, bytes]


def _key(message: Any) -> _Key:
    return (message.arbitration_id, message.is_extended_id, bytes(message.data))


def _drop_stale(sent: deque[float], now: float) -> int:
    """Forget the sends in ``sent`` older than ECHO_WINDOW; how many are left."""
    while sent and now - sent[0] > ECHO_WINDOW:
        sent.popleft()
    return len(sent)


class MulticastGateway(Relay):
    """Carries frames both ways between the in-process bus ``local_channel`` and the
    ``udp_multicast`` group ``group`` (on ``port``), until :meth:`stop`."""

    def __init__(self, local_channel: str, group: str, port: int | None, *, fd: bool) -> None:
        super().__init__()
        self.local_channel = local_channel
        self.group = group
        self.port = port
        self.fd = fd
        self.frames_out = 0
        """Frames the boards sent that went to the group."""
        self.frames_in = 0
        """Frames from the group handed to the boards."""
        self.echoes = 0
        """Frames from the group recognised as the gateway's own, dropped."""
        self._local: Any = None
        self._group: Any = None
        self._sent: dict[_Key, deque[float]] = {}
        """When each frame awaiting its echo was sent, by identifier and data."""
        self._next_sweep = 0.0
        self._lock = threading.Lock()

    def start(self) -> MulticastGateway:
        import can

        kwargs: dict[str, Any] = {"interface": "udp_multicast", "channel": self.group}
        if self.port is not None:
            kwargs["port"] = self.port
        if self.fd:
            kwargs["fd"] = True
        self._group = can.Bus(**kwargs)
        self._local = shared_virtual_bus(self.local_channel)
        self._spawn((self._outbound, "mcast-out"), (self._inbound, "mcast-in"))
        return self

    def stop(self) -> None:
        self._join()
        for bus in (self._local, self._group):
            if bus is not None:
                with contextlib.suppress(Exception):
                    bus.shutdown()
        self._local = self._group = None

    def _outbound(self) -> None:
        import can

        local, group = self._local, self._group
        while not self._stop.is_set():
            message = local.recv(0.05)
            if message is None:
                continue
            key = _key(message)
            with self._lock:  # counted before it goes: its echo may be back before send returns
                sent = self._sent.setdefault(key, deque())
                sent.append(time.monotonic())
                self.frames_out += 1
            try:
                group.send(message)
            except (can.CanError, OSError):
                with self._lock:
                    sent.pop()
                    self.frames_out -= 1
                if self._stop.is_set():
                    return
                continue

    def _inbound(self) -> None:
        import can

        local, group = self._local, self._group
        while not self._stop.is_set():
            try:
                message = group.recv(0.05)
            except (can.CanError, OSError, ValueError) as exc:
                if not self._stop.is_set():
                    log.error("multicast group %s failed: %s", self.group, exc)
                return
            now = time.monotonic()
            with self._lock:
                if now >= self._next_sweep:
                    self._sweep(now)
                if message is None:
                    continue
                sent = self._sent.get(_key(message))
                if sent and _drop_stale(sent, now):
                    sent.popleft()
                    self.echoes += 1
                    continue
            try:
                local.send(message)
            except can.CanError:
                continue  # a board's receive queue is full: that board loses the frame
            self.frames_in += 1

    def _sweep(self, now: float) -> None:
        """Forget frames whose echo never came (every ECHO_WINDOW seconds)."""
        self._next_sweep = now + ECHO_WINDOW
        for key in list(self._sent):
            if not _drop_stale(self._sent[key], now):
                del self._sent[key]
