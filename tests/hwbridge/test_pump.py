"""SessionPump (hwbridge.pump) driving real native sessions over a real ``memory://`` pipe."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from typing import Any, cast

import pytest

from hwbridge.links import Link, open_link
from hwbridge.protocols.native import session as ns
from hwbridge.pump import SessionPump
from tests.boards import native_sketch, wait_for

LINK_TIMEOUT = 0.3
"""The device's link timeout."""
HOST_HEARTBEAT = 0.1
"""The host's heartbeat period: the device, ticking every DEVICE_HEARTBEAT, finds the link empty
between two of them."""
DEVICE_HEARTBEAT = 0.05
HOLD = 0.6
"""Seconds another thread keeps the device pump's lock: twice the link timeout, while the host's
heartbeats keep arriving."""


class PausingLink:
    """A real link that, once armed, stops in the next ``read`` that found nothing until
    :attr:`go` is set (it sets :attr:`empty` first): the pump thread is then exactly between a
    read that returned nothing and taking the session lock."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self.armed = threading.Event()
        self.empty = threading.Event()
        self.go = threading.Event()

    def read(self, max_bytes: int = 4096, timeout: float | None = None) -> bytes:
        data = self.link.read(max_bytes, timeout)
        if not data and self.armed.is_set():
            self.armed.clear()
            self.empty.set()
            self.go.wait(5)
        return data

    def __getattr__(self, name: str) -> Any:
        return getattr(self.link, name)


@pytest.fixture
def pair() -> Iterator[tuple[SessionPump, SessionPump, PausingLink, list[Any], list[Any]]]:
    host_link, device_link = open_link("memory://pump-lock"), open_link("memory://pump-lock")
    # The host waits longer than the hold: the device is silent meanwhile (its pump is stuck).
    host = ns.HostSession(
        ns.HostConfig(
            time_sync_interval=0, link_timeout=HOLD * 4, heartbeat_interval=HOST_HEARTBEAT
        )
    )
    sketch = native_sketch()
    config = ns.DeviceConfig(
        time_sync_interval=0, link_timeout=LINK_TIMEOUT, heartbeat_interval=DEVICE_HEARTBEAT
    )
    device = ns.DeviceSession(sketch.board, list(sketch.topics.values()), config)
    pausing = PausingLink(device_link)
    host_events: list[Any] = []
    device_events: list[Any] = []
    host_pump = SessionPump(host_link, host, host_events.append, name="host").start()
    device_pump = SessionPump(
        cast(Link, pausing), device, device_events.append, name="device"
    ).start()
    try:
        assert wait_for(lambda: any(isinstance(e, ns.Connected) for e in host_events), 10)
        yield host_pump, device_pump, pausing, host_events, device_events
    finally:
        pausing.go.set()
        host_pump.stop()
        device_pump.stop()
        host_link.close()
        device_link.close()


def test_a_long_hold_of_the_lock_is_not_taken_for_a_silent_peer(
    pair: tuple[SessionPump, SessionPump, PausingLink, list[Any], list[Any]],
) -> None:
    """Another thread holds the device pump's lock (a long write under call()) right after the
    pump's read found nothing. The host's heartbeats arrive meanwhile; once the pump has the lock,
    its timers must see them, not a silence of HOLD seconds (twice the link timeout)."""
    _host_pump, device_pump, pausing, host_events, device_events = pair
    pausing.armed.set()
    assert pausing.empty.wait(5), "the device pump never read an empty link"
    holding = threading.Event()

    def long_action(_session: Any) -> None:
        holding.set()
        time.sleep(HOLD)

    holder = threading.Thread(target=device_pump.call, args=(long_action,))
    holder.start()
    assert holding.wait(5)
    pausing.go.set()  # the pump returns from its read and waits for the lock
    holder.join(5)
    time.sleep(LINK_TIMEOUT)  # room for a (wrong) timeout to be reported
    ended = [e for e in device_events + host_events if isinstance(e, ns.Disconnected)]
    assert ended == []
    assert cast(ns.DeviceSession, device_pump.session).connected


def _burst_pair(
    on_host_event: Any, name: str
) -> tuple[SessionPump, SessionPump, list[Any], Callable[[], None]]:
    """A host and a device pump (native sessions, default timers) over ``memory://name``,
    connected; the host's events go to ``on_host_event``; returns the pumps, the host's events
    and a function that stops both."""
    host_link, device_link = open_link(f"memory://{name}"), open_link(f"memory://{name}")
    host = ns.HostSession(ns.HostConfig(time_sync_interval=0))
    sketch = native_sketch()
    device = ns.DeviceSession(
        sketch.board, list(sketch.topics.values()), ns.DeviceConfig(time_sync_interval=0)
    )
    host_events: list[Any] = []

    def on_event(event: Any) -> None:
        host_events.append(event)
        on_host_event(event)

    host_pump = SessionPump(host_link, host, on_event, name="host").start()
    device_pump = SessionPump(device_link, device, lambda _e: None, name="device").start()

    def stop() -> None:
        host_pump.stop()
        device_pump.stop()
        host_link.close()
        device_link.close()

    assert wait_for(lambda: any(isinstance(e, ns.Connected) for e in host_events), 10)
    return host_pump, device_pump, host_events, stop


def _string(text: str) -> bytes:
    data = text.encode()
    return len(data).to_bytes(4, "little") + data


BURST = 60
"""Messages the board sends at once in the burst test."""
PER_EVENT = 0.05
"""Seconds the host's handler takes for each (a graph publish blocked behind a slow subscriber):
the burst takes BURST * PER_EVENT = 3 s to hand on, almost four times the device's link timeout."""
BLOCKED = 3.0
"""Seconds the host's handler takes for one message in the single-event tests (Zenoh's BLOCK
congestion control waits up to 5 s for a lagging subscriber)."""


