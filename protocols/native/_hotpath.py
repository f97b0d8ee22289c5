"""The native protocol's per-message fast paths, in one place.

A topic message costs the host a few microseconds from bytes to event, so constant costs of a
few hundred nanoseconds matter there and nowhere else. The tricks below are used only on those
paths (decoding a frame, sending a frame, turning a delivery into an event) and each stays only
because a measurement shows it pays; ``tools/bench/framing.py --hotpath`` measures each against
the plain code it replaces with ``timeit`` (figures: CPython 3.11.7, the bench machine, best of 5
runs of 10^6, timeit's loop included on both sides):

* **Slot setters** (:func:`slot_setter`): a frozen slotted dataclass built with
  ``object.__new__(cls)`` and one slot setter per field skips the generated ``__init__``, which
  goes through ``object.__setattr__`` once per field. :func:`make_frame` (every frame a sender
  builds) and the stream decoder (every frame received, written out inline in
  ``FrameDecoder._decode_runs``) build :class:`Frame` this way: 521 ns -> 286 ns a frame (1.8x).
  :func:`message` builds the :class:`~hwbridge.protocols.base.Message` event of every topic
  message: 354 ns -> 225 ns (1.6x). The service events (one per call, next to tens of
  microseconds of the call itself) are built plainly: the ~130 ns it would save did not show in
  a call's cost. The decoders of SERVICE_REQUEST and SERVICE_RESPONSE (``_control/calls.py``)
  use setters and one precompiled ``struct`` unpack too: 394 ns against 825 ns for the generic
  ``_Reader`` path (2.1x), 453 ns against 1310 ns (2.9x). The bench cannot time those two (the
  generic path only runs, through public names, on a payload too short to decode); the figures
  come from one ``timeit`` run against the reader code written out. A call on its service's own
  channel (SERVICE_CHANNELS) has neither decoder nor message object: ``_session/services.py``
  reads its request id (and status) where the message lies and hands the fields on.
* **Enum members as module globals** (:data:`ACK`, :data:`CONNECTED`, ...): ``x is
  SessionState.CONNECTED`` costs ~65 ns on Python 3.11 (the enum metaclass defines
  ``__getattr__``), ``x is CONNECTED`` ~8 ns (7.8x); per frame they are tested several times.
* **Inlined code** (written out where it runs, each place marked with a comment): the session's
  ``receive_data`` and ``tick`` take their events without calling ``_take_events``; its
  ``_on_frame``, ``_on_best_effort`` and ``_on_control`` set ``_last_rx`` instead of calling
  ``_alive``; the stream decoder's loop binds its globals to locals and builds frames inline;
  ``encode_frame`` checks and appends a carried ACK and computes CRC and COBS itself.
  Each saves one Python method call per frame or per read: ~17 ns on Python 3.11 (24 ns for
  ``self._alive(now)`` against 7 ns for the attribute set, measured once; not in the bench).

Anything not on a per-message path is written plainly.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Final, TypeVar

from hwbridge.protocols.base import Message
from hwbridge.protocols.native._control.common import ServiceStatus
from hwbridge.protocols.native._framing.frames import Frag, Frame, FrameType
from hwbridge.protocols.native._session.config import SessionState

__all__ = [
    "ACK",
    "BEST_EFFORT",
    "CLOSED",
    "CONFIGURING",
    "CONNECTED",
    "RELIABLE",
    "SERVICE_ERROR",
    "SERVICE_NO_SERVICE",
    "SERVICE_OK",
    "WHOLE",
    "make_frame",
    "message",
    "slot_setter",
    "with_ack",
]

_T = TypeVar("_T")


def slot_setter(cls: type[_T], name: str) -> Callable[[_T, Any], None]:
    """The setter of the slot ``name`` of a slotted dataclass ``cls``, frozen or not."""
    setter: Callable[[_T, Any], None] = vars(cls)[name].__set__
    return setter


# ---- enum members ---------------------------------------------------------------------------

ACK: Final = FrameType.ACK
BEST_EFFORT: Final = FrameType.BEST_EFFORT
RELIABLE: Final = FrameType.RELIABLE
WHOLE: Final = Frag.WHOLE
CONFIGURING: Final = SessionState.CONFIGURING
CONNECTED: Final = SessionState.CONNECTED
CLOSED: Final = SessionState.CLOSED
SERVICE_OK: Final = ServiceStatus.OK
SERVICE_ERROR: Final = ServiceStatus.ERROR
SERVICE_NO_SERVICE: Final = ServiceStatus.NO_SERVICE

# ---- frames ---------------------------------------------------------------------------------

NEW_FRAME: Final[Callable[[type[Frame]], Frame]] = object.__new__
SET_TYPE: Final = slot_setter(Frame, "type")
SET_CHANNEL: Final = slot_setter(Frame, "channel")
SET_SEQ: Final = slot_setter(Frame, "seq")
SET_PAYLOAD: Final = slot_setter(Frame, "payload")
SET_FRAG: Final = slot_setter(Frame, "frag")
SET_ACK: Final = slot_setter(Frame, "ack")


def make_frame(
    type: FrameType, channel: int, seq: int, payload: bytes, frag: Frag = Frag.WHOLE
) -> Frame:
    """``Frame(type, channel, seq, payload, frag)`` built the fast way (the senders' hot path).

    The arguments are taken as they are (``payload`` must be ``bytes``); like ``Frame(...)``,
    nothing is range-checked until the frame is encoded.
    """
    frame = NEW_FRAME(Frame)
    SET_TYPE(frame, type)
    SET_CHANNEL(frame, channel)
    SET_SEQ(frame, seq)
    SET_PAYLOAD(frame, payload)
    SET_FRAG(frame, frag)
    SET_ACK(frame, None)
    return frame


def with_ack(frame: Frame, ack: int) -> Frame:
    """A copy of ``frame`` carrying ``ack`` (``dataclasses.replace(frame, ack=ack)`` without its
    field-by-field introspection: the host pays it on every service request it sends)."""
    copy = NEW_FRAME(Frame)
    SET_TYPE(copy, frame.type)
    SET_CHANNEL(copy, frame.channel)
    SET_SEQ(copy, frame.seq)
    SET_PAYLOAD(copy, frame.payload)
    SET_FRAG(copy, frame.frag)
    SET_ACK(copy, ack)
    return copy


# ---- events ---------------------------------------------------------------------------------

_set_message: Final = tuple(slot_setter(Message, name) for name in ("channel", "payload", "seq"))


def message(channel: int, payload: bytes, seq: int) -> Message:
    """``Message(channel, payload, seq)``, the event of every topic message received."""
    event = object.__new__(Message)
    set_channel, set_payload, set_seq = _set_message
    set_channel(event, channel)
    set_payload(event, payload)
    set_seq(event, seq)
    return event
