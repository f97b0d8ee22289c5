"""Fault injection for virtual boards: what a bad cable, a noisy line or a flaky board does.

:class:`FaultySession` sits between a board's protocol session and its link (sans-I/O, like the
session itself): it drops and corrupts bytes in both directions at given rates and can stall the
board's output for a while, from a seeded RNG. Board resets and unplugging are done by
:class:`~hwbridge.emulator.board.VirtualBoard` (``reset()``, ``unplug()``).
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Any

__all__ = ["FaultySession", "LinkFaults"]


@dataclass(frozen=True)
class LinkFaults:
    """Per-byte probabilities of loss and corruption (each direction)."""

    loss: float = 0.0
    corrupt: float = 0.0

    def __post_init__(self) -> None:
        for name in ("loss", "corrupt"):
            value = getattr(self, name)
            if not 0.0 <= value < 1.0:
                raise ValueError(f"{name} must be in [0, 1), not {value!r}")


class FaultySession:
    """Wraps a session; everything not about bytes passes through to ``inner``."""

    def __init__(self, inner: Any, seed: int = 0) -> None:
        self.inner = inner
        self.faults = LinkFaults()
        self.bytes_lost = 0
        self.bytes_corrupted = 0
        self._rng = random.Random(seed)
        self._stalled_until = 0.0
        self._held = bytearray()
        self._now = 0.0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def stall(self, until: float) -> None:
        """Hold everything the board sends until monotonic time ``until``."""
        self._stalled_until = until

    def _damage(self, data: bytes) -> bytes:
        faults = self.faults
        if not data or (faults.loss == 0.0 and faults.corrupt == 0.0):
            return data
        out = bytearray()
        rng = self._rng
        for byte in data:
            roll = rng.random()
            if roll < faults.loss:
                self.bytes_lost += 1
                continue
            if roll < faults.loss + faults.corrupt:
                self.bytes_corrupted += 1
                out.append(byte ^ (1 << rng.randrange(8)))
            else:
                out.append(byte)
        return bytes(out)

    def receive_data(self, data: bytes, now: float) -> list[Any]:
        self._now = now
        result: list[Any] = self.inner.receive_data(self._damage(data), now)
        return result

    def tick(self, now: float) -> list[Any]:
        self._now = now
        result: list[Any] = self.inner.tick(now)
        return result

    def chunks_to_send(self) -> list[bytes]:
        """What the board writes, damaged; on a stream link (virtual boards are on one), so it
        is held back whole while stalled and goes out as one chunk."""
        chunks: list[bytes] = self.inner.chunks_to_send()
        for chunk in chunks:
            self._held += self._damage(chunk)
        if self._now < self._stalled_until or not self._held:
            return []
        data, self._held = bytes(self._held), bytearray()
        return [data]

    def data_to_send(self) -> bytes:
        return b"".join(self.chunks_to_send())

    def next_deadline(self) -> float | None:
        deadline: float | None = self.inner.next_deadline()
        if self._held and self._stalled_until > self._now:
            return self._stalled_until if deadline is None else min(deadline, self._stalled_until)
        return deadline
