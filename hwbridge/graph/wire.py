"""What rides beside a payload on the graph: every topic message and service call carries its
type's md5 and name in Zenoh's attachment (the md5's 32 hex digits, then the name), so that a
receiver that expects another type refuses the bytes instead of misreading them."""

from __future__ import annotations

import functools
from typing import Final

__all__ = ["MD5_LEN", "attachment", "parse_attachment"]

MD5_LEN: Final = 32


def attachment(md5: str, type_name: str) -> bytes:
    return (md5 + type_name).encode()


@functools.lru_cache(maxsize=256)
def parse_attachment(raw: bytes | None) -> tuple[str, str]:
    """(md5, type) from an attachment; cached, since a topic repeats the same few."""
    if raw is None or len(raw) < MD5_LEN:
        return "", ""
    text = raw.decode("ascii", "replace")
    return text[:MD5_LEN], text[MD5_LEN:]
