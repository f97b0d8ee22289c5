"""Parameter answers of the rosserial host: a Python value as a ``RequestParam`` response.

The device asks with ``rosserial_msgs/RequestParam`` ``{string name}`` on topic 6 and the host
answers on the same topic with ``{int32[] ints, float32[] floats, string[] strings}``: bools and
ints go in ``ints``, floats in ``floats``, strings in ``strings`` (a list mixing ints and floats is
sent as floats). None means the parameter does not exist: an empty answer, which the library
reports as a length mismatch at once instead of waiting for its timeout.
"""

from __future__ import annotations

import math
import numbers
import struct
from collections.abc import Sequence
from typing import Any, Final, TypeAlias

from hwbridge.protocols.errors import SerializationError
from hwbridge.protocols.msgtypes import INT_RANGES

__all__ = ["FLOAT32_MAX", "ParamValue", "encode_param"]

ParamValue: TypeAlias = bool | int | float | str | Sequence[bool | int | float | str] | None
"""What ``RosserialHost.answer_param`` accepts; None answers "missing" (empty arrays)."""

FLOAT32_MAX: Final = 3.4028234663852886e38
"""The largest finite float32."""
_COUNT: Final = struct.Struct("<I")


def encode_param(name: str, value: ParamValue) -> bytes:
    """The ``RequestParam`` response bytes (ROS 1 serialization) for ``value``.

    Raises:
        SerializationError: the value has no rosserial form (dict, strings mixed with numbers,
            out of int32/float32 range).
    """
    items = _param_items(value)
    kinds = {_param_kind(name, item) for item in items}
    if "str" in kinds and len(kinds) > 1:
        raise SerializationError(
            f"parameter {name!r}: a list must not mix strings and numbers (rosserial sends "
            f"one array type per parameter)"
        )
    ints: list[int] = []
    floats: list[float] = []
    strings: list[bytes] = []
    if "str" in kinds:
        strings = [str(item).encode("utf-8") for item in items]
    elif "float" in kinds:
        floats = [_float32(name, float(item)) for item in items]
    else:
        ints = [_int32(name, int(item)) for item in items]
    out = bytearray(_COUNT.pack(len(ints)))
    out += struct.pack(f"<{len(ints)}i", *ints)
    out += _COUNT.pack(len(floats))
    out += struct.pack(f"<{len(floats)}f", *floats)
    out += _COUNT.pack(len(strings))
    for text in strings:
        out += _COUNT.pack(len(text))
        out += text
    return bytes(out)


def _param_items(value: ParamValue) -> list[Any]:
    if value is None:
        return []
    if isinstance(value, list | tuple):
        return list(value)
    return [value]


def _param_kind(name: str, item: Any) -> str:
    if isinstance(item, str):
        return "str"
    if isinstance(item, numbers.Integral):  # bool, int and numpy integers
        return "int"
    if isinstance(item, numbers.Real):  # float and numpy floats
        return "float"
    raise SerializationError(
        f"parameter {name!r}: {type(item).__name__} values cannot be sent to a rosserial "
        "device (only bool, int, float, str and lists of one of them)"
    )


def _int32(name: str, value: int) -> int:
    low, high = INT_RANGES["int32"]
    if not low <= value <= high:
        raise SerializationError(
            f"parameter {name!r}: {value} does not fit an int32 (rosserial sends ints as int32)"
        )
    return value


def _float32(name: str, value: float) -> float:
    if math.isfinite(value) and abs(value) > FLOAT32_MAX:
        raise SerializationError(
            f"parameter {name!r}: {value} does not fit a float32 (rosserial sends floats as "
            "float32)"
        )
    return value
