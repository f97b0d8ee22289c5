"""Time sync of a native session: requests both ways, the offset between the two clocks.

PROTOCOL.md 2.8. Each end asks every ``time_sync_interval`` and answers the other's requests;
the offset is that of the best of the last few samples (the newest with a short round trip).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from typing import Any, TypeVar

from hwbridge.protocols.native._control.common import Features
from hwbridge.protocols.native._session.config import (
    _MAX_TIME_AGE,
    _U32,
    HostConfig,
    SessionError,
)
from hwbridge.protocols.native._session.core import SessionCore
from hwbridge.protocols.native._session.events import TimeSynced
from hwbridge.protocols.native.control import (
    HostTimeRequestMsg,
    HostTimeResponseMsg,
    TimeRequestMsg,
    TimeResponseMsg,
)

_S = TypeVar("_S", bound=tuple[float, ...])


def _best_sample(samples: Iterable[_S]) -> _S:
    """The newest time sample whose RTT is within 25 % (or 0.1 ms) of the smallest one.

    A short round trip bounds the offset error best (NTP's clock filter); among similar round
    trips the newest wins, because clocks drift.
    """
    items = list(samples)
    floor = min(item[0] for item in items)
    limit = floor + max(floor * 0.25, 1e-4)
    return [item for item in items if item[0] <= limit][-1]


class TimeSync(SessionCore[Any]):
    """What both ends do: start an exchange, schedule the next one."""

    def _time_answered(self) -> None:
        self._time_next = self._now + self._cfg.time_sync_interval


class HostTime(TimeSync):
    """The host's side: it asks the board's microsecond counter and answers in host time."""

    _host_cfg: HostConfig

    def board_to_host(self, board_us: int) -> float:
        """Host time of a board timestamp (its 32-bit microsecond counter).

        Valid within +-35 minutes of the last time sync.

        Raises:
            SessionError: no time sync has completed in this session.
        """
        _, host_ref, board_ref = self._best_time_sample()
        delta = (board_us - int(board_ref)) % _U32
        if delta >= _U32 // 2:
            delta -= _U32
        return host_ref + delta / 1e6

    def host_to_board(self, host_time: float) -> int:
        """The board's 32-bit microsecond counter at a host time.

        Raises:
            SessionError: no time sync has completed in this session.
        """
        _, host_ref, board_ref = self._best_time_sample()
        return (int(board_ref) + round((host_time - host_ref) * 1e6)) % _U32

    @property
    def time_offset(self) -> float | None:
        """Host time minus board time (board counter as seconds), None before a sync."""
        if not self._time_samples:
            return None
        _, host_ref, board_ref = _best_sample(self._time_samples)
        return host_ref - board_ref / 1e6

    def _best_time_sample(self) -> tuple[float, float, float]:
        if not self._time_samples:
            raise SessionError("no time sync with the board has completed in this session")
        return _best_sample(self._time_samples)

    def _host_time_ns(self) -> int:
        # whole microseconds: a float of ~1.7e9 s carries nothing finer
        return max(0, round((self._now + self._host_cfg.epoch_offset) * 1e6) * 1000)

    def _send_time_request(self) -> None:
        self._send_control_be(HostTimeRequestMsg(self._host_time_ns()))

    def _answer_time_request(self, msg: TimeRequestMsg) -> None:
        if self._cfg.features & Features.TIME_SYNC:
            now_ns = self._host_time_ns()
            self._send_control_be(TimeResponseMsg(msg.t1_us, now_ns, now_ns))

    def _on_time_response(self, msg: HostTimeResponseMsg) -> None:
        now = self._now
        t1 = msg.t1_ns / 1e9 - self._host_cfg.epoch_offset
        if not 0 <= now - t1 <= _MAX_TIME_AGE:
            return
        board_busy = ((msg.t3_us - msg.t2_us) % _U32) / 1e6
        rtt = max(0.0, (now - t1) - board_busy)
        host_mid = (t1 + now) / 2 + self._host_cfg.epoch_offset
        board_mid_us = (msg.t2_us + ((msg.t3_us - msg.t2_us) % _U32) / 2) % _U32
        self._time_samples.append((rtt, host_mid, board_mid_us))
        self._time_answered()
        offset = self.time_offset
        assert offset is not None
        self._events.append(TimeSynced(offset, rtt))


class DeviceTime(TimeSync):
    """The board's side: its clock is the session's ``now``; it learns host time."""

    _time_offset_samples: deque[tuple[float, float]]

    def to_host_time(self, device_time: float) -> float:
        """Host time at a device time (both seconds; device time is this session's ``now``).

        Raises:
            SessionError: no time sync has completed in this session.
        """
        return device_time + self._offset()

    def to_device_time(self, host_time: float) -> float:
        """Device time at a host time.

        Raises:
            SessionError: no time sync has completed in this session.
        """
        return host_time - self._offset()

    @property
    def time_offset(self) -> float | None:
        """Host time minus device time (seconds), None before a sync."""
        if not self._time_offset_samples:
            return None
        return _best_sample(self._time_offset_samples)[1]

    def _offset(self) -> float:
        offset = self.time_offset
        if offset is None:
            raise SessionError("no time sync with the host has completed in this session")
        return offset

    def _send_time_request(self) -> None:
        self._send_control_be(TimeRequestMsg(self._device_us()))

    def _device_us(self) -> int:
        return round(self._now * 1e6) % _U32

    def _answer_time_request(self, msg: HostTimeRequestMsg) -> None:
        if self._cfg.features & Features.TIME_SYNC:
            now_us = self._device_us()
            self._send_control_be(HostTimeResponseMsg(msg.t1_ns, now_us, now_us))

    def _on_time_response(self, msg: TimeResponseMsg) -> None:
        now = self._now
        elapsed = ((self._device_us() - msg.t1_us) % _U32) / 1e6
        if elapsed > _MAX_TIME_AGE:
            return
        t1 = now - elapsed
        t2, t3 = msg.t2_ns / 1e9, msg.t3_ns / 1e9
        rtt = max(0.0, elapsed - (t3 - t2))
        offset = ((t2 - t1) + (t3 - now)) / 2
        self._time_offset_samples.append((rtt, offset))
        self._time_answered()
        best = self.time_offset
        assert best is not None
        self._events.append(TimeSynced(best, rtt))
