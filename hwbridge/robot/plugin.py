"""The device-plugin contract: what a device (a sonar, an IMU, wheel encoders, a servo bus) gives
hwbridge in one place.

A robot file (:mod:`hwbridge.robot.config`) lists devices by ``type``; each type is a
:class:`DevicePlugin` found in the registry (:mod:`hwbridge.robot.registry`: built-ins and the
``hwbridge.devices`` entry-point group). A plugin declares:

* its **settings** (:class:`Field`): names, types, defaults and limits, so a robot file is
  checked before anything starts and each problem names the file and line;
* its **emulated model** (:meth:`DevicePlugin.emulate`): how a virtual board carries the device
  (the topics the firmware would publish and subscribe, read from the emulator's world);
* its **host node** (:meth:`DevicePlugin.host_node`): the graph node that turns the board's raw
  topics into the messages users want (odometry, Range, Imu, joint states);
* its **pin-level model** (:meth:`DevicePlugin.pin_model`, a :class:`PinModel`): the device on
  the pins of real firmware running in simavr (:class:`hwbridge.emulator.pins.PinWorld`), if it
  has one;
* the **firmware driver** it pairs with (:attr:`DevicePlugin.firmware`, a name in the Arduino
  library; None until the firmware has one);
* its **wiring** on an MCU board (:meth:`DevicePlugin.wiring`, a :class:`Wiring`): the pins,
  I2C addresses and UARTs its settings give it (or its defaults for that board), checked by
  ``hwbridge robot check`` against the board's pin table (:mod:`hwbridge.firmware.boards`);
* its **part of a generated sketch** (:meth:`DevicePlugin.sketch`, a :class:`SketchPart`): the
  C++ that ``hwbridge firmware generate`` puts together (:mod:`hwbridge.sketchgen`), rendered
  from its settings, so that host and board read their shared settings from one file;
* the **topics and services** it uses with given settings (:meth:`DevicePlugin.topics`, a
  tuple of :class:`TopicUse`), so a robot file in which two devices would publish one topic is
  refused with both lines. A plugin that does not say (returns None) is left out of that check.

Where a device lives: ``board`` devices sit on a board's pins and reach the host through the
board's link (their host node talks to the board's raw topics in the board's namespace); ``host``
devices sit on an adapter of the host's own (a U2D2 for Dynamixel servos) and have a link of
their own in the robot file.

``hwbridge up``, the emulator and the demo call plugins only through this contract: none of
them names a device type.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Final, Literal, Protocol

if TYPE_CHECKING:
    from hwbridge.firmware.boards import McuBoard, PinName
    from hwbridge.firmware.sim import Tick

__all__ = [
    "REQUIRED",
    "Closeable",
    "DevicePlugin",
    "EmulatedBoard",
    "Field",
    "HostContext",
    "PinBoard",
    "PinModel",
    "PinUse",
    "SketchContext",
    "SketchPart",
    "TopicUse",
    "Where",
    "Wiring",
    "WiringError",
]

Where = Literal["board", "host"]
Use = Literal["publishes", "subscribes", "serves"]


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Final[Any] = _Required()
"""The default of a :class:`Field` that a robot file must give."""


@dataclass(frozen=True)
class Field:
    """One setting of a device plugin, as a robot file gives it."""

    name: str
    kind: type | tuple[type, ...]
    """The YAML value's type: ``float`` also takes an int; ``list``/``dict`` for structures."""
    default: Any = REQUIRED
    doc: str = ""
    choices: tuple[Any, ...] = ()
    """The allowed values (empty: any value of ``kind``)."""
    minimum: float | None = None
    maximum: float | None = None

    @property
    def required(self) -> bool:
        return self.default is REQUIRED


@dataclass(frozen=True)
class TopicUse:
    """A topic a device publishes or subscribes, or a service it serves."""

    name: str
    """Relative to the device's namespace (the board's for a board device), or absolute."""
    type: str
    """The message or service type (``sensor_msgs/Range``)."""
    use: Use = "publishes"
    side: Where = "host"
    """Who does it: the board's firmware (``board``) or the device's host node (``host``)."""
    shared: bool = False
    """Meant to have many publishers (``/tf``, ``/diagnostics``): never a clash."""


@dataclass(frozen=True)
class PinUse:
    """One pin a device takes on its board."""

    pin: PinName
    """As the robot file (or the plugin's default) gives it: ``2`` or ``"A0"``."""
    role: str
    """What the device does with it (``left encoder A``), for messages."""
    setting: str = ""
    """Where in the device's settings it was given, a dotted path (``pins.left_encoder.0``);
    empty for a default of the plugin."""
    needs: tuple[Literal["interrupt", "pwm"], ...] = ()
    """What the pin must have for the device's firmware driver."""


