"""The C++ codec of the native protocol's control messages, generated from the schema.

``hwbridge firmware generate OUTDIR`` writes ``OUTDIR/hwbridge_control.h`` and its three parts
from ``protocols/native/schema.json`` (the file the Python codec is built from too): C++11,
header-only, no heap, no exceptions. ``hwbridge_control_msgs.h`` holds per message a struct and

- ``bool encode(const Msg& m, uint8_t* buf, size_t cap, size_t* len)``: writes the payload
  (opcode first) and its length; false, with nothing promised about ``buf[0..cap)``, when it does
  not fit in ``cap`` bytes or a field is out of range (a string above its limit, an unknown enum
  value, nanoseconds >= 1e9). Never writes at or past ``buf + cap``.
- ``bool decode(const uint8_t* buf, size_t len, Msg* m)``: false when the payload is shorter than
  its fields, names another opcode, holds an unknown enum value, a wrong version or malformed
  UTF-8 where the schema wants it well-formed; never reads at or past ``buf + len``. Strings and
  byte strings are views (:code:`Bytes`) into ``buf``: valid while ``buf`` is.

``hwbridge_control_base.h``, which the other two include, holds the frame header
(``FrameHeader``, its encode/decode of the 3 header bytes), the enums, flags and constants;
``hwbridge_control_board.h`` the board's in-place view (``namespace board``). Everything is in
``namespace hwbridge { namespace control {``. ``hwbridge_control.h``, what everything includes,
defines the firmware identity's macros and includes the three. The fixed text
(``templates/control_prelude.h``, the start of the base part) reads and writes with the
library's one bounded Reader/Writer and CRC, ``hwbridge_wire.h``, copied next to the headers
(:func:`generate_control_files`). Read in the order ``hwbridge_control.h`` includes them, the
four are the whole codec in the schema's order; each part starts with its comment, guard and
``#include`` and opens and closes the namespaces itself, so that it compiles alone.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Final

from hwbridge.firmware._templates import WIRE_NAME, template
from hwbridge.protocols.native._control.schema import (
    SCALARS,
    FieldSpec,
    MessageSpec,
    Schema,
    load_schema,
)

__all__ = [
    "BASE_NAME",
    "BOARD_NAME",
    "CONTROL_NAMES",
    "HEADER_NAME",
    "MSGS_NAME",
    "PART_NAMES",
    "WIRE_NAME",
    "generate_control_files",
    "generate_control_header",
]

HEADER_NAME: Final = "hwbridge_control.h"
"""What a sketch or the library includes: the identity macros and the three parts below."""
BASE_NAME: Final = "hwbridge_control_base.h"
"""The prelude, constants, enums, flags, structs, the frame header, ``param_value_size``."""
MSGS_NAME: Final = "hwbridge_control_msgs.h"
"""The message structs and their encode and decode; includes :data:`BASE_NAME`."""
BOARD_NAME: Final = "hwbridge_control_board.h"
"""``control::board``, the board's in-place view; includes :data:`BASE_NAME`."""
PART_NAMES: Final = (BASE_NAME, MSGS_NAME, BOARD_NAME)
"""The parts in the order :data:`HEADER_NAME` includes them."""
CONTROL_NAMES: Final = (HEADER_NAME, *PART_NAMES)
"""Every control header :func:`generate_control_files` writes (``hwbridge_wire.h`` aside)."""
PRELUDE_NAME: Final = "control_prelude.h"

_CTYPES: Final = {
    "u8": "uint8_t",
    "u16": "uint16_t",
    "u32": "uint32_t",
    "u64": "uint64_t",
    "i32": "int32_t",
    "f32": "float",
}

_CRC_POLY: Final = 0x1021
_CRC_INIT: Final = 0xFFFF
"""The CRC ``hwbridge_wire.h`` computes; the schema's frame CRC must be this one."""


def _ctype(typ: str) -> str:
    return _CTYPES[typ]


