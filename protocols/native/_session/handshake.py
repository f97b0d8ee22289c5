"""The handshake of a native session (HELLO, negotiation, end of a session) and its timers.

PROTOCOL.md 2.5, 2.9 and 2.10: HELLOs until both ends know each other's session, the limits
both agree on, the link timeout, the heartbeat, and what ends a session.
"""

from __future__ import annotations

from typing import Any

from hwbridge.protocols.errors import HwBridgeError, HwBridgeTimeoutError
from hwbridge.protocols.native._control.common import (
    MAX_WINDOW,
    MIN_MTU,
    NO_SESSION,
    Features,
    HelloFlags,
    Role,
)
from hwbridge.protocols.native._hotpath import CONFIGURING, CONNECTED
from hwbridge.protocols.native._session.config import (
    BoardInfo,
    LinkParams,
    SessionResetError,
    SessionState,
    TopicEntry,
)
from hwbridge.protocols.native._session.core import HELLO_FIRST_RETRY, SessionCore, _role_name
from hwbridge.protocols.native._session.events import Connected, Disconnected, ServiceResponse
from hwbridge.protocols.native.control import HeartbeatMsg, HelloMsg
from hwbridge.protocols.native.reliable import ReliableReceiver, ReliableSender


class Handshake(SessionCore[Any]):
    """HELLO exchange, negotiation, teardown, and the timers that run a session."""

    def _hello(self) -> HelloMsg:
        cfg = self._cfg
        return HelloMsg(
            role=self._ROLE,
            flags=HelloFlags.ESTABLISHED if self._established else HelloFlags.NONE,
            session=self._id,
            peer_session=self._peer_id,
            mtu=cfg.mtu,
            max_message=cfg.max_message,
            window=cfg.window,
            isn=self._isn,
            features=cfg.features,
        )

    def _send_hello(self) -> None:
        self._c.hellos_sent += 1
        self._framing.lead_next()  # PROTOCOL.md 1.3: flush the receiver before a HELLO
        self._send_control_be(self._hello())

    def _on_hello(self, msg: HelloMsg) -> None:
        if msg.role == self._ROLE:
            if msg.session == self._id:
                self._protocol_error(
                    "received this end's own HELLO: the link echoes (loopback) what is sent",
                    key="echo",
                )
            else:
                role = _role_name(self._ROLE)
                self._protocol_error(
                    f"the peer is also a {role}: connect a host to a board", key="role"
                )
            return
        self._heard_at = self._now
        if self._established and (msg.session != self._peer_id or msg.peer_session != self._id):
            self._c.peer_resets += 1
            peer = _role_name(msg.role)
            if msg.session != self._peer_id:
                reason = (
                    f"the {peer} restarted (session {self._peer_id:#010x} -> {msg.session:#010x})"
                )
            else:
                reason = f"the {peer} dropped the session (its link timed out or it restarted)"
            self._teardown(reason, SessionResetError(reason))
        if not self._established:
            problem = self._check_peer_limits(msg)
            if problem:
                self._protocol_error(problem, key=f"limits-{msg.session}")
                return
            self._peer_id = msg.session
            if msg.peer_session == self._id:
                self._establish(msg)
        else:
            self._alive()
        if not msg.flags & HelloFlags.ESTABLISHED:
            self._send_hello()
            if self._listen_first:  # this answer is the HELLO the retry timer would send now
                self._next_hello = max(self._next_hello, self._now + self._hello_wait)

    def _check_peer_limits(self, msg: HelloMsg) -> str:
        peer = _role_name(msg.role)
        if msg.mtu < MIN_MTU:
            return f"the {peer} announces mtu {msg.mtu}, below the minimum {MIN_MTU}"
        if not 1 <= msg.window <= 255:
            return f"the {peer} announces window {msg.window}; it must be at least 1"
        if msg.max_message < 1:
            return f"the {peer} announces max_message {msg.max_message}"
        if msg.session == NO_SESSION:
            return f"the {peer} announces session id 0, which is reserved"
        return ""

    def _establish(self, peer: HelloMsg) -> None:
        cfg = self._cfg
        window = min(cfg.window, peer.window, MAX_WINDOW)
        mtu = min(cfg.mtu, peer.mtu)
        own_features = cfg.features
        if self._ROLE == Role.HOST:
            host_max, device_max = cfg.max_message, peer.max_message
        else:
            host_max, device_max = peer.max_message, cfg.max_message
        link = LinkParams(mtu, window, host_max, device_max, own_features & peer.features)
        self._link = link
        self._peer_max = device_max if self._ROLE == Role.HOST else host_max
        self._time_sync = cfg.time_sync_interval > 0 and bool(link.features & Features.TIME_SYNC)
        self._ack_in_data = bool(link.features & Features.ACK_IN_DATA)
        self._service_channels = bool(link.features & Features.SERVICE_CHANNELS)
        self._short_calls = self._service_channels and bool(link.features & Features.SHORT_CALLS)
        self._established = True
        self._reported.clear()
        self._c.sessions += 1
        self._rel_tx = ReliableSender(
            self._seq,
            self._rtt,
            isn=self._isn,
            window=window,
            mtu=mtu,
            max_retries=cfg.max_retries,
            queue_limit=cfg.tx_queue_limit,
        )
        self._rel_rx = ReliableReceiver(
            self._seq,
            isn=peer.isn,
            window=window,
            max_message=cfg.max_message,
            # ACKs wait (ack_delay) only while the peer keeps at least half its window free,
            # or (ACK_IN_DATA, window below 4) for a frame of this end's to carry them.
            ack_every=_ack_every(window, cfg.ack_delay, self._ack_in_data),
        )
        self._ack_due = None
        self._framing.max_payload = mtu
        self._state = SessionState.CONFIGURING
        self._configuring_since = self._now
        self._alive()
        self._on_established()

    def _teardown(self, reason: str, error: HwBridgeError) -> None:
        was_connected = self._state is CONNECTED
        for request_id, call in sorted(self._calls.items()):
            self._events.append(
                ServiceResponse(
                    call.channel,
                    request_id,
                    b"",
                    SessionResetError(
                        f"service call {request_id} to {call.name} (channel {call.channel}) "
                        f"abandoned: {reason}"
                    ),
                )
            )
        self._calls.clear()
        self._retired_ids.clear()
        self._incoming_calls.clear()
        self._fail_role_pending(reason)
        self._on_teardown()
        if self._established:
            self._last_peer_id = self._peer_id
        if self._be_peer == self._peer_id:
            # The peer's next HELLO starts its best-effort seq space afresh even if it names the
            # same session: a board that rebooted without entropy for a new id (a port with no
            # noise source and no boot count, firmware hwbridge/boot_count.h) counts from 0
            # again, and its HELLOs would be dropped as late.
            self._be_peer = NO_SESSION
        self._rel_tx = None
        self._rel_rx = None
        self._ack_due = None
        self._ack_in_data = False
        self._service_channels = False
        self._short_calls = False
        self._established = False
        self._peer_id = NO_SESSION
        self._link = None
        self._peer_max = MIN_MTU
        self._time_sync = False
        self._isn = self._rng.getrandbits(8)
        self._framing.max_payload = self._cfg.mtu
        self._time_samples.clear()
        if self._state is not SessionState.CONFIGURING:
            self._waiting_since = self._now
            self._wait_reported = False
        self._state = SessionState.HANDSHAKE
        self._next_hello = self._now
        self._hello_wait = min(HELLO_FIRST_RETRY, self._cfg.hello_interval)
        if was_connected:
            self._events.append(Disconnected(reason, error))

    def _connect(self, board: BoardInfo, topics: tuple[TopicEntry, ...]) -> None:
        assert self._link is not None
        self._state = SessionState.CONNECTED
        self._wait_reported = False
        resumed = self._last_peer_id == self._peer_id
        host_id, device_id = (
            (self._id, self._peer_id) if self._ROLE == Role.HOST else (self._peer_id, self._id)
        )
        self._time_next = self._now
        self._events.append(
            Connected(
                topics,
                board.name,
                resumed,
                board.identity,
                board=board,
                link=self._link,
                host_session=host_id,
                device_session=device_id,
            )
        )

    # ---- timers -----------------------------------------------------------------------------

    def _run_timers(self) -> None:
        now = self._now
        cfg = self._cfg
        if (
            self._state is not CONNECTED
            and not self._wait_reported
            and now >= self._waiting_since + cfg.handshake_timeout
        ):
            self._wait_reported = True
            self._error(HwBridgeTimeoutError(self._handshake_timeout_text()))
        if not self._established:
            if now >= self._next_hello and self._may_call():
                self._send_hello()
                self._next_hello = now + self._hello_wait
                self._hello_wait = min(2 * self._hello_wait, cfg.hello_interval)
            return
        if now >= self._last_rx + cfg.link_timeout:
            self._c.link_losses += 1
            peer = _role_name(Role(1 - self._ROLE))
            reason = f"link lost: nothing received from the {peer} for {cfg.link_timeout:.2f} s"
            self._teardown(reason, HwBridgeTimeoutError(reason))
            self._run_timers()
            return
        if self._state is CONFIGURING and (now >= self._configuring_since + cfg.handshake_timeout):
            reason = f"the topic table exchange did not complete in {cfg.handshake_timeout:.1f} s"
            self._error(HwBridgeTimeoutError(reason))
            self._teardown(reason, HwBridgeTimeoutError(reason))
            self._run_timers()
            return
        if self._ack_due is not None and now >= self._ack_due:
            self._send_ack()
        sender = self._rel_tx
        assert sender is not None
        try:
            for frame in sender.poll(now):
                self._send_frame(frame)
        except HwBridgeTimeoutError as exc:
            self._c.link_losses += 1
            self._teardown(f"link lost: {exc}", exc)
            self._run_timers()
            return
        if self._state is CONNECTED:
            if self._calls:
                self._expire_calls(now)
            self._run_role_timers(now)
            if self._time_sync and now >= self._time_next:
                self._send_time_request()
                self._time_next = now + cfg.time_sync_retry
        if now >= self._last_tx + cfg.heartbeat_interval:
            self._c.heartbeats_sent += 1
            self._send_control_be(HeartbeatMsg())

    def _handshake_timeout_text(self) -> str:
        peer = _role_name(Role(1 - self._ROLE))
        if self._established:
            what = "the session is established but the topic table exchange has not completed"
        elif self._peer_id:
            what = f"the {peer} answers HELLO but the handshake does not complete"
        else:
            what = f"no HELLO from the {peer}"
        return f"no connected session after {self._cfg.handshake_timeout:.1f} s: {what}" + (
            self._hello_context()
        )


def _ack_every(window: int, ack_delay: float, ack_in_data: bool) -> int:
    """In-order frames after which an ACK goes at once (PROTOCOL.md 2.4, delayed ACKs): half the
    window; with ACK_IN_DATA and a window below 4, 2 (a window-1 peer's one frame waits up to
    ack_delay for an answer to carry its ACK); 1 (never held) without an ack_delay."""
    if ack_delay <= 0:
        return 1
    if ack_in_data and window < 4:
        return 2
    return max(1, window // 2)
