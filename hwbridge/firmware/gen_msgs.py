"""C++ headers for ROS 1 message and service types: ``hwbridge firmware generate``.

For every type asked for, and every message type it uses, ``OUTDIR/<pkg>/<Type>.h`` holds a
struct ``pkg::Type`` with its fields and constants, and:

- ``size_t serialize(uint8_t* buf, size_t cap) const``: the ROS 1 bytes (the same bytes as
  ``hwbridge.msg.encode``), or 0 when they do not fit in ``cap`` bytes or an array holds more
  than its capacity; never writes past ``buf + cap``. (A message without fields is 0 bytes too.)
- ``bool deserialize(const uint8_t* buf, size_t len)``: false unless the ``len`` bytes are exactly
  one message whose arrays and strings fit their capacities; never reads past ``buf + len``.
- ``type_name()`` and ``md5sum()``: NUL-terminated ``static const char`` arrays, and
  ``md5_bytes()``: the md5 sum's 16 bytes (what the board's topic table sends); all in flash
  (``PROGMEM``) on AVR.

A service ``pkg/Srv`` gives ``SrvRequest``, ``SrvResponse`` and ``Srv`` (the pair, with the
service's name and md5) in ``OUTDIR/<pkg>/<Srv>.h``. Variable-length arrays are
``hwbridge::msg::Array<T, N>`` and strings ``hwbridge::msg::String<N>``, with a fixed capacity
per field (:data:`DEFAULT_ARRAY_CAPACITY` elements, :data:`DEFAULT_STRING_CAPACITY` bytes, or what
``--capacity pkg/Type.field=N`` says; ``pkg/Type.field[]=N`` for each string of a string array).
float64 is 8 bytes on the wire everywhere; where ``double`` has 4 (AVR) the field is a ``float``,
converted to and from IEEE-754 binary64 by hand. What the headers share is
``OUTDIR/hwbridge_msg.h`` (:data:`RUNTIME_HEADER`) over ``OUTDIR/hwbridge_wire.h`` (the library's
byte helpers); both are copied from ``templates/``. C++11, no heap, no exceptions.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, Final

from rosbags.interfaces import Nodetype

from hwbridge.errors import HwBridgeError
from hwbridge.firmware._templates import WIRE_NAME, template
from hwbridge.protocols.msgtypes import TypeRegistry, ros1_name

__all__ = [
    "DEFAULT_ARRAY_CAPACITY",
    "DEFAULT_STRING_CAPACITY",
    "DEFINITIONS_NAME",
    "LIBRARY_TYPES",
    "MESSAGES_HASH_MACRO",
    "RUNTIME_HEADER",
    "RUNTIME_NAME",
    "Capacities",
    "MessageHeaders",
    "library_messages_hash",
    "messages_hash",
    "parse_capacity",
]

DEFAULT_ARRAY_CAPACITY: Final = 8
"""Elements a variable-length array field holds unless told otherwise."""
DEFAULT_STRING_CAPACITY: Final = 32
"""Bytes a string field holds unless told otherwise."""
RUNTIME_NAME: Final = "hwbridge_msg.h"
DEFINITIONS_NAME: Final = "hwbridge_msgdefs.h"
MESSAGES_HASH_MACRO: Final = "HWBRIDGE_MSGS_HASH"

RUNTIME_HEADER: Final = template(RUNTIME_NAME)
"""The text of ``hwbridge_msg.h`` (``templates/hwbridge_msg.h``): strings, arrays, time, float64,
the ROS 1 Writer/Reader over ``hwbridge_wire.h``'s."""

