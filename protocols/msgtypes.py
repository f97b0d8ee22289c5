"""ROS 1 message and service types on top of ``rosbags``.

This module is the one place where hwbridge turns .msg/.srv text into types: it validates
definitions (so errors name the file, the line and the problem), hands them to ``rosbags`` for
parsing, md5 sums and ROS 1 serialization, and maps ROS 1 names (``sensor_msgs/Imu``) to the
names ``rosbags`` uses (``sensor_msgs/msg/Imu``). It sits in the bottom layer because the wire
protocols need it too (rosserial's TopicInfo, Log and RequestParam); ``hwbridge.msg`` is the
user-facing API over it.

Search path layout: each directory holds packages laid out ``PKG/msg/*.msg`` and ``PKG/srv/*.srv``.
"""

from __future__ import annotations

import difflib
import hashlib
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from hwbridge.protocols.errors import (
    DefinitionError,
    SerializationError,
    UnknownTypeError,
)

__all__ = [
    "BUILTIN_TYPES",
    "BUNDLED_MSG_DIR",
    "EMPTY_MARKER",
    "INT_RANGES",
    "MessageType",
    "ServiceType",
    "TypeRegistry",
    "ros1_name",
    "suggest",
]

BUNDLED_MSG_DIR: Final = Path(__file__).with_name("msg")
"""Definitions shipped with hwbridge that the ROS 1 noetic set lacks (rosserial_msgs, ...)."""

INT_RANGES: Final[dict[str, tuple[int, int]]] = {
    "byte": (-(2**7), 2**7 - 1),
    "char": (0, 2**8 - 1),
    "int8": (-(2**7), 2**7 - 1),
    "uint8": (0, 2**8 - 1),
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
    "int64": (-(2**63), 2**63 - 1),
    "uint64": (0, 2**64 - 1),
}
_FLOAT_TYPES: Final = frozenset({"float32", "float64"})
_CONSTANT_TYPES: Final = frozenset({*INT_RANGES, *_FLOAT_TYPES, "bool", "string"})
BUILTIN_TYPES: Final = frozenset({*_CONSTANT_TYPES, "time", "duration"})
"""Every builtin (non-message) field type of the ROS 1 interface language."""

_TIME_TYPES: Final = {
    "builtin_interfaces/msg/Time": "time",
    "builtin_interfaces/msg/Duration": "duration",
}
EMPTY_MARKER: Final = "structure_needs_at_least_one_member"
"""Field rosbags adds to empty messages; not part of the ROS 1 definition or wire format."""
_IDENT = r"[A-Za-z][A-Za-z0-9_]*"
_TYPE_RE: Final = re.compile(
    rf"^(?:(?P<pkg>{_IDENT})/)?(?P<base>{_IDENT})(?P<array>\[(?P<size>\d*)\])?$"
)
_NAME_RE: Final = re.compile(rf"^{_IDENT}$")
_SRV_SEPARATOR: Final = "---"


@dataclass(frozen=True)
class MessageType:
    """A registered message type: its ROS 1 name, md5 and where it came from."""

    name: str
    """ROS 1 name, ``pkg/Type``."""
    md5: str
    source: str
    """File it was read from, or ``rosbags`` for the standard set."""
    store_name: str = field(repr=False)
    """Name inside the rosbags type store (``pkg/msg/Type``)."""


@dataclass(frozen=True)
class ServiceType:
    """A registered service: request and response message types and the combined md5."""

    name: str
    md5: str
    request: MessageType
    response: MessageType
    source: str


@dataclass
class _Line:
    number: int
    type: str
    name: str
    value: str | None  # set for constants


def ros1_name(store_name: str) -> str:
    """``pkg/msg/Type`` (a rosbags name) -> ``pkg/Type`` (the ROS 1 name)."""
    pkg, _, base = store_name.split("/")
    return f"{pkg}/{base}"


