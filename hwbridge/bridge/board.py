"""One board: its link, reconnection, protocol detection and state.

A :class:`BoardConnection` thread keeps its board connected for the bridge's lifetime:

1. open the link (a port that does not exist yet is waited for, with backoff);
2. find the protocol: named in the spec, or on a stream link detected from what the board sends
   (:mod:`hwbridge.protocols.detect`); a silent board is sent the probes of the protocols that
   have one (rosserial's "request topics", which native boards ignore) at once and again with
   backoff. A datagram link is never probed: it carries the protocol the spec names (``auto``
   takes the first registered protocol that runs on datagrams);
3. build the protocol's session (:mod:`hwbridge.protocols.registry`) and run it in a
   :class:`~hwbridge.pump.SessionPump` until the link fails;
4. take the board's topics off the graph, close the link and start again.

Every transition is logged, so a user sees an unplugged cable, a reset board or a port that
came back.
"""

from __future__ import annotations

import json
import logging
import math
import os
import random
import threading
import time
from collections.abc import Callable
from pathlib import PurePosixPath
from typing import TYPE_CHECKING, Any, TypeVar

from hwbridge.bridge.adapter import SessionAdapter
from hwbridge.bridge.control import control_key
from hwbridge.bridge.identity import FirmwareCheck
from hwbridge.bridge.port import BoardPort
from hwbridge.errors import HwBridgeError, LinkError
from hwbridge.graph import Node, resolve_name
from hwbridge.graph.names import encode_segment
from hwbridge.links import Link, LinkClosedError, create_link
from hwbridge.protocols.base import BoardSession
from hwbridge.protocols.calling import BOOTLOADER_QUIET, CALL_BURST, may_call, next_call
from hwbridge.protocols.detect import ProtocolDetector, detectable_protocols
from hwbridge.protocols.registry import (
    ProtocolSpec,
    SessionContext,
    UnknownProtocolError,
    get_protocol,
    protocol_names,
)
from hwbridge.pump import SessionPump

if TYPE_CHECKING:
    import zenoh

    from hwbridge.bridge.core import Bridge

__all__ = [
    "DEFAULT_SERVICE_TIMEOUT",
    "DETECT_BUFFER",
    "MAX_PAUSE",
    "MAX_SERVICE_TIMEOUT",
    "BoardConnection",
    "BoardSpec",
    "check_service_timeout",
    "link_device",
]

DEFAULT_SERVICE_TIMEOUT = 5.0
"""Seconds the bridge waits for a service answer (both protocols, both directions)."""
MAX_SERVICE_TIMEOUT = 86400.0
"""Longest service timeout accepted (a day): Zenoh refuses query timeouts past about 1e19 s."""
DETECT_BUFFER = 65536
"""Bytes kept while detecting a protocol (handed to the session once it is known); older ones
are dropped, so a noisy line costs bounded memory."""
_SHORT_LINK = 2.0
"""A link that closes sooner than this after opening counts as a short one (backoff grows)."""
_MAX_RECONNECT_DELAY = 10.0
_PROBE_FIRST = 0.1
_PROBE_MAX = 1.0
"""Seconds between probes of a silent board: the first gap, doubling up to the last."""
MAX_PAUSE = 3600.0
"""Longest pause a board takes at once (an hour); an uploader renews a shorter one."""

T = TypeVar("T")


def check_service_timeout(seconds: float) -> float:
    """``seconds`` if it is a usable service timeout; HwBridgeError saying why otherwise."""
    number = isinstance(seconds, int | float) and not isinstance(seconds, bool)
    if not number or not math.isfinite(seconds) or not 0 < seconds <= MAX_SERVICE_TIMEOUT:
        given = f"{seconds:g}" if number else repr(seconds)
        raise HwBridgeError(
            f"service timeout must be a number of seconds above 0 and at most "
            f"{MAX_SERVICE_TIMEOUT:g} (a day), not {given}"
        )
    return float(seconds)


