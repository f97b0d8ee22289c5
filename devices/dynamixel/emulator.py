"""Emulated Dynamixel servos on a bus, answering raw packets as real ones behind a USB adapter.

:class:`EmulatedDynamixelBus` is sans-I/O: ``feed(data, now)`` takes the bytes the host sent and
returns the bytes the servos send back that are due by ``now``; ``advance(now)`` moves the
simulated clock (motion, return delays) and returns what became due. Nothing sleeps: tests pass
any clock they like. :class:`EmulatedBusRunner` serves a bus on a ``pty://`` link in a thread,
so a host opens the pty's slave path as it would open ``/dev/ttyUSB0``.

What the servos do (facts from DEVICES.md and the ROBOTIS e-manual; "modelled" marks choices
where the documents say nothing and a simple rule stands in):

* IDs, PING (Protocol 2.0 broadcast PING: every servo answers in ID order), READ, WRITE,
  REG_WRITE + ACTION (Registered Instruction flag), SYNC_READ / BULK_READ (answers in the order
  asked), SYNC_WRITE / BULK_WRITE, REBOOT, FACTORY_RESET (2.0 options 0xFF / 0x01 / 0x02; a
  broadcast reset-all is refused), CLEAR (multi-turn, Result Fail while moving).
* Status Return Level 0 (PING only), 1 (PING and reads), 2 (all); no status to broadcasts
  except PING (2.0) and the SYNC/BULK reads; Return Delay Time (2 us units) before each status,
  and one talker at a time on the half-duplex line (a status takes 10 bits per byte).
* X series: EEPROM (addresses 0-63) refused while torque is on (Access Error); read-only or
  undefined addresses (Access Error); partial multi-byte writes (Data Length Error); values out
  of range (Data Range Error) or beyond their limit registers (Data Limit Error: Goal Position
  between Min/Max Position Limit in position mode, Goal Velocity within Velocity Limit...).
  AX-12A (Protocol 1.0 has no such error numbers): such writes are refused with Range Error
  (modelled), Goal Position outside the angle limits with Angle Limit Error, and Lock (47)
  protects the EEPROM (Range Error, modelled).
* A write that changes Status Return Level is answered under the level it arrived with
  (modelled; the host driver copes with either).
* A bad CRC/checksum is answered with CRC Error / Checksum Error (status return level 2).
* Motion, with a simulated clock: position modes follow a trapezoid (Profile Velocity and
  Profile Acceleration; 0 means the Velocity Limit / no ramp); velocity mode ramps to Goal
  Velocity; Moving, Moving Status, Present Position/Velocity, Realtime Tick update. AX-12A joint
  mode moves at Moving Speed (0: full speed); wheel mode (both angle limits 0) turns at Moving
  Speed, bit 10 clockwise. Speeds never exceed the model's no-load speed. PWM and current modes
  hold still (no load model).
* Hardware errors (:meth:`EmulatedServo.inject_hardware_error`): Hardware Error Status (X) and
  the Alert bit in every status, or the AX error bits; torque off for the bits in Shutdown;
  torque cannot come back on (X: Result Fail, AX: Range Error; modelled) until REBOOT (X).
* Not modelled: indirect addresses, Drive Mode (direction, time-based profiles), Homing
  Offset, current/PWM/load physics, the AX-12A's 60 degree dead zone, collisions between two
  servos with one ID, the Bus Watchdog.
* Baud Rate and Protocol Type are obeyed: a servo set to another rate or protocol than the
  bus's stops answering, as on a real bus.
"""

from __future__ import annotations

import bisect
import logging
import math
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, TypeVar

import yaml

from hwbridge.devices.dynamixel.packets import (
    ALERT_BIT,
    BROADCAST_ID,
    CLEAR_MULTI_TURN,
    CorruptPacket,
    Error1,
    Error2,
    Instruction,
    InstructionPacket,
    PacketParser,
    StatusPacket,
    encode,
    parse_bulk_read,
    parse_bulk_write,
    parse_read,
    parse_sync_read,
    parse_sync_write,
    parse_write,
    ping_status_params,
)
from hwbridge.devices.dynamixel.servo import EmulatedServo
from hwbridge.devices.dynamixel.tables import (
    MODELS,
    UnknownModelError,
    find_model,
)
from hwbridge.errors import FramingError, HwBridgeError