def _read_lines(path: str, text: str, *, constants_allowed: bool = True) -> list[_Line]:
    """Validate a .msg body line by line; raise DefinitionError naming the first bad line."""
    lines: list[_Line] = []
    seen: dict[str, int] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        code = raw.strip()
        if not code or code.startswith("#"):
            continue
        parts = code.split(None, 1)
        if len(parts) < 2:
            raise DefinitionError(path, number, f"expected 'TYPE NAME', got {code!r}")
        typ, rest = parts
        if typ == "string" and "=" in rest:
            # A string constant's value runs to the end of the line, '#' included.
            name, value = (p.strip() for p in rest.split("=", 1))
        else:
            rest = rest.split("#", 1)[0].strip()
            if "=" in rest:
                name, value = (p.strip() for p in rest.split("=", 1))
            else:
                name, value = rest, None
                if len(rest.split()) != 1:
                    raise DefinitionError(
                        path, number, f"expected 'TYPE NAME', got {code!r} (extra words)"
                    )
        match = _TYPE_RE.match(typ)
        if match is None:
            raise DefinitionError(path, number, f"bad type {typ!r}: expected pkg/Type or a builtin")
        if not _NAME_RE.match(name):
            raise DefinitionError(path, number, f"bad field name {name!r}")
        if value is not None:
            _check_constant(path, number, typ, name, value)
        if name in seen:
            raise DefinitionError(
                path, number, f"duplicate name {name!r} (first defined on line {seen[name]})"
            )
        seen[name] = number
        lines.append(_Line(number, typ, name, value))
    return lines


def _check_constant(path: str, number: int, typ: str, name: str, value: str) -> None:
    if typ not in _CONSTANT_TYPES:
        allowed = ", ".join(sorted(_CONSTANT_TYPES))
        raise DefinitionError(
            path, number, f"constant {name} has type {typ!r}; constants must be one of {allowed}"
        )
    if typ == "string":
        return
    if typ == "bool":
        if value.lower() not in {"true", "false", "1", "0"}:
            raise DefinitionError(path, number, f"constant {name}: {value!r} is not a bool")
        return
    if typ in _FLOAT_TYPES:
        try:
            float(value)
        except ValueError:
            raise DefinitionError(
                path, number, f"constant {name}: {value!r} is not a {typ} value"
            ) from None
        return
    try:
        number_value = int(value, 0)
    except ValueError:
        raise DefinitionError(
            path, number, f"constant {name}: {value!r} is not an integer ({typ})"
        ) from None
    low, high = INT_RANGES[typ]
    if not low <= number_value <= high:
        raise DefinitionError(
            path, number, f"constant {name}={value} is out of range for {typ} [{low}, {high}]"
        )


def _qualify(typ: str, package: str) -> tuple[str, str | None]:
    """Return (definition text type, referenced ROS 1 message name or None for builtins)."""
    match = _TYPE_RE.match(typ)
    assert match is not None  # validated by _read_lines
    base, array = match["base"], match["array"] or ""
    if match["pkg"] is None and base in BUILTIN_TYPES:
        return typ, None
    if match["pkg"] is None:
        ref = "std_msgs/Header" if base == "Header" else f"{package}/{base}"
    else:
        ref = f"{match['pkg']}/{base}"
    return ref + array, ref


@dataclass
class _Pending:
    """A definition read from disk, validated line by line, not yet registered."""

    store_name: str
    path: str
    lines: list[_Line]
    refs: list[tuple[int, str, str]]  # (line number, referenced ROS 1 name, as written)
    text: str  # normalized text handed to rosbags


