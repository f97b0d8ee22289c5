"""The device-plugin registry: device types by name, built in or from the ``hwbridge.devices``
entry-point group (an entry point names a :class:`~hwbridge.robot.plugin.DevicePlugin`
subclass or instance), imported on first use.
"""

from __future__ import annotations

from typing import Final

from hwbridge.errors import HwBridgeError
from hwbridge.protocols.plugins import NamedRegistry
from hwbridge.robot.plugin import DevicePlugin

__all__ = [
    "BUILTIN_DEVICES",
    "ENTRY_POINT_GROUP",
    "UnknownDeviceError",
    "device_types",
    "get_device",
    "refresh",
    "register_device",
    "unregister_device",
]

ENTRY_POINT_GROUP: Final = "hwbridge.devices"

BUILTIN_DEVICES: Final[dict[str, str]] = {
    "diffdrive": "hwbridge.devices.diffdrive.plugin:DiffDrivePlugin",
    "hcsr04": "hwbridge.devices.ultrasonic.plugin:HcSr04Plugin",
    "mpu6050": "hwbridge.devices.imu.plugin:Mpu6050Plugin",
    "mpu9250": "hwbridge.devices.imu.plugin:Mpu9250Plugin",
    "bme280": "hwbridge.devices.bme280.plugin:Bme280Plugin",
    "dynamixel": "hwbridge.devices.dynamixel.plugin:BoardServoPlugin",
    "dynamixel_bus": "hwbridge.devices.dynamixel.plugin:DynamixelBusPlugin",
}
"""Built-in device types (``module:attr``)."""


class UnknownDeviceError(HwBridgeError):
    """No device plugin of that type is registered."""


def _plugin(loaded: object, name: str) -> DevicePlugin:
    if isinstance(loaded, type) and issubclass(loaded, DevicePlugin):
        return loaded()
    if isinstance(loaded, DevicePlugin):
        return loaded
    raise UnknownDeviceError(
        f"device type {name!r} is registered as {loaded!r}, not a DevicePlugin"
    )


_REGISTRY: Final = NamedRegistry(
    "device type", ENTRY_POINT_GROUP, BUILTIN_DEVICES, _plugin, UnknownDeviceError
)


def register_device(
    plugin: DevicePlugin | type[DevicePlugin] | str, name: str | None = None
) -> None:
    """Make ``plugin`` (or ``"module:attr"`` naming one) the device type ``name`` (default:
    the plugin's ``type``)."""
    key = name if name is not None else None if isinstance(plugin, str) else plugin.type
    if not key:
        raise ValueError("a device given as 'module:attr' needs a name")
    _REGISTRY.register(key, plugin)


def unregister_device(name: str) -> None:
    """Forget a device type given by :func:`register_device` (tests, applications)."""
    _REGISTRY.unregister(name)


def refresh() -> None:
    """Read the entry points again and forget loaded plugins (after ``sys.path`` changed)."""
    _REGISTRY.refresh()


def device_types() -> list[str]:
    """Every device type known now, built-in first."""
    return _REGISTRY.names()


def get_device(name: str) -> DevicePlugin:
    """The plugin of device type ``name``; :class:`UnknownDeviceError` listing the known ones."""
    return _REGISTRY.get(name)
