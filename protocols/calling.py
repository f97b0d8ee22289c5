"""How a host calls a board that does not answer: in bursts, with silence between them.

Some boards reset into a bootloader that takes any byte it receives as the start of an upload
and then waits for the next one: the Mega 2560's stk500v2 goes on to the sketch only 5 s after
the last byte. A host that kept calling a silent board (detection probes, native HELLOs,
rosserial's "request topics") every second or faster would hold such a board in its bootloader
for as long as it runs: after the port's open resets it, or its reset button, or a brown-out.
So on stream links a host calls a silent board for at most :data:`CALL_BURST` seconds, then
leaves it :data:`BOOTLOADER_QUIET` seconds of silence, then calls again, and so on, each pause
half as long again as the last up to :data:`PAUSE_MAX`. Answers to what the board says are
never held back, and a board that speaks ends the silence.
"""

from __future__ import annotations

import math
from typing import Final

__all__ = [
    "BOOTLOADER_QUIET",
    "CALL_BURST",
    "PAUSE_GROWTH",
    "PAUSE_MAX",
    "check_bursts",
    "may_call",
    "next_call",
]

CALL_BURST: Final = 5.0
"""Seconds a host calls a board that does not answer before it falls silent."""

BOOTLOADER_QUIET: Final = 6.0
"""Seconds of silence that let a reset board out of a bootloader that waits after each byte: the
Mega 2560's stk500v2 leaves for the sketch 5 s after the last byte it received (F_CPU/2 turns of
its receive loop at 16 MHz; 5.0 s measured in simavr). The first pause; each next one is
:data:`PAUSE_GROWTH` times longer, up to :data:`PAUSE_MAX`, for a bootloader slower to give up
(or a simulated board running behind real time)."""

PAUSE_GROWTH: Final = 1.5
PAUSE_MAX: Final = 20.0


def check_bursts(burst: float, pause: float) -> None:
    """Raise ValueError unless ``burst`` is at least 0 (0: no pauses) and ``pause`` above 0."""
    if not (burst >= 0 and pause > 0):
        raise ValueError(f"need call_burst >= 0 and call_pause > 0, not {burst}, {pause}")


def _cycle(now: float, since: float, burst: float, pause: float) -> tuple[float, float]:
    """The start of the burst-and-pause cycle ``now`` is in, and that cycle's pause: cycles
    begin at ``since``, each a ``burst`` then a pause, the first ``pause`` long and each next one
    PAUSE_GROWTH times the last, up to PAUSE_MAX (or ``pause``, if longer)."""
    start, quiet = since, pause
    longest = max(pause, PAUSE_MAX)
    while quiet < longest and now >= start + burst + quiet:
        start += burst + quiet
        quiet = min(quiet * PAUSE_GROWTH, longest)
    period = burst + quiet
    if now >= start + period:  # the pauses stopped growing: the cycles repeat
        start += math.floor((now - start) / period) * period
    return start, quiet


def _in_burst(now: float, since: float, burst: float, start: float, quiet: float) -> bool:
    """Whether ``now`` falls in the burst of the cycle that begins at ``start`` (``_cycle``)."""
    slack = 1e-9 * max(1.0, now - since)  # a burst's start as next_call() computes it, rounded
    return now - start < burst + slack or start + burst + quiet - now < slack


def may_call(now: float, since: float, burst: float, pause: float) -> bool:
    """Whether a host that began calling a silent board at ``since`` may call it at ``now``:
    in the first ``burst`` seconds of each cycle (always with ``burst`` 0)."""
    if burst <= 0 or now < since:
        return True
    return _in_burst(now, since, burst, *_cycle(now, since, burst, pause))


def next_call(now: float, since: float, burst: float, pause: float) -> float:
    """The earliest time from ``now`` on at which :func:`may_call` is true: ``now`` itself
    within a burst, else the start of the next one."""
    if burst <= 0 or now < since:
        return now
    start, quiet = _cycle(now, since, burst, pause)
    return now if _in_burst(now, since, burst, start, quiet) else start + burst + quiet