class TypeRegistry:
    """Every message and service type hwbridge knows, by ROS 1 name.

    ``search_path`` directories are read in order; a type defined twice must be defined the same
    way. The ROS 1 noetic standard set and hwbridge's bundled definitions are always present.
    """

    def __init__(self, search_path: Iterable[str | Path] = ()) -> None:
        self._store: Typestore = get_typestore(Stores.ROS1_NOETIC)
        self._messages: dict[str, MessageType] = {}
        self._services: dict[str, ServiceType] = {}
        self._sources: dict[str, str] = {}
        self._md5: dict[str, str] = {}
        self._service_halves: set[str] = set()
        self._store_names: dict[str, str] = {}
        self.search_path: tuple[Path, ...] = tuple(Path(p) for p in search_path)
        for store_name in self._store.fielddefs:
            if store_name not in _TIME_TYPES:
                self._sources[store_name] = "rosbags"
        self._load([BUNDLED_MSG_DIR, *self.search_path])

    # ------------------------------------------------------------------ loading
    def _load(self, roots: Sequence[Path]) -> None:
        pending: dict[str, _Pending] = {}
        services: dict[str, tuple[str, str, str]] = {}  # ros1 name -> (req, resp, path)
        for root in roots:
            for path in sorted(root.glob("*/msg/*.msg")):
                package = path.parent.parent.name
                item = self._parse(path, _read_definition(path), package, path.stem)
                self._add_pending(pending, item)
            for path in sorted(root.glob("*/srv/*.srv")):
                package = path.parent.parent.name
                text = _read_definition(path)
                request_text, response_text, offset = _split_srv(str(path), text)
                request = self._parse(path, request_text, package, f"{path.stem}Request")
                response = self._parse(path, response_text, package, f"{path.stem}Response", offset)
                self._add_pending(pending, request)
                self._add_pending(pending, response)
                self._service_halves.update((request.store_name, response.store_name))
                services[f"{package}/{path.stem}"] = (
                    request.store_name,
                    response.store_name,
                    str(path),
                )
        known = {ros1_name(n) for n in self._store.fielddefs} | {ros1_name(n) for n in pending}
        for item in pending.values():
            for number, ref, written in item.refs:
                if ref in known:
                    continue
                if "/" in written:
                    problem = f"unknown type {ref!r}{_suggest_suffix(ref, known)}"
                else:  # an unqualified name may be a misspelt builtin as well
                    close = difflib.get_close_matches(written, sorted(BUILTIN_TYPES), n=2)
                    hint = close or suggest(ref, known)
                    problem = f"unknown type {ref!r} ({written!r} is not a builtin type)" + (
                        f"; did you mean {', '.join(hint)}?" if hint else ""
                    )
                raise DefinitionError(item.path, number, problem)
        _refuse_cycles(pending)
        typedefs: dict[str, Any] = {}
        for item in pending.values():
            try:
                typedefs.update(get_types_from_msg(item.text, item.store_name))
            except TypesysError as exc:
                raise DefinitionError(item.path, None, f"cannot parse: {exc}") from exc
        new = {k: v for k, v in typedefs.items() if k not in self._store.fielddefs}
        for name, definition in typedefs.items():
            have = self._store.fielddefs.get(name)
            if have is not None and _fields_key(have) != _fields_key(definition):
                raise DefinitionError(
                    pending[name].path,
                    None,
                    f"redefines {ros1_name(name)} differently from {self._sources[name]}",
                )
        if new:
            self._store.register(new)
        for name in new:
            self._sources[name] = pending[name].path
        for srv, (req, resp, srv_path) in services.items():
            self._services[srv] = ServiceType(
                name=srv,
                md5=hashlib.md5(
                    (self._hash_text(req) + self._hash_text(resp)).encode()
                ).hexdigest(),
                request=self._message_by_store(req),
                response=self._message_by_store(resp),
                source=srv_path,
            )

    def _add_pending(self, pending: dict[str, _Pending], item: _Pending) -> None:
        other = pending.get(item.store_name)
        if other is not None and other.text != item.text:
            raise DefinitionError(
                item.path,
                None,
                f"{ros1_name(item.store_name)} is also defined, differently, in {other.path}",
            )
        pending.setdefault(item.store_name, item)

    @staticmethod
    def _parse(path: Path, text: str, package: str, name: str, offset: int = 0) -> _Pending:
        if not _NAME_RE.match(package) or not _NAME_RE.match(name):
            raise DefinitionError(str(path), None, f"bad package or type name {package}/{name}")
        lines = _read_lines(str(path), text)
        refs: list[tuple[int, str, str]] = []
        out: list[str] = []
        for line in lines:
            line.number += offset
            typ, ref = _qualify(line.type, package)
            if ref is not None:
                refs.append((line.number, ref, line.type.split("[")[0]))
            out.append(
                f"{typ} {line.name}" if line.value is None else f"{typ} {line.name}={line.value}"
            )
        return _Pending(f"{package}/msg/{name}", str(path), lines, refs, "\n".join(out) + "\n")

    # ------------------------------------------------------------------ lookup
    def _store_name(self, name: str) -> str:
        """Map a ROS 1 message name (or a rosbags name) to the store's name."""
        found = self._store_names.get(name)
        if found is None:
            found = self._store_names[name] = self._find_store_name(name)
        return found

    def _find_store_name(self, name: str) -> str:
        if name in self._store.fielddefs:
            return name
        if name.count("/") == 1:
            pkg, base = name.split("/")
            candidate = f"{pkg}/msg/{base}"
            if candidate in self._store.fielddefs and candidate not in _TIME_TYPES:
                return candidate
        raise UnknownTypeError(name, suggest(name, self.message_names()), searched=self.search_path)

    def _message_by_store(self, store_name: str) -> MessageType:
        name = ros1_name(store_name)
        found = self._messages.get(name)
        if found is None:
            found = MessageType(
                name=name,
                md5=self._md5_of(store_name),
                source=self._sources.get(store_name, "rosbags"),
                store_name=store_name,
            )
            self._messages[name] = found
        return found

    def message(self, name: str) -> MessageType:
        """The message type called ``name`` (ROS 1 name); UnknownTypeError with suggestions."""
        return self._message_by_store(self._store_name(name))

    def service(self, name: str) -> ServiceType:
        """The service type called ``name`` (``pkg/Srv``); UnknownTypeError with suggestions."""
        found = self._services.get(name)
        if found is None:
            raise UnknownTypeError(
                name, suggest(name, self.service_names()), "service type", self.search_path
            )
        return found

    def md5(self, name: str) -> str:
        """md5 of a message type or, if no message has that name, of a service type."""
        try:
            return self.message(name).md5
        except UnknownTypeError:
            if name in self._services:
                return self._services[name].md5
            raise

    def message_names(self, package: str | None = None) -> list[str]:
        """Sorted ROS 1 names of all message types (service halves excluded)."""
        names = (
            ros1_name(n)
            for n in self._store.fielddefs
            if n not in _TIME_TYPES and n not in self._service_halves
        )
        return sorted(n for n in names if package is None or n.split("/")[0] == package)

    def service_names(self, package: str | None = None) -> list[str]:
        """Sorted names of all service types."""
        return sorted(n for n in self._services if package is None or n.split("/")[0] == package)

    def packages(self) -> list[str]:
        """Sorted package names that define at least one message or service."""
        return sorted({n.split("/")[0] for n in [*self.message_names(), *self.service_names()]})

    # ------------------------------------------------------------------ structure
    def fields(self, name: str) -> list[tuple[str, Any]]:
        """rosbags field descriptors ``(name, desc)`` of a message type (ROS 1 name)."""
        return [f for f in self._store.fielddefs[self._store_name(name)][1] if f[0] != EMPTY_MARKER]

    def constants(self, name: str) -> list[tuple[str, str, Any]]:
        """Constants ``(name, type, value)`` of a message type (ROS 1 name)."""
        return list(self._store.fielddefs[self._store_name(name)][0])

    def message_class(self, name: str) -> type[Any]:
        """The dataclass rosbags generated for a message type."""
        return self._store.types[self._store_name(name)]

    def definition(self, name: str) -> str:
        """Full ROS 1 message definition, dependencies included (as rosbag/MCAP ros1msg want)."""
        text, _ = self._store.generate_msgdef(self._store_name(name))
        return text

    def _md5_of(self, store_name: str) -> str:
        md5 = self._md5.get(store_name)
        if md5 is None:
            md5 = hashlib.md5(self._hash_text(store_name).encode()).hexdigest()
            self._md5[store_name] = md5
        return md5

    def _hash_text(self, store_name: str) -> str:
        """The text ROS 1 hashes for a type (MESSAGES.md, 'md5sum of a definition')."""
        constants, fields = self._store.fielddefs[store_name]
        lines = [f"{typ} {name}={value}" for name, typ, value in constants]
        lines.extend(
            f"{self._hash_type(desc)} {name}" for name, desc in fields if name != EMPTY_MARKER
        )
        return "\n".join(lines)

    def _hash_type(self, desc: Any) -> str:
        kind, arg = desc
        if kind == Nodetype.BASE:
            return str(arg[0])
        if kind == Nodetype.NAME:
            return _TIME_TYPES.get(arg) or self._md5_of(arg)
        (sub_kind, sub_arg), size = arg
        suffix = f"[{size}]" if kind == Nodetype.ARRAY else "[]"
        if sub_kind == Nodetype.BASE:
            return f"{sub_arg[0]}{suffix}"
        if sub_arg in _TIME_TYPES:
            return f"{_TIME_TYPES[sub_arg]}{suffix}"
        return self._md5_of(sub_arg)  # nested message arrays hash without their suffix

    # ------------------------------------------------------------------ bytes
    def serialize(self, message: object, name: str) -> bytes:
        """ROS 1 bytes of ``message`` (a rosbags dataclass instance of type ``name``)."""
        store_name = self._store_name(name)
        try:
            return bytes(self._store.serialize_ros1(message, store_name))
        except Exception as exc:  # struct.error, numpy and attribute errors share no narrower base
            raise SerializationError(f"cannot encode value as {name}: {exc}") from exc

    def deserialize(self, data: bytes | bytearray | memoryview, name: str) -> Any:
        """Decode ROS 1 bytes as type ``name``; SerializationError if they do not fit."""
        store_name = self._store_name(name)
        try:
            message, end = self._deserialize_prefix(data, store_name)
        except SerializationError:
            raise
        except Exception as exc:  # struct.error, UnicodeDecodeError, IndexError, ...
            raise SerializationError(f"{len(data)} bytes do not decode as {name}: {exc}") from exc
        if end > len(data):
            raise SerializationError(
                f"{len(data)} bytes do not decode as {name}: truncated, needs at least {end}"
            )
        if end != len(data):
            raise SerializationError(
                f"{len(data)} bytes do not decode as {name}: {len(data) - end} bytes left over"
            )
        return message

    def _deserialize_prefix(
        self, data: bytes | bytearray | memoryview, store_name: str
    ) -> tuple[Any, int]:
        msgdef = self._store.get_msgdef(store_name)
        view = memoryview(data)
        message, end = msgdef.deserialize_ros1(view, 0, msgdef.cls, self._store)
        return message, int(end)


