"""Robot files: one YAML file describes a robot, read and checked here before anything starts.

::

    robot: diffbot                     # the robot's name
    world: {...}                       # the emulator's world (room, obstacles, wheel geometry)
    boards:
      - name: base                     # what --link base=URL and the logs call it
        link: /dev/ttyACM0             # a link URL (serial path, socket://, tcp-listen://, ...)
        protocol: auto                 # auto, native, rosserial or a plugin's protocol
        namespace: /diffbot            # where its topics (and its devices' nodes) appear
        mcu: mega                      # optional: uno, nano or mega; its pins are then checked
        baud: 115200                   # optional; also start_delay, service_timeout
        devices:                       # devices on the board's pins (plugins with where: board)
          - type: hcsr04               # a device type (hwbridge.robot.registry)
            name: front_sonar          # optional: default the type (numbered when repeated)
            pins: {trigger: 8, echo: 12}  # the device's pins (defaults: the plugin's wiring)
            only_on: [mega]            # optional: the MCU boards it is on (default every one)
            topic: sonar_echo          # ...the plugin's settings
    host_devices:                      # devices on the host's own adapters (where: host)
      - type: dynamixel_bus
        name: arm                      # required: --link arm=URL
        link: /dev/ttyUSB0
        namespace: /arm
        baud: 57600
        joints: {shoulder: 1, elbow: 2}
    ros:                               # optional: the gateways 'hwbridge up' also starts
      ros2: true                       # 'hwbridge ros2' (as --ros2; --no-ros2 overrides)
      ros1: false                      # 'hwbridge ros1' (as --ros1; --no-ros1 overrides)
      qos:                             # optional: ROS 2 QoS by topic pattern, first match wins
        /diffbot/imu: sensor           # reliable, sensor, tf or latched (hwbridge.gateway.qos)
    boards_per_process: 16             # optional: 'hwbridge up' splits more boards (0: never)

:func:`load_robot` checks every key, link URL, protocol, namespace and device setting (against
the plugin's :class:`~hwbridge.robot.plugin.Field` list, filling in defaults) and reports every
problem at once, each as ``FILE:LINE: what is wrong``, in file order, in one
:class:`~hwbridge.robot.model.RobotFileError`. The rules:

- top level: ``robot`` (a name) is required; ``world`` is an optional mapping, kept as it is for
  the emulator; at least one board or host device. Unknown keys are errors that name the known
  ones (and the closest, when one is close).
- a board: ``name`` (required, ``[A-Za-z_][A-Za-z0-9_]*``) and ``link`` (required; parsed by
  :func:`hwbridge.links.create_link`, never opened: ``hwbridge up`` opens it;
  ``usb:VID:PID[:SERIAL]`` and ``auto`` name a USB board, resolved to its port by ``hwbridge up``,
  see :mod:`hwbridge.links.discovery`); ``protocol``
  (default ``auto``), ``namespace`` (default ``/``, a graph name), ``baud`` (a whole number above
  0), ``service_timeout`` (default 5 s), ``start_delay`` (default 0 s; 2 s with ``mcu: mega``;
  above 0 the bridge never talks on to a silent board, a bootloader each byte holds), ``devices``,
  ``mcu`` (``uno``, ``nano`` or ``mega``, :mod:`hwbridge.firmware.boards`): when given, every
  device's wiring (:meth:`~hwbridge.robot.plugin.DevicePlugin.wiring`: its pins, I2C address,
  UART) is checked against that board's pins by :mod:`hwbridge.robot.wiring`, each problem at
  the line of the offending value.
- a device: ``type`` (a registered device type) and an optional ``name``, unique on its board
  (default the type; ``hcsr04_2``, ``hcsr04_3`` for repeats), an optional ``only_on`` (the MCU
  boards the device is on, e.g. ``[mega]`` for a servo bus that needs a spare UART); every
  other key is a setting of the
  plugin: unknown ones, missing required ones, values of the wrong type (a bool is not a number;
  an int is taken for a float), not among the choices or out of the minimum/maximum are errors.
  A ``host`` device under a board, or a ``board`` device under ``host_devices``, is an error that
  says where it belongs; a plugin that fails to import is a problem at its ``type`` line.
- a host device: ``type``, ``name`` (required), ``link`` (required), ``namespace``, ``baud`` and
  the plugin's settings.
- board names and host-device names are unique across the robot (``--link NAME=URL`` picks one).
- ``ros``: an optional mapping of ``ros2`` and ``ros1``, each ``true`` or ``false`` (default),
  and ``qos``, a mapping of topic patterns (full names, shell patterns) to QoS kinds
  (:data:`hwbridge.gateway.qos.KINDS`) for the ROS 2 gateway.
- two devices that would publish one topic, or serve one service, in the same namespace are an
  error at the later one's line naming the earlier one's (each plugin says what it uses with
  :meth:`~hwbridge.robot.plugin.DevicePlugin.topics`, resolved in its board's or its own
  namespace; a plugin that does not say is left out; topics meant for many publishers, such as
  ``/tf``, never clash).

:func:`link_overrides` applies ``hwbridge up --link NAME=URL`` (and ``robot check --link``) to a
checked robot: a URL that does not parse is an error naming the board's line; a ``baud`` from the
file that the new link takes no baud for (``socket://``) is dropped with a note naming its line.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, Final, TypeVar

import yaml

from hwbridge.errors import HwBridgeError
from hwbridge.robot.clashes import topic_clashes
from hwbridge.robot.model import (
    DeviceConfig,
    HostDeviceConfig,
    Robot,
    RobotBoardConfig,
    RobotFileError,
)
from hwbridge.robot.plugin import DevicePlugin, Field
from hwbridge.robot.shards import boards_per_process_key

__all__ = [
    "check_robot",
    "check_value",
    "device_config",
    "link_overrides",
    "load_robot",
    "parse_robot",
]

_TOP_KEYS: Final = ("robot", "world", "boards", "host_devices", "ros", "boards_per_process")
_ROS_KEYS: Final = ("ros2", "ros1", "qos")
_BOARD_KEYS: Final = (
    "name",
    "link",
    "protocol",
    "namespace",
    "baud",
    "service_timeout",
    "start_delay",
    "devices",
    "mcu",
)
_HOST_KEYS: Final = ("type", "name", "link", "namespace", "baud")
_NAME: Final = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_KIND_NAMES: Final = {
    float: "a number",
    int: "a whole number",
    str: "a string",
    bool: "true or false",
    list: "a list",
    dict: "a mapping",
}


class _Problems:
    """The problems found so far, each with its line; :attr:`lines` in file order."""

    def __init__(self, path: str) -> None:
        self.path = path
        self._found: list[tuple[int, str]] = []
        self.names: dict[str, int] = {}
        """Board and host-device names seen so far, with their lines (they must be unique)."""

    def at(self, node: yaml.Node | None, text: str) -> None:
        self.at_line(node.start_mark.line + 1 if node is not None else 1, text)

    def at_line(self, line: int, text: str) -> None:
        self._found.append((line, f"{self.path}:{line}: {text}"))

    @property
    def lines(self) -> list[str]:
        return [text for _line, text in sorted(self._found, key=lambda found: found[0])]

    def where(self, node: yaml.Node) -> str:
        return f"{self.path}:{node.start_mark.line + 1}"

    def unique(self, name: str, node: yaml.Node) -> None:
        """Note a board's or host device's name (what ``--link NAME=URL`` addresses)."""
        line = node.start_mark.line + 1
        if name in self.names:
            self.at_line(
                line,
                f"two boards or host devices named {name!r} (the other is at line "
                f"{self.names[name]}): --link {name}=URL could not tell them apart",
            )
        else:
            self.names[name] = line


class _BadValue(Exception):
    """A value YAML cannot build (``!!float abc``): a problem at its line."""

    def __init__(self, line: int, text: str) -> None:
        super().__init__(text)
        self.line = line


def _value(node: yaml.Node) -> Any:
    """The plain Python value of a node (safe YAML types only); :class:`_BadValue` if YAML
    cannot build it."""
    line = node.start_mark.line + 1
    try:
        return yaml.SafeLoader("").construct_object(node, deep=True)
    except yaml.MarkedYAMLError as exc:  # an unknown tag, a bad !!binary...
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else line
        raise _BadValue(line, f"not valid here: {exc.problem or exc}") from exc
    except (ValueError, TypeError, OverflowError) as exc:  # !!float abc, !!int x, ...
        raise _BadValue(line, f"YAML cannot read this value: {exc}") from exc


def _mapping(
    node: yaml.Node, what: str, problems: _Problems
) -> dict[str, tuple[yaml.Node, yaml.Node]] | None:
    """``key -> (key node, value node)`` of a mapping node; None (and a problem) otherwise."""
    if not isinstance(node, yaml.MappingNode):
        problems.at(node, f"{what} must be a mapping (key: value lines)")
        return None
    out: dict[str, tuple[yaml.Node, yaml.Node]] = {}
    for key_node, value_node in node.value:
        if not isinstance(key_node, yaml.ScalarNode):
            problems.at(key_node, f"{what}: a key must be a name, not a list or a mapping")
            continue
        try:
            key = str(_value(key_node))
        except _BadValue as exc:
            problems.at_line(exc.line, f"{what}: {exc}")
            continue
        if key in out:
            problems.at(key_node, f"{what}: {key!r} is given twice")
        out[key] = (key_node, value_node)
    return out


def _sequence(node: yaml.Node, what: str, problems: _Problems) -> list[yaml.Node]:
    if isinstance(node, yaml.ScalarNode) and node.tag == "tag:yaml.org,2002:null":
        return []
    if not isinstance(node, yaml.SequenceNode):
        problems.at(node, f"{what} must be a list (lines starting with '- ')")
        return []
    return list(node.value)


def _unknown_keys(
    items: dict[str, tuple[yaml.Node, yaml.Node]],
    known: Iterable[str],
    what: str,
    problems: _Problems,
) -> None:
    choices = list(known)
    for key, (key_node, _value_node) in items.items():
        if key not in choices:
            close = difflib.get_close_matches(key, choices, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            problems.at(key_node, f"{what}: unknown key {key!r}{hint}; known: {', '.join(choices)}")


def _kind_name(kind: type | tuple[type, ...]) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    return " or ".join(_KIND_NAMES.get(k, k.__name__) for k in kinds)


def check_value(field: Field, value: Any) -> tuple[Any, str | None]:
    """``value`` as ``field`` takes it (an int for a float), or the reason it does not fit."""
    kinds = field.kind if isinstance(field.kind, tuple) else (field.kind,)
    fits = False
    for kind in kinds:
        if kind is float and isinstance(value, int | float) and not isinstance(value, bool):
            value, fits = float(value), True
            break
        if kind is int and isinstance(value, int) and not isinstance(value, bool):
            fits = True
            break
        if kind not in (float, int) and isinstance(value, kind):
            fits = True
            break
    if not fits:
        return value, f"expected {_kind_name(field.kind)}, got {value!r}"
    if isinstance(value, float) and not math.isfinite(value):
        return value, f"expected a finite number, got {value!r}"
    if field.choices and value not in field.choices:
        return value, f"must be one of {', '.join(map(repr, field.choices))}, not {value!r}"
    if isinstance(value, int | float) and not isinstance(value, bool):
        if field.minimum is not None and value < field.minimum:
            return value, f"must be at least {field.minimum:g}, not {value!r}"
        if field.maximum is not None and value > field.maximum:
            return value, f"must be at most {field.maximum:g}, not {value!r}"
    return value, None


def _settings(
    plugin: DevicePlugin,
    items: dict[str, tuple[yaml.Node, yaml.Node]],
    skip: Iterable[str],
    entry: yaml.Node,
    what: str,
    problems: _Problems,
    extra: Iterable[str] = (),
) -> dict[str, Any]:
    """The device's settings checked against its plugin's fields, defaults filled in (the keys
    ``skip`` and ``extra`` are not settings: they are listed before and after the fields)."""
    fields = {f.name: f for f in plugin.fields}
    given = {k: v for k, v in items.items() if k not in {*skip, *extra}}
    _unknown_keys(given, [*skip, *fields, *extra], what, problems)
    settings: dict[str, Any] = {}
    for name, field in fields.items():
        if name not in given:
            if field.required:
                doc = f" ({field.doc})" if field.doc else ""
                problems.at(entry, f"{what}: missing setting {name!r}{doc}")
            else:
                settings[name] = field.default
            continue
        _key_node, value_node = given[name]
        try:
            value, why = check_value(field, _value(value_node))
        except _BadValue as exc:
            problems.at_line(exc.line, f"{what}: {name}: {exc}")
            continue
        if why is not None:
            problems.at(value_node, f"{what}: {name}: {why}")
        settings[name] = value
    return settings


def _string(
    items: dict[str, tuple[yaml.Node, yaml.Node]],
    key: str,
    what: str,
    problems: _Problems,
    node: yaml.Node,
    default: str | None = None,
) -> str | None:
    if key not in items:
        if default is None:
            problems.at(node, f"{what}: missing {key!r}")
        return default
    try:
        value = _value(items[key][1])
    except _BadValue as exc:
        problems.at_line(exc.line, f"{what}: {key}: {exc}")
        return default
    if not isinstance(value, str) or not value:
        problems.at(items[key][1], f"{what}: {key} must be a non-empty string, not {value!r}")
        return default
    return value


def _checked(
    items: dict[str, tuple[yaml.Node, yaml.Node]],
    key: str,
    check: Callable[[Any], Any],
    what: str,
    problems: _Problems,
    default: Any,
) -> Any:
    """``check(value)`` of ``key`` (its HwBridgeError or ValueError becomes a problem)."""
    if key not in items:
        return default
    node = items[key][1]
    try:
        return check(_value(node))
    except _BadValue as exc:
        problems.at_line(exc.line, f"{what}: {key}: {exc}")
        return default
    except (HwBridgeError, ValueError, TypeError) as exc:
        problems.at(node, f"{what}: {key}: {exc}")
        return default


def _check_link(url: Any, baud: int | None) -> str:
    from hwbridge.links import create_link
    from hwbridge.links.discovery import parse_usb_link

    if not isinstance(url, str) or not url:
        raise ValueError(f"expected a link URL, got {url!r}")
    parse_usb_link(url)  # usb:VID:PID and auto are resolved at 'up'; their syntax is checked here
    create_link(url, **({"baud": baud} if baud is not None else {}))  # parses, does not open
    return url


def _check_protocol(name: Any) -> str:
    from hwbridge.protocols.registry import get_protocol

    if not isinstance(name, str):
        raise ValueError(f"expected a protocol name, got {name!r}")
    if name != "auto":
        get_protocol(name)
    return name


def _check_namespace(name: Any) -> str:
    from hwbridge.graph import resolve_name

    if not isinstance(name, str) or not name:
        raise ValueError(f"expected a graph name such as /robot, got {name!r}")
    return resolve_name(name) if name != "/" else "/"


def _check_baud(value: Any) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
        raise ValueError(f"expected a whole number above 0, got {value!r}")
    return value


def _check_seconds(value: Any) -> float:
    if not isinstance(value, int | float) or isinstance(value, bool) or not value >= 0:
        raise ValueError(f"expected seconds (a number, 0 or more), got {value!r}")
    return float(value)


def _check_timeout(value: Any) -> float:
    from hwbridge.bridge.board import check_service_timeout

    return check_service_timeout(value)


def _check_only_on(value: Any) -> tuple[str, ...]:
    from hwbridge.firmware.boards import mcu_board

    names = [value] if isinstance(value, str) else value
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise ValueError(f"expected MCU board names such as [mega], got {value!r}")
    return tuple(mcu_board(name).name for name in names)


def _check_mcu(value: Any) -> str:
    from hwbridge.firmware.boards import mcu_board

    if not isinstance(value, str):
        raise ValueError(f"expected an MCU board name (uno, nano, mega), got {value!r}")
    return mcu_board(value).name


def _lines(path: str, node: yaml.Node) -> Iterator[tuple[str, int]]:
    """(dotted path, line) of ``node`` and of every value inside it."""
    yield path, node.start_mark.line + 1
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            if isinstance(key_node, yaml.ScalarNode):
                yield from _lines(f"{path}.{key_node.value}", value_node)
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            yield from _lines(f"{path}.{index}", item)


def _plugin(type_node: yaml.Node, what: str, problems: _Problems) -> DevicePlugin | None:
    from hwbridge.robot.registry import get_device

    try:
        name = _value(type_node)
    except _BadValue as exc:
        problems.at_line(exc.line, f"{what}: type: {exc}")
        return None
    if not isinstance(name, str):
        problems.at(type_node, f"{what}: type must be a device type name, not {name!r}")
        return None
    try:
        return get_device(name)
    except HwBridgeError as exc:
        problems.at(type_node, f"{what}: {exc}")
    except Exception as exc:  # noqa: BLE001 - a plugin that fails to import is a user's problem
        problems.at(type_node, f"{what}: type {name} cannot be loaded: {type(exc).__name__}: {exc}")
    return None


def _devices(node: yaml.Node, board: str, problems: _Problems) -> tuple[DeviceConfig, ...]:
    devices: list[DeviceConfig] = []
    counts: dict[str, int] = {}
    names: set[str] = set()
    for index, entry in enumerate(_sequence(node, f"board {board}: devices", problems)):
        what = f"board {board}: device {index + 1}"
        items = _mapping(entry, what, problems)
        if items is None:
            continue
        if "type" not in items:
            problems.at(entry, f"{what}: missing 'type' (the device type, e.g. hcsr04)")
            continue
        plugin = _plugin(items["type"][1], what, problems)
        if plugin is None:
            continue
        what = f"board {board}: {plugin.type}"
        if plugin.where != "board":
            problems.at(
                items["type"][1],
                f"{what}: a {plugin.where} device: list it under host_devices with a link of its "
                "own, not on a board",
            )
            continue
        counts[plugin.type] = counts.get(plugin.type, 0) + 1
        default_name = (
            plugin.type if counts[plugin.type] == 1 else f"{plugin.type}_{counts[plugin.type]}"
        )
        name = _string(items, "name", what, problems, entry, default_name) or default_name
        if name in names:
            problems.at(
                items.get("name", (entry, entry))[1],
                f"{what}: two devices named {name!r} on board {board}",
            )
        names.add(name)
        settings = _settings(plugin, items, ("type", "name"), entry, what, problems, ("only_on",))
        only_on = _checked(items, "only_on", _check_only_on, what, problems, ())
        lines = {key: line for key, (_k, node) in items.items() for key, line in _lines(key, node)}
        devices.append(
            DeviceConfig(plugin.type, name, settings, problems.where(entry), only_on, lines)
        )
    return tuple(devices)


def _board(entry: yaml.Node, index: int, problems: _Problems) -> RobotBoardConfig | None:
    what = f"board {index + 1}"
    items = _mapping(entry, what, problems)
    if items is None:
        return None
    _unknown_keys(items, _BOARD_KEYS, what, problems)
    name = _string(items, "name", what, problems, entry)
    if name is not None:
        if not _NAME.match(name):
            problems.at(items["name"][1], f"{what}: name {name!r} must be letters, digits and _")
        problems.unique(name, items["name"][1])
    what = f"board {name or index + 1}"
    baud = _checked(items, "baud", _check_baud, what, problems, None)
    link = _checked(items, "link", lambda url: _check_link(url, baud), what, problems, None)
    if "link" not in items:
        problems.at(entry, f"{what}: missing 'link' (e.g. /dev/ttyACM0 or socket://HOST:PORT)")
    mcu = _checked(items, "mcu", _check_mcu, what, problems, None)
    # A Mega's stk500v2 bootloader stays in charge while bytes keep coming: the sketch speaks first.
    delay = 2.0 if mcu == "mega" else 0.0
    board = RobotBoardConfig(
        name=name or "",
        link=link or "",
        protocol=_checked(items, "protocol", _check_protocol, what, problems, "auto"),
        namespace=_checked(items, "namespace", _check_namespace, what, problems, "/"),
        baud=baud,
        service_timeout=_checked(items, "service_timeout", _check_timeout, what, problems, 5.0),
        start_delay=_checked(items, "start_delay", _check_seconds, what, problems, delay),
        devices=_devices(items["devices"][1], name or str(index + 1), problems)
        if "devices" in items
        else (),
        source=problems.where(entry),
        baud_source=problems.where(items["baud"][0]) if "baud" in items else "",
        mcu=mcu,
        mcu_line=items["mcu"][1].start_mark.line + 1 if "mcu" in items else 0,
    )
    return board if name and link else None


def _host_device(entry: yaml.Node, index: int, problems: _Problems) -> HostDeviceConfig | None:
    what = f"host device {index + 1}"
    items = _mapping(entry, what, problems)
    if items is None:
        return None
    if "type" not in items:
        problems.at(entry, f"{what}: missing 'type' (the device type, e.g. dynamixel_bus)")
        return None
    plugin = _plugin(items["type"][1], what, problems)
    if plugin is None:
        return None
    name = _string(items, "name", what, problems, entry)
    if name is not None:
        if not _NAME.match(name):
            problems.at(items["name"][1], f"{what}: name {name!r} must be letters, digits and _")
        problems.unique(name, items["name"][1])
    what = f"host device {name or index + 1} ({plugin.type})"
    if plugin.where != "host":
        problems.at(
            items["type"][1],
            f"{what}: a {plugin.where} device: list it under a board's devices, not host_devices",
        )
        return None
    baud = _checked(items, "baud", _check_baud, what, problems, None)
    link = _checked(items, "link", lambda url: _check_link(url, baud), what, problems, None)
    if "link" not in items:
        problems.at(entry, f"{what}: missing 'link' (e.g. /dev/ttyUSB0)")
    namespace = _checked(items, "namespace", _check_namespace, what, problems, "/")
    settings = _settings(plugin, items, _HOST_KEYS, entry, what, problems)
    if not (name and link):
        return None
    device = DeviceConfig(plugin.type, name, settings, problems.where(entry))
    baud_source = problems.where(items["baud"][0]) if "baud" in items else ""
    return HostDeviceConfig(device, link, namespace, baud, problems.where(entry), baud_source)


def parse_robot(text: str, path: str = "<robot>") -> Robot:
    """A robot from the text of a robot file (``path`` names it in errors)."""
    try:
        return _parse_robot(text, path)
    except yaml.MarkedYAMLError as exc:  # a value YAML cannot build (a tag, an odd key...)
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else 1
        raise RobotFileError([f"{path}:{line}: not valid here: {exc.problem or exc}"]) from exc
    except _BadValue as exc:  # one that no check above caught
        raise RobotFileError([f"{path}:{exc.line}: {exc}"]) from exc


def _parse_robot(text: str, path: str) -> Robot:
    problems = _Problems(path)
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else 1
        raise RobotFileError([f"{path}:{line}: not valid YAML: {exc.problem or exc}"]) from exc
    if root is None:
        raise RobotFileError(
            [f"{path}:1: the file is empty: a robot file starts with 'robot: NAME'"]
        )
    top = _mapping(root, "the robot file", problems)
    if top is None:
        raise RobotFileError(problems.lines)
    _unknown_keys(top, _TOP_KEYS, "the robot file", problems)
    name = _string(top, "robot", "the robot file", problems, root) or ""
    world: dict[str, Any] = {}
    if "world" in top:
        try:
            value = _value(top["world"][1])
        except _BadValue as exc:
            problems.at_line(exc.line, f"world: {exc}")
            value = None
        if isinstance(value, dict):
            world = value
        elif value is not None:
            problems.at(top["world"][1], "world must be a mapping (the emulator's world)")
    boards = [
        board
        for index, entry in enumerate(
            _sequence(top["boards"][1], "boards", problems) if "boards" in top else []
        )
        if (board := _board(entry, index, problems)) is not None
    ]
    hosts = [
        host
        for index, entry in enumerate(
            _sequence(top["host_devices"][1], "host_devices", problems)
            if "host_devices" in top
            else []
        )
        if (host := _host_device(entry, index, problems)) is not None
    ]
    gateways = _ros(top["ros"][1], problems) if "ros" in top else {}
    gateways |= boards_per_process_key(top, problems.at)
    if not boards and not hosts and not problems.lines:
        problems.at(root, "the robot has no boards and no host_devices")
    for line, clash in topic_clashes(boards, hosts):
        problems.at_line(line, clash)
    if not problems.lines:  # the pins of boards that name their MCU board
        from hwbridge.robot.wiring import board_problems

        for board in boards:
            if board.mcu is not None:
                for line, problem in board_problems(board, board.mcu):
                    problems.at_line(line, f"board {board.name} ({board.mcu}): {problem}")
    if problems.lines:
        raise RobotFileError(problems.lines)
    return Robot(name, Path(path), tuple(boards), tuple(hosts), world, **gateways)


def _ros(node: yaml.Node, problems: _Problems) -> dict[str, Any]:
    """The ``ros:`` section: which gateways ``hwbridge up`` starts with the robot, and the ROS 2
    gateway's QoS rules (as :class:`Robot`'s ``ros2``, ``ros1`` and ``ros2_qos``)."""
    if isinstance(node, yaml.ScalarNode) and node.tag == "tag:yaml.org,2002:null":
        return {}
    items = _mapping(node, "ros", problems)
    if items is None:
        return {}
    _unknown_keys(items, _ROS_KEYS, "ros", problems)
    wanted: dict[str, Any] = {}
    for key in ("ros2", "ros1"):
        if key not in items:
            continue
        value_node = items[key][1]
        try:
            value = _value(value_node)
        except _BadValue as exc:
            problems.at_line(exc.line, f"ros: {key}: {exc}")
            continue
        if isinstance(value, bool):
            wanted[key] = value
        else:
            problems.at(value_node, f"ros: {key} must be true or false, not {value!r}")
    if "qos" in items:
        wanted["ros2_qos"] = _ros2_qos(items["qos"][1], problems)
    return wanted


def _ros2_qos(node: yaml.Node, problems: _Problems) -> tuple[tuple[str, str], ...]:
    """``ros: {qos: {PATTERN: KIND, ...}}``, in file order."""
    from hwbridge.gateway.qos import check_kind, check_pattern

    if isinstance(node, yaml.ScalarNode) and node.tag == "tag:yaml.org,2002:null":
        return ()
    items = _mapping(node, "ros: qos", problems)
    if items is None:
        return ()
    rules: list[tuple[str, str]] = []
    for pattern, (key_node, value_node) in items.items():
        why = check_pattern(pattern)
        if why is not None:
            problems.at(key_node, f"ros: qos: {why}")
            continue
        try:
            kind = _value(value_node)
        except _BadValue as exc:
            problems.at_line(exc.line, f"ros: qos: {pattern}: {exc}")
            continue
        why = check_kind(kind) if isinstance(kind, str) else f"{kind!r} is no QoS kind"
        if why is not None:
            problems.at(value_node, f"ros: qos: {pattern}: {why}")
            continue
        rules.append((pattern, kind))
    return tuple(rules)


def device_config(entry: dict[str, Any], source: str = "<device>") -> DeviceConfig:
    """One device from a mapping (``{"type": "hcsr04", "rate": 10}``), checked against its
    plugin's fields with defaults filled in, as a robot file's device entry is."""
    from hwbridge.robot.registry import get_device

    settings = dict(entry)
    plugin = get_device(str(settings.pop("type", "")))
    name = str(settings.pop("name", plugin.type))
    problems: list[str] = []
    fields = {f.name: f for f in plugin.fields}
    for key in sorted(set(settings) - set(fields)):
        close = difflib.get_close_matches(key, list(fields), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        problems.append(
            f"{source}: {plugin.type}: unknown setting {key!r}{hint}; known: "
            + (", ".join(fields) or "none")
        )
    checked: dict[str, Any] = {}
    for field in plugin.fields:
        if field.name not in settings:
            if field.required:
                problems.append(f"{source}: {plugin.type}: missing setting {field.name!r}")
            checked[field.name] = field.default
            continue
        value, why = check_value(field, settings[field.name])
        if why is not None:
            problems.append(f"{source}: {plugin.type}: {field.name}: {why}")
        checked[field.name] = value
    if problems:
        raise RobotFileError(problems)
    return DeviceConfig(plugin.type, name, checked, source)


def load_robot(path: str | Path) -> Robot:
    """Read and check a robot file; :class:`RobotFileError` lists every problem found."""
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise RobotFileError([f"{file}: no such robot file"]) from exc
    except UnicodeDecodeError as exc:
        raise RobotFileError([f"{file}: not a text file (UTF-8): {exc.reason}"]) from exc
    except OSError as exc:
        raise RobotFileError([f"{file}: cannot read: {exc.strerror or exc}"]) from exc
    return parse_robot(text, str(file))


def _overridden_baud(
    url: str, baud: int | None, baud_source: str, where: str, what: str, name: str
) -> tuple[int | None, str | None]:
    """The baud rate to use with an overriding ``url`` and the note to print when the file's
    does not apply to it; RobotFileError if ``url`` is not a link URL at all."""
    from hwbridge.links import create_link

    try:
        create_link(url, **({"baud": baud} if baud is not None else {}))  # parses, never opens
        return baud, None
    except HwBridgeError as exc:
        refused = exc
    if baud is not None:
        try:
            create_link(url)
        except HwBridgeError:
            pass
        else:  # the URL is fine; only the file's baud rate does not fit it
            return None, f"{baud_source or where}: baud {baud} does not apply to {url}; ignored"
    raise RobotFileError([f"{where}: {what}: --link {name}={url}: {refused}"])


_Linked = TypeVar("_Linked", RobotBoardConfig, HostDeviceConfig)
"""A board or a host device: what ``--link`` can give another link."""


def link_overrides(robot: Robot, links: Mapping[str, str]) -> tuple[Robot, list[str]]:
    """``robot`` with the links of some boards and host devices replaced (``--link NAME=URL``),
    and the notes to show: a ``baud`` the file gives that the new link takes none for
    (``socket://``) is dropped, with a note naming its line. An unknown name or a URL that does
    not parse is an error (:class:`~hwbridge.errors.HwBridgeError`, RobotFileError with the
    board's or host device's line)."""
    replaced = robot.with_links(links)  # an unknown name: HwBridgeError listing the known ones
    notes: list[str] = []

    def relinked(item: _Linked, name: str, what: str) -> _Linked:
        if name not in links:
            return item
        source = item.source or str(robot.path)
        baud, note = _overridden_baud(item.link, item.baud, item.baud_source, source, what, name)
        notes.extend([note] if note else [])
        return dataclasses.replace(item, baud=baud)

    boards = tuple(relinked(b, b.name, f"board {b.name}") for b in replaced.boards)
    hosts = tuple(
        relinked(h, h.device.name, f"host device {h.device.name} ({h.device.type})")
        for h in replaced.host_devices
    )
    return dataclasses.replace(replaced, boards=boards, host_devices=hosts), notes


def check_robot(
    path: str | Path, links: Mapping[str, str] | None = None
) -> tuple[Robot, list[str]]:
    """What ``hwbridge robot check`` and ``hwbridge up`` both run: the robot file read and
    checked (:func:`load_robot`), then the ``--link`` overrides applied
    (:func:`link_overrides`); the robot as it will run and the notes to show."""
    robot = load_robot(path)
    return link_overrides(robot, links or {})