@dataclass(frozen=True)
class Wiring:
    """What a device takes of a board: pins, I2C addresses (the bus's SDA and SCL with them)
    and UARTs, each with the setting that gave it (a dotted path; empty for a default)."""

    pins: tuple[PinUse, ...] = ()
    i2c: tuple[tuple[int, str], ...] = ()
    """(7-bit address, setting)."""
    uarts: tuple[tuple[str, str], ...] = ()
    """(Arduino serial object, ``Serial1``, setting)."""


class WiringError(ValueError):
    """A device's pin settings do not have the shape its plugin reads (``setting`` names the
    offending one, a dotted path)."""

    def __init__(self, setting: str, text: str) -> None:
        super().__init__(text)
        self.setting = setting


@dataclass(frozen=True)
class SketchContext:
    """What a device's part of a generated sketch may use besides its settings."""

    name: str
    """The device's name on its board, made a C++ identifier (``front_sonar``): prefix its
    globals with it so two devices of one type do not collide."""
    board: McuBoard
    """The MCU board the sketch is for."""
    wiring: Wiring
    """The device's wiring on it (checked)."""
    node: str = "nh"
    """The sketch's ``hwbridge::NodeHandle``."""


@dataclass(frozen=True)
class SketchPart:
    """A device's C++ in a generated sketch, each piece a block of statements or declarations
    (the generator indents them). The loop's pieces run in device order each ``loop()``; the
    ``connect`` pieces once each time the host connects, ``disconnect`` each loop while no host
    is connected."""

    includes: tuple[str, ...] = ()
    """Headers (``hwbridge/drivers/hcsr04.h``, ``Wire.h``), each included once."""
    prelude: tuple[str, ...] = ()
    """Setup statements that several devices may share (``Wire.begin();``): each written once,
    in order, before the devices' setup."""
    globals: str = ""
    setup: str = ""
    loop: str = ""
    connect: str = ""
    disconnect: str = ""


class Closeable(Protocol):
    """What a host node returns: something to stop when the robot goes down."""

    def close(self) -> None: ...


class EmulatedBoard(Protocol):
    """What a virtual board offers the emulated models of its devices (see
    :class:`hwbridge.emulator.board.VirtualBoard`)."""

    @property
    def world(self) -> Any:
        """The simulated world (:class:`hwbridge.emulator.world.World`): robot base, room,
        IMU truth."""
        ...

    @property
    def seed(self) -> int:
        """The board's random seed (a device adds its own offset for its noise)."""
        ...

    @property
    def registry(self) -> Any:
        """The message type registry."""
        ...

    def publisher(
        self, topic: str, type_name: str, rate: float, read: Callable[[], bytes | None]
    ) -> int:
        """Declare a board publisher; ``read()`` is called ``rate`` times a (simulated) second
        and its bytes (ROS 1 serialized ``type_name``) published; None skips a reading."""
        ...

    def subscriber(self, topic: str, type_name: str, handle: Callable[[bytes], None]) -> int:
        """Declare a board subscriber; ``handle(payload)`` gets each message."""
        ...

    def header(self, frame_id: str) -> dict[str, Any]:
        """A ``std_msgs/Header`` mapping stamped now, in host time (as firmware with time sync
        stamps its readings)."""
        ...

    def on_step(self, step: Callable[[float], None]) -> None:
        """Run ``step(world_time)`` after each physics step (under the board's lock)."""
        ...

    def on_reset(self, reset: Callable[[], None]) -> None:
        """Run ``reset()`` when the board reboots (counters and state back to power-on)."""
        ...


class PinBoard(Protocol):
    """What the pin-level twin of a board (:class:`hwbridge.emulator.pins.PinWorld`: the
    emulator's world on the pins of firmware in simavr) offers the pin models of its devices."""

    @property
    def world(self) -> Any:
        """The simulated world (:class:`hwbridge.emulator.world.World`)."""
        ...

    @property
    def pins(self) -> McuBoard:
        """The board's pin table (:mod:`hwbridge.firmware.boards`): a device's pin model takes
        its own pins from its settings with :meth:`DevicePlugin.wiring` on it."""
        ...

    @property
    def mcu(self) -> str:
        """The simulated AVR (``atmega328p``, ``atmega2560``), for
        :func:`hwbridge.firmware.sim.arduino_pin`."""
        ...

    @property
    def seed(self) -> int:
        """The board's random seed (a device adds its own offset for its noise)."""
        ...

    @property
    def last_time(self) -> float:
        """The simulated time (s) the world was last stepped to."""
        ...

    def command(self, line: str) -> None:
        """Send one command line to the simulator (see ``hwbridge/firmware/sim/runner.c``)."""
        ...


