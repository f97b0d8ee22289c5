"""Message types for hwbridge users: ROS 1 names, md5 sums, bytes, dicts and YAML.

A thin layer over ``rosbags`` (through :class:`hwbridge.protocols.msgtypes.TypeRegistry`)::

    from hwbridge import msg

    twist = msg.from_dict("geometry_msgs/Twist", {"linear": {"x": 0.2}})
    data = msg.encode(twist)                    # ROS 1 bytes
    again = msg.decode(data, "geometry_msgs/Twist")
    msg.to_dict(again)["linear"]["x"]           # 0.2
    msg.md5("geometry_msgs/Twist")              # '9f195f881246fdfa2798d1d3eebca84a'

User packages are found on a search path: directories laid out ``PKG/msg/*.msg`` and
``PKG/srv/*.srv``, from the ``HWBRIDGE_MSG_PATH`` environment variable (``os.pathsep``-separated;
an entry that is no folder is skipped with a warning) or passed explicitly to :func:`registry`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any, Final

import numpy as np
import yaml

from hwbridge.protocols.errors import MessageTypeError, SerializationError
from hwbridge.protocols.msgtypes import (
    EMPTY_MARKER,
    INT_RANGES,
    MessageType,
    ServiceType,
    TypeRegistry,
    ros1_name,
)

__all__ = [
    "ENV_VAR",
    "MessageType",
    "ServiceType",
    "TypeRegistry",
    "check_field_path",
    "child_environment",
    "decode",
    "dump_yaml",
    "encode",
    "from_dict",
    "from_yaml",
    "md5",
    "new",
    "pick",
    "registry",
    "show",
    "to_dict",
    "to_yaml",
    "type_of",
]

ENV_VAR: Final = "HWBRIDGE_MSG_PATH"

log = logging.getLogger("hwbridge.msg")

_NUMPY_TYPES: Final[dict[str, type[np.generic]]] = {
    "bool": np.bool_,
    "byte": np.int8,
    "char": np.uint8,
    "int8": np.int8,
    "uint8": np.uint8,
    "int16": np.int16,
    "uint16": np.uint16,
    "int32": np.int32,
    "uint32": np.uint32,
    "int64": np.int64,
    "uint64": np.uint64,
    "float32": np.float32,
    "float64": np.float64,
}
_TIME_CLASSES: Final = {"builtin_interfaces/msg/Time", "builtin_interfaces/msg/Duration"}
# rosbags keeps ROS 1 time in a ROS 2 shaped class (int32 sec, uint32 nanosec), so time stamps
# after 2038-01-19 and unnormalized nanoseconds cannot be represented; refuse them clearly.
NSEC_LIMITS: Final = (0, 999_999_999)
SEC_LIMITS: Final = {
    "builtin_interfaces/msg/Time": (0, 2**31 - 1),
    "builtin_interfaces/msg/Duration": (-(2**31), 2**31 - 1),
}


@lru_cache(maxsize=16)
def _env_path(env_value: str) -> tuple[Path, ...]:
    """The folders of ``HWBRIDGE_MSG_PATH``'s value; an entry that is none is left out with a
    warning (once per value: like PATH, the variable tolerates it, but a typo is told; the
    processes a command starts get the folders only, :func:`child_environment`)."""
    found = []
    for entry in env_value.split(os.pathsep):
        if not entry:
            continue
        if Path(entry).is_dir():
            found.append(Path(entry))
        else:
            problem = "is not a folder" if Path(entry).exists() else "does not exist"
            log.warning("%s entry %s %s; skipped", ENV_VAR, entry, problem)
    return tuple(found)


def child_environment(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """``environ`` (default: this process's) for a hwbridge process this command starts (a
    shard of ``hwbridge up``, a gateway): its ``HWBRIDGE_MSG_PATH`` holds only the entries that
    are folders. This process warns about the others (once); the child, not given them, does
    not warn again: one warning per command, not one per process."""
    env = dict(os.environ if environ is None else environ)
    value = env.get(ENV_VAR)
    if value:
        env[ENV_VAR] = os.pathsep.join(str(folder) for folder in _env_path(value))
    return env


@lru_cache(maxsize=16)
def _cached_registry(env_value: str, extra: tuple[str, ...]) -> TypeRegistry:
    path = (*(Path(p) for p in extra), *_env_path(env_value))
    return TypeRegistry(p.resolve() for p in path)


def registry(extra_path: Iterable[str | Path] = ()) -> TypeRegistry:
    """The type registry for ``extra_path`` followed by ``HWBRIDGE_MSG_PATH`` (cached)."""
    return _cached_registry(os.environ.get(ENV_VAR, ""), tuple(str(p) for p in extra_path))


def _reg(reg: TypeRegistry | None) -> TypeRegistry:
    return reg if reg is not None else registry()


def type_of(message: object) -> str:
    """ROS 1 type name of a message object made by this module (or by rosbags)."""
    store_name = getattr(message, "__msgtype__", None)
    if not isinstance(store_name, str):
        raise MessageTypeError(f"{type(message).__name__} is not a message object")
    return ros1_name(store_name)


def md5(type_name: str, reg: TypeRegistry | None = None) -> str:
    """md5 sum of a message type, or of a service type if no message has that name."""
    return _reg(reg).md5(type_name)


def encode(message: object, type_name: str | None = None, reg: TypeRegistry | None = None) -> bytes:
    """ROS 1 bytes of ``message``; the type defaults to the message's own."""
    return _reg(reg).serialize(message, type_name or type_of(message))