def _enum_block(name: str, values: dict[str, int], typ: str, doc: str) -> Iterator[str]:
    yield f"/** {doc} */"
    yield f"struct {name} {{"
    yield f"  enum : {_ctype(typ)} {{"
    for key, value in values.items():
        yield f"    {key} = {value:#04x},"
    yield "  };"
    yield "};"


def _valid_fn(name: str, values: dict[str, int], exclude: tuple[str, ...] = ()) -> Iterator[str]:
    suffix = "_" + "_".join(exclude) if exclude else ""
    yield f"inline bool valid_{name}{suffix}(uint8_t v) {{"
    yield "  switch (v) {"
    for key in values:
        if key not in exclude:
            yield f"    case {name}::{key}:"
    yield "      return true;"
    yield "    default:"
    yield "      return false;"
    yield "  }"
    yield "}"


def _mask(schema: Schema, flags: str) -> int:
    mask = 0
    for bit in schema.flags[flags].values():
        mask |= bit
    return mask


def _member(schema: Schema, field: FieldSpec) -> str:
    if field.is_scalar:
        return f"{_ctype(field.type)} {field.name}"
    if field.type in schema.structs:
        return f"{field.type} {field.name}"
    if field.size is not None:
        return f"uint8_t {field.name}[{field.size}]"
    return f"Bytes {field.name}"


def _comment(schema: Schema, field: FieldSpec) -> str:
    parts = []
    if field.enum:
        parts.append(f"{field.enum}::*")
    if field.flags:
        parts.append(f"{field.flags} bits")
    if field.type == "string":
        parts.append("UTF-8" + (", may be malformed" if field.lenient else ""))
    if field.length is not None:
        prefix = "to the end of the payload" if field.length == "rest" else f"{field.length} length"
        parts.append(prefix)
    if field.max is not None:
        parts.append(f"at most {field.max} bytes")
    if field.type == "param_value":
        parts.append(f"the encoded elements of {field.selector} (see param_value_size)")
    if field.when is not None:
        name, value, equal = field.when
        parts.append(f"only if {name} {'==' if equal else '!='} {value}")
    return "  // " + "; ".join(parts) if parts else ""


def _condition(spec: MessageSpec, field: FieldSpec, obj: str) -> str | None:
    if field.when is None:
        return None
    name, value, equal = field.when
    source = next(f for f in spec.fields if f.name == name)
    return f"{obj}{name} {'==' if equal else '!='} {source.enum}::{value}"


def _encode_field(schema: Schema, field: FieldSpec) -> Iterator[str]:
    ref = f"m.{field.name}"
    if field.is_scalar:
        if field.enum is not None:
            suffix = "_" + "_".join(field.exclude) if field.exclude else ""
            yield f"if (!valid_{field.enum}{suffix}({ref})) return false;"
            yield f"w.u8({ref});"
        elif field.flags is not None:
            mask = _mask(schema, field.flags)
            yield f"w.u8(static_cast<uint8_t>({ref} & {mask:#04x}));"
        else:
            if field.min:
                yield f"if ({ref} < {field.min}) return false;"
            yield f"w.{field.type}({ref});"
    elif field.type in schema.structs:
        for sub in schema.structs[field.type]:
            if sub.max is not None:
                yield f"if ({ref}.{sub.name} > {sub.max}u) return false;"
            yield f"w.{sub.type}({ref}.{sub.name});"
    elif field.type == "param_value":
        yield f"if (param_value_size(m.{field.selector}, {ref}) != {ref}.size) return false;"
        yield f"w.raw({ref}.data, {ref}.size);"
    elif field.size is not None:
        yield f"w.raw({ref}, {field.size});"
    else:
        limit = field.max
        if field.length in SCALARS:
            limit = min(limit or 1 << 32, (1 << (8 * SCALARS_SIZE[field.length])) - 1)
        if limit is not None:
            yield f"if ({ref}.size > {limit}u) return false;"
        if field.length != "rest":
            yield f"w.{field.length}(static_cast<{_ctype(field.length or 'u8')}>({ref}.size));"
        yield f"w.raw({ref}.data, {ref}.size);"


