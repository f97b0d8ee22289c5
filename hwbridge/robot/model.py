"""What a robot file describes, once read and checked (:func:`hwbridge.robot.config.load_robot`).

A robot is boards on links, each with the devices on its pins, plus devices on the host's own
adapters; the ``world`` section describes the room and the robot's body for the emulator. Every
item remembers where it was written (``FILE:LINE``) so that later errors can say so too.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hwbridge.errors import HwBridgeError

__all__ = ["DeviceConfig", "HostDeviceConfig", "Robot", "RobotBoardConfig", "RobotFileError"]


class RobotFileError(HwBridgeError):
    """A robot file is wrong; ``problems`` holds one ``FILE:LINE: what is wrong`` line each."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = problems
        super().__init__("\n".join(problems))


@dataclass(frozen=True)
class DeviceConfig:
    """One device: its plugin's type and its settings (checked, with defaults filled in)."""

    type: str
    name: str
    """Unique on its board (default: the type, numbered when repeated)."""
    settings: Mapping[str, Any]
    source: str = ""
    """``FILE:LINE`` of the device's entry."""
    only_on: tuple[str, ...] = ()
    """``only_on: [mega]``: the MCU boards the device is on (empty: every one). On another
    board the sketch generator and the simulation leave it out, and the pins are not checked
    (as ``#if`` in a hand-written sketch)."""
    lines: Mapping[str, int] = field(default_factory=dict)
    """The line of each setting the file gives, by dotted path (``pins``,
    ``pins.left_encoder``, ``pins.left_encoder.0``), for messages about its value."""

    def line_of(self, setting: str) -> int | None:
        """The line of ``setting`` (a dotted path) or of the nearest enclosing one given."""
        path = setting
        while path:
            if path in self.lines:
                return self.lines[path]
            path = path.rpartition(".")[0]
        return None


@dataclass(frozen=True)
class RobotBoardConfig:
    """One board: how to reach it and the devices on it."""

    name: str
    link: str
    protocol: str = "auto"
    namespace: str = "/"
    baud: int | None = None
    service_timeout: float = 5.0
    start_delay: float = 0.0
    devices: tuple[DeviceConfig, ...] = ()
    source: str = ""
    baud_source: str = ""
    """``FILE:LINE`` of the ``baud`` key, where the file gives one."""
    mcu: str | None = None
    """``mcu: uno | nano | mega``: the MCU board (:mod:`hwbridge.firmware.boards`); its pins
    are checked when given. None: not said (the sketch generator takes ``uno``)."""
    mcu_line: int = 0
    """The line of ``mcu``, where the file gives one."""


@dataclass(frozen=True)
class HostDeviceConfig:
    """A device on an adapter of the host's own (a Dynamixel bus on a U2D2), with its link."""

    device: DeviceConfig
    link: str
    namespace: str = "/"
    baud: int | None = None
    source: str = ""
    baud_source: str = ""
    """``FILE:LINE`` of the ``baud`` key, where the file gives one."""


@dataclass(frozen=True)
class Robot:
    """A whole robot file."""

    name: str
    path: Path
    boards: tuple[RobotBoardConfig, ...] = ()
    host_devices: tuple[HostDeviceConfig, ...] = ()
    world: Mapping[str, Any] = field(default_factory=dict)
    """The emulator's world (room, obstacles, wheel geometry); see
    :class:`hwbridge.emulator.world.WorldConfig`."""
    ros2: bool = False
    """``ros: {ros2: true}``: ``hwbridge up`` also starts the ROS 2 gateway (as ``--ros2``)."""
    ros1: bool = False
    """``ros: {ros1: true}``: ``hwbridge up`` also starts the ROS 1 gateway (as ``--ros1``)."""
    ros2_qos: tuple[tuple[str, str], ...] = ()
    """``ros: {qos: {PATTERN: KIND}}``: ROS 2 QoS rules (topic pattern, kind), in file order;
    ``hwbridge up --ros2-qos`` rules go before them (see :mod:`hwbridge.gateway.qos`)."""
    boards_per_process: int | None = None
    """``boards_per_process: N``: ``hwbridge up`` runs more boards than N in several bridge
    processes (as ``--boards-per-process``; None: the default, 0: one process)."""

    def board(self, name: str) -> RobotBoardConfig:
        for board in self.boards:
            if board.name == name:
                return board
        known = ", ".join(b.name for b in self.boards) or "none"
        raise HwBridgeError(f"{self.path}: no board named {name!r} (boards: {known})")

    def with_links(self, links: Mapping[str, str]) -> Robot:
        """The same robot with some boards' (or host devices') links replaced, by name
        (``hwbridge up --link base=socket://...``)."""
        names = {b.name for b in self.boards} | {h.device.name for h in self.host_devices}
        unknown = sorted(set(links) - names)
        if unknown:
            raise HwBridgeError(
                f"{self.path}: --link names {', '.join(unknown)}, but the robot has "
                f"{', '.join(sorted(names)) or 'no boards'}"
            )
        boards = tuple(
            dataclasses.replace(b, link=links[b.name]) if b.name in links else b
            for b in self.boards
        )
        hosts = tuple(
            dataclasses.replace(h, link=links[h.device.name]) if h.device.name in links else h
            for h in self.host_devices
        )
        return dataclasses.replace(self, boards=boards, host_devices=hosts)
