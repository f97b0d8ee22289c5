"""The records of the rosserial device emulation: endpoints, events and counters.

They are defined here and re-exported by :mod:`hwbridge.protocols.rosserial.device`, where
:class:`~hwbridge.protocols.rosserial.device.RosserialDevice` uses them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import TypeAlias

__all__ = [
    "Configured",
    "DeviceEvent",
    "DeviceStats",
    "Endpoint",
    "InputOverrun",
    "ParamResult",
    "Received",
    "ServiceCalled",
    "ServiceEndpoint",
    "ServiceHandler",
    "ServiceResult",
    "TimeSynced",
    "Unconfigured",
]

ServiceHandler: TypeAlias = Callable[[bytes], "bytes | None"]
"""A device service server's callback: request bytes -> response bytes (None: never answer)."""


@dataclass(frozen=True)
class Endpoint:
    """A publisher or subscriber: topic name, message type and md5 (None: the registry's)."""

    name: str
    type: str
    md5: str | None = None


@dataclass(frozen=True)
class ServiceEndpoint:
    """A service server (with ``handler``) or client; half md5s default to the registry's."""

    name: str
    type: str
    handler: ServiceHandler | None = None
    request_md5: str | None = None
    response_md5: str | None = None


# ---------------------------------------------------------------------------------- events
@dataclass(frozen=True)
class Configured:
    """The device answered "request topics" and is now configured."""


@dataclass(frozen=True)
class Unconfigured:
    """The device stopped being configured: ``tx_stop``, ``sync_timeout`` or ``reset``."""

    reason: str


@dataclass(frozen=True)
class Received:
    """A subscriber callback ran with ``payload``."""

    topic: str
    payload: bytes


@dataclass(frozen=True)
class ServiceCalled:
    """The host called the device's service server ``name``."""

    name: str
    request: bytes


@dataclass(frozen=True)
class ServiceResult:
    """A device service client call returned; ``response`` is None if it gave up (unconfigured)."""

    name: str
    response: bytes | None


@dataclass(frozen=True)
class ParamResult:
    """A parameter request ended; ``ok`` is False on timeout (the arrays are then empty)."""

    name: str
    ok: bool
    ints: tuple[int, ...] = ()
    floats: tuple[float, ...] = ()
    strings: tuple[str, ...] = ()


@dataclass(frozen=True)
class TimeSynced:
    """A time reply set the device clock; ``sec``/``nsec`` is its time right after."""

    sec: int
    nsec: int


@dataclass(frozen=True)
class InputOverrun:
    """A frame's payload is larger than ``input_size``: the real library would overrun memory."""

    topic_id: int
    size: int


DeviceEvent: TypeAlias = (
    Configured
    | Unconfigured
    | Received
    | ServiceCalled
    | ServiceResult
    | ParamResult
    | TimeSynced
    | InputOverrun
)


@dataclass(slots=True)
class DeviceStats:
    """Counters of a :class:`RosserialDevice`."""

    frames_in: int = 0
    """Frames whose checksums passed."""
    frames_out: int = 0
    bytes_out: int = 0
    length_checksum_errors: int = 0
    checksum_errors: int = 0
    timed_out_frames: int = 0
    """Frames abandoned because they took more than 20 ms to arrive."""
    version_mismatches: int = 0
    dropped_unconfigured: int = 0
    """Publications dropped because the device was not configured."""
    dropped_too_large: int = 0
    input_overruns: int = 0
    unknown_topic: int = 0
    """Frames on ids with no subscriber slot (undefined behaviour in the real library)."""
    stray_responses: int = 0
    """Service responses or parameter answers that nothing waited for."""
    undecodable: int = 0
    time_requests: int = 0
    time_syncs: int = 0
    negotiations: int = 0

    def as_dict(self) -> dict[str, int]:
        """Counters by name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}
