"""The control-message schema (``protocols/native/schema.json``) and a codec built from it.

``schema.json`` describes the frame header and every control message of PROTOCOL.md 2.14 once:
opcode, fields in wire order with their wire types, enums, flags and size limits. Two codecs are
generated from it: this module's Python codec (built when first asked for, then cached) and the
C++ header that ``hwbridge firmware generate`` writes (:mod:`hwbridge.firmware.gen_control`).
The session still uses the hand-written message classes (their service decoders are about 3x
faster than this interpreted codec); the schema is their contract, not their implementation.

The Python codec speaks in the attributes of the message classes of
:mod:`hwbridge.protocols.native.control` (``t1_ns`` for a host time, hex strings for md5 sums,
masked flags), so that ``codec(name).decode(payload)`` returns the same attribute values as
``Class.decode(payload)`` and ``codec(name).encode(attrs)`` the same bytes as ``msg.encode()``;
``tests/firmware/test_control_schema.py`` holds the two to that, message by message.

Pure data: nothing here keeps state or knows about time.
"""

from __future__ import annotations

import functools
import hashlib
import json
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from hwbridge.protocols.errors import ProtocolError

__all__ = [
    "SCALARS",
    "SCHEMA_PATH",
    "FieldSpec",
    "IdentitySpec",
    "MessageCodec",
    "MessageSpec",
    "ParamValueSpec",
    "Schema",
    "codec",
    "decode",
    "load_schema",
]

SCHEMA_PATH: Final = Path(__file__).resolve().parent.parent / "schema.json"
"""Where the schema lives (``protocols/native/schema.json``, package data)."""

SCALARS: Final = {"u8": "B", "u16": "H", "u32": "I", "u64": "Q", "i32": "i", "f32": "f"}
"""Scalar wire types and their ``struct`` codes (little-endian on the wire)."""
_LENGTHS: Final = ("u8", "u16", "rest")


@dataclass(frozen=True)
class FieldSpec:
    """One field of a message, a struct or a list element, as the schema gives it."""

    name: str
    type: str
    """A scalar (:data:`SCALARS`), ``bytes``, ``string``, ``param_value`` or a struct name."""
    attr: str
    """The Python attribute (the name unless the schema says otherwise)."""
    label: str
    """How error messages name the field."""
    enum: str | None = None
    flags: str | None = None
    size: int | None = None
    """Fixed size of a ``bytes`` field."""
    length: str | None = None
    """Length prefix of a variable ``bytes``/``string`` field: u8, u16 or rest."""
    max: int | None = None
    min: int | None = None
    const: str | None = None
    """A constant's name: the value every sender writes (HELLO's version)."""
    hex: bool = False
    """Python carries these bytes as lowercase hex digits."""
    zeros_if_empty: bool = False
    """All-zero bytes on the wire are the empty hex string in Python."""
    lenient: bool = False
    """Invalid UTF-8 is replaced rather than refused."""
    wrap: bool = False
    """Sending truncates the value to the type's width instead of refusing it."""
    when: tuple[str, str, bool] | None = None
    """(field, enum value name, equal): sent only if that earlier field equals (or not) it."""
    selector: str | None = None
    """For ``param_value``: the field whose value chooses the layout."""
    exclude: tuple[str, ...] = ()
    """Enum values not allowed here."""
    doc: str = ""

    @property
    def is_scalar(self) -> bool:
        """True for u8..f32."""
        return self.type in SCALARS

    @property
    def is_variable(self) -> bool:
        """True for length-prefixed or rest-of-payload bytes and strings."""
        return self.type in ("bytes", "string") and self.size is None


@dataclass(frozen=True)
class MessageSpec:
    """One control message: name, opcode, Python class name and fields in wire order."""

    name: str
    opcode: int
    class_name: str
    direction: str
    doc: str
    fields: tuple[FieldSpec, ...]

    @property
    def reliable(self) -> bool:
        """True when the message travels on the reliable stream (opcode 0x10 and up)."""
        return self.opcode >= 0x10


@dataclass(frozen=True)
class ParamValueSpec:
    """The layout of PARAM_VALUE's value: element types by (scalar) ParamType name."""

    selector_enum: str
    list_bit: int
    count: str
    elements: Mapping[str, FieldSpec]


@dataclass(frozen=True)
class IdentitySpec:
    """The firmware identity items of BOARD_INFO's firmware_version text, in the order a board
    sends them: attribute name -> one-letter key on the wire; and the hex digits of a hash."""

    items: Mapping[str, str]
    hash_hex: int


