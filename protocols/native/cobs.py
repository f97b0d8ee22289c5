"""Consistent Overhead Byte Stuffing with 0x00 as the frame delimiter.

The encoder writes the canonical (shortest) form: a final group of exactly 254 non-zero bytes
is *not* followed by an empty ``0x01`` group. The decoder also accepts that extra ``0x01``, which
some popular implementations (e.g. the Arduino PacketSerial library) emit, so both decode to
the same bytes. See PROTOCOL.md, Part 1, "COBS".
"""

from __future__ import annotations

from typing import Final

from hwbridge.protocols.errors import FramingError

__all__ = [
    "MAX_GROUP",
    "decode",
    "decode_or_none",
    "encode",
    "encode_short",
    "max_encoded_size",
]

MAX_GROUP: Final = 254
"""Most data bytes one code byte can cover (code 0xFF: 254 bytes, no implied zero)."""

_ZERO: Final = b"\x00"


def max_encoded_size(size: int) -> int:
    """Longest COBS encoding of ``size`` bytes that :func:`decode` accepts.

    The canonical encoder never needs more than ``size + max(1, ceil(size / 254))`` bytes;
    the bound returned here, ``size + size // 254 + 1``, also covers encoders that append an
    empty group after a final run of 254 non-zero bytes.
    """
    return size + size // MAX_GROUP + 1


_CODE: Final = tuple(bytes((code,)) for code in range(256))
"""Code byte ``i`` as a one-byte ``bytes``."""


def encode(data: bytes | bytearray | memoryview) -> bytes:
    """Encode ``data``; the result never contains 0x00 and has no trailing delimiter."""
    raw = bytes(data)
    if len(raw) < MAX_GROUP:
        return encode_short(raw)
    groups = raw.split(_ZERO)
    out = bytearray()
    last = len(groups) - 1
    for index, group in enumerate(groups):
        length = len(group)
        start = 0
        while length - start >= MAX_GROUP:
            out.append(0xFF)
            out += group[start : start + MAX_GROUP]
            start += MAX_GROUP
        rest = length - start
        # A group followed by a zero always needs its code byte (the zero is implied by it);
        # the final group needs one unless it was fully covered by 0xFF groups.
        if rest or index < last or length == 0:
            out.append(rest + 1)
            out += group[start:]
    return bytes(out)


def encode_short(raw: bytes) -> bytes:
    """:func:`encode` of fewer than 254 bytes (the frame encoder's hot path).

    No group can reach 254 bytes, so each is just its code byte and its data.
    """
    if _ZERO not in raw:  # the common case: one group
        return _CODE[len(raw) + 1] + raw
    return b"".join([_CODE[len(group) + 1] + group for group in raw.split(_ZERO)])


def decode_or_none(run: bytes) -> bytes | None:
    """Decode one non-empty run that contains no 0x00; ``None`` if it is not valid COBS.

    This is the decoder's hot path: it only zeroes the code bytes in a copy of the run (one
    Python step per group) and falls back to a copying loop when a 0xFF group appears.
    """
    size = len(run)
    pos = run[0]
    if pos == 0xFF:
        return _decode_with_full_groups(run)
    if pos == size:  # one group, no zero inside
        return run[1:]
    buf: bytearray | None = None
    while pos < size:
        code = run[pos]
        if code == 0xFF:
            return _decode_with_full_groups(run)
        if buf is None:
            buf = bytearray(run)
        buf[pos] = 0
        pos += code
    if pos != size or buf is None:
        return None
    del buf[0]
    return bytes(buf)


def _decode_with_full_groups(run: bytes) -> bytes | None:
    """General decoder for runs with 0xFF groups (254 data bytes and no implied zero)."""
    size = len(run)
    out = bytearray()
    pos = 0
    while pos < size:
        code = run[pos]
        end = pos + code
        if end > size:
            return None
        out += run[pos + 1 : end]
        if code != 0xFF and end < size:
            out.append(0)
        pos = end
    return bytes(out)


def decode(data: bytes | bytearray | memoryview) -> bytes:
    """Decode one COBS-encoded block (without its delimiter).

    Raises:
        FramingError: ``data`` is empty, contains 0x00, or a code byte points past its end.
    """
    raw = bytes(data)
    if not raw:
        raise FramingError("COBS data is empty: a valid encoding has at least one code byte")
    zero_at = raw.find(_ZERO)
    if zero_at >= 0:
        raise FramingError(f"COBS data contains 0x00 at offset {zero_at}: split it into frames")
    decoded = decode_or_none(raw)
    if decoded is None:
        raise FramingError(f"invalid COBS: a code byte points past the end of {len(raw)} bytes")
    return decoded
