"""Example control messages from the schema, and the control messages of the golden vectors."""

from __future__ import annotations

import json
from itertools import cycle, islice
from pathlib import Path
from typing import Any

from hwbridge.protocols.native._control.schema import FieldSpec, MessageSpec, Schema

VECTORS = Path(__file__).parents[2] / "protocols" / "vectors"


def control_vectors() -> list[tuple[str, bytes]]:
    """(name, payload) of every control message in the golden vectors.

    ``native_session.json``'s decoded control messages, and the channel-0 frames of
    ``native_frames.json`` (the truncated HELLO there must be refused, see
    :func:`truncated_vectors`).
    """
    session = json.loads((VECTORS / "native_session.json").read_text())
    found = []
    for entry in session["transcript"] + session["extra"]:
        frame = entry.get("frame", {})
        if "control" in frame:
            found.append((entry["name"], bytes.fromhex(frame["payload"])))
    return found


def truncated_vectors() -> list[tuple[str, bytes]]:
    """Channel-0 payloads of ``native_frames.json`` (one HELLO cut to its opcode)."""
    frames = json.loads((VECTORS / "native_frames.json").read_text())
    return [
        (v["name"], bytes.fromhex(v["frame"]["payload_hex"]))
        for v in frames["vectors"] + frames["decode_only"]
        if v["frame"]["channel"] == 0 and v["frame"]["type"] != "ACK"
    ]


def _scalar_values(schema: Schema, field: FieldSpec) -> list[Any]:
    if field.enum is not None:
        return [v for k, v in schema.enums[field.enum].items() if k not in field.exclude]
    if field.flags is not None:
        bits = list(schema.flags[field.flags].values())
        return [0, sum(bits), *bits]
    if field.const is not None:
        return [schema.constants[field.const]]
    top = (1 << (8 * schema.width(field))) - 1
    return [max(field.min or 0, 1), top, 0x5A & top, (field.min or 0)]


def _param_value(schema: Schema, ptype: int, n: int) -> Any:
    pv = schema.param_value
    names = {v: k for k, v in schema.enums[pv.selector_enum].items()}
    base = names[ptype & ~pv.list_bit]
    samples: dict[str, list[Any]] = {
        "BOOL": [True, False, True],
        "INT32": [-(2**31), 2**31 - 1, 7],
        "FLOAT32": [0.5, -1.25e10, 3.0],
        "STRING": ["", "rate", "µs ✓"],
    }
    if ptype & pv.list_bit:
        return tuple(islice(cycle(samples[base]), n))
    return samples[base][n % 3]


def _values(schema: Schema, field: FieldSpec) -> list[Any]:
    if field.is_scalar:
        return _scalar_values(schema, field)
    if field.type in schema.structs:
        return [0, 999_999_999, 1_700_000_000_123_456_789, (2**32 - 1) * 10**9 + 999_999_999]
    if field.size is not None:
        if field.hex:
            return ["00" * field.size, "ff" * field.size, bytes(range(field.size)).hex()]
        return [bytes(field.size), bytes(range(field.size))]
    top = field.max if field.max is not None else 300
    if field.type == "string":
        return ["", "/chatter", "é" * (top // 2) + "x" * (top % 2), "ü✓"]
    return [b"", b"\x00\x01\xff", bytes(range(256))[:top]]


def examples(schema: Schema, spec: MessageSpec) -> list[dict[str, Any]]:
    """Attribute values for several messages of this kind: every field's edge values, every
    enum value (so every conditional branch) at least once."""
    candidates: dict[str, list[Any]] = {}
    for field in spec.fields:
        if field.type != "param_value":
            candidates[field.attr] = _values(schema, field)
    rows = max((len(c) for c in candidates.values()), default=1)
    found = []
    for i in range(rows):
        attrs = {attr: values[i % len(values)] for attr, values in candidates.items()}
        found.append(attrs)
    for field in spec.fields:
        if field.type == "param_value":
            selector = next(f for f in spec.fields if f.name == field.selector)
            status_field = selector.when[0] if selector.when else None
            ok = [a for a in found if status_field is None or a[status_field] == 0]
            base = ok[0] if ok else found[0]
            for j, ptype in enumerate(_scalar_values(schema, selector)):
                for n in (0, 1, 3) if ptype & schema.param_value.list_bit else (j,):
                    row = {**base, selector.attr: ptype, field.attr: _param_value(schema, ptype, n)}
                    found.append(row)
            for a in found:
                a.setdefault(field.attr, _param_value(schema, a[selector.attr], 1))
    return found