def _split_srv(path: str, text: str) -> tuple[str, str, int]:
    """Split .srv text at its ``---`` line; the int is the response's line offset."""
    lines = text.splitlines()
    marks = [i for i, line in enumerate(lines) if line.strip() == _SRV_SEPARATOR]
    if not marks:
        raise DefinitionError(
            path, None, "missing '---' line between the request and the response part"
        )
    if len(marks) > 1:
        raise DefinitionError(path, marks[1] + 1, "a second '---' line; a .srv has exactly one")
    cut = marks[0]
    return "\n".join(lines[:cut]), "\n".join(lines[cut + 1 :]), cut + 1


def _read_definition(path: Path) -> str:
    """A .msg/.srv file's text; DefinitionError naming the line of a byte that is not UTF-8."""
    data = path.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise DefinitionError(
            str(path), line, f"not UTF-8 text (byte 0x{data[exc.start]:02x}): save it as UTF-8"
        ) from exc


def _refuse_cycles(pending: Mapping[str, _Pending]) -> None:
    """DefinitionError for a type that contains itself, directly or through others (its size
    and md5 would be infinite)."""
    by_ros1 = {ros1_name(name): item for name, item in pending.items()}
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(name: str, path: list[tuple[str, int]]) -> None:
        state[name] = 1
        item = by_ros1[name]
        for number, ref, _written in item.refs:
            if ref not in by_ros1 or state.get(ref) == 2:
                continue
            if state.get(ref) == 1:
                chain = [n for n, _ in path] + [name, ref]
                start = chain.index(ref)
                raise DefinitionError(
                    item.path,
                    number,
                    f"{ref} contains itself ({' -> '.join(chain[start:])}): a message cannot "
                    "hold itself, not even in an array",
                )
            visit(ref, [*path, (name, number)])
        state[name] = 2

    for name in by_ros1:
        if name not in state:
            visit(name, [])


