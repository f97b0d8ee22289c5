"""Errors raised by hwbridge (re-exported from the bottom layer, ``hwbridge.protocols.errors``)."""

from hwbridge.protocols.errors import (
    DefinitionError,
    FramingError,
    HwBridgeError,
    HwBridgeTimeoutError,
    LinkError,
    MessageTypeError,
    NoServerError,
    ProtocolError,
    ProtocolMismatchError,
    SerializationError,
    UnknownTypeError,
)

__all__ = [
    "DefinitionError",
    "FramingError",
    "HwBridgeError",
    "HwBridgeTimeoutError",
    "LinkError",
    "MessageTypeError",
    "NoServerError",
    "ProtocolError",
    "ProtocolMismatchError",
    "SerializationError",
    "UnknownTypeError",
]
