"""The bridge runtime: boards on links, mirrored onto the graph (see :mod:`.core`)."""

from hwbridge.bridge.board import PROTOCOLS, BoardConnection, BoardSpec
from hwbridge.bridge.core import Bridge

__all__ = ["PROTOCOLS", "BoardConnection", "BoardSpec", "Bridge"]