_EMPTY_PLACEHOLDER: Final = "structure_needs_at_least_one_member"
"""The member rosbags' stores give a message without fields (std_msgs/Empty): not a field."""


def _fields_key(definition: Any) -> list[tuple[str, Any]]:
    return [(n.lower(), d) for n, d in definition[1] if n != _EMPTY_PLACEHOLDER]


def suggest(name: str, known: Iterable[str], limit: int = 3) -> list[str]:
    """Closest known names: same base name in another package first, then by similarity."""
    known = list(known)
    base = name.rsplit("/", 1)[-1].lower()
    same_base = [k for k in known if k.rsplit("/", 1)[-1].lower() == base]
    close = difflib.get_close_matches(name, known, n=limit, cutoff=0.5)
    close_base = difflib.get_close_matches(
        base, [k.rsplit("/", 1)[-1].lower() for k in known], n=limit, cutoff=0.7
    )
    by_base = [k for k in known if k.rsplit("/", 1)[-1].lower() in close_base]
    out: list[str] = []
    for item in [*same_base, *close, *by_base]:
        if item not in out and item != name:
            out.append(item)
    return out[:limit]


def _suggest_suffix(name: str, known: Iterable[str]) -> str:
    found = suggest(name, known)
    return f"; did you mean {', '.join(found)}?" if found else ""
