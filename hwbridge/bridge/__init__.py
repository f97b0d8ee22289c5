"""The bridge runtime: boards on links, mirrored onto the graph (see :mod:`.core`)."""

from hwbridge.bridge.board import (
    DEFAULT_SERVICE_TIMEOUT,
    BoardConnection,
    BoardSpec,
    check_service_timeout,
)
from hwbridge.bridge.core import Bridge

__all__ = [
    "DEFAULT_SERVICE_TIMEOUT",
    "BoardConnection",
    "BoardSpec",
    "Bridge",
    "check_service_timeout",
]