SCALARS_SIZE: Final = {"u8": 1, "u16": 2, "u32": 4, "u64": 8, "i32": 4, "f32": 4}


def _decode_field(schema: Schema, spec: MessageSpec, field: FieldSpec) -> Iterator[str]:
    ref = f"m->{field.name}"
    if field.is_scalar:
        yield f"{ref} = r.{field.type}();"
        if field.enum is not None:
            suffix = "_" + "_".join(field.exclude) if field.exclude else ""
            yield f"if (r.ok() && !valid_{field.enum}{suffix}({ref})) return false;"
        elif field.flags is not None:
            yield f"{ref} = static_cast<uint8_t>({ref} & {_mask(schema, field.flags):#04x});"
        elif field.const is not None:
            yield f"if (r.ok() && {ref} != {field.const}) return false;"
    elif field.type in schema.structs:
        for sub in schema.structs[field.type]:
            yield f"{ref}.{sub.name} = r.{sub.type}();"
            if sub.max is not None:
                yield f"if ({ref}.{sub.name} > {sub.max}u) return false;"
    elif field.type == "param_value":
        yield "{"
        yield "  detail::Reader rest = r;"
        yield "  Bytes all = rest.rest();"
        yield f"  size_t n = param_value_size(m->{field.selector}, all);"
        yield "  if (n == 0) return false;"
        yield f"  {ref} = r.take(n);"
        yield "}"
    elif field.size is not None:
        yield f"r.copy({ref}, {field.size});"
    else:
        if field.length == "rest":
            yield f"{ref} = r.rest();"
        else:
            yield f"{ref} = r.take(r.{field.length}());"
        if field.type == "string" and not field.lenient:
            yield f"if (r.ok() && !detail::utf8_valid({ref})) return false;"
        if field.length == "rest" and field.max is not None:
            yield f"if ({ref}.size > {field.max}u) return false;"


def _message(schema: Schema, spec: MessageSpec) -> Iterator[str]:
    cls = spec.class_name
    yield ""
    yield f"/** {spec.name} ({spec.opcode:#04x}, {spec.direction}, "
    yield f"    {'reliable' if spec.reliable else 'best effort'}): {spec.doc} */"
    yield f"struct {cls} {{"
    yield f"  static const uint8_t OPCODE = Opcode::{spec.name};"
    for field in spec.fields:
        init = ""
        if field.const is not None:
            init = f" = {field.const}"
        elif field.is_scalar:
            init = " = 0"
        elif field.type in schema.structs:
            init = " = {0, 0}"
        elif field.size is not None:
            init = " = {0}"
        yield f"  {_member(schema, field)}{init};{_comment(schema, field)}"
    yield "};"
    fields = spec.fields
    m = "m" if fields else "/*m*/"
    yield ""
    yield f"inline bool encode(const {cls}& {m}, uint8_t* buf, size_t cap, size_t* len) {{"
    yield "  detail::Writer w(buf, cap);"
    yield f"  w.u8({cls}::OPCODE);"
    for field in fields:
        cond = _condition(spec, field, "m.")
        body = list(_encode_field(schema, field))
        if cond:
            yield f"  if ({cond}) {{"
            yield from ("    " + line for line in body)
            yield "  }"
        else:
            yield from ("  " + line for line in body)
    yield "  return detail::finish(w, len);"
    yield "}"
    yield ""
    yield f"inline bool decode(const uint8_t* buf, size_t len, {cls}* {m}) {{"
    yield "  detail::Reader r(buf, len);"
    if fields:
        yield f"  *m = {cls}();"
    yield f"  if (r.u8() != {cls}::OPCODE) return false;"
    for field in fields:
        cond = _condition(spec, field, "m->")
        body = list(_decode_field(schema, spec, field))
        if cond:
            yield f"  if (r.ok() && {cond}) {{"
            yield from ("    " + line for line in body)
            yield "  }"
        else:
            yield from ("  " + line for line in body)
    yield "  return r.ok();"
    yield "}"