def decode(
    data: bytes | bytearray | memoryview, type_name: str, reg: TypeRegistry | None = None
) -> Any:
    """Decode ROS 1 bytes as ``type_name``; SerializationError when they do not fit exactly."""
    return _reg(reg).deserialize(data, type_name)


# ---------------------------------------------------------------------- dict conversion
def to_dict(message: object) -> dict[str, Any]:
    """Plain dict of a message: nested messages as dicts, arrays as lists, time as secs/nsecs."""
    result = _plain(message)
    assert isinstance(result, dict)
    return result


def _plain(value: Any) -> Any:
    store_name = getattr(value, "__msgtype__", None)
    if isinstance(store_name, str):
        if store_name in _TIME_CLASSES:
            return {"secs": int(value.sec), "nsecs": int(value.nanosec)}
        return {name: _plain(getattr(value, name)) for name in _field_names(type(value))}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value


_FIELD_NAMES: dict[type[Any], tuple[str, ...]] = {}


def _field_names(cls: type[Any]) -> tuple[str, ...]:
    """The fields of a rosbags message class, in order: not its constants.

    rosbags declares a type's constants (sensor_msgs/Range's ``ULTRASOUND``) and ``__msgtype__``
    as class variables with their values, which ``dataclasses`` still lists as fields; the
    message's own fields never have a default. So a member with a default is not a field (but
    rosbags' placeholder of an empty message, which has one, is left out by name).
    """
    names = _FIELD_NAMES.get(cls)
    if names is None:
        names = _FIELD_NAMES[cls] = tuple(
            name
            for name, member in cls.__dataclass_fields__.items()
            if member.default is dataclasses.MISSING and name != EMPTY_MARKER
        )
    return names


def new(type_name: str, reg: TypeRegistry | None = None, /, **fields: Any) -> Any:
    """A message of ``type_name`` with default (zero) values, overridden by ``fields``."""
    return from_dict(type_name, fields, reg)


def from_dict(
    type_name: str, data: Mapping[str, Any] | None, reg: TypeRegistry | None = None
) -> Any:
    """Build a message from a (possibly partial) dict; missing fields take zero values.

    Values are checked against the field types; errors name the field path, e.g.
    ``geometry_msgs/Twist: linear.x: expected a number, got 'fast'``.
    """
    r = _reg(reg)
    store_name = r.message(type_name).store_name
    try:
        return _build(r, store_name, data if data is not None else {}, "")
    except _FieldError as exc:
        raise MessageTypeError(f"{type_name}: {exc.path}: {exc.problem}") from None


