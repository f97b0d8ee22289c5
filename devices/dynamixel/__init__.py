"""Dynamixel servos: packet codecs (Protocol 1.0 and 2.0), a host bus driver, an emulated bus
and a graph node.

* :mod:`~hwbridge.devices.dynamixel.packets`: encode/decode, CRC-16, checksum, byte stuffing
  (``framing``), a stream parser (``parser``), instruction parameters;
  :mod:`~hwbridge.devices.dynamixel.tables`: control tables and units.
* :class:`DynamixelBus`: ping/scan, read/write, REG_WRITE + ACTION, SYNC/BULK READ/WRITE,
  reboot, factory reset, typed register helpers, on any :class:`~hwbridge.links.Link`.
* :class:`EmulatedDynamixelBus` (sans-I/O; its :class:`EmulatedServo` lives in ``servo``) and
  :class:`EmulatedBusRunner` (serves it on a pty); :func:`emulated_bus` builds the ready ones,
  ``dxl-bus`` and ``dxl-bus-p1``.
* :class:`DynamixelNode`: ``joint_states``, per-joint goals and ``torque_enable`` on the graph.

The graph node is imported on first use, so this package does not load Zenoh.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hwbridge.devices.dynamixel.bus import (
    BusStats,
    DynamixelBus,
    DynamixelStatusError,
    PingResult,
)
from hwbridge.devices.dynamixel.emulator import (
    EmulatedBusRunner,
    EmulatedDynamixelBus,
    EmulatedServo,
    bus_configs,
    emulated_bus,
)
from hwbridge.devices.dynamixel.packets import (
    BROADCAST_ID,
    CorruptPacket,
    Error1,
    Error2,
    Instruction,
    InstructionPacket,
    PacketParser,
    StatusPacket,
)
from hwbridge.devices.dynamixel.tables import (
    MODELS,
    ControlTable,
    Register,
    ServoModel,
    UnknownModelError,
    UnknownRegisterError,
    find_model,
)

if TYPE_CHECKING:
    from hwbridge.devices.dynamixel.node import DynamixelNode

__all__ = [
    "BROADCAST_ID",
    "MODELS",
    "BusStats",
    "ControlTable",
    "CorruptPacket",
    "DynamixelBus",
    "DynamixelNode",
    "DynamixelStatusError",
    "EmulatedBusRunner",
    "EmulatedDynamixelBus",
    "EmulatedServo",
    "Error1",
    "Error2",
    "Instruction",
    "InstructionPacket",
    "PacketParser",
    "PingResult",
    "Register",
    "ServoModel",
    "StatusPacket",
    "UnknownModelError",
    "UnknownRegisterError",
    "bus_configs",
    "emulated_bus",
    "find_model",
]


def __getattr__(name: str) -> Any:
    """Import :class:`DynamixelNode` (and with it the graph) on first access."""
    if name == "DynamixelNode":
        from hwbridge.devices.dynamixel.node import DynamixelNode

        return DynamixelNode
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