def _param_value(schema: Schema) -> Iterator[str]:
    pv = schema.param_value
    enum = pv.selector_enum
    yield ""
    yield "/** Bytes of a well-formed value of this type at the start of v (after the type byte),"
    yield "    or 0 when v does not start with one (a list is its count and its elements). */"
    yield "inline size_t param_value_size(uint8_t type, const Bytes& v) {"
    yield "  detail::Reader r(v.data, v.size);"
    yield f"  bool is_list = (type & {pv.list_bit:#04x}) != 0;"
    yield f"  uint32_t count = is_list ? r.{pv.count}() : 1;"
    yield f"  uint8_t element = static_cast<uint8_t>(type & {~pv.list_bit & 0xFF:#04x});"
    yield f"  if (!valid_{enum}(type) || element == 0) return 0;"
    yield "  for (uint32_t i = 0; i < count && r.ok(); ++i) {"
    yield "    switch (element) {"
    for name, element in pv.elements.items():
        yield f"      case {enum}::{name}:"
        if element.type == "string":
            yield f"        r.take(r.{element.length}());"
        else:
            yield f"        r.{element.type}();"
        yield "        break;"
    yield "      default:"
    yield "        return 0;"
    yield "    }"
    yield "  }"
    yield "  if (!r.ok()) return 0;"
    yield "  return v.size - r.rest().size;"
    yield "}"


def _frame(schema: Schema) -> Iterator[str]:
    frame = schema.frame
    header = frame["header"]
    bits = header[0]["bits"]
    names = [f["name"] for f in header]
    yield ""
    yield f"/** The frame header (PROTOCOL.md 1.4): {', '.join(names)}; flags = "
    yield "    " + " | ".join(f"{b['name']} << {b['shift']}" for b in bits) + ". */"
    yield "struct FrameHeader {"
    members = [b for b in bits if "const" not in b]
    for b in members:
        yield f"  uint8_t {b['name']} = 0;  // {b['enum']}::*"
    for f in header[1:]:
        yield f"  {_ctype(f['type'])} {f['name']} = 0;"
    yield "};"
    yield f"static const size_t FRAME_HEADER_SIZE = {len(header)};"
    yield f"static const size_t FRAME_CRC_SIZE = {SCALARS_SIZE[frame['crc']['type']]};"
    yield f"static const uint8_t FRAME_DELIMITER = {frame['delimiter']};"
    yield ""
    yield "inline bool encode(const FrameHeader& h, uint8_t* buf, size_t cap, size_t* len) {"
    yield "  detail::Writer w(buf, cap);"
    for b in members:
        yield f"  if (!valid_{b['enum']}(h.{b['name']})) return false;"
    parts = []
    for b in bits:
        value = str(b["const"]) if "const" in b else f"h.{b['name']}"
        parts.append(f"({value} << {b['shift']})")
    yield f"  w.u8(static_cast<uint8_t>({' | '.join(parts)}));"
    for f in header[1:]:
        yield f"  w.{f['type']}(h.{f['name']});"
    yield "  return detail::finish(w, len);"
    yield "}"
    yield ""
    yield "/** false for another version or the reserved type; the reserved bits are ignored. */"
    yield "inline bool decode(const uint8_t* buf, size_t len, FrameHeader* h) {"
    yield "  detail::Reader r(buf, len);"
    yield "  uint8_t flags = r.u8();"
    for b in bits:
        mask = (1 << b["width"]) - 1
        value = f"static_cast<uint8_t>((flags >> {b['shift']}) & {mask:#x})"
        if b.get("ignored"):
            continue
        if "const" in b:
            yield f"  if (r.ok() && {value} != {b['const']}) return false;"
        else:
            yield f"  h->{b['name']} = {value};"
            yield f"  if (r.ok() && !valid_{b['enum']}(h->{b['name']})) return false;"
    for f in header[1:]:
        yield f"  h->{f['name']} = r.{f['type']}();"
    yield "  return r.ok();"
    yield "}"
    crc = frame["crc"]
    if (crc["poly"], crc["init"]) != (_CRC_POLY, _CRC_INIT):
        raise ValueError(f"schema frame CRC {crc['name']} is not hwbridge_wire.h's crc16")