class BoardSpec:
    """How to reach one board: URL, protocol, options, namespace and name.

    ``service_timeout`` is how long the bridge waits for an answer to a service call, in both
    directions: a graph caller's call of one of the board's services, and the board's call of
    a graph service. A call that takes longer fails with an error naming the service and this
    timeout (the graph caller's own timeout is separate: make it at least as long).
    """

    def __init__(
        self,
        url: str,
        *,
        protocol: str = "auto",
        baud: int | None = None,
        namespace: str = "/",
        name: str | None = None,
        start_delay: float = 0.0,
        service_timeout: float = DEFAULT_SERVICE_TIMEOUT,
        build_tag: str | None = None,
        robot_file: str = "",
    ) -> None:
        if protocol != "auto":
            get_protocol(protocol)  # UnknownProtocolError listing the known ones
        self.service_timeout = check_service_timeout(service_timeout)
        self.url = url
        self.protocol = protocol
        self.baud = baud
        self.namespace = resolve_name(namespace) if namespace != "/" else "/"
        self.name = name or _name_from_url(url)
        self.start_delay = start_delay
        self.build_tag = build_tag
        """The build tag (PROTOCOL.md 2.6.1) of firmware generated for this board from
        ``robot_file`` (``hwbridge up``); a board that reports another one is warned about."""
        self.robot_file = robot_file
        create_link(url, **self.link_options())  # a bad URL is refused here, before any thread
        """Seconds of silence after the link opens before the first probe (0: probe at once)."""

    def link_options(self) -> dict[str, Any]:
        return {"baud": self.baud} if self.baud is not None else {}


def _name_from_url(url: str) -> str:
    tail = url.split("?", 1)[0].rstrip("/")
    tail = PurePosixPath(tail.split("://", 1)[-1]).name or "board"
    cleaned = "".join(c if c.isalnum() or c == "_" else "_" for c in tail).strip("_")
    if not cleaned or cleaned[0].isdigit():
        cleaned = "board_" + cleaned
    return cleaned


