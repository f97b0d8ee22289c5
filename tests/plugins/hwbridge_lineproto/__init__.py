"""A toy protocol and a link that hwbridge knows only through entry points (a test plugin).

The ``lines`` protocol is text, one command per line::

    board -> host   TOPIC <channel> pub|sub <name> <type> <md5>   declare an endpoint
                    READY                                          the table is complete
                    MSG <channel> <hex>                            a message on a board publisher
    host -> board   HELLO                                          the probe: "say your table"
                    MSG <channel> <hex>                            a message to a board subscriber

``linepipe://NAME`` is an in-process stream pipe (the memory link under another scheme).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from hwbridge.errors import HwBridgeError
from hwbridge.links.memory import MemoryLink
from hwbridge.protocols import base
from hwbridge.protocols.registry import ProtocolSpec, SessionContext

__all__ = ["PROTOCOL", "LineFraming", "LinePipeLink", "LineSession"]


class LinePipeLink(MemoryLink):
    """``linepipe://NAME``: the two ends of an in-process pipe."""

    scheme = "linepipe"


class LineFraming:
    """Frames are lines: a stream framing that splits on newlines."""

    datagram = False

    def __init__(self) -> None:
        self._partial = b""

    def decode(self, data: bytes, /) -> Sequence[bytes]:
        lines = (self._partial + data).split(b"\n")
        self._partial = lines.pop()
        return [line for line in lines if line]

    def encode(self, frames: Sequence[Any], now: float, /) -> list[bytes]:
        return [b"".join(bytes(frame) + b"\n" for frame in frames)] if frames else []


class LineSession:
    """The host side of a ``lines`` board (a :class:`~hwbridge.protocols.base.BoardSession`)."""

    def __init__(self) -> None:
        self._framing = LineFraming()
        self._table: dict[int, base.Endpoint] = {}
        self._out: list[bytes] = [b"HELLO"]
        self._ready = False
        self._received = 0

    @property
    def connected(self) -> bool:
        return self._ready

    def receive_data(self, data: bytes, now: float, /) -> list[base.Event]:
        events: list[base.Event] = []
        for line in self._framing.decode(data):
            self._received += 1
            word, _, rest = line.decode("ascii").partition(" ")
            if word == "TOPIC":
                channel, kind, name, type_name, md5 = rest.split(" ")
                direction = base.EntryKind.PUBLISHER if kind == "pub" else base.EntryKind.SUBSCRIBER
                self._table[int(channel)] = base.Endpoint(
                    int(channel), direction, name, type_name, md5
                )
            elif word == "READY":
                self._ready = True
                events.append(base.Connected(tuple(self._table.values()), board_name="lines-board"))
            elif word == "MSG" and self._ready:
                channel, payload = rest.split(" ")
                events.append(base.Message(int(channel), bytes.fromhex(payload), 0))
            else:
                events.append(base.Error(HwBridgeError(f"lines: cannot use {line!r}")))
        return events

    def tick(self, now: float, /) -> list[base.Event]:
        return []

    def next_deadline(self) -> float | None:
        return None

    def chunks_to_send(self) -> list[bytes]:
        chunks = self._framing.encode(self._out, 0.0)
        self._out = []
        return chunks

    def counters(self) -> base.SessionStats:
        return base.SessionStats(frames_received=self._received, sessions=int(self._ready))

    def describe(self) -> dict[str, Any]:
        return {"endpoints": len(self._table)}

    def publish(self, channel: int, payload: bytes, /) -> bool:
        self._out.append(f"MSG {channel} {payload.hex()}".encode())
        return True

    def call_service(self, channel: int, request: bytes, *, timeout: float, now: float) -> int:
        raise HwBridgeError("the lines protocol has no services")

    def respond_service(
        self, channel: int, request_id: int, payload: bytes = b"", *, error: str | None = None
    ) -> bool:
        return False

    def answer_param(self, request_id: int, value: Any, /) -> bool:
        return False

    def push_param(self, name: str, value: Any, /) -> bool:
        return False

    def close(self, now: float, /) -> list[base.Event]:
        self._ready = False
        return []


class _Detector:
    def __init__(self) -> None:
        self._seen = b""

    def feed(self, data: bytes, /) -> bool:
        self._seen = (self._seen + data)[-64:]
        return b"\nREADY\n" in self._seen or self._seen.startswith(b"TOPIC ")


def _new_session(context: SessionContext) -> LineSession:
    if context.datagram:
        raise HwBridgeError("the lines protocol runs on stream links only")
    return LineSession()


PROTOCOL = ProtocolSpec(
    name="lines",
    summary="a toy text protocol (tests)",
    new_session=_new_session,
    detector=_Detector,
)
