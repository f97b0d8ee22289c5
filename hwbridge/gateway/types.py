"""ROS 1 <-> ROS 2 type names and bytes, without rclpy.

The hwbridge graph carries ROS 1 bytes; ROS 2 carries CDR. rosbags converts one into the other
field by field when it knows the ROS 2 layout of the type: ``std_msgs/Header`` loses ``seq`` on
the way to ROS 2 and gets ``seq = 0`` on the way back, and ROS 1 ``time``/``duration`` have the
same bytes as ``builtin_interfaces/Time``/``Duration``. A type maps when the ROS 2 layout has the
same fields as the ROS 1 one (``Header.seq`` aside); :func:`layout_problem` says why one does not.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Any, Final, cast

from hwbridge.errors import HwBridgeError

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

    from hwbridge.msg import TypeRegistry

__all__ = [
    "RENAMED",
    "CdrConverter",
    "TypeMapError",
    "layout_problem",
    "ros1_type_name",
    "ros2_type_name",
    "split_ros2_name",
]

RENAMED: Final[dict[str, str]] = {
    "tf/tfMessage": "tf2_msgs/msg/TFMessage",
}
"""ROS 1 types whose ROS 2 counterpart lives under another name (same layout)."""
_RENAMED_BACK: Final = {ros2: ros1 for ros1, ros2 in RENAMED.items()}

_TIME: Final = {"builtin_interfaces/msg/Time", "builtin_interfaces/msg/Duration"}
_HEADER: Final = "std_msgs/msg/Header"


class TypeMapError(HwBridgeError):
    """A type has no ROS 2 counterpart, or its layout differs."""


def ros2_type_name(ros1: str, kind: str = "msg") -> str:
    """``std_msgs/String`` -> ``std_msgs/msg/String`` (``kind`` ``srv`` for services)."""
    if kind == "msg" and ros1 in RENAMED:
        return RENAMED[ros1]
    package, sep, name = ros1.partition("/")
    if not sep or not package or not name or "/" in name:
        raise TypeMapError(f"{ros1!r} is not a ROS 1 type name (package/Type)")
    return f"{package}/{kind}/{name}"


def ros1_type_name(ros2: str) -> str:
    """``std_msgs/msg/String`` -> ``std_msgs/String`` (and ``pkg/srv/X`` -> ``pkg/X``)."""
    if ros2 in _RENAMED_BACK:
        return _RENAMED_BACK[ros2]
    parts = ros2.split("/")
    if len(parts) != 3 or parts[1] not in ("msg", "srv") or not all(parts):
        raise TypeMapError(f"{ros2!r} is not a ROS 2 type name (package/msg/Type)")
    return f"{parts[0]}/{parts[2]}"


def split_ros2_name(ros2: str) -> tuple[str, str, str]:
    """``pkg/msg/Type`` -> ``("pkg", "msg", "Type")``."""
    parts = ros2.split("/")
    if len(parts) != 3 or not all(parts):
        raise TypeMapError(f"{ros2!r} is not a ROS 2 type name (package/msg/Type)")
    return parts[0], parts[1], parts[2]


def _field_names(fields: list[tuple[str, Any]], store_name: str) -> list[str]:
    names = [name for name, _ in fields if name != "structure_needs_at_least_one_member"]
    if store_name == _HEADER and names and names[0] == "seq":
        names = names[1:]
    return names


def layout_problem(
    ros1_fields: dict[str, list[tuple[str, Any]]],
    ros2_fields: dict[str, list[tuple[str, Any]]],
    ros1_store_name: str,
    ros2_store_name: str,
) -> str | None:
    """Why bytes of ``ros1_store_name`` cannot become ``ros2_store_name`` (None if they can).

    The arguments map store names to rosbags field lists (``Typestore.fielddefs[name][1]``).
    Field names must agree in order, recursively; base types must agree; ``Header.seq`` and
    time types are taken care of by the conversion.
    """
    seen: set[tuple[str, str]] = set()

    def compare(one: str, two: str, path: str) -> str | None:
        if (one, two) in seen or (one in _TIME and two in _TIME):
            return None
        seen.add((one, two))
        if two not in ros2_fields:
            return f"{path or ros2_store_name}: ROS 2 has no {two}"
        first, second = ros1_fields[one], ros2_fields[two]
        names1, names2 = _field_names(first, one), _field_names(second, two)
        if names1 != names2:
            return f"{path or two}: fields {names1} in ROS 1, {names2} in ROS 2"
        descs1 = {name: desc for name, desc in first}
        for name, desc2 in second:
            if name == "structure_needs_at_least_one_member":
                continue
            problem = compare_desc(descs1[name], desc2, f"{path or two}.{name}")
            if problem:
                return problem
        return None

    def compare_desc(desc1: Any, desc2: Any, path: str) -> str | None:
        kind1, arg1 = desc1
        kind2, arg2 = desc2
        if int(kind1) != int(kind2):
            return f"{path}: {desc1} in ROS 1, {desc2} in ROS 2"
        if int(kind1) == 1:  # BASE: (type, bound)
            type1, type2 = _base(arg1[0]), _base(arg2[0])
            return None if type1 == type2 else f"{path}: {arg1[0]} in ROS 1, {arg2[0]} in ROS 2"
        if int(kind1) == 2:  # NAME
            return compare(arg1, arg2, path)
        (sub1, size1), (sub2, size2) = arg1, arg2  # ARRAY / SEQUENCE: ((desc), size)
        if int(kind1) == 3 and size1 != size2:
            return f"{path}: array of {size1} in ROS 1, of {size2} in ROS 2"
        return compare_desc(sub1, sub2, path + "[]")

    return compare(ros1_store_name, ros2_store_name, "")


_SIZES: Final = {
    "bool": 1,
    "byte": 1,
    "char": 1,
    "int8": 1,
    "uint8": 1,
    "octet": 1,
    "int16": 2,
    "uint16": 2,
    "int32": 4,
    "uint32": 4,
    "float32": 4,
    "int64": 8,
    "uint64": 8,
    "float64": 8,
}


def _base(name: str) -> str:
    # ROS 1 byte/char are ROS 2 int8/uint8 on the wire.
    return {"byte": "uint8", "char": "uint8", "int8": "uint8", "octet": "uint8"}.get(name, name)


class CdrConverter:
    """ROS 1 bytes <-> CDR for types known to rosbags' ROS 2 store (or added from the registry).

    ``to_cdr(data, store2)``/``from_cdr(data, store2)`` take the ROS 2 store name of the type
    (``sensor_msgs/msg/Imu``). :meth:`prepare` checks a type once and says why it cannot map.
    """

    def __init__(self, registry: TypeRegistry) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.registry = registry
        self.store: Typestore = get_typestore(Stores.LATEST)
        self._ros1: Typestore = get_typestore(Stores.ROS1_NOETIC)
        self._checked: dict[tuple[str, str], str | None] = {}
        self._extended: dict[str, tuple[str, list[tuple[int, int]]]] = {}
        """ROS 2 name -> (stand-in of the ROS 1 layout, (size, alignment) of each added field)."""
        self._lock = threading.Lock()

    def _ros1_fielddefs(self, store_name: str) -> dict[str, list[tuple[str, Any]]]:
        """Every ROS 1 field list ``store_name`` needs, from the hwbridge registry."""
        out: dict[str, list[tuple[str, Any]]] = {}
        pending = [store_name]
        while pending:
            name = pending.pop()
            if name in out or name in _TIME:
                continue
            fields = self.registry.fields(name)
            out[name] = fields
            for _, desc in fields:
                pending.extend(_names_in(desc))
        return out

    def prepare(self, ros1_store_name: str, ros2_store_name: str) -> None:
        """Make sure ``ros1_store_name`` (a store name from the hwbridge registry) converts to
        ``ros2_store_name``; TypeMapError with the reason if it cannot."""
        key = (ros1_store_name, ros2_store_name)
        with self._lock:
            if key not in self._checked:
                self._checked[key] = self._check(ros1_store_name, ros2_store_name)
            problem = self._checked[key]
        if problem is not None:
            raise TypeMapError(problem)

    def _check(self, ros1_store_name: str, ros2_store_name: str) -> str | None:
        problem = self._check_strict(ros1_store_name, ros2_store_name)
        if problem is not None and self._extend(ros1_store_name, ros2_store_name):
            return None
        return problem

    def _extend(self, ros1_store_name: str, ros2_store_name: str) -> bool:
        """ROS 2 added fixed-size fields at the end of the type (``sensor_msgs/Range`` got
        ``variance``): convert the ROS 1 fields through a stand-in type of the ROS 1 layout and
        send the added fields as zeros (dropped on the way back). True if that works."""
        ros2_fields = self.store.fielddefs.get(ros2_store_name)
        if ros2_fields is None:
            return False
        ros1_fields = self.registry.fields(ros1_store_name)
        names1 = _field_names(ros1_fields, ros1_store_name)
        names2 = _field_names(ros2_fields[1], ros2_store_name)
        if len(names2) <= len(names1) or names2[: len(names1)] != names1:
            return False
        added: list[tuple[int, int]] = []
        for _, desc in ros2_fields[1][len(names1) :]:
            kind, arg = cast("tuple[Any, Any]", desc)
            size = _SIZES.get(str(arg[0])) if int(kind) == 1 else None
            if size is None:
                return False
            added.append((size, size))
        package, _, name = ros2_store_name.split("/")
        stand_in = f"hwbridge_gateway/msg/{package}__{name}"
        kept = ros2_fields[1][: len(names1)]
        try:
            self.store.register({stand_in: ([], kept)})
        except Exception:  # noqa: BLE001 - rosbags raises several kinds here
            return False
        if self._check_strict(ros1_store_name, stand_in) is not None:
            return False
        self._extended[ros2_store_name] = (stand_in, added)
        return True

    def _check_strict(self, ros1_store_name: str, ros2_store_name: str) -> str | None:
        try:
            ros1 = self._ros1_fielddefs(ros1_store_name)
        except HwBridgeError as exc:
            return str(exc)
        ros2 = {name: defs[1] for name, defs in self.store.fielddefs.items()}
        if ros2_store_name not in ros2:
            # Not in rosbags' ROS 2 set (a service half, a user package): take the ROS 1
            # layout as the ROS 2 one, the way ROS 2 ports of ROS 1 packages are written.
            additions: dict[str, Any] = {}
            for name, fields in ros1.items():
                target = ros2_store_name if name == ros1_store_name else name
                if target not in ros2 and name != _HEADER:
                    constants = self.registry.constants(name) if "/msg/" in name else []
                    additions[target] = (constants, fields)
            try:
                self.store.register(additions)
            except Exception as exc:  # noqa: BLE001 - rosbags raises several kinds here
                return f"{ros2_store_name}: cannot be described to rosbags: {exc}"
            ros2 = {name: defs[1] for name, defs in self.store.fielddefs.items()}
        return layout_problem(ros1, ros2, ros1_store_name, ros2_store_name)

    def added_fields(self, ros2_store_name: str) -> list[str]:
        """Fields ROS 2 has at the end of a type and ROS 1 lacks (sent as zeros)."""
        if ros2_store_name not in self._extended:
            return []
        stand_in = self._extended[ros2_store_name][0]
        kept = len(self.store.fielddefs[stand_in][1])
        return [name for name, _ in self.store.fielddefs[ros2_store_name][1][kept:]]

    def to_cdr(self, data: bytes, ros2_store_name: str) -> bytes:
        """ROS 1 bytes -> CDR (with its 4-byte encapsulation header), as rmw serializes."""
        extended = self._extended.get(ros2_store_name)
        if extended is None:
            return bytes(self.store.ros1_to_cdr(data, ros2_store_name))
        stand_in, added = extended
        out = bytearray(self.store.ros1_to_cdr(data, stand_in))
        for size, align in added:  # zeros, aligned as CDR aligns (from after the header)
            out += bytes((-(len(out) - 4)) % align + size)
        return bytes(out)

    def from_cdr(self, data: bytes, ros2_store_name: str) -> bytes:
        """CDR -> ROS 1 bytes (``Header.seq`` = 0; fields ROS 1 lacks are dropped)."""
        extended = self._extended.get(ros2_store_name)
        if extended is None:
            return bytes(self.store.cdr_to_ros1(data, ros2_store_name))
        stand_in, added = extended
        fixed = sum(size for size, _ in added)
        problem: Exception | None = None
        for padding in range(8 * len(added) + 1):  # where the added fields began
            length = len(data) - fixed - padding
            end = length
            for size, align in added:
                end += (-(end - 4)) % align + size
            if length < 4 or end != len(data):
                continue
            try:
                return bytes(self.store.cdr_to_ros1(data[:length], stand_in))
            except Exception as exc:  # noqa: BLE001 - try the next split
                problem = exc
        raise TypeMapError(f"{len(data)} CDR bytes do not hold a {ros2_store_name}: {problem}")


def _names_in(desc: Any) -> list[str]:
    kind, arg = desc
    if int(kind) == 2:
        return [arg]
    if int(kind) in (3, 4):
        return _names_in(arg[0])
    return []