class BoardConnection:
    """Keeps one board connected and mirrored on the graph (a thread)."""

    def __init__(self, bridge: Bridge, spec: BoardSpec) -> None:
        self.bridge = bridge
        self.spec = spec
        self.name = spec.name
        self.log = logging.getLogger(f"hwbridge.board.{self.name}")
        self.node: Node = bridge.graph.node(self.name, namespace=spec.namespace)
        self.state = "starting"
        self.state_detail: dict[str, Any] = {}
        self.connects = 0
        self.link: Link | None = None
        self.adapter: SessionAdapter | None = None
        self._pump: SessionPump | None = None
        self._stop = threading.Event()
        self._short_links = 0
        """Links in a row that closed soon after they opened (see _back_off_if_short)."""
        self._opened_once = threading.Event()
        self.first_open_problem: str | None = None
        """Why the first attempt to open the link failed (None: it opened, or not tried yet)."""
        self.firmware = FirmwareCheck(
            self.name,
            self.log,
            bridge.registry,
            expected_build=spec.build_tag,
            robot_file=spec.robot_file,
        )
        """The firmware the board runs, checked against this host once per identity."""
        self._thread = threading.Thread(target=self._run, name=f"board-{self.name}", daemon=True)
        self._token = bridge.graph.announce("board", self.name, spec.url, spec.protocol)
        self._info = bridge.graph.keep(
            bridge.graph.session.declare_queryable(
                board_key(bridge.graph.prefix, self.name), self._on_info
            )
        )
        self._pause = threading.Event()
        """Set while the board is paused (asked to release its link, e.g. for an upload)."""
        self._resume = threading.Event()
        self._released = threading.Event()
        """Set while paused and the link is closed."""
        self._pause_lock = threading.Lock()
        self._pause_until = 0.0
        self._pause_reason = ""
        self._control = bridge.graph.keep(
            bridge.graph.session.declare_queryable(
                control_key(bridge.graph.prefix, self.name), self._on_control
            )
        )

    @property
    def pump(self) -> SessionPump:
        if self._pump is None:
            raise HwBridgeError(f"board {self.name} is not connected")
        return self._pump

    def resolve(self, name: str) -> str:
        """A board topic/service/param name in the board's namespace."""
        return resolve_name(name, self.spec.namespace, self.name)

    def set_state(self, state: str, **detail: Any) -> None:
        self.state = state
        self.state_detail = detail

    def _port(self, call: _SessionCall) -> BoardPort:
        """What the adapter of a new session gets of this board (it calls in through ``call``)."""
        return BoardPort(
            name=self.name,
            log=self.log,
            node=self.node,
            service_timeout=self.spec.service_timeout,
            call=call,
            resolve=self.resolve,
            set_state=self.set_state,
            get_param=self.bridge.get_param,
            on_param_update=self.bridge.param_source.on_update,
            on_firmware=self.firmware.check,
        )

    # ------------------------------------------------------------------ info
    def info(self) -> dict[str, Any]:
        adapter = self.adapter
        return {
            "name": self.name,
            "url": self.spec.url,
            "namespace": self.spec.namespace,
            "protocol": adapter.protocol if adapter else self.spec.protocol,
            "service_timeout": self.spec.service_timeout,
            "state": self.state,
            "connects": self.connects,
            "firmware": self.firmware.info(),
            "topics": adapter.topics() if adapter else {},
            "session": adapter.describe() if adapter else {},
            "stats": adapter.stats() if adapter else {},
            "device": link_device(self.spec.url),
            "pid": os.getpid(),
            "link": self.link.stats.as_dict() if self.link is not None else {},
            "transport": self.link.transport_stats() if self.link is not None else {},
            **self.state_detail,
        }

    def _on_info(self, query: zenoh.Query) -> None:
        try:
            query.reply(query.key_expr, json.dumps(self.info(), default=str).encode())
        except Exception as exc:  # noqa: BLE001 - the asker gets the failure, the bridge goes on
            query.reply_err(f"{type(exc).__name__}: {exc}")

    # ------------------------------------------------------------------ pause
    @property
    def paused(self) -> bool:
        """Whether the board is paused (its link released, or being released)."""
        return self._pause.is_set()

    def pause(self, seconds: float, reason: str = "an upload", wait: float = 15.0) -> bool:
        """Release the board's link and hold it off until :meth:`resume`, or for ``seconds``
        (a later call extends the hold). The session ends as on a stop: the board's endpoints
        leave the graph and a goodbye is written. Returns once the link is closed (True), or
        False if that did not happen within ``wait`` seconds."""
        if not 0 < seconds <= MAX_PAUSE:
            raise HwBridgeError(f"pause seconds must be above 0 and at most {MAX_PAUSE:g}")
        with self._pause_lock:
            self._pause_until = time.monotonic() + seconds
            self._pause_reason = reason
            self._resume.clear()
            self._pause.set()
        return self._released.wait(wait)

    def resume(self) -> bool:
        """End a pause: the board's link is opened again. False if it was not paused."""
        with self._pause_lock:
            was = self._pause.is_set()
            self._resume.set()
        return was

    def _hold(self) -> None:
        """While paused: the link is closed; wait for :meth:`resume`, the pause's end or a
        stop, then let the connection loop open the link again."""
        with self._pause_lock:
            reason = self._pause_reason
        self.log.warning(
            "%s: released %s for %s; holding off until told to resume",
            self.name,
            self.spec.url,
            reason,
        )
        self.set_state("paused", problem=f"released for {reason}")
        self._released.set()
        while not self._stop.is_set():
            with self._pause_lock:
                left = self._pause_until - time.monotonic()
                if self._resume.is_set() or left <= 0:
                    self._pause.clear()
                    self._released.clear()
                    self._resume.clear()
                    break
            self._resume.wait(min(left, 0.5))
        else:
            return
        if left <= 0:
            self.log.warning(
                "%s: no resume came before the pause's deadline; reopening %s",
                self.name,
                self.spec.url,
            )
        else:
            self.log.warning("%s: resuming: reopening %s", self.name, self.spec.url)
        self.set_state("starting")

    def _halted(self) -> bool:
        """The connection loop must let go of the link: stopping or pausing."""
        return self._stop.is_set() or self._pause.is_set()

    def _nap(self, seconds: float) -> None:
        """Wait ``seconds``, less if the board is stopped or paused."""
        end = time.monotonic() + seconds
        while not self._halted():
            left = end - time.monotonic()
            if left <= 0 or self._stop.wait(min(left, 0.1)):
                return

    def _on_control(self, query: zenoh.Query) -> None:
        """``{"pause": SECONDS, "reason": TEXT}`` or ``{"resume": true}``; replies the board's
        state with ``paused``, ``pid`` and ``device``."""
        try:
            payload = query.payload
            request = json.loads(bytes(payload.to_bytes())) if payload is not None else {}
            if not isinstance(request, dict):
                raise HwBridgeError("a control request is a JSON object")
            released = None
            if "pause" in request:
                seconds = request["pause"]
                if isinstance(seconds, bool) or not isinstance(seconds, int | float):
                    raise HwBridgeError("pause: a number of seconds")
                released = self.pause(float(seconds), str(request.get("reason") or "an upload"))
            elif request.get("resume"):
                self.resume()
            else:
                raise HwBridgeError('give {"pause": SECONDS} or {"resume": true}')
            answer = {
                "board": self.name,
                "paused": self.paused,
                "released": released if released is not None else self._released.is_set(),
                "state": self.state,
                "pid": os.getpid(),
                "device": link_device(self.spec.url),
            }
            query.reply(query.key_expr, json.dumps(answer).encode())
        except Exception as exc:  # noqa: BLE001 - the asker gets the failure, the bridge goes on
            query.reply_err(f"{type(exc).__name__}: {exc}")

    # ------------------------------------------------------------------ life
    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 3.0) -> None:
        self._stop.set()
        self._resume.set()
        pump, adapter, link = self._pump, self.adapter, self.link
        if adapter is not None and link is not None:
            try:
                goodbye = (
                    pump.call(lambda _s: adapter.close(HwBridgeError("bridge stopped")))
                    if pump
                    else []
                )
                for chunk in goodbye:
                    link.write(chunk)
            except HwBridgeError as exc:
                self.log.debug("%s: goodbye not sent: %s", self.name, exc)
        if pump is not None:
            pump.stop(timeout)
        if link is not None:
            link.close()
        self._thread.join(timeout)

    def wait_first_open(self, timeout: float | None = None) -> str | None:
        """Wait for the first attempt to open the link; its problem, or None if it opened (or
        the wait timed out)."""
        self._opened_once.wait(timeout)
        return self.first_open_problem

    def _first_open(self, problem: str | None) -> None:
        if not self._opened_once.is_set():
            self.first_open_problem = problem
            self._opened_once.set()

    def _run(self) -> None:
        backoff = 0.2
        last_problem = ""
        while not self._stop.is_set():
            if self._pause.is_set():
                self._hold()
                continue
            try:
                link = create_link(self.spec.url, **self.spec.link_options())
                link.open()
            except LinkError as exc:
                problem = str(exc)
                if problem != last_problem:
                    self.log.warning("%s: waiting for %s: %s", self.name, self.spec.url, problem)
                    last_problem = problem
                self.set_state("waiting", problem=problem)
                self._first_open(problem)
                self._nap(backoff)
                backoff = min(backoff * 2, 2.0)
                continue
            self._first_open(None)
            backoff, last_problem = 0.2, ""
            self.link = link
            opened_at = time.monotonic()
            try:
                # A link that outlives its peers (tcp-listen://, pty://) stays open between
                # them: closing it would refuse (or rename) the next board while it reopens.
                while not self._halted():
                    self._serve(link)
                    if not link.is_open:
                        break
            except LinkError as exc:
                if not self._halted():
                    self.log.warning("%s: link lost (%s); reconnecting", self.name, exc)
                    self.set_state("lost", problem=str(exc))
            except HwBridgeError as exc:  # e.g. a protocol that cannot start: say so, try again
                self.log.error("%s: %s", self.name, exc)
                self.set_state("failed", problem=str(exc))
                self._nap(2.0)
            except Exception as exc:  # a bug: log it where the user sees it, keep the board
                self.log.exception("%s: board connection failed", self.name)
                self.set_state("failed", problem=f"{type(exc).__name__}: {exc}")
                self._nap(2.0)
            finally:
                link.close()
                self.link = None
            self._back_off_if_short(time.monotonic() - opened_at)

    def _back_off_if_short(self, lasted: float) -> None:
        """After a link that closed soon after it opened, wait longer each time (with jitter)
        before opening it again: two clients of one TCP board that each kick the other off would
        otherwise reconnect thousands of times a second. Say so once, naming the likely cause."""
        if lasted >= _SHORT_LINK or self._halted():
            self._short_links = 0
            return
        self._short_links += 1
        delay = min(_PROBE_FIRST * 2**self._short_links, _MAX_RECONNECT_DELAY)
        if self._short_links == 3:
            self.log.warning(
                "%s: the link to %s keeps closing right after it opens; is another program "
                "connected to the same board (a second bridge, a serial monitor)? Reconnecting "
                "with backoff (up to %.0f s)",
                self.name,
                self.spec.url,
                _MAX_RECONNECT_DELAY,
            )
        self._nap(delay * random.uniform(0.5, 1.5))

    def _serve(self, link: Link) -> None:
        early = self._wait_for_peer(link)
        if early is None:
            return
        self.set_state("detecting")
        spec, early = self._detect(link, early)
        if spec is None:
            return
        datagram = _is_datagram(link)
        session = spec.new_session(
            SessionContext(
                registry=self.bridge.registry,
                datagram=datagram,
                now=time.monotonic(),
                wall_offset=time.time() - time.monotonic(),
                board_spoke=bool(early),
                start_delay=self.spec.start_delay,
            )
        )
        call = _SessionCall(self.name, lambda: self._pump)
        port = self._port(call)
        adapter = SessionAdapter(port, spec, session)
        self.adapter = adapter
        try:
            self._run_session(link, adapter, call, early)
        finally:
            port.close()  # the session's parameter listeners end with it, however it ended

    def _run_session(
        self, link: Link, adapter: SessionAdapter, call: _SessionCall, early: list[bytes]
    ) -> None:
        """Pump ``adapter``'s session (``early``: what the board sent before it) until it ends or
        the board is stopped."""
        session = adapter.session
        done = threading.Event()
        exit_error: list[BaseException | None] = []

        def on_exit(error: BaseException | None) -> None:
            exit_error.append(error)
            done.set()

        pump = SessionPump(
            link,
            session,
            adapter.on_event,
            name=f"pump-{self.name}",
            on_exit=on_exit,
            end_with_peer=adapter.session_per_peer,
        )
        self._pump = call.pump = pump
        self.connects += 1
        self.set_state("negotiating")
        for chunk in early:
            pump.call(_feed(chunk))
        pump.start()
        while not done.wait(0.2):
            if self._stop.is_set():
                return
            if self._pause.is_set():
                self._end_for_pause(link, adapter, pump)
                return
            try:
                adapter.report_losses(time.monotonic())
            except HwBridgeError as exc:  # the session is going away: its pump reports why
                self.log.debug("%s: no loss report: %s", self.name, exc)
        error = exit_error[0] if exit_error else None
        reason = (
            error if isinstance(error, HwBridgeError) else HwBridgeError(f"link ended: {error}")
        )
        adapter.close(reason)
        self.adapter = None
        self._pump = None
        if self._stop.is_set():
            return
        if link.is_open:  # a listening link: its board went, the next one gets a new session
            self.log.warning("%s: board gone (%s); waiting for the next one", self.name, error)
            self.set_state("waiting", problem=str(error))
        else:
            self.log.warning("%s: link lost (%s); reconnecting", self.name, error)
            self.set_state("lost", problem=str(error))

    def _end_for_pause(self, link: Link, adapter: SessionAdapter, pump: SessionPump) -> None:
        """End the session because the board is paused: its endpoints leave the graph, the
        goodbye is written, the pump stops (the caller closes the link)."""
        try:
            for chunk in pump.call(lambda _s: adapter.close(HwBridgeError("paused"))):
                link.write(chunk)
        except HwBridgeError as exc:
            self.log.debug("%s: goodbye not sent: %s", self.name, exc)
        pump.stop(3.0)
        self.adapter = None
        self._pump = None
        self.log.info("%s: session ended for the pause", self.name)

    def _wait_for_peer(self, link: Link) -> list[bytes] | None:
        """Wait until a board is on the link (at once but on links that wait for peers, such as
        tcp-listen:// and pty://); returns what it sent meanwhile (one item per read), None if
        stopped first."""
        seen = _Received()
        said = False
        while not self._halted():
            if link.connected:
                return seen.chunks
            if not said:
                said = True
                self.set_state("waiting", problem="no board attached")
                where = getattr(link, "slave_path", None)
                # A pty's path is made up when it opens: the user needs it to attach a board.
                self.log.log(
                    logging.WARNING if where else logging.INFO,
                    "%s: waiting for a board on %s",
                    self.name,
                    f"{where} ({self.spec.url})" if where else self.spec.url,
                )
            try:
                seen.add(link.read(4096, timeout=0.1))  # a listener accepts its client here
            except LinkClosedError:
                if not link.is_open:
                    raise
        return None

    def _detect(self, link: Link, early: list[bytes]) -> tuple[ProtocolSpec | None, list[bytes]]:
        """The protocol to speak, and what was already read (``early`` first) that belongs to
        the session. Only stream links are detected and probed."""
        if self.spec.protocol != "auto":
            return get_protocol(self.spec.protocol), early
        if _is_datagram(link):
            return self._datagram_default(), early
        specs = detectable_protocols()
        detector = ProtocolDetector(specs)
        probes = [spec.probe for spec in specs if spec.probe]
        seen = _Received(early)
        started = time.monotonic()
        probe_at = first_probe = started + self.spec.start_delay
        # A board with a start delay may sit in a bootloader that every byte keeps waiting (a
        # Mega's stk500v2): its unanswered probes leave it the silence it needs to leave.
        gap = BOOTLOADER_QUIET if self.spec.start_delay > 0 else _PROBE_FIRST
        warned_at = started
        pending = list(early)
        while not self._halted():
            for data in pending:
                found = detector.feed(data)
                if found is not None:
                    self.log.info("%s: speaks %s", self.name, found)
                    return get_protocol(found), seen.chunks
            now = time.monotonic()
            if probes and now >= probe_at:
                # In bursts with pauses (hwbridge.protocols.calling): a Mega's bootloader that
                # took a probe goes on to the sketch in a pause.
                if may_call(now, first_probe, CALL_BURST, BOOTLOADER_QUIET):
                    for probe in probes:
                        link.write(probe)
                    probe_at = now + gap
                    if gap < _PROBE_MAX:
                        gap = min(gap * 2, _PROBE_MAX)
                else:
                    probe_at = next_call(now, first_probe, CALL_BURST, BOOTLOADER_QUIET)
            if now - warned_at >= 5.0:
                warned_at = now
                self.log.warning(
                    "%s: no protocol recognised on %s after %.0f s and %d bytes (%s)%s; "
                    "still trying",
                    self.name,
                    self.spec.url,
                    now - started,
                    seen.total,
                    " or ".join(spec.name for spec in specs),
                    ": wrong baud rate?"
                    if seen.total
                    # (silent: a Mega's bootloader may hold it, and lets go in a pause)
                    else "; probes pause after every 5 s (6 s, then longer), so that a "
                    "bootloader that took them (a Mega's) starts the sketch",
                )
            data = link.read(4096, timeout=0.05)
            pending = [data] if data else []
            seen.add(data)
        return None, []

    def _datagram_default(self) -> ProtocolSpec:
        for name in protocol_names():
            spec = get_protocol(name)
            if spec.datagram:
                self.log.info("%s: a datagram link; speaking %s", self.name, spec.name)
                return spec
        raise UnknownProtocolError("no registered protocol runs on datagram links")


