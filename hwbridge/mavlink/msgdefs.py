"""Every MAVLink message as a ROS 1 message type of its own (``mavlink/Attitude``...): the
definitions, their md5 sums and the ROS 1 bytes of a received message.

The definitions are made from pymavlink's generated dialect (names, C types and array lengths
come from the MAVLink XML through it): each field keeps its MAVLink name, in the XML's order (the
order the MAVLink documentation lists, not the wire's size-sorted order); ``char[N]`` becomes
``string``, ``float`` ``float32``, ``double`` ``float64``, ``uintN_t`` ``uintN``, and a fixed
array ``T[N]``. The type is the message name in CamelCase in the package ``mavlink``
(``GLOBAL_POSITION_INT`` -> ``mavlink/GlobalPositionInt``).

Messages are serialized here with :mod:`struct` (the types are flat), so a bridge publishes them
without a message registry that knows them. To decode them elsewhere (``hwbridge topic echo``,
``hwbridge viz``, a recording's schema), write the package once and put it on the message path::

    python -m hwbridge.mavlink.msgdefs ~/mavlink_msgs        # writes ~/mavlink_msgs/mavlink/msg/
    hwbridge --msg-path ~/mavlink_msgs topic echo /fc/mavlink/ATTITUDE
"""

from __future__ import annotations

import functools
import hashlib
import struct
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

__all__ = [
    "PACKAGE",
    "RawType",
    "find_type",
    "load_dialect",
    "raw_type",
    "type_name",
    "write_package",
]

PACKAGE: Final = "mavlink"

_ROS_TYPES: Final[dict[str, tuple[str, str]]] = {
    # MAVLink C type: (ROS type, struct code)
    "int8_t": ("int8", "b"),
    "uint8_t": ("uint8", "B"),
    "uint8_t_mavlink_version": ("uint8", "B"),
    "char": ("uint8", "B"),
    "int16_t": ("int16", "h"),
    "uint16_t": ("uint16", "H"),
    "int32_t": ("int32", "i"),
    "uint32_t": ("uint32", "I"),
    "int64_t": ("int64", "q"),
    "uint64_t": ("uint64", "Q"),
    "float": ("float32", "f"),
    "double": ("float64", "d"),
}


def load_dialect(name: str = "ardupilotmega") -> Any:
    """pymavlink's MAVLink 2 module of dialect ``name`` (``common``, ``ardupilotmega``...)."""
    import importlib

    from hwbridge.errors import HwBridgeError

    if not name.replace("_", "").isalnum():
        raise HwBridgeError(f"MAVLink dialect {name!r}: expected a name such as common")
    try:
        return importlib.import_module(f"pymavlink.dialects.v20.{name}")
    except ImportError as exc:
        raise HwBridgeError(
            f"MAVLink dialect {name!r} cannot be loaded ({exc}); is pymavlink installed "
            "(pip install 'hwbridge[mavlink]')?"
        ) from exc


def type_name(msgname: str) -> str:
    """The ROS type of MAVLink message ``msgname``: ``mavlink/GlobalPositionInt``."""
    return f"{PACKAGE}/" + "".join(part.capitalize() for part in msgname.lower().split("_"))


@dataclass(frozen=True)
class _Field:
    name: str
    ros: str
    code: str
    length: int
    string: bool


@dataclass(frozen=True)
class RawType:
    """The ROS 1 view of one MAVLink message: type name, definition, md5, serializer."""

    msgname: str
    name: str
    definition: str
    md5: str
    fields: tuple[_Field, ...]

    def serialize(self, message: Any) -> bytes:
        """The ROS 1 bytes of a pymavlink message of this type."""
        out = bytearray()
        for field in self.fields:
            value = getattr(message, field.name, None)
            if field.string:
                if isinstance(value, str):
                    raw = value.encode("utf-8", "replace")
                else:
                    raw = bytes(value) if value is not None else b""
                raw = raw.split(b"\0", 1)[0]
                out += struct.pack("<I", len(raw)) + raw
            elif field.length:
                items = list(value) if value is not None else []
                items = (items + [0] * field.length)[: field.length]
                out += struct.pack(f"<{field.length}{field.code}", *items)
            else:
                out += struct.pack(f"<{field.code}", value if value is not None else 0)
        return bytes(out)


def _fields(cls: Any) -> tuple[_Field, ...]:
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=False))
    fields = []
    for name, ctype in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        ros, code = _ROS_TYPES[ctype]
        length = int(lengths.get(name, 0))
        if ctype == "char" and length:
            fields.append(_Field(name, "string", "s", 0, True))
        else:
            fields.append(_Field(name, ros, code, length, False))
    return tuple(fields)


@functools.cache
def _raw_type(dialect_name: str, msgname: str) -> RawType:
    module = load_dialect(dialect_name)
    cls = next((c for c in module.mavlink_map.values() if c.msgname == msgname), None)
    if cls is None:
        from hwbridge.errors import HwBridgeError

        raise HwBridgeError(f"no MAVLink message {msgname!r} in dialect {dialect_name}")
    fields = _fields(cls)
    lines = [f"{f.ros}[{f.length}] {f.name}" if f.length else f"{f.ros} {f.name}" for f in fields]
    text = "\n".join(lines)
    md5 = hashlib.md5(text.encode(), usedforsecurity=False).hexdigest()
    definition = f"# MAVLink {msgname} (id {cls.id}), fields in the XML's order\n{text}\n"
    return RawType(msgname, type_name(msgname), definition, md5, fields)


def raw_type(msgname: str, dialect: str = "ardupilotmega") -> RawType:
    """The ROS view of MAVLink message ``msgname`` (``ATTITUDE``) in ``dialect`` (cached)."""
    return _raw_type(dialect, msgname)


@functools.cache
def _names(dialect: str) -> dict[str, str]:
    module = load_dialect(dialect)
    return {type_name(cls.msgname): cls.msgname for cls in module.mavlink_map.values()}


def find_type(name: str, dialect: str = "ardupilotmega") -> RawType | None:
    """The ROS view of the MAVLink message whose ROS type is ``name`` (``mavlink/Attitude``);
    None if ``name`` is not one (or pymavlink is not installed)."""
    from hwbridge.errors import HwBridgeError

    if not name.startswith(PACKAGE + "/"):
        return None
    try:
        msgname = _names(dialect).get(name)
    except HwBridgeError:
        return None
    return raw_type(msgname, dialect) if msgname is not None else None


def write_package(root: Path, dialect: str = "ardupilotmega") -> Path:
    """Write ``root/mavlink/msg/*.msg`` for every message of ``dialect``; returns the package
    folder (``root`` goes on ``--msg-path``)."""
    module = load_dialect(dialect)
    folder = root / PACKAGE / "msg"
    folder.mkdir(parents=True, exist_ok=True)
    for cls in module.mavlink_map.values():
        if cls.msgname == "BAD_DATA":
            continue
        info = raw_type(cls.msgname, dialect)
        (folder / f"{info.name.split('/', 1)[1]}.msg").write_text(info.definition, "utf-8")
    return folder.parent


def main(argv: list[str] | None = None) -> int:
    """``python -m hwbridge.mavlink.msgdefs DIR [DIALECT]``: write the package under DIR."""
    args = sys.argv[1:] if argv is None else argv
    if not 1 <= len(args) <= 2:
        sys.stderr.write("usage: python -m hwbridge.mavlink.msgdefs DIR [DIALECT]\n")
        return 2
    folder = write_package(Path(args[0]), *(args[1:]))
    sys.stdout.write(f"{folder}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