__all__ = [
    "BUSES_FILE",
    "EmulatedBusRunner",
    "EmulatedDynamixelBus",
    "EmulatedServo",
    "bus_configs",
    "emulated_bus",
]

log = logging.getLogger("hwbridge.devices.dynamixel")

T = TypeVar("T")

BUSES_FILE: Final = Path(__file__).with_name("buses.yaml")
"""The ready bus descriptions (``dxl-bus``, ``dxl-bus-p1``) as YAML."""

_X_IN_PROTOCOL_1: Final[Mapping[int, int]] = {
    Error2.INSTRUCTION: Error1.INSTRUCTION,
    Error2.CRC: Error1.CHECKSUM,
}
"""An X servo set to Protocol 1.0 reports its errors as 1.0 bits (others: Range, modelled)."""
_MAX_STEPS: Final = 20000


@dataclass
class BusStats:
    """Counters of an emulated bus."""

    packets: int = 0
    corrupt: int = 0
    replies: int = 0
    ignored: int = 0
    """Packets no servo listened to (wrong ID, baud or protocol, status packets, broadcasts)."""


class EmulatedDynamixelBus:
    """Servos on one half-duplex bus, as a sans-I/O state machine (see the module docs)."""

    def __init__(
        self,
        servos: Iterable[EmulatedServo] = (),
        *,
        protocol: int = 2,
        baud: int = 57600,
        step: float = 0.001,
        name: str = "",
    ) -> None:
        if protocol not in (1, 2):
            raise ValueError(f"protocol must be 1 or 2, not {protocol!r}")
        self.protocol = protocol
        self.baud = baud
        self.name = name
        self.step = step
        self.servos: list[EmulatedServo] = list(servos)
        self.stats = BusStats()
        self.parser = PacketParser(protocol, expect="instruction", stale_after=0.05)
        self._outbox: list[tuple[float, int, bytes]] = []
        self._serial = 0
        self._line_free = -math.inf
        self._now: float | None = None

    def __repr__(self) -> str:
        ids = ", ".join(str(s.id) for s in self.servos)
        return f"<EmulatedDynamixelBus {self.name or ''} protocol {self.protocol} ids [{ids}]>"

    # ---------------------------------------------------------------- config
    @classmethod
    def from_config(cls, config: Mapping[str, Any], name: str = "") -> EmulatedDynamixelBus:
        """Build from a description: ``{protocol, baud, servos: [{id, model, settings}]}``."""
        try:
            servos = []
            for entry in config["servos"]:
                try:
                    model = find_model(entry["model"])
                except UnknownModelError as exc:
                    bus = f"emulated Dynamixel bus {name}" if name else "emulated Dynamixel bus"
                    raise UnknownModelError(f"{bus}: servo {entry.get('id')}: {exc}") from None
                servos.append(
                    EmulatedServo(
                        model,
                        int(entry["id"]),
                        firmware=entry.get("firmware"),
                        settings=entry.get("settings"),
                    )
                )
            return cls(
                servos,
                protocol=int(config.get("protocol", 2)),
                baud=int(config.get("baud", 57600)),
                name=name or str(config.get("name", "")),
            )
        except UnknownModelError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise HwBridgeError(
                f"bad emulated Dynamixel bus description {name or ''}: {exc!r}; expected "
                "protocol, baud and servos: [{id, model}] with a model in "
                f"{', '.join(MODELS)}"
            ) from exc

    def servo(self, id_: int) -> EmulatedServo:
        """The servo that has ID ``id_`` now."""
        for servo in self.servos:
            if servo.id == id_:
                return servo
        raise KeyError(f"no emulated servo with ID {id_}")

    # ------------------------------------------------------------ sans-I/O
    def feed(self, data: bytes | bytearray | memoryview, now: float) -> bytes:
        """Take the host's bytes at time ``now``; return the bytes the bus sends by then."""
        self._advance_motion(now)
        for item in self.parser.feed(data, now):
            self.stats.packets += 1
            if isinstance(item, CorruptPacket):
                self.stats.corrupt += 1
                self._corrupt(item, now)
            elif isinstance(item, InstructionPacket):
                self._handle(item, now)
            else:
                self.stats.ignored += 1
        return self._due(now)

    def advance(self, now: float) -> bytes:
        """Move the clock to ``now``; return the bytes that became due."""
        self._advance_motion(now)
        return self._due(now)

    def next_deadline(self) -> float | None:
        """When the next status goes out (None: nothing queued)."""
        return self._outbox[0][0] if self._outbox else None

    def _advance_motion(self, now: float) -> None:
        if self._now is None:
            self._now = now
        elapsed = now - self._now
        if elapsed > 0:
            steps = min(max(1, math.ceil(elapsed / self.step)), _MAX_STEPS)
            dt = elapsed / steps
            for servo in self.servos:
                if servo.torque:
                    for _ in range(steps):
                        servo.step(dt)
                else:
                    servo.velocity = 0.0
            self._now = now
        for servo in self.servos:
            servo._publish(now)

    def _due(self, now: float) -> bytes:
        out = bytearray()
        while self._outbox and self._outbox[0][0] <= now:
            out += self._outbox.pop(0)[2]
        return bytes(out)

    def _queue(self, packet: StatusPacket, at: float) -> None:
        data = encode(packet)
        start = max(at, self._line_free)
        self._line_free = start + len(data) * 10 / self.baud
        self._serial += 1
        bisect.insort(self._outbox, (start, self._serial, data))
        self.stats.replies += 1

    # ------------------------------------------------------------ dispatch
    def _listening(self, now: float) -> list[EmulatedServo]:
        return [
            s
            for s in self.servos
            if s.baud == self.baud and s.protocol == self.protocol and now >= s.listening_after
        ]

    def _status(self, servo: EmulatedServo, error: int, params: bytes = b"") -> StatusPacket:
        if self.protocol == 1 and servo.x_series and error:
            error = _X_IN_PROTOCOL_1.get(error, Error1.RANGE)
        if self.protocol == 2:
            if servo.hardware_error:
                error |= ALERT_BIT
        else:
            error |= servo.alarm
        return StatusPacket(servo.id, error, params, self.protocol)

    def _reply(
        self,
        servo: EmulatedServo,
        error: int,
        params: bytes,
        now: float,
        *,
        level: int = 2,
        current: int | None = None,
    ) -> None:
        """Queue a status if the servo's Status Return Level (``current``, default the one in
        its table now) allows ``level`` (0 ping, 1 reads, 2 all)."""
        if (servo.status_return_level if current is None else current) < level:
            return
        self._queue(self._status(servo, error, params), now + servo.return_delay)

    def _errors(self) -> tuple[int, int]:
        """(instruction error, data error) codes of this bus's protocol."""
        if self.protocol == 2:
            return Error2.INSTRUCTION, Error2.ACCESS
        return Error1.INSTRUCTION, Error1.RANGE

    def _corrupt(self, item: CorruptPacket, now: float) -> None:
        code = Error2.CRC if self.protocol == 2 else Error1.CHECKSUM
        for servo in self._listening(now):
            if servo.id == item.id:
                self._reply(servo, code, b"", now)

    def _handle(self, packet: InstructionPacket, now: float) -> None:
        listening = self._listening(now)
        broadcast = packet.id == BROADCAST_ID
        targets = listening if broadcast else [s for s in listening if s.id == packet.id]
        code = packet.instruction
        if code in (
            Instruction.SYNC_READ,
            Instruction.SYNC_WRITE,
            Instruction.BULK_READ,
            Instruction.BULK_WRITE,
        ):
            if broadcast:
                self._group(packet, listening, now)
            else:
                self.stats.ignored += 1  # group instructions go to the broadcast ID only
            return
        if not targets:
            self.stats.ignored += 1
            return
        if code == Instruction.PING:
            self._ping(packet, targets, now)
            return
        for servo in sorted(targets, key=lambda s: s.id):
            self._single(servo, packet, now, broadcast)

    def _ping(self, packet: InstructionPacket, targets: list[EmulatedServo], now: float) -> None:
        if packet.id == BROADCAST_ID:
            if self.protocol == 1:
                return  # Protocol 1.0: no status to any broadcast
            slot = 14 * 10 / self.baud
            for servo in sorted(targets, key=lambda s: s.id):
                params = ping_status_params(servo.model.number, servo.firmware)
                self._reply(servo, 0, params, now + servo.id * slot, level=0)
            return
        for servo in targets:
            params = ping_status_params(servo.model.number, servo.firmware)
            self._reply(servo, 0, params if self.protocol == 2 else b"", now, level=0)

    def _single(
        self, servo: EmulatedServo, packet: InstructionPacket, now: float, broadcast: bool
    ) -> None:
        """Execute one addressed (or broadcast) instruction on one servo."""
        bad_instruction, _ = self._errors()
        code = packet.instruction
        p = self.protocol
        quiet = broadcast  # no status to broadcasts (PING is handled elsewhere)
        current = servo.status_return_level  # a write that changes it is answered as before

        def reply(error: int, params: bytes = b"", level: int = 2) -> None:
            if not quiet:
                self._reply(servo, error, params, now, level=level, current=current)

        try:
            if code == Instruction.READ:
                address, length = parse_read(p, packet.params)
                error, data = self._read(servo, address, length)
                reply(error, data, level=1)
            elif code in (Instruction.WRITE, Instruction.REG_WRITE):
                address, data = parse_write(p, packet.params)
                if code == Instruction.WRITE:
                    error = servo.write(address, data)
                else:
                    error = servo.check_write(address, data)
                    if not error:
                        servo.registered = (address, data)
                        servo.set(servo.registered_name, 1)
                reply(error)
            elif code == Instruction.ACTION:
                if packet.params:
                    raise FramingError("ACTION takes no parameters")
                if servo.registered is None:
                    reply(bad_instruction)
                else:
                    address, data = servo.registered
                    servo.registered = None
                    servo.set(servo.registered_name, 0)
                    reply(servo.write(address, data))
            elif code == Instruction.FACTORY_RESET:
                self._factory_reset(servo, packet, broadcast, reply)
            elif code == Instruction.REBOOT and p == 2:
                reply(0)
                servo.reboot(now)
            elif code == Instruction.CLEAR and p == 2:
                if bytes(packet.params) != CLEAR_MULTI_TURN:
                    reply(bad_instruction)
                else:
                    reply(0 if servo.clear_multi_turn(now) else Error2.RESULT_FAIL)
            else:
                reply(bad_instruction)
        except FramingError as exc:
            log.debug("servo %d: malformed %s: %s", servo.id, packet.name, exc)
            reply(bad_instruction)

    def _factory_reset(
        self,
        servo: EmulatedServo,
        packet: InstructionPacket,
        broadcast: bool,
        reply: Callable[..., None],
    ) -> None:
        if self.protocol == 1:
            if packet.params:
                raise FramingError("RESET takes no parameters in Protocol 1.0")
            reply(0)
            servo.factory_reset(0xFF)
            return
        if len(packet.params) != 1 or packet.params[0] not in (0xFF, 0x01, 0x02):
            raise FramingError("FACTORY_RESET takes one option byte: 0xFF, 0x01 or 0x02")
        option = packet.params[0]
        if broadcast and option == 0xFF:
            return  # refused: everything would end up with ID 1
        reply(0)
        servo.factory_reset(option)

    def _read(self, servo: EmulatedServo, address: int, length: int) -> tuple[int, bytes]:
        _, data_error = self._errors()
        if length == 0:
            return (Error2.DATA_LENGTH if self.protocol == 2 else Error1.RANGE), b""
        if address + length > len(servo.memory):
            return data_error, b""
        return 0, bytes(servo.memory[address : address + length])

    def _group(self, packet: InstructionPacket, listening: list[EmulatedServo], now: float) -> None:
        """SYNC/BULK READ/WRITE (always broadcast)."""
        code, p = packet.instruction, self.protocol
        by_id = {s.id: s for s in listening}
        try:
            if code == Instruction.SYNC_WRITE:
                address, _, items = parse_sync_write(p, packet.params)
                for id_, data in items:
                    servo = by_id.get(id_)
                    if servo is not None:
                        servo.write(address, data)
            elif code == Instruction.BULK_WRITE and p == 2:
                for id_, address, data in parse_bulk_write(packet.params):
                    servo = by_id.get(id_)
                    if servo is not None:
                        servo.write(address, data)
            elif code == Instruction.SYNC_READ and p == 2:
                address, length, ids = parse_sync_read(p, packet.params)
                self._answer_reads([(i, address, length) for i in ids], by_id, now)
            elif code == Instruction.BULK_READ:
                reads = parse_bulk_read(p, packet.params)
                if p == 1:  # Protocol 1.0 BULK_READ is an MX feature; an AX-12A ignores it
                    reads = [i for i in reads if i[0] in by_id and by_id[i[0]].x_series]
                self._answer_reads(reads, by_id, now)
            else:
                self.stats.ignored += 1
        except FramingError as exc:
            log.debug("malformed %s: %s", packet.name, exc)
            self.stats.ignored += 1

    def _answer_reads(
        self, items: list[tuple[int, int, int]], by_id: Mapping[int, EmulatedServo], now: float
    ) -> None:
        """Each listed servo answers in the order asked, after the one before it."""
        seen: set[int] = set()
        for id_, address, length in items:
            servo = by_id.get(id_)
            if servo is None or id_ in seen:
                continue
            seen.add(id_)
            error, data = self._read(servo, address, length)
            self._reply(servo, error, data, now, level=1)