def test_a_slow_handler_does_not_silence_the_link() -> None:
    """The host's handler takes PER_EVENT for each message of a burst (as a Zenoh publish does
    when a subscriber lags). Handing the burst on takes 3 s, but the session's timers keep
    running meanwhile (the pump keeper): the device (default link timeout, 0.8 s) keeps hearing
    heartbeats and never declares the link lost, and every message arrives in order. Without
    them the device hears nothing for 3 s and ends the session."""
    from hwbridge.protocols import base

    received: list[bytes] = []

    def on_host_event(event: Any) -> None:
        if isinstance(event, base.Message):
            time.sleep(PER_EVENT)
            received.append(bytes(event.payload))

    host_pump, device_pump, host_events, stop = _burst_pair(on_host_event, "pump-burst")
    try:
        payloads = [_string(f"m{i}") for i in range(BURST)]

        def burst(session: ns.DeviceSession) -> list[bool]:
            return [session.publish(1, payload) for payload in payloads]

        assert all(device_pump.call(burst))
        assert wait_for(lambda: len(received) == BURST, 60)
        assert received == payloads
        device_stats = device_pump.call(lambda s: s.stats)
        assert (device_stats.link_losses, device_stats.peer_resets) == (0, 0)
        assert not [e for e in host_events if isinstance(e, ns.Disconnected)]
        assert device_pump.call(lambda s: s.connected)
        assert host_pump.services > 0
    finally:
        stop()


def test_one_long_event_does_not_silence_the_link_nor_hide_a_dead_peer() -> None:
    """The host's handler blocks BLOCKED seconds on one message. The device keeps hearing the
    host's heartbeats (no link loss, no reset), and the host does not take the link it was not
    reading for a silent device. Then the same again, but the device stops for good while the
    handler blocks: once the host reads again it declares the link lost (the keeper hides no
    dead peer)."""
    from hwbridge.protocols import base

    blocking = threading.Event()

    def on_host_event(event: Any) -> None:
        if isinstance(event, base.Message):
            blocking.set()
            time.sleep(BLOCKED)

    host_pump, device_pump, host_events, stop = _burst_pair(on_host_event, "pump-long")
    try:
        assert device_pump.call(lambda s: s.publish(1, _string("slow")))
        assert blocking.wait(10)
        assert wait_for(lambda: host_pump.services >= 3, 20)  # the keeper ran meanwhile
        time.sleep(BLOCKED)  # the handler returns; room for a (wrong) loss to show
        device_stats = device_pump.call(lambda s: s.stats)
        assert (device_stats.link_losses, device_stats.peer_resets) == (0, 0)
        assert not [e for e in host_events if isinstance(e, ns.Disconnected)]

        blocking.clear()
        assert device_pump.call(lambda s: s.publish(1, _string("last")))
        assert blocking.wait(10)
        device_pump.stop()  # the device falls silent for good while the host's handler blocks
        assert wait_for(
            lambda: any(
                isinstance(e, ns.Disconnected) and e.reason.startswith("link lost")
                for e in host_events
            ),
            30,
        ), host_events
    finally:
        stop()


class _AskCountingHost(ns.HostSession):
    """A native host session that counts how often it is asked for its next deadline."""

    asks = 0

    def next_deadline(self) -> float | None:
        self.asks += 1
        return super().next_deadline()


def test_reads_that_complete_no_frame_do_not_ask_for_the_deadline_again() -> None:
    """The host pump reads one byte at a time (a service answer comes in many reads, as from a
    board on a slow line): it asks the session for its next deadline only after the reads that
    complete a frame (and after ticks and calls), and every call is answered."""
    host_link, device_link = open_link("memory://pump-settled"), open_link("memory://pump-settled")
    host = _AskCountingHost(ns.HostConfig(time_sync_interval=0))
    sketch = native_sketch()
    device = ns.DeviceSession(
        sketch.board, list(sketch.topics.values()), ns.DeviceConfig(time_sync_interval=0)
    )
    answers: list[Any] = []
    host_pump = SessionPump(
        host_link,
        host,
        lambda e: answers.append(e) if isinstance(e, ns.ServiceResponse) else None,
        name="host",
        read_size=1,
    ).start()

    def answer(event: Any) -> None:
        if isinstance(event, ns.ServiceRequest):
            device_pump.call(
                lambda s: s.respond_service(event.channel, event.request_id, b"\x01" + _string(""))
            )

    device_pump = SessionPump(device_link, device, answer, name="device").start()
    try:
        assert wait_for(lambda: host_pump.call(lambda s: s.connected), 10)
        calls = 20
        for n in range(calls):
            host_pump.call(lambda s: s.call_service(3, b""))
            assert wait_for(lambda n=n: len(answers) > n, 10)
        assert all(e.ok for e in answers)
        reads, asks = host_link.stats.reads, host.asks
        assert reads > 20 * calls  # (an answer is 19 bytes; the board's heartbeats add more)
        assert asks * 3 < reads, (asks, reads)
    finally:
        host_pump.stop()
        device_pump.stop()
        host_link.close()
        device_link.close()


