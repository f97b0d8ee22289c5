"""Parameter values as the host gives them, converted to the type a device asked for."""

from __future__ import annotations

import math
import struct
from typing import Final, cast

from hwbridge.protocols.native._control.common import (
    ParamInput,
    ParamStatus,
    ParamType,
    ParamValue,
)

_INT32_MIN: Final = -(2**31)
_INT32_MAX: Final = 2**31 - 1
_FLOAT32_MAX: Final = 3.4028234663852886e38


def _param_kind(value: object) -> ParamType | None:
    """Natural wire type of a scalar, or None when it is not a parameter scalar."""
    if isinstance(value, bool):
        return ParamType.BOOL
    if isinstance(value, int):
        return ParamType.INT32
    if isinstance(value, float):
        return ParamType.FLOAT32
    if isinstance(value, str):
        return ParamType.STRING
    return None


def _coerce_scalar(value: object, want: ParamType) -> bool | int | float | str | None:
    """``value`` converted to element type ``want``, or None when it does not convert."""
    kind = _param_kind(value)
    if kind is None:
        return None
    if want == ParamType.BOOL:
        if kind == ParamType.BOOL:
            return bool(value)
        if kind == ParamType.INT32 and value in (0, 1):
            return bool(value)
        return None
    if want == ParamType.INT32:
        if kind in (ParamType.BOOL, ParamType.INT32):
            number = int(value)  # type: ignore[call-overload]
            return number if _INT32_MIN <= number <= _INT32_MAX else None
        return None
    if want == ParamType.FLOAT32:
        if kind in (ParamType.INT32, ParamType.FLOAT32):
            number_f = float(value)  # type: ignore[arg-type]
            if math.isfinite(number_f) and abs(number_f) > _FLOAT32_MAX:
                return None
            return struct.unpack("<f", struct.pack("<f", number_f))[0]  # type: ignore[no-any-return]
        return None
    if want == ParamType.STRING:
        return value if isinstance(value, str) else None
    return None


def coerce_param(
    value: ParamInput, want: ParamType = ParamType.ANY, max_count: int = 0
) -> tuple[ParamStatus, ParamType, ParamValue | None]:
    """Convert a host-side value to the type a device asked for.

    Returns ``(status, wire type, value)``; value is None unless the status is OK. Rules: ANY
    keeps the natural type (bool, int32, float32, string, or a list of one of them); ints
    convert to floats and 0/1 to bools; a scalar converts to a one-element list; a list never
    converts to a scalar; ints outside int32 are a TYPE_MISMATCH; a list longer than a non-zero
    ``max_count`` is TOO_LARGE. Float values come back rounded to float32, as the device sees them.
    """
    if isinstance(value, (list, tuple)):
        items: list[object] = list(value)
        if want != ParamType.ANY and not want.is_list:
            return ParamStatus.TYPE_MISMATCH, ParamType.ANY, None
        if want == ParamType.ANY:
            kinds = {_param_kind(item) for item in items}
            if None in kinds:
                return ParamStatus.TYPE_MISMATCH, ParamType.ANY, None
            if kinds == {ParamType.INT32, ParamType.FLOAT32}:
                elem = ParamType.FLOAT32
            elif len(kinds) > 1:
                return ParamStatus.TYPE_MISMATCH, ParamType.ANY, None
            else:
                elem = next((k for k in kinds if k is not None), ParamType.INT32)
        else:
            elem = want.element
    else:
        if want == ParamType.ANY:
            natural = _param_kind(value)
            if natural is None:
                return ParamStatus.TYPE_MISMATCH, ParamType.ANY, None
            want = natural
        items = [value]
        elem = want.element
    if max_count and len(items) > max_count:
        return ParamStatus.TOO_LARGE, ParamType.ANY, None
    converted = [_coerce_scalar(item, elem) for item in items]
    if any(item is None for item in converted):
        return ParamStatus.TYPE_MISMATCH, ParamType.ANY, None
    if want != ParamType.ANY and not want.is_list:
        return ParamStatus.OK, want, converted[0]
    as_list = cast(ParamValue, tuple(converted))
    return ParamStatus.OK, ParamType(elem | 0x80), as_list