def _strip_docs(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _strip_docs(v) for k, v in value.items() if k != "doc"}
    if isinstance(value, list):
        return [_strip_docs(v) for v in value]
    return value


def schema_hash(raw: Mapping[str, Any], digits: int) -> str:
    """The schema's hash (PROTOCOL.md 2.6.1): the first ``digits`` lowercase hex digits of
    SHA-256 over its JSON without any ``doc`` member, keys sorted, no spaces, UTF-8. Prose
    edits keep it; any change of what is on the wire changes it."""
    canonical = json.dumps(
        _strip_docs(raw), sort_keys=True, separators=(",", ":"), ensure_ascii=False
    )
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()[:digits]


@dataclass(frozen=True)
class Schema:
    """The parsed schema."""

    version: int
    doc: str
    constants: Mapping[str, int]
    enums: Mapping[str, Mapping[str, int]]
    flags: Mapping[str, Mapping[str, int]]
    structs: Mapping[str, tuple[FieldSpec, ...]]
    param_value: ParamValueSpec
    messages: tuple[MessageSpec, ...]
    frame: Mapping[str, Any]
    """The frame header as the schema gives it (``header``, ``crc``, ``length_prefix``)."""
    identity: IdentitySpec
    hash: str
    """:func:`schema_hash` of the file: what boards built from it send as ``schema_hash``."""

    def message(self, name: str) -> MessageSpec:
        """The message called ``name`` (``HELLO``); KeyError if there is none."""
        for message in self.messages:
            if message.name == name:
                return message
        raise KeyError(name)

    def by_opcode(self) -> dict[int, MessageSpec]:
        """Messages by opcode."""
        return {message.opcode: message for message in self.messages}

    def width(self, field: FieldSpec) -> int:
        """Bytes of a fixed-size field (scalar, fixed bytes or struct); 0 for variable ones."""
        if field.is_scalar:
            return struct.calcsize("<" + SCALARS[field.type])
        if field.size is not None:
            return field.size
        if field.type in self.structs:
            return sum(self.width(sub) for sub in self.structs[field.type])
        return 0


def _field(raw: Mapping[str, Any]) -> FieldSpec:
    when = raw.get("when")
    condition = None
    if when is not None:
        equal = "is" in when
        condition = (str(when["field"]), str(when["is" if equal else "not"]), equal)
    name = str(raw["name"])
    return FieldSpec(
        name=name,
        type=str(raw["type"]),
        attr=str(raw.get("attr", name)),
        label=str(raw.get("label", raw.get("attr", name).replace("_", " "))),
        enum=raw.get("enum"),
        flags=raw.get("flags"),
        size=raw.get("size"),
        length=raw.get("length"),
        max=raw.get("max"),
        min=raw.get("min"),
        const=raw.get("const"),
        hex=bool(raw.get("hex", False)),
        zeros_if_empty=bool(raw.get("zeros_if_empty", False)),
        lenient=bool(raw.get("lenient", False)),
        wrap=bool(raw.get("wrap", False)),
        when=condition,
        selector=raw.get("selector"),
        exclude=tuple(raw.get("exclude", ())),
        doc=str(raw.get("doc", "")),
    )


def _check(schema: Schema) -> None:
    """Refuse a schema the generators would get wrong (a typo in schema.json)."""
    named = set(schema.enums) | set(schema.flags)
    seen: set[int] = set()
    for message in schema.messages:
        if message.opcode in seen or schema.enums["Opcode"].get(message.name) != message.opcode:
            raise ValueError(f"schema: {message.name} opcode {message.opcode} is not in Opcode")
        seen.add(message.opcode)
        names: set[str] = set()
        for i, field in enumerate(message.fields):
            where = f"schema: {message.name}.{field.name}"
            known = field.is_scalar or field.type in ("bytes", "string", "param_value")
            if not known and field.type not in schema.structs:
                raise ValueError(f"{where}: unknown type {field.type}")
            for ref in (field.enum, field.flags):
                if ref is not None and ref not in named:
                    raise ValueError(f"{where}: unknown enum {ref}")
            if field.is_variable and field.length not in _LENGTHS:
                raise ValueError(f"{where}: length must be one of {_LENGTHS}")
            if field.length == "rest" and i != len(message.fields) - 1:
                raise ValueError(f"{where}: only the last field may run to the end")
            if field.when is not None and field.when[0] not in names:
                raise ValueError(f"{where}: 'when' names a later or unknown field")
            if field.const is not None and field.const not in schema.constants:
                raise ValueError(f"{where}: unknown constant {field.const}")
            names.add(field.name)
    keys = list(schema.identity.items.values())
    if len(set(keys)) != len(keys) or any(
        len(k) != 1 or k in "\n=" or not k.isascii() for k in keys
    ):
        raise ValueError(f"schema: identity keys must be distinct ASCII letters, not {keys}")


