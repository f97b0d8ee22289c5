"""The hand-written control classes against the schema, field by field.

The session encodes and decodes with the classes of ``hwbridge.protocols.native.control``, not
with the codec built from ``protocols/native/schema.json``; this test holds them to the schema's
layout so that a drift in either fails here, naming the message and the field: the same
attribute names, enum and flag types; every fixed field at the schema's offset, with the
schema's width, little-endian (probed by encoding values that differ in one byte); the fixed
part's size (``_FMT``/``SIZE`` where a class has them).
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Any

import pytest

from hwbridge.protocols.native import control as ctl
from hwbridge.protocols.native._control import schema as sc
from tests.firmware.examples import examples

SCHEMA = sc.load_schema()
NS_PER_S = 1_000_000_000


def _class(spec: sc.MessageSpec) -> Any:
    return getattr(ctl, spec.class_name)


def _sample(spec: sc.MessageSpec) -> Any:
    """A valid instance whose conditional fields are all sent, when some example has that."""
    cls = _class(spec)
    found = [cls.decode(sc.codec(spec.name).encode(v)) for v in examples(SCHEMA, spec)]
    return max(found, key=lambda m: len(m.encode()))


def _diff(a: bytes, b: bytes) -> list[int]:
    assert len(a) == len(b)
    return [i for i in range(len(a)) if a[i] != b[i]]


@pytest.mark.parametrize("spec", SCHEMA.messages, ids=lambda s: s.name)
def test_names_and_types(spec: sc.MessageSpec) -> None:
    cls = _class(spec)
    assert spec.opcode == cls.OPCODE, spec.name
    attrs = [f.name for f in dataclasses.fields(cls)]
    wire = [f.attr for f in spec.fields]
    assert sorted(attrs) == sorted(wire), f"{spec.name}: class {attrs}, schema {wire}"
    hints = typing.get_type_hints(cls)
    for field in spec.fields:
        kind = field.enum or field.flags
        if kind is not None:
            assert getattr(hints[field.attr], "__name__", None) == kind, (spec.name, field.name)


@pytest.mark.parametrize("spec", SCHEMA.messages, ids=lambda s: s.name)
def test_fixed_fields_at_the_schemas_offsets(spec: sc.MessageSpec) -> None:
    """Order, width and byte order of every fixed field, by probing the encoder."""
    base = _sample(spec)
    at = 1
    for field in spec.fields:
        if field.when is not None:
            name, value, equal = field.when
            source = next(f for f in spec.fields if f.name == name)
            assert source.enum is not None
            held = getattr(base, source.attr) == SCHEMA.enums[source.enum][value]
            if held != equal:
                break
        width = SCHEMA.width(field)
        if width == 0:
            break  # variable from here on
        probes: list[tuple[Any, Any, int]] = []
        if field.type in SCHEMA.structs:  # HostTime: sec then nsec, carried as ns
            probes = [(0, 1, at + 4), (0, NS_PER_S, at)]
        elif field.is_scalar and field.enum is None and field.flags is None and not field.const:
            low, top = field.min or 0, 1 << (8 * width - 8)
            probes = [(low, low + 1, at), (low, low + top, at + width - 1)]
        elif field.type == "bytes" and field.size:
            probes = [("00" * width, "00" * (width - 1) + "01", at + width - 1)]
        for low, high, offset in probes:
            a = dataclasses.replace(base, **{field.attr: low}).encode()
            b = dataclasses.replace(base, **{field.attr: high}).encode()
            assert _diff(a, b) == [offset], f"{spec.name}.{field.name}: expected byte {offset}"
        at += width
    cls = _class(spec)
    fmt = getattr(cls, "_FMT", None)
    if fmt is not None:
        scalars = [f for f in spec.fields if f.is_scalar]
        wanted = "<B" + "".join(sc.SCALARS[f.type] for f in scalars)
        assert fmt.format == wanted and fmt.size == at, spec.name
    if hasattr(cls, "SIZE"):
        assert at == cls.SIZE, spec.name
