"""Counters of native sessions: what the session counts and the snapshot it gives.

Each counter is declared once, in the object that counts it: :class:`SequenceStats` (the
sequencing and reliability layer) or :class:`SessionCounters` (the rest); :class:`NativeStats`
takes their names from those declarations.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Final

from hwbridge.protocols.base import SessionStats
from hwbridge.protocols.native.reliable import SequenceStats


@dataclass(slots=True)
class SessionCounters:
    """What one end of a native link counts beside its sequencing layer (:class:`SequenceStats`).

    The session adds to them as it runs; a snapshot (:class:`NativeStats`) copies them. The first
    five are :class:`~hwbridge.protocols.base.SessionStats` fields, the rest native's own.
    """

    frames_sent: int = 0
    bytes_sent: int = 0
    dropped_messages: int = 0
    protocol_errors: int = 0
    sessions: int = 0
    ignored_frames: int = 0
    """Valid frames that did not belong to the current session (e.g. before the handshake)."""
    tx_refused: int = 0
    """Sends refused because the session was not connected or the queue was full."""
    hellos_sent: int = 0
    heartbeats_sent: int = 0
    link_losses: int = 0
    """Sessions ended by the link timeout or the retry limit."""
    peer_resets: int = 0
    """Sessions ended because the peer restarted or dropped the session."""
    stalls: int = 0
    """Times this end was not run for longer than twice the heartbeat interval (a starved or
    stopped process); that time does not count towards the link timeout (PROTOCOL.md 2.9)."""


_SHARED: Final = frozenset(f.name for f in fields(SessionStats))
OWN_COUNTERS: Final = tuple(
    name
    for name in (f.name for f in fields(SequenceStats) + fields(SessionCounters))
    if name not in _SHARED
)
"""Native's own counters, in the order :meth:`NativeStats.as_dict` lists them (before ``rtt``
and ``rto``): those of :class:`SequenceStats`, then those of :class:`SessionCounters`."""
_OWN: Final = frozenset(OWN_COUNTERS)
_SESSION: Final = frozenset(f.name for f in fields(SessionCounters))


@dataclass(frozen=True, slots=True, kw_only=True)
class NativeStats(SessionStats):
    """Counters of one end of a native link (cumulative over sessions) and its RTT estimate.

    The shared :class:`~hwbridge.protocols.base.SessionStats` counters (frames and bytes each
    way, ``bad_frames`` for runs the decoder rejected for any reason, CRC errors included,
    ``non_frame_bytes``, ``dropped_messages`` for messages on channels that are unknown, refused
    or not yet connected, ``protocol_errors``, ``sessions`` established) plus native's own, which
    are declared once, where they are counted: :class:`SequenceStats` (the sequencing and
    reliability layer) and :class:`SessionCounters` (the rest). They are in ``detail`` with
    ``rtt`` and ``rto``, and read as attributes too (``stats.retransmits``); ``as_dict()`` gives
    them all by name.
    """

    @property
    def rtt(self) -> float | None:
        """Smoothed round-trip time of reliable frames, seconds (None before a sample)."""
        value = self.detail.get("rtt")
        return None if value is None else float(value)

    @property
    def rto(self) -> float:
        """The retransmission timeout, seconds."""
        return float(self.detail.get("rto") or 0.0)

    def __getattr__(self, name: str) -> int:
        """One of native's own counters (``stats.retransmits``); 0 if ``detail`` lacks it."""
        if name not in _OWN:
            raise AttributeError(f"'{type(self).__name__}' object has no attribute '{name}'")
        return int(self.detail.get(name) or 0)


def native_detail(
    sequence: SequenceStats, session: SessionCounters, rtt: float | None, rto: float
) -> dict[str, int | float | None]:
    """:attr:`NativeStats.detail`: native's own counters copied from where they are counted."""
    detail: dict[str, int | float | None] = {
        name: getattr(session if name in _SESSION else sequence, name) for name in OWN_COUNTERS
    }
    detail["rtt"] = rtt
    detail["rto"] = rto
    return detail
