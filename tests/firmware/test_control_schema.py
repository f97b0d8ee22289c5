"""The control-message schema (protocols/native/schema.json) against the Python codec.

The message classes of ``hwbridge.protocols.native.control`` must encode and decode exactly as
the codec generated from the schema does: for every golden vector and for example values of
every field (edges, every enum value, every conditional branch), byte for byte; their names,
opcodes, enums and constants must be the schema's.
"""

from __future__ import annotations

import dataclasses
import enum
from typing import Any

import pytest

from hwbridge.protocols.errors import ProtocolError
from hwbridge.protocols.native import control as ctl
from hwbridge.protocols.native._control import schema as sc
from hwbridge.protocols.native.framing import Frag, FrameType
from tests.firmware.examples import control_vectors, examples, truncated_vectors

SCHEMA = sc.load_schema()
CLASSES: dict[str, Any] = {m.name: getattr(ctl, m.class_name) for m in SCHEMA.messages}


def attrs_of(msg: Any) -> dict[str, Any]:
    return {f.name: getattr(msg, f.name) for f in dataclasses.fields(msg)}


def same_as_class(payload: bytes, *, exact: bool = True) -> None:
    """The class and the schema codec decode ``payload`` alike (or both refuse it), and encode
    what they decoded alike (``payload`` again, if ``exact``: no lenient text was cut)."""
    try:
        msg = ctl.decode_control(payload)
    except ProtocolError:
        with pytest.raises(ProtocolError):
            sc.decode(payload)
        return
    spec, values = sc.decode(payload)
    assert type(msg).__name__ == spec.class_name
    got = attrs_of(msg)
    defaults = {f.name: f.default for f in dataclasses.fields(msg)}
    for attr, value in got.items():
        assert values.get(attr, defaults[attr]) == value, (spec.name, attr)
    assert sc.codec(spec.name).encode(got) == msg.encode()
    assert msg.encode() == payload or not exact


def test_the_classes_are_the_schemas_messages() -> None:
    assert {m.name: m.opcode for m in SCHEMA.messages} == {o.name: int(o) for o in ctl.Opcode}
    for spec in SCHEMA.messages:
        cls = CLASSES[spec.name]
        assert spec.opcode == cls.OPCODE
        attrs = {f.name for f in dataclasses.fields(cls)}
        assert attrs == {f.attr for f in spec.fields}, spec.name
    assert sorted(SCHEMA.by_opcode()) == sorted(int(o) for o in ctl.Opcode)


@pytest.mark.parametrize("name", [*SCHEMA.enums, *SCHEMA.flags])
def test_enums_and_flags_are_the_schemas(name: str) -> None:
    where = {"FrameType": FrameType, "Frag": Frag}
    python: type[enum.Enum] = where.get(name) or getattr(ctl, name)
    values = {m.name: int(m.value) for m in python if m.name and m.name != "NONE"}
    assert values == dict({**SCHEMA.enums, **SCHEMA.flags}[name])


def test_constants_are_the_schemas() -> None:
    for name, value in SCHEMA.constants.items():
        if hasattr(ctl, name):
            assert getattr(ctl, name) == value, name
    header = SCHEMA.frame["header"]
    assert [f["name"] for f in header] == ["flags", "channel", "seq"]


@pytest.mark.parametrize(("name", "payload"), control_vectors())
def test_golden_vectors(name: str, payload: bytes) -> None:
    same_as_class(payload)


@pytest.mark.parametrize(("name", "payload"), truncated_vectors())
def test_truncated_golden_payloads_are_refused(name: str, payload: bytes) -> None:
    with pytest.raises(ProtocolError, match="too short"):
        sc.decode(payload)
    same_as_class(payload)


@pytest.mark.parametrize("spec", SCHEMA.messages, ids=lambda m: m.name)
def test_examples_encode_and_decode_as_the_classes_do(spec: sc.MessageSpec) -> None:
    cls = CLASSES[spec.name]
    for attrs in examples(SCHEMA, spec):
        typed = dict(attrs)
        for field in spec.fields:
            if field.enum or field.flags:  # the classes take their enums
                typed[field.attr] = getattr(ctl, field.enum or field.flags or "")(attrs[field.attr])
        msg = cls(**typed)
        payload = msg.encode()
        assert sc.codec(spec.name).encode(attrs) == payload, attrs
        same_as_class(payload)
        for cut in range(1, len(payload)):  # every truncation: refused by both, or by neither
            same_as_class(payload[:cut], exact=False)


def test_bad_values_are_refused_by_both() -> None:
    hello = sc.codec("HELLO").decode(
        ctl.HelloMsg(
            ctl.Role.HOST, ctl.HelloFlags.NONE, 1, 0, 64, 64, 1, 0, ctl.Features.NONE
        ).encode()
    )
    with pytest.raises(ValueError, match="mtu 65536 does not fit in 16 unsigned bits"):
        sc.codec("HELLO").encode({**hello, "mtu": 65536})
    with pytest.raises(ValueError, match="board name is 256 bytes, at most 255"):
        sc.codec("BOARD_INFO").encode(
            {"topic_count": 1, "name": "x" * 256, "unique_id": b"", "firmware_version": ""}
        )
    with pytest.raises(ValueError, match="request id 0 is below 1"):
        sc.codec("PARAM_GET").encode(
            {"request_id": 0, "type": 0, "flags": 0, "max_count": 0, "name": "a"}
        )
    with pytest.raises(ProtocolError, match="LOG: unknown level 9"):
        sc.decode(b"\x40\x09")
    with pytest.raises(ProtocolError, match="HELLO: version 2, expected 1"):
        sc.decode(bytes([1, 2]) + bytes(19))
    with pytest.raises(ProtocolError, match="unknown control opcode 0x7f"):
        sc.decode(b"\x7f")
