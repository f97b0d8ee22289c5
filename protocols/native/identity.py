"""The firmware identity in BOARD_INFO's ``firmware_version`` text (PROTOCOL.md 2.6.1).

The text is the sketch's own version on its first line, then one line per identity item,
``"\\n" KEY "=" VALUE``, and a final ``"\\n"``::

    0.1.0\\ns=1a2b3c4d\\nm=5e6f7a8b\\nb=demo/base@0123456789ab\\nv=0.1.0\\nn=demo/base\\n

The keys, their order and the hash length are the schema's (``identity`` in ``schema.json``). A
line counts only when the ``"\\n"`` after it arrived: a board whose send buffer is too small for
the whole text cuts its last items off, never sends a shortened value. A text with no item (an old
board: ``"0.1.0"``) is an unknown identity. Unknown keys and lines without ``=`` are ignored, so
that later items can be added.

Pure data: nothing here keeps state.
"""

from __future__ import annotations

import functools
from typing import Final

from hwbridge.protocols.base import FirmwareIdentity
from hwbridge.protocols.native._control.schema import load_schema

__all__ = ["ITEM_KEYS", "format_identity", "parse_identity", "schema_hash"]


@functools.cache
def _items() -> tuple[tuple[str, str], ...]:
    return tuple(load_schema().identity.items.items())


ITEM_KEYS: Final = dict(_items())
"""FirmwareIdentity attribute -> its one-letter key on the wire, in the order boards send them."""


@functools.cache
def schema_hash() -> str:
    """The hash of the control-message schema this host speaks (what a board built from the
    same schema sends as ``schema_hash``)."""
    return load_schema().hash


def parse_identity(text: str) -> FirmwareIdentity:
    """The identity in a BOARD_INFO ``firmware_version`` text; never raises (garbage gives an
    identity with fewer items, or none)."""
    lines = text.split("\n")
    found: dict[str, str] = {}
    by_key = {key: attr for attr, key in _items()}
    for line in lines[1:-1]:  # the last piece has no "\n" after it: cut, or empty
        key, sep, value = line.partition("=")
        attr = by_key.get(key)
        if sep and attr is not None and attr not in found:
            found[attr] = value
    return FirmwareIdentity(version=lines[0], **found)


def format_identity(identity: FirmwareIdentity) -> str:
    """The ``firmware_version`` text of ``identity`` (what a board built with it sends): its
    version, then every item that is not empty. ValueError if a value holds a line break."""
    parts = [identity.version]
    for attr, key in _items():
        value: str = getattr(identity, attr)
        if value:
            parts.append(f"{key}={value}")
    for part in parts:
        if "\n" in part:
            raise ValueError(f"a firmware identity value holds a line break: {part!r}")
    if len(parts) == 1:
        return identity.version
    return "\n".join(parts) + "\n"
