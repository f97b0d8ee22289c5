"""A simulated, lossy link between a HostSession and a DeviceSession, on a virtual clock.

Each direction cuts the sender's bytes into frames at the 0x00 delimiters and, per frame and from
one seeded RNG, drops it, corrupts it (flips one bit, never creating a 0x00, so that a corrupted
frame stays exactly one bad frame), duplicates it, or delays it past later frames (reordering).
Delivered bytes are split into random chunks. The device runs on its own clock (offset and
drift) so that time sync has something to measure. Nothing sleeps: time jumps to the next
deadline, delivery, or step.

With ``datagram=True`` the sessions must use the datagram framing: each direction carries the
datagrams of ``chunks_to_send()`` one by one (dropped, corrupted, duplicated or delayed whole,
one datagram per delivery) instead of a byte stream.
"""

from __future__ import annotations

import heapq
import random
from collections.abc import Callable
from dataclasses import dataclass, field

from hwbridge.protocols.native.framing import FrameType, decode_datagram, decode_frame
from hwbridge.protocols.native.session import DeviceSession, Event, HostSession


@dataclass
class Faults:
    """Fault rates of one direction (probabilities per frame) and its timing."""

    drop: float = 0.0
    corrupt: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    """Probability that a frame is delayed by up to ``reorder_delay`` extra seconds."""
    reorder_delay: float = 0.02
    latency: float = 0.002
    max_chunk: int = 0
    """Deliver in random chunks of 1..max_chunk bytes (0: as sent)."""
    cut: bool = False
    """Drop everything (a pulled cable)."""
    drop_types: frozenset[FrameType] = frozenset()
    """Drop every frame of these types (a selectively broken path)."""


@dataclass
class DirectionStats:
    frames: int = 0
    dropped: int = 0
    corrupted: int = 0
    duplicated: int = 0
    delayed: int = 0
    be_frames: int = 0
    be_dropped: int = 0
    be_corrupted: int = 0
    max_payload: int = 0
    """Largest frame payload carried (of frames that decode)."""


@dataclass
class Direction:
    """One direction of the link."""

    faults: Faults
    rng: random.Random
    stats: DirectionStats = field(default_factory=DirectionStats)
    datagram: bool = False
    """Carry whole datagrams (one frame each) rather than a byte stream."""
    _queue: list[tuple[float, int, bytes]] = field(default_factory=list)
    _order: int = 0

    def send(self, data: bytes, now: float) -> None:
        if not data:
            return
        runs = data.split(b"\x00")
        runs.pop()  # data always ends with a delimiter
        for run in runs:
            self._send_frame(run, now)

    def send_datagrams(self, datagrams: list[bytes], now: float) -> None:
        for datagram in datagrams:
            self._send_frame(datagram, now)

    def _send_frame(self, run: bytes, now: float) -> None:
        f = self.faults
        wire = run if self.datagram else run + b"\x00"
        is_be = False
        frame_type: FrameType | None = None
        if run:
            self.stats.frames += 1
            try:
                frame = decode_datagram(wire) if self.datagram else decode_frame(wire)
            except Exception:  # noqa: BLE001 - the sender never sends bad frames; count them
                frame = None
            if frame is not None:
                frame_type = frame.type
                is_be = frame.type is FrameType.BEST_EFFORT
                self.stats.be_frames += is_be
                self.stats.max_payload = max(self.stats.max_payload, len(frame.payload))
        if f.cut or (frame_type is not None and frame_type in f.drop_types):
            if run:
                self.stats.dropped += 1
                self.stats.be_dropped += is_be
            return
        if run and self.rng.random() < f.drop:
            self.stats.dropped += 1
            self.stats.be_dropped += is_be
            return
        if run and self.rng.random() < f.corrupt:
            self.stats.corrupted += 1
            self.stats.be_corrupted += is_be
            wire = self._corrupt(run) if self.datagram else self._corrupt(run) + b"\x00"
        copies = 1
        if run and self.rng.random() < f.duplicate:
            self.stats.duplicated += 1
            copies = 2
        for _ in range(copies):
            delay = f.latency
            if run and self.rng.random() < f.reorder:
                self.stats.delayed += 1
                delay += self.rng.uniform(0, f.reorder_delay)
            self._order += 1
            heapq.heappush(self._queue, (now + delay, self._order, wire))

    def _corrupt(self, run: bytes) -> bytes:
        data = bytearray(run)
        while True:
            i = self.rng.randrange(len(data))
            flipped = data[i] ^ (1 << self.rng.randrange(8))
            if flipped or self.datagram:
                data[i] = flipped
                return bytes(data)

    def pop_due(self, now: float) -> list[bytes]:
        if self.datagram:
            due = []
            while self._queue and self._queue[0][0] <= now:
                due.append(heapq.heappop(self._queue)[2])
            return due
        out = bytearray()
        while self._queue and self._queue[0][0] <= now:
            out += heapq.heappop(self._queue)[2]
        if not out:
            return []
        if not self.faults.max_chunk:
            return [bytes(out)]
        chunks = []
        pos = 0
        while pos < len(out):
            size = self.rng.randint(1, self.faults.max_chunk)
            chunks.append(bytes(out[pos : pos + size]))
            pos += size
        return chunks

    def next_time(self) -> float | None:
        return self._queue[0][0] if self._queue else None

    def clear(self) -> None:
        self._queue.clear()

    @property
    def in_flight(self) -> int:
        return len(self._queue)