_TIME: Final = {
    "builtin_interfaces/msg/Time": "time",
    "builtin_interfaces/msg/Duration": "duration",
}
_SCALARS: Final = {
    # ROS 1 type: (C++ type, Writer/Reader method)
    "bool": ("bool", "boolean"),
    "int8": ("int8_t", "i8"),
    "byte": ("int8_t", "i8"),
    "uint8": ("uint8_t", "u8"),
    "char": ("uint8_t", "u8"),
    "int16": ("int16_t", "i16"),
    "uint16": ("uint16_t", "u16"),
    "int32": ("int32_t", "i32"),
    "uint32": ("uint32_t", "u32"),
    "int64": ("int64_t", "i64"),
    "uint64": ("uint64_t", "u64"),
    "float32": ("float", "f32"),
    "float64": ("hwbridge::msg::float64", "f64"),
    "time": ("hwbridge::msg::Time", "time"),
    "duration": ("hwbridge::msg::Duration", "duration"),
}
_KEYWORDS: Final = frozenset(
    [
        "alignas",
        "alignof",
        "and",
        "asm",
        "auto",
        "bitand",
        "bitor",
        "bool",
        "break",
        "case",
        "catch",
        "char",
        "class",
        "compl",
        "const",
        "constexpr",
        "continue",
        "decltype",
        "default",
        "delete",
        "do",
        "double",
        "else",
        "enum",
        "explicit",
        "export",
        "extern",
        "false",
        "float",
        "for",
        "friend",
        "goto",
        "if",
        "inline",
        "int",
        "long",
        "mutable",
        "namespace",
        "new",
        "noexcept",
        "not",
        "nullptr",
        "operator",
        "or",
        "private",
        "protected",
        "public",
        "register",
        "return",
        "short",
        "signed",
        "sizeof",
        "static",
        "struct",
        "switch",
        "template",
        "this",
        "throw",
        "true",
        "try",
        "typedef",
        "typeid",
        "typename",
        "union",
        "unsigned",
        "using",
        "virtual",
        "void",
        "volatile",
        "while",
        "xor",
    ]
)
_MEMBERS: Final = frozenset(
    {"write", "read", "serialize", "deserialize", "type_name", "md5sum", "md5_bytes"}
)
"""Names the generated structs use themselves: a field called so gets a trailing underscore."""
_CAPACITY_RE: Final = re.compile(
    r"^(?P<type>[A-Za-z]\w*/[A-Za-z]\w*)\.(?P<field>[A-Za-z]\w*)(?P<elem>\[\])?=(?P<n>\d+)$"
)


@dataclass
class Capacities:
    """Capacities of variable-length fields: ``(ROS type, field)`` -> elements or bytes, and
    ``(ROS type, field + "[]")`` -> bytes of each string of a string array."""

    arrays: int = DEFAULT_ARRAY_CAPACITY
    strings: int = DEFAULT_STRING_CAPACITY
    fields: dict[tuple[str, str], int] = field(default_factory=dict)

    def of(self, type_name: str, name: str, default: int) -> int:
        """The capacity of one field (the default unless set)."""
        return self.fields.get((type_name, name), default)


def parse_capacity(text: str) -> tuple[str, str, int]:
    """``pkg/Type.field=N`` (or ``pkg/Type.field[]=N``: each string of a string array) ->
    ``(type, field, N)``; HwBridgeError if malformed."""
    found = _CAPACITY_RE.match(text.strip())
    if found is None or not 1 <= int(found["n"]) <= 65535:
        raise HwBridgeError(
            f"--capacity {text!r}: expected pkg/Type.field=N (or pkg/Type.field[]=N for the "
            "strings of a string array), N from 1 to 65535"
        )
    return found["type"], found["field"] + (found["elem"] or ""), int(found["n"])


def _ident(name: str) -> str:
    return name + "_" if name in _KEYWORDS or name in _MEMBERS else name


def _cpp_name(ros_name: str) -> str:
    pkg, base = ros_name.split("/")
    return f"::{pkg}::{base}"