class _FieldError(Exception):
    def __init__(self, path: str, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = path or "(message)"
        self.problem = problem


def _build(r: TypeRegistry, store_name: str, data: Any, path: str) -> Any:
    cls = r.message_class(store_name)
    if store_name in _TIME_CLASSES:
        return _build_time(cls, store_name, data, path)
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise _FieldError(path, f"expected a mapping for {ros1_name(store_name)}, got {data!r}")
    fields = r.fields(store_name)
    names = [n for n, _ in fields]
    unknown = [k for k in data if k not in names]
    if unknown:
        known = ", ".join(names) or "(none)"
        raise _FieldError(
            _join(path, str(unknown[0])),
            f"no such field in {ros1_name(store_name)}; its fields are {known}",
        )
    values = {name: _build_field(r, d, data.get(name), _join(path, name)) for name, d in fields}
    if not fields:
        values[EMPTY_MARKER] = 0  # rosbags' placeholder member of an empty message
    return cls(**values)


def _build_time(cls: type[Any], store_name: str, data: Any, path: str) -> Any:
    if data is None:
        secs, nsecs = 0, 0
    elif isinstance(data, (int, float)) and not isinstance(data, bool):
        secs = math.floor(data)
        nsecs = round((data - secs) * 1e9)
        if nsecs >= 1_000_000_000:
            secs, nsecs = secs + 1, nsecs - 1_000_000_000
    elif isinstance(data, Mapping):
        secs = data.get("secs", data.get("sec", 0))
        nsecs = data.get("nsecs", data.get("nanosec", 0))
    else:
        raise _FieldError(path, f"expected seconds or {{secs, nsecs}}, got {data!r}")
    for value, what, (low, high) in (
        (secs, "secs", SEC_LIMITS[store_name]),
        (nsecs, "nsecs", NSEC_LIMITS),
    ):
        if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
            raise _FieldError(path, f"{what} must be an integer in [{low}, {high}], got {value!r}")
    return cls(sec=secs, nanosec=nsecs)


def _build_field(r: TypeRegistry, desc: Any, value: Any, path: str) -> Any:
    kind, arg = desc
    if kind == 1:  # Nodetype.BASE
        return _scalar(arg[0], value, path)
    if kind == 2:  # Nodetype.NAME
        return _build(r, arg, value, path)
    (sub_kind, sub_arg), size = arg
    fixed = size if kind == 3 else None  # Nodetype.ARRAY has a fixed size
    if value is None:
        items: list[Any] = [None] * (fixed or 0)
    elif isinstance(value, (bytes, bytearray, list, tuple, np.ndarray)):
        items = list(value)
    else:
        raise _FieldError(path, f"expected a list, got {value!r}")
    if fixed is not None and len(items) != fixed:
        raise _FieldError(path, f"expected exactly {fixed} elements, got {len(items)}")
    if sub_kind == 1:
        base = sub_arg[0]
        scalars = [_scalar(base, v, f"{path}[{i}]") for i, v in enumerate(items)]
        if base == "string":
            return scalars
        return np.array(scalars, dtype=_NUMPY_TYPES[base])
    return [_build(r, sub_arg, v, f"{path}[{i}]") for i, v in enumerate(items)]


def _scalar(base: str, value: Any, path: str) -> Any:
    if base == "string":
        if value is None:
            return ""
        if not isinstance(value, str):
            raise _FieldError(path, f"expected a string, got {value!r}")
        return value
    if base == "bool":
        if value is None:
            return False
        if isinstance(value, (bool, np.bool_)) or value in (0, 1):
            return bool(value)
        raise _FieldError(path, f"expected true or false, got {value!r}")
    if base in ("float32", "float64"):
        if value is None:
            return 0.0
        if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
            raise _FieldError(path, f"expected a number, got {value!r}")
        return float(value)
    if value is None:
        return 0
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise _FieldError(path, f"expected an integer ({base}), got {value!r}")
    low, high = INT_RANGES[base]
    if not low <= int(value) <= high:
        raise _FieldError(path, f"{value} is out of range for {base} [{low}, {high}]")
    return int(value)


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


# ---------------------------------------------------------------------- field paths
def check_field_path(type_name: str, path: Sequence[str], reg: TypeRegistry | None = None) -> None:
    """MessageTypeError unless ``path`` names something inside ``type_name``: field names, and
    list indexes (digits) after an array, as ``rostopic echo /odom/pose/pose/position`` or
    ``/joint_states/position/0`` select. The error names the fields there are."""
    r = _reg(reg)
    desc: tuple[int, Any] = (2, r.message(type_name).store_name)  # Nodetype.NAME
    walked: list[str] = []
    for part in path:
        kind, arg = desc
        here = f"{type_name} {'.'.join(walked)}" if walked else type_name
        if kind == 1:  # Nodetype.BASE
            raise MessageTypeError(f"{here} is a {arg[0]}: it has no field {part!r}")
        if kind == 2 and arg in _TIME_CLASSES:
            if part not in ("secs", "nsecs"):
                raise MessageTypeError(
                    f"no field {part!r} in {here} (a {_type_label(arg)}); its fields are secs, "
                    "nsecs"
                )
            desc = (1, ("int32", 0))
        elif kind == 2:
            fields = dict(r.fields(arg))
            if part not in fields:
                known = ", ".join(fields) or "(none)"
                what = ros1_name(arg) if not walked else f"{here} (a {ros1_name(arg)})"
                raise MessageTypeError(f"no field {part!r} in {what}; its fields are {known}")
            desc = fields[part]
        else:  # an array: an index comes next
            element, size = arg
            if not part.isdigit():
                raise MessageTypeError(
                    f"{here} is a list: expected an index (0, 1, ...), got {part!r}"
                )
            length = int(size)
            if kind == 3 and int(part) >= length:  # Nodetype.ARRAY: its length is fixed
                raise MessageTypeError(
                    f"{here} has {length} elements: no index {part} (0 to {length - 1})"
                )
            desc = (int(element[0]), element[1])
        walked.append(part)


def pick(data: Any, path: Sequence[str]) -> Any:
    """The value at ``path`` in plain data (:func:`to_dict`'s); MessageTypeError if an index is
    past the end of its list (which the type cannot tell in advance)."""
    for depth, part in enumerate(path):
        if isinstance(data, list):
            index = int(part)
            if index >= len(data):
                where = ".".join(path[:depth]) or "the message"
                raise MessageTypeError(
                    f"{where} has {len(data)} element(s): no index {index} in this message"
                )
            data = data[index]
        else:
            data = data[part]
    return data


# ---------------------------------------------------------------------- YAML
class _Dumper(yaml.SafeDumper):
    """Mappings in block style, sequences inline: the look of ``rostopic echo``."""


def _inline_list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=True)