EventHandler = Callable[[Event], None]


class SimLink:
    """Host and device sessions joined by two lossy directions, run on a virtual clock."""

    def __init__(
        self,
        host: HostSession,
        device: DeviceSession,
        *,
        seed: int = 0,
        h2d: Faults | None = None,
        d2h: Faults | None = None,
        clock_offset: float = 1000.0,
        clock_drift: float = 0.0,
        max_step: float = 0.01,
        datagram: bool = False,
    ) -> None:
        self.host = host
        self.device = device
        self.datagram = datagram
        rng = random.Random(seed)
        self.h2d = Direction(h2d or Faults(), random.Random(rng.getrandbits(64)), datagram=datagram)
        self.d2h = Direction(d2h or Faults(), random.Random(rng.getrandbits(64)), datagram=datagram)
        self.clock_offset = clock_offset
        self.clock_drift = clock_drift
        self.max_step = max_step
        self.now = 0.0
        self.host_events: list[Event] = []
        self.device_events: list[Event] = []
        self.on_host: EventHandler | None = None
        self.on_device: EventHandler | None = None
        self.h2d_log: list[bytes] = []
        """Every byte chunk the host wrote (to check what the device was sent)."""
        self.d2h_log: list[bytes] = []
        """Every byte chunk the device wrote (to check what the host was sent)."""

    def device_time(self, t: float) -> float:
        """The device's clock at simulation time ``t``."""
        return self.clock_offset + t * (1 + self.clock_drift)

    def sim_time(self, device_time: float) -> float:
        """Simulation time at which the device clock reads ``device_time``."""
        return (device_time - self.clock_offset) / (1 + self.clock_drift)

    def reset_device(self, device: DeviceSession) -> None:
        """The board reboots: a new session object; bytes already on the wire stay there."""
        self.device = device

    def _host_events(self, events: list[Event]) -> None:
        for event in events:
            self.host_events.append(event)
            if self.on_host is not None:
                self.on_host(event)

    def _device_events(self, events: list[Event]) -> None:
        for event in events:
            self.device_events.append(event)
            if self.on_device is not None:
                self.on_device(event)

    def step(self) -> None:
        """Deliver what is due, run timers, and collect what both ends send."""
        now = self.now
        dnow = self.device_time(now)
        for chunk in self.d2h.pop_due(now):
            self._host_events(self.host.receive_data(chunk, now))
        for chunk in self.h2d.pop_due(now):
            self._device_events(self.device.receive_data(chunk, dnow))
        self._host_events(self.host.tick(now))
        self._device_events(self.device.tick(dnow))
        self.flush()

    def flush(self) -> None:
        """Put what both ends want to send on the wire (at the current time)."""
        if self.datagram:
            out_chunks = self.host.chunks_to_send()
            self.h2d_log.extend(out_chunks)
            self.h2d.send_datagrams(out_chunks, self.now)
            device_chunks = self.device.chunks_to_send()
            self.d2h_log.extend(device_chunks)
            self.d2h.send_datagrams(device_chunks, self.now)
            return
        out = self.host.data_to_send()
        if out:
            self.h2d_log.append(out)
        self.h2d.send(out, self.now)
        out = self.device.data_to_send()
        if out:
            self.d2h_log.append(out)
        self.d2h.send(out, self.now)

    def _next_time(self) -> float:
        candidates = [self.now + self.max_step]
        host_deadline = self.host.next_deadline()
        if host_deadline is not None:
            candidates.append(host_deadline)
        device_deadline = self.device.next_deadline()
        if device_deadline is not None:
            candidates.append(self.sim_time(device_deadline))
        for direction in (self.h2d, self.d2h):
            t = direction.next_time()
            if t is not None:
                candidates.append(t)
        return max(min(candidates), self.now + 1e-6)

    def run(self, duration: float, until: Callable[[], bool] | None = None) -> bool:
        """Run for ``duration`` simulated seconds or until ``until()``; True if it returned True."""
        end = self.now + duration
        while self.now < end:
            self.step()
            if until is not None and until():
                return True
            self.now = min(self._next_time(), end)
        self.step()
        return until is not None and until()

    def drain(self, max_rounds: int = 50) -> None:
        """Deliver everything in flight without running timers (no new timer traffic)."""
        for _ in range(max_rounds):
            if not self.h2d.in_flight and not self.d2h.in_flight:
                return
            times = [t for t in (self.h2d.next_time(), self.d2h.next_time()) if t is not None]
            self.now = max(self.now, *times)
            dnow = self.device_time(self.now)
            for chunk in self.d2h.pop_due(self.now):
                self._host_events(self.host.receive_data(chunk, self.now))
            for chunk in self.h2d.pop_due(self.now):
                self._device_events(self.device.receive_data(chunk, dnow))
            self.flush()
        raise AssertionError("the link did not drain")
