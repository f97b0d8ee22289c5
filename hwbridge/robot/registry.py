"""The device-plugin registry: device types by name, built in or from the ``hwbridge.devices``
entry-point group (an entry point names a :class:`~hwbridge.robot.plugin.DevicePlugin`
subclass or instance), imported on first use.
"""

from __future__ import annotations

import importlib
import threading
from importlib.metadata import EntryPoint, entry_points
from typing import Final

from hwbridge.errors import HwBridgeError
from hwbridge.robot.plugin import DevicePlugin

__all__ = [
    "BUILTIN_DEVICES",
    "ENTRY_POINT_GROUP",
    "UnknownDeviceError",
    "device_types",
    "get_device",
    "refresh",
    "register_device",
]

ENTRY_POINT_GROUP: Final = "hwbridge.devices"

BUILTIN_DEVICES: Final[dict[str, str]] = {
    "diffdrive": "hwbridge.devices.plugins:DiffDrivePlugin",
    "hcsr04": "hwbridge.devices.plugins:HcSr04Plugin",
    "mpu6050": "hwbridge.devices.plugins:Mpu6050Plugin",
    "mpu9250": "hwbridge.devices.plugins:Mpu9250Plugin",
    "dynamixel": "hwbridge.devices.plugins:BoardServoPlugin",
    "dynamixel_bus": "hwbridge.devices.dynamixel.plugin:DynamixelBusPlugin",
}
"""Built-in device types (``module:attr``)."""


class UnknownDeviceError(HwBridgeError):
    """No device plugin of that type is registered."""


_lock = threading.RLock()
_registered: dict[str, DevicePlugin | type[DevicePlugin] | str] = {}
_resolved: dict[str, DevicePlugin] = {}
_entry_points: dict[str, EntryPoint] | None = None


def register_device(
    plugin: DevicePlugin | type[DevicePlugin] | str, name: str | None = None
) -> None:
    """Make ``plugin`` (or ``"module:attr"`` naming one) the device type ``name`` (default:
    the plugin's ``type``)."""
    key = name if name is not None else None if isinstance(plugin, str) else plugin.type
    if not key:
        raise ValueError("a device given as 'module:attr' needs a name")
    with _lock:
        _registered[key] = plugin
        _resolved.pop(key, None)


def _load_entry_points(refresh: bool = False) -> dict[str, EntryPoint]:
    global _entry_points  # noqa: PLW0603 - a lazily filled module cache
    with _lock:
        if _entry_points is None or refresh:
            _entry_points = {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}
        return _entry_points


def refresh() -> None:
    """Read the entry points again and forget loaded plugins (after ``sys.path`` changed)."""
    with _lock:
        _resolved.clear()
        _load_entry_points(refresh=True)


def device_types() -> list[str]:
    """Every device type known now, built-in first."""
    with _lock:
        names = [*BUILTIN_DEVICES, *_registered, *_load_entry_points()]
    return list(dict.fromkeys(names))


def _instance(loaded: object, name: str) -> DevicePlugin:
    if isinstance(loaded, type) and issubclass(loaded, DevicePlugin):
        return loaded()
    if isinstance(loaded, DevicePlugin):
        return loaded
    raise UnknownDeviceError(
        f"device type {name!r} is registered as {loaded!r}, not a DevicePlugin"
    )


def get_device(name: str) -> DevicePlugin:
    """The plugin of device type ``name``; :class:`UnknownDeviceError` listing the known ones."""
    with _lock:
        found = _resolved.get(name)
        if found is not None:
            return found
        target: object = _registered.get(name) or BUILTIN_DEVICES.get(name)
        if target is None:
            target = _load_entry_points().get(name) or _load_entry_points(refresh=True).get(name)
        if target is None:
            raise UnknownDeviceError(
                f"unknown device type {name!r}; known types: {', '.join(device_types())}"
            )
        if isinstance(target, EntryPoint):
            target = target.load()
        elif isinstance(target, str):
            module, _, attr = target.partition(":")
            target = getattr(importlib.import_module(module), attr)
        plugin = _instance(target, name)
        _resolved[name] = plugin
        return plugin