_Dumper.add_representer(list, _inline_list)


def dump_yaml(data: Any) -> str:
    """YAML text of plain data (dicts, lists, scalars) in rostopic's style."""
    text: str = yaml.dump(
        data, Dumper=_Dumper, sort_keys=False, default_flow_style=False, width=100
    )
    return text


def to_yaml(message: object) -> str:
    """YAML text of a message, in the style of ``rostopic echo``."""
    return dump_yaml(to_dict(message))


def from_yaml(type_name: str, text: str, reg: TypeRegistry | None = None) -> Any:
    """Build a message from YAML (a mapping; missing fields are zero)."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SerializationError(f"not valid YAML for {type_name}: {exc}") from exc
    return from_dict(type_name, data, reg)


# ---------------------------------------------------------------------- display
def show(type_name: str, reg: TypeRegistry | None = None) -> str:
    """The definition as ``rosmsg show`` prints it: constants, then fields with nested ones."""
    r = _reg(reg)
    lines: list[str] = []
    _show_into(r, r.message(type_name).store_name, "", lines)
    return "\n".join(lines)


def _show_into(r: TypeRegistry, store_name: str, indent: str, lines: list[str]) -> None:
    for name, typ, value in r.constants(store_name):
        lines.append(f"{indent}{typ} {name}={value}")
    for name, desc in r.fields(store_name):
        label, nested = _describe(desc)
        lines.append(f"{indent}{label} {name}")
        if nested is not None and nested not in _TIME_CLASSES:
            _show_into(r, nested, indent + "  ", lines)


def _describe(desc: Any) -> tuple[str, str | None]:
    kind, arg = desc
    if kind == 1:
        return str(arg[0]), None
    if kind == 2:
        return _type_label(arg), arg
    (sub_kind, sub_arg), size = arg
    suffix = f"[{size}]" if kind == 3 else "[]"
    if sub_kind == 1:
        return f"{sub_arg[0]}{suffix}", None
    return f"{_type_label(sub_arg)}{suffix}", sub_arg


def _type_label(store_name: str) -> str:
    if store_name == "builtin_interfaces/msg/Time":
        return "time"
    if store_name == "builtin_interfaces/msg/Duration":
        return "duration"
    return ros1_name(store_name)