class _SessionCall:
    """The port's ``call`` of one session (:class:`~hwbridge.bridge.port.SessionCall`): into that
    session's pump while it is the board's live one, HwBridgeError before and after."""

    def __init__(self, board_name: str, live: Callable[[], SessionPump | None]) -> None:
        self._board_name = board_name
        self._live = live
        self.pump: SessionPump | None = None
        """The session's pump, once it exists."""

    def __call__(self, action: Callable[[BoardSession], T], /) -> T:
        pump = self.pump
        if pump is None or pump is not self._live():
            raise HwBridgeError(f"board {self._board_name} is not connected")
        return pump.call(action)


class _Received:
    """What a board sent before its session started, at most :data:`DETECT_BUFFER` bytes
    (the oldest reads are dropped first), one item per read."""

    def __init__(self, chunks: list[bytes] | None = None) -> None:
        self.chunks: list[bytes] = []
        self.kept = 0
        self.total = 0
        """Bytes received in all (dropped ones included)."""
        for chunk in chunks or ():
            self.add(chunk)

    def add(self, data: bytes) -> None:
        if not data:
            return
        self.chunks.append(data)
        self.kept += len(data)
        self.total += len(data)
        while self.kept > DETECT_BUFFER and len(self.chunks) > 1:
            self.kept -= len(self.chunks.pop(0))


def _feed(data: bytes) -> Callable[[BoardSession], list[Any]]:
    """An action that gives the session ``data`` read before it existed."""
    return lambda session: session.receive_data(data, time.monotonic())


def _is_datagram(link: Link) -> bool:
    """True for links that carry whole frames (CAN, UDP) rather than a byte stream (a wrapper
    such as ``spy+`` is what it wraps)."""
    inner = getattr(link, "inner", None)
    return link.datagram or (isinstance(inner, Link) and inner.datagram)


def board_key(prefix: str, name: str) -> str:
    """Zenoh key of a board's info queryable."""
    return f"{prefix}/board/{encode_segment(name)}"


def link_device(url: str) -> str | None:
    """The device file a serial link URL opens, symlinks resolved (``/dev/ttyACM0`` for
    ``serial:///dev/serial/by-id/...?baud=57600``, ``spy+`` wrappers seen through); None for a
    link that is not a device file (TCP, UDP, CAN, pty://)."""
    base = url.split("?", 1)[0]
    while base.startswith("spy+"):
        base = base.removeprefix("spy+")
    if base.startswith("serial://"):
        base = base.removeprefix("serial://")
    elif "://" in base or not base.startswith("/"):
        return None
    return os.path.realpath(base)