class MessageHeaders:
    """Generates the headers of message and service types and of their dependencies."""

    def __init__(self, registry: TypeRegistry, capacities: Capacities | None = None) -> None:
        self.registry = registry
        self.capacities = capacities or Capacities()
        self._used: set[tuple[str, str]] = set()

    # -- which types --------------------------------------------------------------------------

    def _deps(self, ros_name: str) -> list[str]:
        """Message types the fields of ``ros_name`` use directly."""
        found: list[str] = []
        for _, desc in self.registry.fields(ros_name):
            kind, arg = desc
            if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
                kind, arg = arg[0]
            if kind == Nodetype.NAME and arg not in _TIME:
                name = ros1_name(arg)
                if name not in found:
                    found.append(name)
        return found

    def is_service(self, name: str) -> bool:
        """True if ``name`` is a service type (and no message type has that name)."""
        return name not in self.registry.message_names() and name in self.registry.service_names()

    def closure(self, names: Iterable[str]) -> dict[str, list[str]]:
        """Every header to write: ``pkg/Type`` -> the message types it includes (a service's
        request and response are in the service's header)."""
        out: dict[str, list[str]] = {}
        todo = list(names)
        while todo:
            name = todo.pop(0)
            if name in out:
                continue
            if self.is_service(name):
                srv = self.registry.service(name)
                deps = [*self._deps(srv.request.name), *self._deps(srv.response.name)]
            else:
                self.registry.message(name)  # UnknownTypeError names close matches
                deps = self._deps(name)
            out[name] = list(dict.fromkeys(deps))
            todo.extend(deps)
        return out

    def check_capacities(self) -> None:
        """Refuse a capacity that names no variable-length field of a generated type."""
        for type_name, name in self.capacities.fields:
            if (type_name, name) not in self._used:
                raise HwBridgeError(
                    f"--capacity {type_name}.{name}: not a variable-length array or string "
                    "field of a generated type"
                )

    # -- C++ ----------------------------------------------------------------------------------

    def _element(self, desc: Any) -> tuple[str, str]:
        """(C++ type, Writer/Reader method; '' for a nested message, 'string' for a string)."""
        kind, arg = desc
        if kind == Nodetype.NAME:
            if arg in _TIME:
                return _SCALARS[_TIME[arg]]
            return _cpp_name(ros1_name(arg)), ""
        base = arg[0]
        if base == "string":
            return "", "string"
        return _SCALARS[base]

    def _field(self, owner: str, name: str, desc: Any) -> tuple[str, list[str], list[str]]:
        """(declaration, write lines, read lines) of one field."""
        cname = _ident(name)
        kind, arg = desc
        array = kind in (Nodetype.ARRAY, Nodetype.SEQUENCE)
        elem_desc, size = arg if array else (desc, None)
        ctype, method = self._element(elem_desc)
        if method == "string":
            key = name + "[]" if array else name
            chars = self.capacities.of(owner, key, self.capacities.strings)
            self._used.add((owner, key))
            ctype = f"hwbridge::msg::String<{chars}>"

        def write(ref: str) -> str:
            return f"_w.{method}({ref});" if method else f"{ref}.write(_w);"

        def read(ref: str) -> str:
            if not method:
                return f"{ref}.read(_r);"
            if method in ("string", "time", "duration"):
                return f"_r.{method}(&{ref});"
            return f"{ref} = _r.{method}();"

        if kind == Nodetype.SEQUENCE:
            cap = self.capacities.of(owner, name, self.capacities.arrays)
            self._used.add((owner, name))
            items = f"for (uint16_t _i = 0; _i < {cname}.size && "
            return (
                f"hwbridge::msg::Array<{ctype}, {cap}> {cname};",
                [
                    f"_w.count({cname}.size, {cap});",
                    items + f"_w.ok(); ++_i) {write(cname + '[_i]')}",
                ],
                [
                    f"{cname}.size = _r.count({cap});",
                    items + f"_r.ok(); ++_i) {read(cname + '[_i]')}",
                ],
            )
        if kind == Nodetype.ARRAY:
            loop = f"for (uint16_t _i = 0; _i < {size}; ++_i) "
            return (
                f"{ctype} {cname}[{size}] = {{}};",
                [loop + write(cname + "[_i]")],
                [loop + read(cname + "[_i]")],
            )
        init = ""
        if ctype == "bool":
            init = " = false"
        elif method and method not in ("string", "time", "duration"):
            init = " = 0"
        return f"{ctype} {cname}{init};", [write(cname)], [read(cname)]

    def _constants(self, ros_name: str) -> Iterator[str]:
        for name, typ, value in self.registry.constants(ros_name):
            cname = _ident(name)
            if typ == "string":
                text = str(value).replace("\\", "\\\\").replace('"', '\\"')
                yield f'  static constexpr const char* {cname} = "{text}";'
            elif typ in ("float32", "float64"):
                yield f"  static constexpr {_SCALARS[typ][0]} {cname} = {float(value)!r};"
            elif typ == "bool":
                yield f"  static const bool {cname} = {'true' if value else 'false'};"
            else:
                number = int(value)
                literal = str(number)
                if typ.startswith("uint") or typ == "char":
                    literal += "U"
                if "64" in typ:
                    literal += "LL"
                if number in (-(2**63), -(2**31)):  # no literal for the most negative value
                    literal = f"({number + 1}{'LL' if '64' in typ else 'L'} - 1)"
                yield f"  static const {_SCALARS[typ][0]} {cname} = {literal};"

    def _struct(self, ros_name: str, cls: str) -> Iterator[str]:
        md5 = self.registry.message(ros_name).md5
        writes: list[str] = []
        reads: list[str] = []
        yield f"/** {ros_name} (md5 {md5}). */"
        yield f"struct {cls} {{"
        yield from self._constants(ros_name)
        for name, desc in self.registry.fields(ros_name):
            decl, wr, rd = self._field(ros_name, name, desc)
            yield f"  {decl}"
            writes += wr
            reads += rd
        yield ""
        yield "  /** Writes the ROS 1 bytes into buf: their count, or 0 if they do not fit in cap"
        yield "      bytes (or an array holds more than its capacity). Never writes past cap. */"
        yield "  size_t serialize(uint8_t* buf, size_t cap) const {"
        yield "    hwbridge::msg::Writer w(buf, cap);"
        yield "    write(w);"
        yield "    return w.finish();"
        yield "  }"
        yield "  /** Reads exactly len bytes: false if they are not one message of this type or an"
        yield "      array or string is longer than its capacity. Never reads past len. */"
        yield "  bool deserialize(const uint8_t* buf, size_t len) {"
        yield "    hwbridge::msg::Reader r(buf, len);"
        yield "    read(r);"
        yield "    return r.finish();"
        yield "  }"
        yield f"  void write(hwbridge::msg::Writer& {'_w' if writes else '/*_w*/'}) const {{"
        yield from ("    " + line for line in writes)
        yield "  }"
        yield f"  void read(hwbridge::msg::Reader& {'_r' if reads else '/*_r*/'}) {{"
        yield from ("    " + line for line in reads)
        yield "  }"
        yield from self._names(cls)
        yield "};"

    @staticmethod
    def _names(name: str) -> Iterator[str]:
        yield "  /** Type name and md5 sum, NUL-terminated: in flash on AVR (read them with"
        yield "      pgm_read_byte, strcpy_P, ...), in RAM elsewhere. */"
        yield f"  static const char* type_name() {{ return {name}Names_<void>::type; }}"
        yield f"  static const char* md5sum() {{ return {name}Names_<void>::md5; }}"
        yield "  /** The md5 sum as its 16 bytes (in flash on AVR), as the topic table sends it. */"
        yield f"  static const uint8_t* md5_bytes() {{ return {name}Names_<void>::md5_bytes; }}"

    @staticmethod
    def _names_storage(name: str, ros_name: str, md5: str) -> Iterator[str]:
        # Static members of a class template: one copy however many files include the header.
        yield "template <class D>"
        yield f"struct {name}Names_ {{"
        yield "  static const char type[];"
        yield "  static const char md5[];"
        yield "  static const uint8_t md5_bytes[16];"
        yield "};"
        yield "template <class D>"
        yield f'const char {name}Names_<D>::type[] HWBRIDGE_PROGMEM = "{ros_name}";'
        yield "template <class D>"
        yield f'const char {name}Names_<D>::md5[] HWBRIDGE_PROGMEM = "{md5}";'
        raw = ", ".join(f"0x{md5[i : i + 2]}" for i in range(0, 32, 2))
        yield "template <class D>"
        yield f"const uint8_t {name}Names_<D>::md5_bytes[16] HWBRIDGE_PROGMEM = {{{raw}}};"

    def header(self, name: str, deps: list[str]) -> str:
        """The text of ``pkg/Type.h`` for a message or service type."""
        pkg, base = name.split("/")
        guard = f"HWBRIDGE_MSG_{pkg.upper()}_{base.upper()}_H"
        out = [
            f"// {name}: generated by `hwbridge firmware generate`; do not edit.",
            f"#ifndef {guard}",
            f"#define {guard}",
            "",
            f'#include "../{RUNTIME_NAME}"',
            *(f'#include "../{dep}.h"' for dep in deps),
            "",
            f"namespace {pkg} {{",
            "",
        ]
        if self.is_service(name):
            srv = self.registry.service(name)
            for part, cls in ((srv.request, base + "Request"), (srv.response, base + "Response")):
                out += [*self._names_storage(cls, part.name, part.md5), ""]
                out += [*self._struct(part.name, cls), ""]
            out += self._names_storage(base, name, srv.md5)
            out += [
                "",
                f"/** The service {name} (md5 {srv.md5}). */",
                f"struct {base} {{",
                f"  typedef {base}Request Request;",
                f"  typedef {base}Response Response;",
                *self._names(base),
                "};",
            ]
        else:
            out += self._names_storage(base, name, self.registry.message(name).md5)
            out += ["", *self._struct(name, base)]
        out += ["", f"}}  // namespace {pkg}", "", "#endif", ""]
        return "\n".join(out)

    def md5(self, name: str) -> str:
        """The md5 sum of a message or service type."""
        if self.is_service(name):
            return self.registry.service(name).md5
        return self.registry.message(name).md5

    def definitions_header(self, names: Iterable[str]) -> str:
        """The text of ``hwbridge_msgdefs.h``: :data:`MESSAGES_HASH_MACRO`, the
        :func:`messages_hash` of the types written with it (listed in its comment)."""
        md5s = {name: self.md5(name) for name in names}
        out = [
            f"// {DEFINITIONS_NAME}: the message definitions the headers written with it were",
            "// generated from (PROTOCOL.md 2.6.1: a board sends their hash in BOARD_INFO).",
            "// Generated by `hwbridge firmware generate`; do not edit.",
            "#ifndef HWBRIDGE_MSGDEFS_H",
            "#define HWBRIDGE_MSGDEFS_H",
            "",
            "// The hash covers these types (name md5):",
            *(f"//   {name} {md5s[name]}" for name in sorted(md5s)),
            f"#ifndef {MESSAGES_HASH_MACRO}",
            f'#define {MESSAGES_HASH_MACRO} "{messages_hash(md5s)}"',
            "#endif",
            "",
            "#endif",
            "",
        ]
        return "\n".join(out)

    def headers(self, names: Iterable[str]) -> Mapping[str, str]:
        """Relative path -> text: ``hwbridge_msg.h``, ``hwbridge_msgdefs.h`` and ``pkg/Type.h``
        for the types and every message type they use."""
        found = {RUNTIME_NAME: RUNTIME_HEADER, WIRE_NAME: template(WIRE_NAME)}
        closure = self.closure(names)
        for name, deps in closure.items():
            found[f"{name}.h"] = self.header(name, deps)
        found[DEFINITIONS_NAME] = self.definitions_header(closure)
        self.check_capacities()
        return found


