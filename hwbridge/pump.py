"""Run a sans-I/O protocol session over a link, in a thread.

The protocol code (``hwbridge.protocols``) is pure: bytes and a clock in, events and bytes out.
:class:`SessionPump` is the edge that does the I/O for one link: a thread reads the link, feeds
the session, fires its timers, writes what it wants to send, and hands each event to a callback.
The session's framing decides what a read and a write are (a chunk of a stream, or one datagram):
the pump hands each read to the session whole and writes each item of ``chunks_to_send()`` in one
write.
Other threads act on the session through :meth:`SessionPump.call`, which takes the lock, runs the
action and flushes the bytes it produced, so the session is never used by two threads at once.
While a pump's thread hands events on (its callback may block: a graph publish behind a lagging
subscriber), one keeper thread for all pumps runs the session's timers through its
``keepalive`` (sessions that have one: native), so that the peer keeps hearing from this end.
A session that announces its timers (``next_deadline``) is asked for them between reads, except
after a read it calls ``settled`` (native: one that held the first bytes of a frame).

The bridge uses it on the host side, the emulator on the device side.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol, TypeVar, cast

from hwbridge.errors import HwBridgeError, LinkError
from hwbridge.links import Link, LinkClosedError

__all__ = ["SansIOSession", "SessionPump"]

log = logging.getLogger("hwbridge.pump")

T = TypeVar("T")
_IDLE_TICK = 0.05  # seconds between ticks of a session that announces no deadline
_LOCK_WAIT = 0.01
"""Seconds of waiting for the lock after a read past which the link is read again before a tick."""
_SERVICE_EVERY = 0.05
"""While the pump thread hands events on (a graph publish blocked behind a slow subscriber can
take seconds), the keeper runs the session's timers at least this often (half the native
protocol's heartbeat interval), so that the peer keeps hearing heartbeats, held ACKs and
retransmissions. The link is not read meanwhile: the peer is held back by its own flow control
(a full reliable window, a full socket), not queued for without bound."""


class SansIOSession(Protocol):
    """What the pump needs from a session (HostSession, DeviceSession, RosserialHost, ...)."""

    def receive_data(self, data: bytes, now: float, /) -> list[Any]: ...

    def tick(self, now: float, /) -> list[Any]: ...

    def chunks_to_send(self) -> list[bytes]: ...


def _unsettled() -> bool:
    """A session without ``settled``: every read may have moved its deadline."""
    return False


class SessionPump:
    """Drives ``session`` over ``link`` until the link fails or :meth:`stop` (or
    :meth:`request_stop`) is called.

    ``on_event(event)`` runs on the pump thread, without the lock held, so it may call
    :meth:`call`. ``on_exit(error)`` runs once when the thread ends (``None`` after a stop).
    On a link that outlives its peers (``tcp-listen://``, ``pty://``) the session goes on with
    the next peer, unless ``end_with_peer``: then the peer's going ends the pump, with the
    :class:`LinkClosedError` that said so (for protocols whose session is one peer's).
    """

    def __init__(
        self,
        link: Link,
        session: SansIOSession,
        on_event: Callable[[Any], None],
        *,
        name: str = "pump",
        clock: Callable[[], float] = time.monotonic,
        on_exit: Callable[[BaseException | None], None] | None = None,
        read_size: int = 65536,
        end_with_peer: bool = False,
    ) -> None:
        self.link = link
        self.session = session
        self.name = name
        self._on_event = on_event
        self._on_exit = on_exit
        self._clock = clock
        self._read_size = read_size
        self._end_with_peer = end_with_peer
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None
        self.dropped_bytes = 0
        """Bytes written while a listening link had no peer (lost, as on an open wire)."""
        self.services = 0
        """How often the keeper ran the session's timers while the pump thread handed events on."""
        found = getattr(session, "keepalive", None)
        self._keepalive = cast(
            "Callable[[float], list[Any]] | None", found if callable(found) else None
        )
        self._handing_since: float | None = None
        self._kept_at = 0.0
        self._kept_events: list[Any] = []
        self._acted = False
        """Another thread ran the session (call(), the keeper) since the pump thread last asked
        for its next deadline."""

    # ------------------------------------------------------------------ control
    def start(self) -> SessionPump:
        """Start the pump thread (the link must be open)."""
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()
        if self._keepalive is not None:
            _KEEPER.add(self)
        return self

    def request_stop(self) -> None:
        """Tell the thread to end, without waiting for it: it ends at its next turn, or when a
        read or write it is blocked in returns (close the link to wake it; the closing is then
        no error to it). :meth:`stop` also waits."""
        self._stop.set()

    def stop(self, timeout: float = 2.0) -> None:
        """Ask the thread to end (:meth:`request_stop`) and wait up to ``timeout`` seconds for
        it (the link is left to its owner)."""
        self.request_stop()
        thread = self._thread
        # (not started: a KeyboardInterrupt in start() between the Thread and its start, and
        # join() would raise RuntimeError; a thread that runs sees _stop)
        if thread is not None and thread is not threading.current_thread() and thread.is_alive():
            thread.join(timeout)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None and self._thread.is_alive():
            self._thread.join(timeout)

    def call(self, action: Callable[[Any], T]) -> T:
        """Run ``action(session)`` under the lock, dispatch its events, flush its bytes."""
        with self._lock:
            self._acted = True
            result = action(self.session)
            self._flush()
        if isinstance(result, list):
            for event in result:
                self._dispatch(event)
        return result

    # ------------------------------------------------------------------ thread
    def _flush(self) -> None:
        chunks = self.session.chunks_to_send()
        if not chunks:
            return
        write = self.link.write
        try:
            for chunk in chunks:
                write(chunk)
        except LinkClosedError:
            if not self.link.is_open:
                raise
            # A listening link (pty master, tcp-listen) with nobody attached: the bytes are
            # lost as on a wire with no board; the protocol's timers deal with it.
            self.dropped_bytes += sum(map(len, chunks))

    def _read(self, timeout: float) -> bytes:
        """Read the link; ``b""`` also when the peer of a link that waits for the next one went
        away and the session goes on (other link errors are raised)."""
        link = self.link
        try:
            return link.read(self._read_size, timeout=timeout)
        except LinkClosedError:
            if not link.is_open or self._stop.is_set() or self._end_with_peer:
                raise
            log.info("%s: the peer went away; waiting for the next one", self.name)
            return b""

    def _dispatch(self, event: Any) -> None:
        try:
            self._on_event(event)
        except HwBridgeError as exc:
            log.error("%s: handling %s failed: %s", self.name, type(event).__name__, exc)
        except Exception:
            log.exception("%s: handling %s failed", self.name, type(event).__name__)

    def _hand_on(self, events: list[Any]) -> None:
        """Dispatch ``events``, then what the keeper's timers produced meanwhile."""
        self._handing_since = self._clock()
        try:
            while True:
                for event in events:
                    self._dispatch(event)
                with self._lock:  # the keeper adds under the lock: none is left behind
                    events, self._kept_events = self._kept_events, []
                    if not events:
                        self._handing_since = None
                        return
        finally:
            self._handing_since = None

    def _keep(self) -> None:
        """The keeper's call: when the pump thread has been handing events on for longer than
        :data:`_SERVICE_EVERY` since the session's timers last ran, run them now (the session's
        ``keepalive``, which does not take the unread link for a silent peer) and write what
        they produced; their events wait for the pump thread."""
        keepalive = self._keepalive
        since = self._handing_since
        if keepalive is None or since is None:
            return
        now = self._clock()
        if now - max(since, self._kept_at) < _SERVICE_EVERY:
            return
        with self._lock:
            if self._handing_since is None:
                return
            self._acted = True
            try:
                self._kept_events += keepalive(now)
                self._flush()
            except (HwBridgeError, OSError):  # the link failed: the pump thread finds out itself
                return
            self.services += 1
        self._kept_at = now

    def _run(self) -> None:
        error: BaseException | None = None
        session, lock, clock = self.session, self._lock, self._clock
        found = getattr(session, "next_deadline", None)
        deadline_of = cast("Callable[[], float | None] | None", found if callable(found) else None)
        settled = _settled_of(session)
        deadline: float | None = None
        fresh = False  # ``deadline`` holds: only reads the session called settled ran since
        try:
            with lock:  # what the session queued before the thread started goes out now
                self._flush()
            while not self._stop.is_set():
                # A session that announces its next deadline is ticked only when one is due;
                # others are ticked after every read and at least every _IDLE_TICK. The
                # deadline is asked again unless nothing but settled reads ran the session
                # since (a frame's first bytes: a service answer comes in several reads).
                if not fresh or self._acted:
                    with lock:
                        self._acted = False
                        deadline = deadline_of() if deadline_of is not None else None
                timeout = (
                    _IDLE_TICK
                    if deadline is None
                    else min(max(deadline - clock(), 0.0), _IDLE_TICK)
                )
                data = self._read(timeout)
                read_at = clock()
                with lock:
                    now = clock()
                    events = session.receive_data(data, now) if data else []
                    fresh = bool(data) and not events and settled()
                    if deadline is None or now >= deadline:
                        fresh = False
                        if now - read_at > _LOCK_WAIT:
                            # Another thread held the lock meanwhile (a long write under call(),
                            # say): take what arrived since the read before the timers judge
                            # the link, or they take this thread's wait for the peer's silence.
                            late = self._read(0)
                            if late:
                                events += session.receive_data(late, now)
                        events += session.tick(now)
                    self._flush()
                if events:
                    self._hand_on(events)
        except LinkClosedError as exc:
            if not self._stop.is_set():
                error = exc
        except LinkError as exc:
            error = exc
        except Exception as exc:
            log.exception("%s: pump failed", self.name)
            error = exc
        self.error = error
        _KEEPER.remove(self)
        if self._on_exit is not None:
            try:
                self._on_exit(error)
            except Exception:
                log.exception("%s: exit handler failed", self.name)


def _settled_of(session: object) -> Callable[[], bool]:
    """How the pump asks ``session`` whether its last ``receive_data`` left its timers as they
    were (it only held a frame's first bytes), so that its deadline need not be asked again: the
    session's ``settled`` (native sessions), or always no."""
    found = getattr(type(session), "settled", None)  # (a wrapper's __getattr__ does not count)
    getter = found.fget if isinstance(found, property) else None
    if getter is None:
        return _unsettled
    return lambda: bool(getter(session))


class _Keeper:
    """One thread for every pump whose session has a ``keepalive``: every half
    :data:`_SERVICE_EVERY` it lets each pump run its session's timers if its thread is busy
    handing events on (:meth:`SessionPump._keep`). It runs while there are pumps."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pumps: list[SessionPump] = []
        self._thread: threading.Thread | None = None

    def add(self, pump: SessionPump) -> None:
        with self._lock:
            self._pumps.append(pump)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="pump-keeper", daemon=True)
                self._thread.start()

    def remove(self, pump: SessionPump) -> None:
        with self._lock:
            if pump in self._pumps:
                self._pumps.remove(pump)

    def _run(self) -> None:
        while True:
            time.sleep(_SERVICE_EVERY / 2)
            with self._lock:
                pumps = list(self._pumps)
                if not pumps:
                    self._thread = None
                    return
            for pump in pumps:
                try:
                    pump._keep()
                except Exception:
                    log.exception("%s: keeping the session's timers failed", pump.name)


_KEEPER = _Keeper()