class PinModel:
    """One device on the pins of a :class:`PinBoard`: set up before the AVR runs (and at each
    restart of the simulation), then stepped at each of the simulator's reports."""

    def setup(self, board: PinBoard) -> None:
        """Put the device on its pins (the AVR is held)."""
        raise NotImplementedError

    def tick(self, board: PinBoard, tick: Tick, dt: float) -> None:
        """Before the world steps by ``dt``: read the firmware's outputs into the world."""

    def after(self, board: PinBoard, now: float) -> None:
        """After the world stepped to ``now``: put its state on the pins."""

    def i2c_write(self, board: PinBoard, address: int, register: int, data: bytes) -> None:
        """The firmware wrote registers of an I2C device."""

    def packet(self, board: PinBoard, uart: str, data: bytes) -> bytes | None:
        """The firmware sent ``data`` on bus UART ``uart``: the reply, if this device answers."""
        return None


@dataclass
class HostContext:
    """What a host node gets: where it runs and what it is attached to."""

    graph: Any
    """The robot's graph (:class:`hwbridge.graph.Graph`)."""
    node: Any
    """A graph node in the device's namespace (:class:`hwbridge.graph.Node`)."""
    namespace: str
    board: str | None
    """The board the device is on (None for a host device)."""
    link: str | None
    """The host adapter's link URL (host devices only)."""
    baud: int | None = None
    """The host adapter's baud rate, where the robot file gives one (host devices only)."""
    source: str = ""
    """Where the device was configured (``FILE:LINE``), for messages."""
    extra: dict[str, Any] = field(default_factory=dict)


class DevicePlugin(abc.ABC):
    """One kind of device. Subclasses set the class attributes and implement the methods their
    ``where`` needs (a board device may have no host node, e.g. a servo the board drives
    itself; a host device has no emulated model on a board)."""

    type: ClassVar[str]
    """The name robot files use (``hcsr04``)."""
    summary: ClassVar[str]
    where: ClassVar[Where] = "board"
    fields: ClassVar[tuple[Field, ...]] = ()
    firmware: ClassVar[str | None] = None
    """The Arduino library's driver for this device, once there is one: ``HEADER: Class``
    pairs joined by ``; `` (headers under ``firmware/HwBridge/src``, classes in
    ``hwbridge::drivers``), e.g. ``hwbridge/drivers/hcsr04.h: HcSr04``."""

    def emulate(self, settings: Mapping[str, Any], board: EmulatedBoard) -> None:  # noqa: B027
        """Add the device's model to a virtual board (board devices)."""

    def host_node(self, settings: Mapping[str, Any], context: HostContext) -> Closeable | None:
        """Start the host node for the device; None if it needs none."""
        return None

    def pin_model(self, settings: Mapping[str, Any], board: PinBoard) -> PinModel | None:
        """The device's model on the pins of ``board`` (board devices); None if it has none
        there, or none on this board (the board's pins lack what it needs): the device is then
        left out of the simulation."""
        return None

    def wiring(self, settings: Mapping[str, Any], board: McuBoard) -> Wiring | None:
        """What the device takes of ``board`` with ``settings`` (its pins as given, or its
        defaults for that board): checked by ``hwbridge robot check`` for a board with an
        ``mcu``. None: the device takes nothing of the board's pins. :class:`WiringError` for
        pin settings of the wrong shape."""
        return None

    def sketch(self, settings: Mapping[str, Any], context: SketchContext) -> SketchPart | None:
        """The device's part of a sketch generated from a robot file (``hwbridge firmware
        generate``); None if the plugin cannot generate firmware (the generator then refuses
        the robot file, naming the device)."""
        return None

    def topics(self, settings: Mapping[str, Any]) -> tuple[TopicUse, ...] | None:
        """The topics the device publishes and subscribes and the services it serves with
        ``settings`` (checked, defaults filled in): on the board (what its firmware or its
        emulated model declares) and on the host (its host node). Robot files are checked
        with it: two devices that would publish one topic (or serve one service) in the same
        namespace are an error. None (the default): the plugin does not say, and is left out
        of that check."""
        return None