# -- the board's view ------------------------------------------------------------------------
#
# The board does not link the structs and bounded codecs above: it reads a received payload in
# place (its size checked once against kMinSize) and writes the fixed start of a message
# straight into its transmit buffer. For that the generator gives, per message the board reads
# or writes, a struct in namespace board with the opcode, the size of the fixed fields, getters
# at their offsets and a put() of them: inline, no tables, so that a sketch compiles to the
# loads and stores a hand-written parser would make.

_GET: Final = {"u8": "p[{at}]", "u16": "wire::get16(p + {at})", "u32": "wire::get32(p + {at})"}
_PUT: Final = {
    "u8": "p[{at}] = {value};",
    "u16": "wire::put16(p + {at}, {value});",
    "u32": "wire::put32(p + {at}, {value});",
}


def _fixed_layout(schema: Schema, spec: MessageSpec) -> tuple[list[tuple[str, str, int]], int]:
    """(name, wire type, offset) of the scalar fields at fixed offsets (struct fields flattened
    as NAME_SUB), and the offset where the first field of another kind starts."""
    out: list[tuple[str, str, int]] = []
    at = 1
    for field in spec.fields:
        if field.is_scalar and field.type in _GET:
            out.append((field.name, field.type, at))
        elif field.type in schema.structs:
            sub_at = at
            for sub in schema.structs[field.type]:
                out.append((f"{field.name}_{sub.name}", sub.type, sub_at))
                sub_at += schema.width(sub)
        else:
            return out, at
        at += schema.width(field)
    return out, at


def _board_struct(schema: Schema, spec: MessageSpec) -> Iterator[str]:
    reads = spec.direction in ("host->board", "both")
    writes = spec.direction in ("board->host", "both")
    layout, end = _fixed_layout(schema, spec)
    consts = {f.name: f.const for f in spec.fields if f.const is not None}
    yield ""
    does = "reads and writes" if reads and writes else "reads" if reads else "writes"
    yield f"/** {spec.name} as the board {does} it: its fixed fields at their offsets. */"
    yield f"struct {spec.class_name.removesuffix('Msg')} {{"
    yield f"  static const uint8_t kOpcode = Opcode::{spec.name};"
    yield "  /** Bytes of the opcode and the fixed fields: the shortest valid payload. */"
    yield f"  static const uint8_t kMinSize = {_min_size(schema, spec)};"
    # offsets of what follows the fixed start: variable fields, and fields sent on a condition
    at: int | None = 1
    for field in spec.fields:
        width = schema.width(field)
        if at is not None and field.type not in schema.structs:
            if field.length == "u8":
                yield f"  /** {field.name}: its u8 length here, its bytes after it. */"
            if field.length is not None or field.when is not None or not field.is_scalar:
                yield f"  static const uint8_t k{_camel(field.name)} = {at};"
        at = at + width if at is not None and width else None
        if field.when is not None and at is not None:
            name, value, equal = field.when
            cond = f"{name} {'==' if equal else '!='} {value}"
            yield f"  /** Bytes up to {field.name} when it is sent ({cond}). */"
            yield f"  static const uint8_t k{_camel(field.name)}End = {at};"
    if reads:
        for name, typ, off in layout:
            get = _GET[typ].format(at=off)
            yield f"  static {_ctype(typ)} {name}(const uint8_t* p) {{ return {get}; }}"
    if writes:
        args = [f"{_ctype(typ)} {name}" for name, typ, _ in layout if name not in consts]
        yield "  /** Writes the opcode and the fixed fields at p; returns the end of them. */"
        yield f"  static uint8_t* put(uint8_t* p{''.join(', ' + a for a in args)}) {{"
        yield "    p[0] = kOpcode;"
        for name, typ, off in layout:
            value = consts.get(name, name)
            yield "    " + _PUT[typ].format(at=off, value=value)
        yield f"    return p + {end};"
        yield "  }"
    yield "};"


