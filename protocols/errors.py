"""The error tree shared by every layer of hwbridge.

Everything hwbridge raises on purpose derives from :class:`HwBridgeError`, so a caller can catch
one class and know that anything else is a bug. The tree lives in the bottom layer (``protocols``)
so that wire-format code can raise it without importing the runtime; ``hwbridge.errors``
re-exports it for users.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path


class HwBridgeError(Exception):
    """Root of every error hwbridge raises on purpose."""


class MessageTypeError(HwBridgeError):
    """A message or service type is unknown, malformed, or a value does not fit its type."""


class UnknownTypeError(MessageTypeError, KeyError):
    """A type name was not found; ``suggestions`` holds the closest known names, ``searched``
    the folders of the search path (named in the message: a misplaced package shows)."""

    def __init__(
        self,
        name: str,
        suggestions: list[str],
        kind: str = "message type",
        searched: Sequence[Path] = (),
    ) -> None:
        self.name = name
        self.suggestions = suggestions
        self.kind = kind
        self.searched = tuple(searched)
        where = (
            f" (searched {', '.join(map(str, searched))} and the built-in types)"
            if searched
            else ""
        )
        hint = f"; did you mean {', '.join(suggestions)}?" if suggestions else ""
        super().__init__(f"unknown {kind} {name!r}{where}{hint}")

    def __str__(self) -> str:  # KeyError would otherwise quote the whole message
        return str(self.args[0])


class DefinitionError(MessageTypeError):
    """A .msg or .srv definition is malformed; names the file, the line and the problem."""

    def __init__(self, path: str, line: int | None, problem: str) -> None:
        self.path = path
        self.line = line
        self.problem = problem
        where = f"{path}:{line}" if line is not None else path
        super().__init__(f"{where}: {problem}")


class SerializationError(MessageTypeError):
    """Bytes do not decode as the given type, or a value cannot be encoded as it."""


class LinkError(HwBridgeError):
    """A link (serial port, socket, pty, bus) failed to open, read or write."""


class FramingError(HwBridgeError):
    """Bytes on the wire do not form a valid frame."""


class ProtocolError(HwBridgeError):
    """A peer broke the rules of the protocol session."""


class ProtocolMismatchError(ProtocolError):
    """Both ends disagree on a protocol version or a message type (md5)."""


class HwBridgeTimeoutError(HwBridgeError, TimeoutError):
    """An operation did not complete in the time allowed."""


class NoServerError(HwBridgeTimeoutError):
    """A request that no server took: nothing answered it, not even with an error, so nothing
    acted on it (asking again once a server is there is safe)."""