@functools.cache
def load_schema(path: Path = SCHEMA_PATH) -> Schema:
    """The schema, read and checked once."""
    raw = json.loads(path.read_text(encoding="utf-8"))
    pv = raw["param_value"]
    schema = Schema(
        version=int(raw["version"]),
        doc=str(raw["doc"]),
        constants={name: int(c["value"]) for name, c in raw["constants"].items()},
        enums={name: dict(e["values"]) for name, e in raw["enums"].items()},
        flags={name: dict(e["values"]) for name, e in raw["flags"].items()},
        structs={name: tuple(_field(f) for f in s["fields"]) for name, s in raw["structs"].items()},
        param_value=ParamValueSpec(
            selector_enum=str(pv["selector_enum"]),
            list_bit=int(pv["list_bit"]),
            count=str(pv["count"]),
            elements={
                name: _field({"name": name.lower(), **e}) for name, e in pv["elements"].items()
            },
        ),
        messages=tuple(
            MessageSpec(
                name=str(m["name"]),
                opcode=int(m["opcode"]),
                class_name=str(m["class"]),
                direction=str(m["direction"]),
                doc=str(m["doc"]),
                fields=tuple(_field(f) for f in m["fields"]),
            )
            for m in raw["messages"]
        ),
        frame=raw["frame"],
        identity=IdentitySpec(
            items={str(i["name"]): str(i["key"]) for i in raw["identity"]["items"]},
            hash_hex=int(raw["identity"]["hash_hex"]),
        ),
        hash=schema_hash(raw, int(raw["identity"]["hash_hex"])),
    )
    _check(schema)
    return schema


# -- the Python codec ---------------------------------------------------------------------------


@functools.cache
def _st(code: str) -> struct.Struct:
    return struct.Struct("<" + code)


class _Reader:
    """Bounds-checked reads from one payload, with errors that name the message and field."""

    __slots__ = ("data", "pos", "what")

    def __init__(self, data: bytes, what: str) -> None:
        self.data = data
        self.pos = 1
        self.what = what

    def take(self, n: int, label: str) -> bytes:
        end = self.pos + n
        if end > len(self.data):
            raise ProtocolError(
                f"{self.what} too short: {label} needs {n} bytes at offset {self.pos}, "
                f"payload has {len(self.data)}"
            )
        chunk = self.data[self.pos : end]
        self.pos = end
        return chunk

    def scalar(self, typ: str, label: str) -> Any:
        st = _st(SCALARS[typ])
        return st.unpack(self.take(st.size, label))[0]

    def rest(self) -> bytes:
        chunk = self.data[self.pos :]
        self.pos = len(self.data)
        return chunk

    def text(self, raw: bytes, field: FieldSpec) -> str:
        if field.lenient:
            return raw.decode("utf-8", errors="replace")
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ProtocolError(f"{self.what}: {field.label} is not UTF-8 ({exc})") from None


_Decode = Callable[[_Reader, dict[str, Any]], Any]
"""Reads one field; gets the wire values decoded so far (by field name)."""
_Encode = Callable[[Any, dict[str, Any]], bytes]
"""Writes one field from its attribute value; gets the wire values written so far."""