class _SettledSession:
    """A session whose every read is settled and whose deadline only moves by ``call()``."""

    def __init__(self) -> None:
        self.deadline = time.monotonic() + 1000.0
        self.ticks: list[float] = []

    @property
    def settled(self) -> bool:
        return True

    def receive_data(self, data: bytes, now: float, /) -> list[Any]:
        return []

    def tick(self, now: float, /) -> list[Any]:
        if now >= self.deadline:
            self.ticks.append(now)
            self.deadline = now + 1000.0
        return []

    def next_deadline(self) -> float | None:
        return self.deadline

    def chunks_to_send(self) -> list[bytes]:
        return []


def test_a_call_between_settled_reads_is_asked_for_its_deadline() -> None:
    """Bytes keep coming (every read settled), and another thread moves the session's deadline
    near through ``call()``: the pump asks again and ticks at it, instead of keeping the far one
    it had."""
    link, peer = open_link("memory://pump-acted"), open_link("memory://pump-acted")
    session = _SettledSession()
    pump = SessionPump(link, session, lambda _e: None, name="settled").start()
    stop = threading.Event()

    def trickle() -> None:
        while not stop.is_set():
            peer.write(b"x")
            time.sleep(0.002)

    writer = threading.Thread(target=trickle, daemon=True)
    writer.start()
    try:
        assert wait_for(lambda: link.stats.reads > 20, 10)
        pump.call(lambda s: setattr(s, "deadline", time.monotonic() + 0.05))
        assert wait_for(lambda: len(session.ticks) == 1, 10)
    finally:
        stop.set()
        writer.join(5)
        pump.stop()
        link.close()
        peer.close()


def test_a_pump_interrupted_in_start_stops_without_joining_a_thread_never_started(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A Ctrl-C that lands in ``start()`` between the Thread's creation and its start (a shard of
    ``hwbridge up`` stopping during start-up) left a Thread that was never started; ``stop()``
    joined it and raised "cannot join thread before it is started" (a traceback in CI)."""
    link = open_link("memory://pump-interrupted")
    pump = SessionPump(link, ns.HostSession(), lambda _event: None, name="pump-interrupted")

    def interrupted(_self: threading.Thread) -> None:
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(threading.Thread, "start", interrupted)
        with pytest.raises(KeyboardInterrupt):
            pump.start()
    try:
        pump.stop()
        pump.join(0.1)
        assert not pump.running
    finally:
        link.close()


class _BlockingLink:
    """A real link whose reads wait without a timeout: the pump thread stays in one until bytes
    come or the link is closed (:attr:`reading` is set as it goes in)."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self.reading = threading.Event()

    def read(self, max_bytes: int = 4096, timeout: float | None = None) -> bytes:
        del timeout
        self.reading.set()
        return self.link.read(max_bytes, None)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.link, name)


def test_request_stop_does_not_wait_for_a_thread_blocked_on_the_link(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``request_stop()`` only tells the thread (the emulator's boards then close the link,
    which wakes it): it returns without joining the thread, still in its read; once the link is
    closed the thread ends, and the closing is no error to it."""
    link = open_link("memory://pump-request-stop")
    blocking = _BlockingLink(link)
    exits: list[BaseException | None] = []
    pump = SessionPump(
        cast(Link, blocking),
        _SettledSession(),
        lambda _event: None,
        name="pump-request-stop",
        on_exit=exits.append,
    ).start()
    joined: list[float | None] = []
    join = threading.Thread.join

    def spy(thread: threading.Thread, timeout: float | None = None) -> None:
        if thread.name == "pump-request-stop":
            joined.append(timeout)
        join(thread, timeout)

    try:
        assert wait_for(blocking.reading.is_set, 10)
        with monkeypatch.context() as patch:
            patch.setattr(threading.Thread, "join", spy)
            pump.request_stop()
        assert joined == []
        assert pump.running  # the read it is in has not returned: nothing came, no close
        link.close()
        assert wait_for(lambda: not pump.running, 10)
        assert exits == [None] and pump.error is None
        pump.stop()  # stop() after the thread ended: nothing to wait for
    finally:
        pump.stop()
        link.close()
