"""A model of what a Mega 2560 with Debian's stk500v2 bootloader does after a reset, as the board's
end of a link sees it (the facts are the bootloader's source, ``stk500boot.c``, and runs of the real
one in simavr: ``tests/sim/test_upload.py``): it says nothing; a byte within its first second makes
it wait for an upload, and it goes on to the sketch 5 s after the last byte it received; with no
byte in that first second it goes on at its end. The sketch is then ``start()``, a new board
session. It stands in for the board in the protocol tests' simulated links."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

FIRST_WINDOW = 1.0
"""Seconds after a reset in which any byte makes the bootloader wait for an upload."""
WAIT_AFTER_BYTE = 5.0
"""Seconds of silence after the last byte before it gives up and starts the sketch."""


class Stk500v2:
    """A reset board in its bootloader at ``reset_at``; :attr:`app` once the sketch runs."""

    def __init__(self, start: Callable[[float], Any], reset_at: float) -> None:
        self._start = start
        self.reset_at = reset_at
        self.last_byte: float | None = None
        self.bytes_taken = 0
        self.app: Any = None
        """The sketch's session once the bootloader left (None before)."""

    @property
    def running(self) -> bool:
        return self.app is not None

    def leaves_at(self) -> float:
        if self.last_byte is None:
            return self.reset_at + FIRST_WINDOW
        return self.last_byte + WAIT_AFTER_BYTE

    def _advance(self, now: float) -> None:
        if self.app is None and now >= self.leaves_at():
            self.app = self._start(now)

    def receive_data(self, data: bytes, now: float) -> list[Any]:
        self._advance(now)
        if self.app is not None:
            return list(self.app.receive_data(data, now))
        if data:
            self.last_byte = now
            self.bytes_taken += len(data)
        return []

    def tick(self, now: float) -> list[Any]:
        self._advance(now)
        return list(self.app.tick(now)) if self.app is not None else []

    def data_to_send(self) -> bytes:
        return bytes(self.app.data_to_send()) if self.app is not None else b""

    def next_deadline(self) -> float | None:
        if self.app is None:
            return self.leaves_at()
        deadline: float | None = self.app.next_deadline()
        return deadline

    @property
    def connected(self) -> bool:
        return self.app is not None and bool(self.app.connected)
