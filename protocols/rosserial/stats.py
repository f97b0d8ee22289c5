"""Counters of the rosserial host, and how they map onto the common :class:`SessionStats`."""

from __future__ import annotations

from dataclasses import dataclass, fields

from hwbridge.protocols.base import SessionStats
from hwbridge.protocols.rosserial.framing import ParserStats

__all__ = ["HostStats"]


@dataclass(slots=True)
class HostStats:
    """Counters of a ``RosserialHost``; ``framing`` holds the receive parser's counters."""

    framing: ParserStats
    tx_frames: int = 0
    tx_bytes: int = 0
    time_syncs: int = 0
    """Time requests answered."""
    topic_requests: int = 0
    """"Request topics" frames sent."""
    topic_infos: int = 0
    topics_refused: int = 0
    """TopicInfos refused (md5 mismatch, undecodable)."""
    unknown_types: int = 0
    """TopicInfos accepted with a type the host does not know (passed through unchecked)."""
    messages_in: int = 0
    messages_out: int = 0
    service_calls: int = 0
    service_responses: int = 0
    service_timeouts: int = 0
    late_service_responses: int = 0
    """Responses that arrived when no call was in flight (after a timeout), dropped."""
    device_service_requests: int = 0
    params_requested: int = 0
    params_answered: int = 0
    logs: int = 0
    unknown_topic_frames: int = 0
    refused_topic_frames: int = 0
    """Frames on the id of a refused topic, dropped."""
    undecodable: int = 0
    """Control frames (TopicInfo, Log, parameter request) that did not decode."""
    sync_lost: int = 0
    silence_probes: int = 0
    """"Request topics" sent because a connected device stopped asking for the time."""
    sessions: int = 0
    """Times the host went from not connected to connected."""

    def as_dict(self) -> dict[str, int]:
        """All counters, the parser's prefixed with ``rx_``."""
        out = {f"rx_{k}": v for k, v in self.framing.as_dict().items()}
        out.update({f.name: getattr(self, f.name) for f in fields(self) if f.name != "framing"})
        return out

    def session_stats(self) -> SessionStats:
        """The common counters (see :class:`SessionStats`); every counter is in ``detail``.

        ``bad_frames`` counts frames failing a checksum, oversize headers and control frames that
        did not decode; ``crc_errors`` the checksum failures (length and frame checksums);
        ``dropped_messages`` frames on unknown or refused topic ids; ``protocol_errors`` refused
        TopicInfos and protocol v1 headers.
        """
        rx = self.framing
        checksums = rx.checksum_errors + rx.length_checksum_errors
        return SessionStats(
            frames_sent=self.tx_frames,
            bytes_sent=self.tx_bytes,
            frames_received=rx.frames,
            bytes_received=rx.bytes,
            bad_frames=checksums + rx.oversize + self.undecodable,
            crc_errors=checksums,
            non_frame_bytes=rx.non_frame_bytes,
            dropped_messages=self.unknown_topic_frames + self.refused_topic_frames,
            protocol_errors=self.topics_refused + rx.old_protocol,
            sessions=self.sessions,
            detail=self.as_dict(),
        )
