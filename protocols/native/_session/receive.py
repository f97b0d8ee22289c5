"""The input of a native session: frames to the reliability layer, deliveries to events.

The per-frame path: ``_on_frame`` hands ACKs and reliable frames to the reliability layer and
best-effort frames to their reassembler; a complete message becomes a Message event
(``_on_data``), a service call on its own channel (``_on_data``, with SERVICE_CHANNELS) or a
control message (``_on_control``). See
:mod:`hwbridge.protocols.native._hotpath` for what is written out inline here.
"""

from __future__ import annotations

from typing import Any

from hwbridge.protocols.errors import ProtocolError, ProtocolMismatchError
from hwbridge.protocols.native._control.common import (
    CONTROL_CHANNEL,
    PROTOCOL_VERSION,
    Opcode,
    Role,
    is_best_effort_opcode,
)
from hwbridge.protocols.native._framing.frames import BadFrame, BadFrameReason, Frame
from hwbridge.protocols.native._hotpath import ACK, BEST_EFFORT, CONNECTED
from hwbridge.protocols.native._hotpath import message as _message
from hwbridge.protocols.native._session.config import _VERSION_FRAMES_TO_REPORT, SessionResetError
from hwbridge.protocols.native._session.core import SessionCore, _role_name
from hwbridge.protocols.native._session.events import Log
from hwbridge.protocols.native.control import (
    GoodbyeMsg,
    HeartbeatMsg,
    HelloMsg,
    LogMsg,
    ServiceRequestMsg,
    ServiceResponseMsg,
    decode_control,
)
from hwbridge.protocols.native.reliable import Delivery


class Receiver(SessionCore[Any]):
    """Frames in, events out."""

    # ---- input ------------------------------------------------------------------------------

    def _on_bad_frame(self, item: BadFrame) -> None:
        if item.reason is BadFrameReason.VERSION:
            self._version_frames += 1
            if self._version_frames < _VERSION_FRAMES_TO_REPORT:
                return
            self._protocol_error(
                "received a frame of another native protocol version: update the firmware or "
                "hwbridge so both match",
                key="frame-version",
            )

    def _on_frame(self, frame: Frame) -> None:
        # A per-frame path: _alive() is written out (``self._last_rx = self._now``).
        ftype = frame.type
        if ftype is ACK:
            sender = self._rel_tx
            if sender is None:
                self._c.ignored_frames += 1
                return
            self._last_rx = self._now
            for again in sender.on_ack(frame, self._now):
                self._send_frame(again)
            return
        ack = frame.ack
        if ack is not None:
            # An ACK in a data frame (ACK_IN_DATA, PROTOCOL.md 2.4): the cumulative ACK of that
            # seq, handled first, as if before the frame, so that an answer to the frame finds
            # the window it freed. Outside a session it is ignored with the frame.
            sender = self._rel_tx
            if sender is not None:
                sender.acknowledge(ack, self._now)
        if ftype is BEST_EFFORT:
            self._on_best_effort(frame)
            return
        receiver = self._rel_rx
        if receiver is None:  # the peer holds a session this end has not established (yet)
            self._c.ignored_frames += 1
            self._heard_at = self._now  # (listen_first: HELLO retries go to a peer that talks)
            return
        self._last_rx = self._now
        for delivery in receiver.receive(frame):
            if delivery.channel == CONTROL_CHANNEL:
                self._on_control(delivery.payload, reliable=True)
            else:
                self._on_data(delivery)
            if self._rel_rx is not receiver:  # the session ended while handling it
                break

    def _on_best_effort(self, frame: Frame) -> None:
        payload = frame.payload
        if (
            frame.channel == CONTROL_CHANNEL
            and len(payload) >= 8
            and payload[0] == Opcode.HELLO
            and payload[1] == PROTOCOL_VERSION
        ):
            # A HELLO names the sender's session: a new one has its own seq space.
            peer = int.from_bytes(payload[4:8], "little")
            if peer not in (self._be_peer, self._id):
                self._be_peer = peer
                self._be_rx.resync()
        if not self._be_rx.accept(frame.seq):
            return
        delivery = self._be_rx.receive(frame)
        if delivery is None:
            return
        if delivery.channel == CONTROL_CHANNEL:
            self._on_control(delivery.payload, reliable=False)
        elif self._established:
            self._last_rx = self._now  # _alive(), on a per-message path
            self._on_data(delivery, False)
        else:
            self._c.ignored_frames += 1

    def _on_data(self, delivery: Delivery, reliable: bool = True) -> None:
        """A message on a channel other than 0: a topic message of this end's, or (reliable,
        SERVICE_CHANNELS) a service call, or a message on the wrong channel."""
        connected = self._state is CONNECTED
        entry = self._entry(delivery.channel) if connected else None
        if entry is None or entry.kind != self._RECEIVE_KIND:
            # Service calls are looked for only here, off the topic messages' path.
            if reliable and self._service_channels and self._on_service_message(delivery, entry):
                return
            self._c.dropped_messages += 1
            if connected:
                self._protocol_error(
                    self._wrong_channel(delivery.channel, entry, "receive a message on"),
                    key=f"data-{delivery.channel}",
                )
            return
        self._events.append(_message(delivery.channel, delivery.payload, delivery.seq))

    def _on_control(self, payload: bytes, *, reliable: bool) -> None:
        try:
            msg = decode_control(payload)
        except ProtocolMismatchError as exc:
            self._c.protocol_errors += 1
            self._error(exc, key="version")
            return
        except ProtocolError as exc:
            self._c.protocol_errors += 1
            self._error(exc)
            return
        if is_best_effort_opcode(msg.OPCODE) == reliable:
            stream = "reliable" if reliable else "best-effort"
            self._protocol_error(
                f"control message {msg.OPCODE.name} arrived on the {stream} stream"
            )
            return
        if isinstance(msg, HelloMsg):
            self._on_hello(msg)
            return
        if not self._established:
            self._c.ignored_frames += 1
            return
        self._last_rx = self._now  # _alive(), on a per-message path
        # The message classes are disjoint: the common ones are tested first.
        if isinstance(msg, ServiceRequestMsg):
            self._on_service_request(msg.channel, msg.request_id, msg.body)
        elif isinstance(msg, ServiceResponseMsg):
            self._on_service_response(msg.channel, msg.request_id, msg.status, msg.body)
        elif isinstance(msg, HeartbeatMsg):
            return
        elif isinstance(msg, GoodbyeMsg):
            self._c.peer_resets += 1
            peer = _role_name(Role(1 - self._ROLE))
            self._teardown(
                f"the {peer} closed the session",
                SessionResetError(f"the {peer} closed the session"),
            )
        elif isinstance(msg, LogMsg):
            self._events.append(Log(msg.level, msg.text))
        elif not self._on_role_control(msg):
            self._protocol_error(
                f"the {_role_name(Role(1 - self._ROLE))} sent {msg.OPCODE.name}, which only "
                f"the {_role_name(self._ROLE)} sends",
                key=f"opcode-{msg.OPCODE}",
            )