class EmulatedBusRunner:
    """Serves an :class:`EmulatedDynamixelBus` on a link (default ``pty://``) in a thread.

    Open :attr:`slave_path` as a serial port to talk to the servos. Use :meth:`call` to look at
    or change the servos while the thread runs (it holds the bus lock).
    """

    def __init__(
        self,
        bus: EmulatedDynamixelBus,
        url: str = "pty://",
        *,
        clock: Callable[[], float] = time.monotonic,
        name: str = "dxl-emulator",
    ) -> None:
        from hwbridge.links import create_link

        self.bus = bus
        self.link = create_link(url)
        self.clock = clock
        self.name = name
        self.error: BaseException | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def slave_path(self) -> str:
        path = getattr(self.link, "slave_path", None)
        if not isinstance(path, str):
            raise HwBridgeError(f"{self.link.url} has no slave path (is it a pty:// link?)")
        return path

    def start(self) -> EmulatedBusRunner:
        self.link.open()
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()
        return self

    def call(self, action: Callable[[EmulatedDynamixelBus], T]) -> T:
        """Run ``action(bus)`` with the bus lock held."""
        with self._lock:
            return action(self.bus)

    def close(self) -> None:
        """Stop the thread and close the link (idempotent)."""
        self._stop.set()
        self.link.close()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)
            self._thread = None

    def __enter__(self) -> EmulatedBusRunner:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _run(self) -> None:
        from hwbridge.links import LinkClosedError

        try:
            while not self._stop.is_set():
                with self._lock:
                    deadline = self.bus.next_deadline()
                wait = 0.005 if deadline is None else min(max(deadline - self.clock(), 0), 0.005)
                try:
                    data = self.link.read(4096, timeout=wait)
                except LinkClosedError:
                    if self._stop.is_set() or not self.link.is_open:
                        return
                    with self._lock:
                        self.bus.parser.reset()
                    continue
                with self._lock:
                    now = self.clock()
                    out = self.bus.feed(data, now) if data else self.bus.advance(now)
                if out:
                    try:
                        self.link.write(out)
                    except LinkClosedError:
                        if self._stop.is_set() or not self.link.is_open:
                            return
                        log.debug(
                            "%s: %d status bytes lost (nobody on the pty)", self.name, len(out)
                        )
        except HwBridgeError as exc:
            if not self._stop.is_set():
                log.error("%s stopped: %s", self.name, exc)
                self.error = exc


def bus_configs() -> dict[str, dict[str, Any]]:
    """The ready bus descriptions from :data:`BUSES_FILE`, by name."""
    loaded = yaml.safe_load(BUSES_FILE.read_text(encoding="utf-8"))
    if not isinstance(loaded, dict):
        raise HwBridgeError(f"{BUSES_FILE}: expected a mapping of bus names to descriptions")
    return {str(k): dict(v) for k, v in loaded.items()}


def emulated_bus(name: str) -> EmulatedDynamixelBus:
    """A new emulated bus from its ready description: ``dxl-bus`` or ``dxl-bus-p1``."""
    configs = bus_configs()
    if name not in configs:
        raise HwBridgeError(
            f"no emulated Dynamixel bus {name!r}; ready ones: {', '.join(sorted(configs))}"
        )
    return EmulatedDynamixelBus.from_config(configs[name], name)