def messages_hash(md5s: Mapping[str, str]) -> str:
    """The messages hash of PROTOCOL.md 2.6.1: the first 8 lowercase hex digits of SHA-256 over
    one line ``pkg/Type md5\\n`` per type (ROS 1 names; a service's own md5), sorted by name,
    UTF-8."""
    text = "".join(f"{name} {md5s[name]}\n" for name in sorted(md5s))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:8]


LIBRARY_TYPES: Final = (
    "geometry_msgs/Quaternion",
    "geometry_msgs/Twist",
    "geometry_msgs/Vector3",
    "hwbridge_msgs/Bme280",
    "hwbridge_msgs/ImuRaw",
    "hwbridge_msgs/SonarEcho",
    "hwbridge_msgs/WheelTargets",
    "hwbridge_msgs/WheelTicks",
    "sensor_msgs/Imu",
    "sensor_msgs/JointState",
    "sensor_msgs/MagneticField",
    "sensor_msgs/Range",
    "std_msgs/Bool",
    "std_msgs/Duration",
    "std_msgs/Empty",
    "std_msgs/Float32",
    "std_msgs/Float64",
    "std_msgs/Header",
    "std_msgs/Int16",
    "std_msgs/Int32",
    "std_msgs/Int8",
    "std_msgs/String",
    "std_msgs/Time",
    "std_msgs/UInt16",
    "std_msgs/UInt32",
    "std_msgs/UInt8",
    "std_srvs/Empty",
    "std_srvs/SetBool",
    "std_srvs/Trigger",
)
"""The types whose headers the HwBridge library carries (``firmware/HwBridge/src/PKG/Type.h``;
tests/firmware/test_library_headers.py keeps the two equal)."""


def library_messages_hash(registry: TypeRegistry) -> str:
    """The messages hash a board built with the library of this hwbridge sends (its definitions
    as ``registry`` has them)."""
    headers = MessageHeaders(registry)
    closure = headers.closure(LIBRARY_TYPES)
    return messages_hash({name: headers.md5(name) for name in closure})