class MessageCodec:
    """Encoder and decoder of one control message, built from its :class:`MessageSpec`."""

    def __init__(self, schema: Schema, spec: MessageSpec) -> None:
        self.schema = schema
        self.spec = spec
        self._steps = [(field, self._decoder(field), self._encoder(field)) for field in spec.fields]

    # What the wire value of a field is, for 'when' conditions and selectors.
    def _holds(self, field: FieldSpec, wire: Mapping[str, Any]) -> bool:
        if field.when is None:
            return True
        name, value, equal = field.when
        source = next(f for f in self.spec.fields if f.name == name)
        assert source.enum is not None
        return bool(wire[name] == self.schema.enums[source.enum][value]) == equal

    def _decoder(self, field: FieldSpec) -> _Decode:
        what = self.spec.name
        schema = self.schema
        if field.is_scalar:
            if field.enum is not None:
                values = schema.enums[field.enum]
                allowed = {v for k, v in values.items() if k not in field.exclude}

                def enum(r: _Reader, wire: dict[str, Any]) -> Any:
                    value = r.scalar(field.type, field.label)
                    if value not in allowed:
                        raise ProtocolError(f"{what}: unknown {field.label} {value}")
                    return value

                return enum
            if field.flags is not None:
                mask = 0
                for bit in schema.flags[field.flags].values():
                    mask |= bit
                return lambda r, wire: r.scalar(field.type, field.label) & mask
            if field.const is not None:
                want = schema.constants[field.const]

                def const(r: _Reader, wire: dict[str, Any]) -> Any:
                    value = r.scalar(field.type, field.label)
                    if value != want:
                        raise ProtocolError(f"{what}: {field.label} {value}, expected {want}")
                    return value

                return const
            return lambda r, wire: r.scalar(field.type, field.label)
        if field.type in schema.structs:
            subs = schema.structs[field.type]
            code = "".join(SCALARS[s.type] for s in subs)

            def host_time(r: _Reader, wire: dict[str, Any]) -> Any:
                st = _st(code)
                sec, nsec = st.unpack(r.take(st.size, field.label))
                if nsec > (subs[1].max or nsec):
                    raise ProtocolError(f"{what}: {field.label} nanoseconds {nsec} >= 1e9")
                return sec * schema.constants["NS_PER_S"] + nsec

            return host_time
        if field.type == "param_value":
            return self._value_decoder(field)
        if field.size is not None:
            size = field.size

            def fixed(r: _Reader, wire: dict[str, Any]) -> Any:
                raw = r.take(size, field.label)
                if field.zeros_if_empty and raw == bytes(size):
                    return ""
                return raw.hex() if field.hex else raw

            return fixed

        def variable(r: _Reader, wire: dict[str, Any]) -> Any:
            if field.length == "rest":
                raw = r.rest()
            else:
                assert field.length is not None
                raw = r.take(r.scalar(field.length, field.label + " length"), field.label)
            return r.text(raw, field) if field.type == "string" else raw

        return variable

    def _value_decoder(self, field: FieldSpec) -> _Decode:
        pv = self.schema.param_value
        names = {v: k for k, v in self.schema.enums[pv.selector_enum].items()}
        elements = {self.schema.enums[pv.selector_enum][k]: e for k, e in pv.elements.items()}

        def value(r: _Reader, wire: dict[str, Any]) -> Any:
            ptype = wire[field.selector or ""]
            is_list = bool(ptype & pv.list_bit)
            count = r.scalar(pv.count, "list length") if is_list else 1
            element = elements[ptype & ~pv.list_bit]
            items: list[Any] = []
            for i in range(count):
                kind = names[ptype & ~pv.list_bit].lower()
                if element.type == "string":
                    assert element.length is not None
                    n = r.scalar(element.length, f"string {i} length")
                    items.append(r.text(r.take(n, f"string {i}"), element))
                elif kind == "bool":
                    items.append(bool(r.scalar(element.type, f"bool {i}")))
                else:
                    items.append(r.scalar(element.type, f"element {i}"))
            return tuple(items) if is_list else items[0]

        return value

    def _encoder(self, field: FieldSpec) -> _Encode:
        schema = self.schema
        if field.is_scalar:
            st = _st(SCALARS[field.type])
            bits = 8 * st.size
            if field.const is not None:
                default = schema.constants[field.const]
                return lambda value, wire: st.pack(default if value is None else value)
            if field.wrap:
                mask = (1 << bits) - 1
                return lambda value, wire: st.pack(value & mask)
            if field.enum is not None or field.flags is not None:
                excluded = (
                    {schema.enums[field.enum][k] for k in field.exclude} if field.enum else set()
                )

                def enum(value: Any, wire: dict[str, Any]) -> bytes:
                    if value in excluded:
                        raise ValueError(f"{self.spec.name}: {field.label} {value} is not allowed")
                    return st.pack(value)

                return enum
            low = field.min or 0

            def checked(value: Any, wire: dict[str, Any]) -> bytes:
                if not 0 <= value < (1 << bits):
                    raise ValueError(f"{field.label} {value} does not fit in {bits} unsigned bits")
                if value < low:
                    raise ValueError(f"{field.label} {value} is below {low}")
                return st.pack(value)

            return checked
        if field.type in schema.structs:
            code = "".join(SCALARS[s.type] for s in schema.structs[field.type])
            per_s = schema.constants["NS_PER_S"]

            def host_time(value: Any, wire: dict[str, Any]) -> bytes:
                if value < 0:
                    raise ValueError(f"host time {value} ns is negative")
                sec, nsec = divmod(value, per_s)
                return _st(code).pack(sec & 0xFFFFFFFF, nsec)

            return host_time
        if field.type == "param_value":
            return self._value_encoder(field)
        if field.size is not None:
            size = field.size

            def fixed(value: Any, wire: dict[str, Any]) -> bytes:
                if field.hex:
                    if not value and field.zeros_if_empty:
                        return bytes(size)
                    try:
                        raw = bytes.fromhex(value)
                    except ValueError:
                        raw = b""
                else:
                    raw = bytes(value)
                if len(raw) != size:
                    raise ValueError(f"{field.label} {value!r} is not {size} bytes")
                return raw

            return fixed
        prefix = None if field.length == "rest" else _st(SCALARS[field.length or "u8"])
        limit = field.max
        if limit is None and prefix is not None:
            limit = (1 << (8 * prefix.size)) - 1

        def variable(value: Any, wire: dict[str, Any]) -> bytes:
            raw = value.encode("utf-8") if field.type == "string" else bytes(value)
            if limit is not None and len(raw) > limit:
                raise ValueError(f"{field.label} is {len(raw)} bytes, at most {limit} allowed")
            return raw if prefix is None else prefix.pack(len(raw)) + raw

        return variable

    def _value_encoder(self, field: FieldSpec) -> _Encode:
        pv = self.schema.param_value
        elements = {self.schema.enums[pv.selector_enum][k]: e for k, e in pv.elements.items()}

        def value(value: Any, wire: dict[str, Any]) -> bytes:
            ptype = wire[field.selector or ""]
            if value is None:
                raise ValueError(f"{self.spec.name}: {field.label} is missing")
            is_list = bool(ptype & pv.list_bit)
            element = elements[ptype & ~pv.list_bit]
            items = tuple(value) if is_list else (value,)
            out = bytearray(_st(SCALARS[pv.count]).pack(len(items)) if is_list else b"")
            for item in items:
                if element.type == "string":
                    raw = str(item).encode("utf-8")
                    out += _st(SCALARS[element.length or "u16"]).pack(len(raw)) + raw
                else:
                    out += _st(SCALARS[element.type]).pack(item)
            return bytes(out)

        return value

    def decode(self, payload: bytes) -> dict[str, Any]:
        """The attribute values of ``payload`` (opcode included); ProtocolError if malformed."""
        if not payload or payload[0] != self.spec.opcode:
            raise ProtocolError(f"not a {self.spec.name} payload")
        r = _Reader(payload, self.spec.name)
        wire: dict[str, Any] = {}
        out: dict[str, Any] = {}
        for field, read, _ in self._steps:
            if not self._holds(field, wire):
                continue
            value = read(r, wire)
            wire[field.name] = value
            out[field.attr] = value
        return out

    def encode(self, attrs: Mapping[str, Any]) -> bytes:
        """The payload of a message with these attribute values (ValueError if one is bad)."""
        parts = [bytes([self.spec.opcode])]
        wire: dict[str, Any] = {}
        for field, _, write in self._steps:
            if not self._holds(field, wire):
                continue
            value = attrs.get(field.attr)
            parts.append(write(value, wire))
            wire[field.name] = value
        return b"".join(parts)


@functools.cache
def _codecs() -> dict[int, MessageCodec]:
    schema = load_schema()
    return {m.opcode: MessageCodec(schema, m) for m in schema.messages}


def codec(name: str) -> MessageCodec:
    """The codec of the message called ``name`` (``"HELLO"``), built once."""
    return _codecs()[load_schema().message(name).opcode]


def decode(payload: bytes) -> tuple[MessageSpec, dict[str, Any]]:
    """Any control payload: its message and attribute values (ProtocolError if malformed)."""
    if not payload:
        raise ProtocolError("empty control payload (no opcode)")
    found = _codecs().get(payload[0])
    if found is None:
        raise ProtocolError(f"unknown control opcode {payload[0]:#04x}")
    return found.spec, found.decode(payload)