def _camel(name: str) -> str:
    return "".join(part.capitalize() for part in name.split("_"))


def _min_size(schema: Schema, spec: MessageSpec) -> int:
    """Opcode and every field before the first optional one, a length prefix counted."""
    size = 1
    for field in spec.fields:
        if field.when is not None:
            break
        width = schema.width(field)
        if width:
            size += width
        elif field.length in SCALARS_SIZE:
            size += SCALARS_SIZE[field.length]
            break
        else:
            break
    return size


def _board(schema: Schema) -> Iterator[str]:
    yield ""
    yield "/** The board's view of the control messages: in place, no copies (gen_control.py). */"
    yield "namespace board {"
    for spec in schema.messages:
        yield from _board_struct(schema, spec)
    yield "}  // namespace board"


def _identity(schema: Schema) -> Iterator[str]:
    """The firmware identity's schema hash and keys (PROTOCOL.md 2.6.1), as macros: the board
    joins them into one string literal at compile time (hwbridge/identity.h)."""
    yield "// The firmware identity (PROTOCOL.md 2.6.1): this schema's hash (a test build may"
    yield "// define another before including the library) and the key of each item."
    yield "#ifndef HWBRIDGE_SCHEMA_HASH"
    yield f'#define HWBRIDGE_SCHEMA_HASH "{schema.hash}"'
    yield "#endif"
    for attr, key in schema.identity.items.items():
        yield f'#define HWBRIDGE_ID_KEY_{attr.upper()} "{key}"'
    yield "// The items in the order a board sends them (each defined in hwbridge/identity.h)."
    items = " ".join(f"HWBRIDGE_ID_{attr.upper()}_" for attr in schema.identity.items)
    yield f"#define HWBRIDGE_ID_ITEMS_ {items}"


def _banner(schema: Schema, name: str, what: tuple[str, ...]) -> list[str]:
    """The comment a generated file starts with: NAME: WHAT (its lines), where it comes from."""
    return [
        f"// {name}: {what[0]}",
        *(f"// {line}" for line in what[1:]),
        "// Generated by `hwbridge firmware generate` from protocols/native/schema.json",
        f"// (version {schema.version}); do not edit.",
    ]


def _guard(name: str) -> str:
    """The include guard of header NAME: ``hwbridge_control_msgs.h`` -> HWBRIDGE_CONTROL_MSGS_H."""
    return name.removesuffix(".h").upper() + "_H"


def _part(schema: Schema, name: str, what: tuple[str, ...], body: Iterable[str]) -> str:
    """One part of ``hwbridge_control.h``: BODY in namespace hwbridge::control, after what it
    needs (:data:`BASE_NAME`), so that it compiles alone too."""
    return "\n".join(
        [
            *_banner(schema, name, what),
            f"// Part of {HEADER_NAME}, which includes it: include that one.",
            f"#ifndef {_guard(name)}",
            f"#define {_guard(name)}",
            "",
            f'#include "{BASE_NAME}"',
            "",
            "namespace hwbridge {",
            "namespace control {",
            *body,
            "",
            "}  // namespace control",
            "}  // namespace hwbridge",
            "",
            "#endif",
            "",
        ]
    )


