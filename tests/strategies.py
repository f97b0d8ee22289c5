"""Hypothesis strategies for hwbridge message types (test helpers)."""

from __future__ import annotations

from typing import Any

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from rosbags.interfaces import Nodetype

from hwbridge import msg
from hwbridge.protocols.msgtypes import INT_RANGES, TypeRegistry

MAX_SEQUENCE = 3


def bounded(max_examples: int) -> settings:
    """Seeded (derandomized) and bounded to ``max_examples``, with no per-example deadline."""
    return settings(
        max_examples=max_examples,
        deadline=None,
        derandomize=True,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )


def _base(name: str) -> st.SearchStrategy[Any]:
    if name == "bool":
        return st.booleans()
    if name == "string":
        return st.text(max_size=12)
    if name == "float32":
        return st.floats(width=32, allow_nan=False)
    if name == "float64":
        return st.floats(allow_nan=False)
    low, high = INT_RANGES[name]
    return st.integers(low, high)


def _field(reg: TypeRegistry, desc: Any) -> st.SearchStrategy[Any]:
    kind, arg = desc
    if kind == Nodetype.BASE:
        return _base(arg[0])
    if kind == Nodetype.NAME:
        return message_dicts(reg, arg)
    (sub_kind, sub_arg), size = arg
    element = _base(sub_arg[0]) if sub_kind == Nodetype.BASE else message_dicts(reg, sub_arg)
    if kind == Nodetype.ARRAY:
        return st.lists(element, min_size=size, max_size=size)
    return st.lists(element, max_size=MAX_SEQUENCE)


def message_dicts(reg: TypeRegistry, type_name: str) -> st.SearchStrategy[dict[str, Any]]:
    """Plain dicts (as msg.from_dict takes) filling every field of ``type_name`` at random."""
    store_name = reg.message(type_name).store_name
    if store_name in msg.SEC_LIMITS:
        return st.fixed_dictionaries(
            {
                "secs": st.integers(*msg.SEC_LIMITS[store_name]),
                "nsecs": st.integers(*msg.NSEC_LIMITS),
            }
        )
    return st.fixed_dictionaries({name: _field(reg, d) for name, d in reg.fields(store_name)})


def messages(reg: TypeRegistry, type_name: str) -> st.SearchStrategy[Any]:
    """Random valid message objects of ``type_name``."""
    return message_dicts(reg, type_name).map(lambda d: msg.from_dict(type_name, d, reg))