def _base_header(schema: Schema) -> str:
    """The text of ``hwbridge_control_base.h``: the prelude, constants, enums, flags, structs,
    the frame header and ``param_value_size``, everything the messages are made of."""
    out = [
        *_banner(
            schema,
            BASE_NAME,
            (
                "what the native protocol's control messages are made of (PROTOCOL.md",
                "1.4, 2.14): constants, enums, flags, the frame header and its codec.",
                "C++11, header-only, no heap, no exceptions; every encode and decode is bounded.",
            ),
        ),
        f"// Part of {HEADER_NAME}, which includes it: include that one.",
        f"#ifndef {_guard(BASE_NAME)}",
        f"#define {_guard(BASE_NAME)}",
        "",
        template(PRELUDE_NAME),
    ]
    for name, value in schema.constants.items():
        ctype = "uint32_t" if value > 0xFFFF else "uint8_t" if value <= 0xFF else "uint16_t"
        out.append(f"static const {ctype} {name} = {value};")
    for name, values in schema.enums.items():
        out.append("")
        out.extend(_enum_block(name, dict(values), "u8", f"enum {name}"))
        out.extend(_valid_fn(name, dict(values)))
        for spec in schema.messages:
            for field in spec.fields:
                if field.enum == name and field.exclude:
                    out.extend(_valid_fn(name, dict(values), field.exclude))
    for name, values in schema.flags.items():
        out.append("")
        out.extend(_enum_block(name, dict(values), "u8", f"flags {name} (bits)"))
    for name, fields in schema.structs.items():
        out.append("")
        out.append(f"struct {name} {{")
        out.extend(f"  {_member(schema, f)};" for f in fields)
        out.append("};")
    out.extend(_frame(schema))
    out.extend(_param_value(schema))
    out += ["", "}  // namespace control", "}  // namespace hwbridge", "", "#endif", ""]
    return "\n".join(out)


def _msgs_header(schema: Schema) -> str:
    """The text of ``hwbridge_control_msgs.h``: per message a struct, its encode and decode."""
    what = (
        "the native protocol's control messages (PROTOCOL.md 2.14):",
        "per message a struct and its bounded encode and decode.",
    )
    body = (line for spec in schema.messages for line in _message(schema, spec))
    return _part(schema, MSGS_NAME, what, body)


def _board_header(schema: Schema) -> str:
    """The text of ``hwbridge_control_board.h``: ``control::board``, the board's view."""
    what = (
        "control::board, the board's view of the control messages: per message",
        "its opcode, its shortest size and its fixed fields at their offsets, read in place.",
    )
    return _part(schema, BOARD_NAME, what, _board(schema))


def generate_control_header(schema: Schema | None = None) -> str:
    """The text of ``hwbridge_control.h``: the firmware identity's macros, then the
    ``#include`` of its parts (:func:`generate_control_files` gives them all)."""
    schema = schema or load_schema()
    out = [
        *_banner(
            schema,
            HEADER_NAME,
            (
                "the native protocol's frame header and control messages",
                "(PROTOCOL.md 1.4, 2.14). C++11, header-only, no heap, no exceptions; every",
                "encode and decode is bounded. This file holds the firmware identity's macros",
                f"and includes the three parts: {BASE_NAME} (constants, enums, flags,",
                f"the frame header), {MSGS_NAME} (a struct, encode and decode per",
                f"message) and {BOARD_NAME} (control::board, the board's view).",
            ),
        ),
        f"#ifndef {_guard(HEADER_NAME)}",
        f"#define {_guard(HEADER_NAME)}",
        "",
        *_identity(schema),
        "",
        *(f'#include "{name}"' for name in PART_NAMES),
        "",
        "#endif",
        "",
    ]
    return "\n".join(out)


def generate_control_files(schema: Schema | None = None) -> dict[str, str]:
    """File name -> text: ``hwbridge_control.h``, its parts (:data:`PART_NAMES`) and the
    ``hwbridge_wire.h`` they include."""
    schema = schema or load_schema()
    return {
        HEADER_NAME: generate_control_header(schema),
        BASE_NAME: _base_header(schema),
        MSGS_NAME: _msgs_header(schema),
        BOARD_NAME: _board_header(schema),
        WIRE_NAME: template(WIRE_NAME),
    }
