"""Host-side Dynamixel bus driver on a :class:`~hwbridge.links.Link` (a USB adapter's serial port).

::

    from hwbridge.devices.dynamixel import DynamixelBus

    with DynamixelBus("serial:///dev/ttyUSB0?baud=57600", protocol=2) as bus:
        print(bus.scan())                            # [PingResult(id=1, model XL430-W250 ...)]
        bus.write_register(1, "Torque Enable", 1)
        bus.set_goal_position(1, 0.5)                # radians
        print(bus.sync_read_register("Present Position", [1, 2]))

Every exchange is one instruction and the status packets it asks for, under a lock (one thread
at a time on the half-duplex line). A missing status raises
:class:`~hwbridge.errors.HwBridgeTimeoutError` naming the servo and the instruction; a status
with an error raises :class:`DynamixelStatusError` naming the error bits. The Protocol 2.0 Alert
bit (and the 1.0 voltage/overheating/overload bits) report a hardware condition, not a failed
instruction: they are logged, counted in :attr:`DynamixelBus.alerts` and the data is returned.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, Final

from hwbridge.devices.dynamixel.packets import (
    ALERT_BIT,
    BROADCAST_ID,
    MAX_ID,
    CorruptPacket,
    Error1,
    Error2,
    Instruction,
    InstructionPacket,
    PacketParser,
    StatusPacket,
    action_packet,
    bulk_read_packet,
    bulk_write_packet,
    clear_packet,
    encode,
    error_names,
    factory_reset_packet,
    instruction_name,
    parse_ping_status,
    ping_packet,
    read_packet,
    reboot_packet,
    sync_read_packet,
    sync_write_packet,
    write_packet,
)
from hwbridge.devices.dynamixel.tables import Register, ServoModel, find_model
from hwbridge.errors import FramingError, HwBridgeError, HwBridgeTimeoutError, LinkError
from hwbridge.links import Link, open_link

__all__ = [
    "BusStats",
    "DynamixelBus",
    "DynamixelStatusError",
    "PingResult",
]

log = logging.getLogger("hwbridge.devices.dynamixel")

_MAX_RETURN_DELAY: Final = 254 * 2e-6
"""Longest Return Delay Time a servo can be set to (seconds)."""
_P1_HARDWARE_BITS: Final = Error1.INPUT_VOLTAGE | Error1.OVERHEATING | Error1.OVERLOAD

_HINTS_2: Final[Mapping[int, str]] = {
    Error2.RESULT_FAIL: "the servo could not execute it",
    Error2.INSTRUCTION: "unknown instruction, or ACTION without REG_WRITE",
    Error2.CRC: "the servo received a corrupted packet",
    Error2.DATA_RANGE: "value outside the register's range",
    Error2.DATA_LENGTH: "a write must cover whole registers",
    Error2.DATA_LIMIT: "value beyond its limit register",
}


class DynamixelStatusError(HwBridgeError):
    """A servo answered with an error in its status packet.

    ``error`` is the raw ERR byte; ``names`` the errors it reports, e.g.
    ``servo 1: Access Error (EEPROM write while torque on) answering WRITE at address 11
    (Operating Mode)``.
    """

    def __init__(
        self,
        id: int,
        protocol: int,
        error: int,
        instruction: int,
        *,
        address: int | None = None,
        register: str | None = None,
        hint: str | None = None,
    ) -> None:
        self.id = id
        self.protocol = protocol
        self.error = error
        self.instruction = instruction
        self.address = address
        self.names = error_names(protocol, error & (0x7F if protocol == 2 else 0xFF))
        where = ""
        if address is not None:
            where = f" at address {address}" + (f" ({register})" if register else "")
        detail = f" ({hint})" if hint else ""
        super().__init__(
            f"servo {id}: {', '.join(self.names) or f'error 0x{error:02X}'}{detail} "
            f"answering {instruction_name(instruction)}{where}"
        )


@dataclass(frozen=True)
class PingResult:
    """A servo that answered PING: its ID, and its model and firmware when known."""

    id: int
    model_number: int | None = None
    firmware: int | None = None

    @property
    def model(self) -> ServoModel | None:
        if self.model_number is None:
            return None
        try:
            return find_model(self.model_number)
        except HwBridgeError:
            return None

    @property
    def model_name(self) -> str:
        model = self.model
        if model is not None:
            return model.name
        return "unknown model" if self.model_number is None else f"model {self.model_number}"

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "model": self.model_name}


@dataclass
class BusStats:
    """Counters of one :class:`DynamixelBus` (they only grow)."""

    instructions: int = 0
    statuses: int = 0
    timeouts: int = 0
    retries: int = 0
    corrupt: int = 0
    """Status packets with a bad CRC/checksum."""
    unexpected: int = 0
    """Status packets nobody waited for (late answers, other IDs) and echoed instructions."""
    errors: int = 0
    """Status packets that reported an error."""


class _CorruptReply(FramingError):
    pass


@dataclass
class _Exchange:
    """What one instruction waits for."""

    packet: InstructionPacket
    ids: list[int]
    reply_bytes: int = 0
    window: float | None = None
    """Collect every status until this many seconds pass (broadcast PING)."""


class DynamixelBus:
    """A Dynamixel bus behind a link (see the module documentation).

    ``link`` is an open :class:`~hwbridge.links.Link` (left open by :meth:`close` unless
    ``owns_link``) or a URL that the bus opens and closes. ``timeout`` is how long to wait for
    a status beyond the time its bytes take at the link's baud rate; ``retries`` resends on a
    timeout or a corrupt status. ``status_return_level`` is what the servos are assumed to be
    set to (per-ID values in :attr:`status_return_levels`; writing the register through this
    bus updates them).
    ``models`` maps IDs to model names to skip detection.
    """

    def __init__(
        self,
        link: Link | str,
        protocol: int = 2,
        *,
        timeout: float = 0.05,
        retries: int = 0,
        baud: int | None = None,
        status_return_level: int = 2,
        models: Mapping[int, str | int | ServoModel] | None = None,
        clock: Callable[[], float] = time.monotonic,
        owns_link: bool | None = None,
    ) -> None:
        if protocol not in (1, 2):
            raise ValueError(f"protocol must be 1 or 2, not {protocol!r}")
        if isinstance(link, str):
            self.link: Link = open_link(link)
            self._owns_link = True
        elif isinstance(link, Link):
            self.link = link
            self._owns_link = False
        else:
            raise TypeError(f"link must be a Link or a URL, not {type(link).__name__}")
        if owns_link is not None:
            self._owns_link = owns_link
        self.protocol = protocol
        self.timeout = timeout
        self.retries = retries
        self.baud: int | None = baud if baud is not None else getattr(self.link, "baud", None)
        self.default_status_return_level = status_return_level
        self.status_return_levels: dict[int, int] = {}
        self.stats = BusStats()
        self.alerts: dict[int, int] = {}
        """IDs whose last status reported a hardware condition, with the ERR byte."""
        self._clock = clock
        self._lock = threading.RLock()
        self._parser = PacketParser(protocol, expect="status")
        self._models: dict[int, ServoModel] = {}
        for id_, model in (models or {}).items():
            self.set_model(id_, model)

    def __repr__(self) -> str:
        return f"<DynamixelBus protocol {self.protocol} on {self.link.url}>"

    def close(self) -> None:
        """Close the link if this bus opened it."""
        if self._owns_link:
            self.link.close()

    def __enter__(self) -> DynamixelBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- instructions
    def ping(self, id: int, *, identify: bool = True) -> PingResult:
        """PING ``id``; Protocol 2.0 replies carry the model and firmware, on 1.0 they are read
        from the control table (addresses 0-2) when ``identify`` (None if that fails)."""
        self._check_id(id)
        status = self._one(ping_packet(self.protocol, id), reply_bytes=14)
        if self.protocol == 2:
            model, firmware = parse_ping_status(status.params)
            return PingResult(id, model, firmware)
        if not identify:
            return PingResult(id)
        try:
            data = self.read(id, 0, 3)
        except HwBridgeError as exc:
            log.debug("servo %d: cannot read its model number: %s", id, exc)
            return PingResult(id)
        return PingResult(id, data[0] | data[1] << 8, data[2])

    def broadcast_ping(self, ids: Iterable[int] | None = None) -> list[PingResult]:
        """Protocol 2.0 broadcast PING: every servo answers in ID order. ``ids`` only bounds how
        long to wait (up to the highest one) and filters the result."""
        if self.protocol != 2:
            raise HwBridgeError("broadcast PING needs Protocol 2.0; use scan() on 1.0")
        wanted = sorted(set(ids)) if ids is not None else list(range(MAX_ID[2] + 1))
        top = wanted[-1] if wanted else 0
        slot = self._byte_time(14) + _MAX_RETURN_DELAY
        exchange = _Exchange(ping_packet(2, BROADCAST_ID), [], window=(top + 1) * slot)
        statuses = self._run(exchange)
        results = []
        for status in sorted(statuses.values(), key=lambda s: s.id):
            if status.id in wanted:
                self._check(status, Instruction.PING)
                model, firmware = parse_ping_status(status.params)
                results.append(PingResult(status.id, model, firmware))
        return results

    def scan(self, ids: Iterable[int] | None = None) -> list[PingResult]:
        """Find the servos among ``ids`` (default: every ID): one broadcast PING on 2.0, a
        PING per ID on 1.0."""
        wanted = sorted(set(ids)) if ids is not None else list(range(MAX_ID[self.protocol] + 1))
        for id_ in wanted:
            self._check_id(id_)
        if self.protocol == 2:
            return self.broadcast_ping(wanted)
        found = []
        for id_ in wanted:
            try:
                found.append(self.ping(id_))
            except HwBridgeTimeoutError:
                continue
        return found

    def read(self, id: int, address: int, length: int) -> bytes:
        """READ ``length`` bytes at ``address``."""
        self._check_id(id)
        packet = read_packet(self.protocol, id, address, length)
        status = self._one(packet, reply_bytes=self._status_size(length), level=1)
        self._check(status, Instruction.READ, id, address)
        if len(status.params) != length:
            raise FramingError(
                f"servo {id}: READ of {length} bytes at {address} returned {len(status.params)}"
            )
        return bytes(status.params)

    def write(self, id: int, address: int, data: bytes) -> None:
        """WRITE ``data`` at ``address`` (no wait when ``id`` is the broadcast ID)."""
        self._write(id, address, bytes(data), registered=False)

    def reg_write(self, id: int, address: int, data: bytes) -> None:
        """REG_WRITE: the servo keeps the write until :meth:`action`."""
        self._write(id, address, bytes(data), registered=True)

    def action(self, id: int = BROADCAST_ID) -> None:
        """ACTION: execute the registered writes (all servos by default)."""
        self._simple(action_packet(self.protocol, id), Instruction.ACTION)

    def reboot(self, id: int) -> None:
        """REBOOT (Protocol 2.0): RAM back to defaults, hardware errors cleared."""
        self._need_2("REBOOT")
        self._simple(reboot_packet(2, id), Instruction.REBOOT)
        self.alerts.pop(id, None)

    def factory_reset(self, id: int, option: int = 0xFF) -> None:
        """FACTORY_RESET (RESET on 1.0); 2.0 ``option``: 0xFF all (ID becomes 1), 0x01 all but
        ID, 0x02 all but ID and baud rate."""
        self._simple(factory_reset_packet(self.protocol, id, option), Instruction.FACTORY_RESET)
        self._models.pop(id, None)
        self.status_return_levels.pop(id, None)

    def clear_multi_turn(self, id: int) -> None:
        """CLEAR (Protocol 2.0): Present Position back within one turn (servo stopped)."""
        self._need_2("CLEAR")
        self._simple(clear_packet(id), Instruction.CLEAR)

    def sync_read(self, address: int, length: int, ids: Sequence[int]) -> dict[int, bytes]:
        """SYNC_READ (Protocol 2.0): the same ``length`` bytes at ``address`` of every ID
        (IDs believed to be at Status Return Level 0 do not answer and are left out)."""
        self._need_2("SYNC_READ")
        ids = list(ids)
        for id_ in ids:
            self._check_id(id_)
        packet = sync_read_packet(2, address, length, ids)
        expected = [i for i in ids if self._level(i) >= 1]
        statuses = self._run(_Exchange(packet, expected, len(expected) * self._status_size(length)))
        out = {}
        for id_ in expected:
            status = statuses[id_]
            self._check(status, Instruction.SYNC_READ, id_, address)
            out[id_] = bytes(status.params)
        return out

    def sync_write(self, address: int, length: int, data: Mapping[int, bytes]) -> None:
        """SYNC_WRITE: ``length`` bytes at ``address`` for each ID (no status replies)."""
        packet = sync_write_packet(self.protocol, address, length, data)
        self._run(_Exchange(packet, []))

    def bulk_read(self, items: Sequence[tuple[int, int, int]]) -> dict[int, bytes]:
        """BULK_READ: ``(id, address, length)`` per servo (Protocol 1.0: MX series only)."""
        items = list(items)
        packet = bulk_read_packet(self.protocol, items)
        expected = [i for i, _, _ in items if self._level(i) >= 1]
        size = sum(self._status_size(n) for i, _, n in items if i in expected)
        statuses = self._run(_Exchange(packet, expected, size))
        out = {}
        for id_, address, _ in items:
            if id_ in statuses:
                self._check(statuses[id_], Instruction.BULK_READ, id_, address)
                out[id_] = bytes(statuses[id_].params)
        return out

    def bulk_write(self, items: Sequence[tuple[int, int, bytes]]) -> None:
        """BULK_WRITE (Protocol 2.0): ``(id, address, data)`` per servo, no status replies."""
        self._need_2("BULK_WRITE")
        self._run(_Exchange(bulk_write_packet(items), []))

    # ---------------------------------------------------------------- typed helpers
    def set_model(self, id: int, model: str | int | ServoModel) -> None:
        """Tell the bus which model ``id`` is (skips detection)."""
        self._models[id] = model if isinstance(model, ServoModel) else find_model(model)

    def model(self, id: int) -> ServoModel:
        """The model of servo ``id`` (asked once: PING on 2.0, Model Number on 1.0)."""
        known = self._models.get(id)
        if known is not None:
            return known
        if self.protocol == 2:
            number = self.ping(id).model_number
        else:
            data = self.read(id, 0, 2)
            number = data[0] | data[1] << 8
        if number is None:  # pragma: no cover - a 2.0 ping always has it
            raise HwBridgeError(f"servo {id}: its model number is unknown")
        try:
            model = find_model(number)
        except HwBridgeError as exc:
            raise HwBridgeError(
                f"servo {id} reports model number {number}, which has no control table here "
                "(use a raw address, or give models={id: name})"
            ) from exc
        self._models[id] = model
        return model

    def register(self, id: int, name: str | int) -> Register:
        """The register ``name`` (or the one starting at address ``name``) of ``id``'s model."""
        model = self.model(id)
        if isinstance(name, int):
            register = model.table.at(name)
            if register is None:
                raise HwBridgeError(
                    f"servo {id} ({model.name}): no register starts at address {name}"
                )
            return register
        return model.table[name]

    def read_register(self, id: int, name: str | int) -> int:
        """A register's value (signed where the register is)."""
        register = self.register(id, name)
        return register.decode(self.read(id, register.address, register.size))

    def write_register(self, id: int, name: str | int, value: int) -> None:
        """Write a register; ValueError when ``value`` does not fit it."""
        register = self.register(id, name)
        self.write(id, register.address, register.encode(value))

    def sync_read_register(self, name: str, ids: Sequence[int]) -> dict[int, int]:
        """One register of several servos (same model family): SYNC_READ on 2.0, READs on 1.0."""
        ids = list(ids)
        if not ids:
            return {}
        register = self.register(ids[0], name)
        if self.protocol == 2:
            raw = self.sync_read(register.address, register.size, ids)
            return {i: register.decode(raw[i]) for i in ids}
        return {i: register.decode(self.read(i, register.address, register.size)) for i in ids}

    def sync_write_register(self, name: str, values: Mapping[int, int]) -> None:
        """One register of several servos in one SYNC_WRITE."""
        if not values:
            return
        register = self.register(next(iter(values)), name)
        data = {i: register.encode(v) for i, v in values.items()}
        self.sync_write(register.address, register.size, data)

    def set_torque(self, id: int, enabled: bool) -> None:
        self.write_register(id, "Torque Enable", int(enabled))

    def torque_enabled(self, id: int) -> bool:
        return bool(self.read_register(id, "Torque Enable"))

    def position(self, id: int) -> float:
        """Present Position in radians (see :class:`ServoModel` for the zero and scale)."""
        return self.model(id).ticks_to_radians(self.read_register(id, "Present Position"))

    def set_goal_position(self, id: int, radians: float) -> None:
        model = self.model(id)
        self.write_register(id, "Goal Position", model.radians_to_ticks(radians))

    def velocity(self, id: int) -> float:
        """Present Velocity (X) / Present Speed (AX) in rad/s."""
        model = self.model(id)
        name = "Present Velocity" if model.series == "X" else "Present Speed"
        return model.velocity_to_rad_s(self.read_register(id, name))

    def set_goal_velocity(self, id: int, rad_s: float) -> None:
        """Goal Velocity (X, velocity mode) or Moving Speed (AX) in rad/s."""
        model = self.model(id)
        name = "Goal Velocity" if model.series == "X" else "Moving Speed"
        self.write_register(id, name, model.rad_s_to_velocity(rad_s))

    # ---------------------------------------------------------------- internals
    def _check_id(self, id_: int) -> None:
        top = MAX_ID[self.protocol]
        if not 0 <= id_ <= top:
            raise ValueError(f"Protocol {self.protocol}.0 servo IDs are 0-{top}, not {id_}")

    def _need_2(self, what: str) -> None:
        if self.protocol != 2:
            raise HwBridgeError(f"{what} is a Protocol 2.0 instruction; this bus speaks 1.0")

    def _level(self, id_: int) -> int:
        return self.status_return_levels.get(id_, self.default_status_return_level)

    def _status_size(self, params: int) -> int:
        return params + (11 if self.protocol == 2 else 6)

    def _byte_time(self, count: int) -> float:
        return count * 10 / self.baud if self.baud else 0.0

    def _write(self, id_: int, address: int, data: bytes, *, registered: bool) -> None:
        if id_ != BROADCAST_ID:
            self._check_id(id_)
        packet = write_packet(self.protocol, id_, address, data, registered=registered)
        code = Instruction.REG_WRITE if registered else Instruction.WRITE
        srl = self._status_return_level_write(id_, address, data)
        if id_ == BROADCAST_ID or self._level(id_) < 2:
            self._run(_Exchange(packet, []))
        else:
            try:
                status = self._one(packet, reply_bytes=self._status_size(0))
            except HwBridgeTimeoutError:
                if srl is None or srl >= 2:
                    raise
                status = None  # the servo may already obey its new level
            if status is not None:
                self._check(status, code, id_, address)
        if srl is not None and not registered:
            if id_ == BROADCAST_ID:
                self.default_status_return_level = srl
                self.status_return_levels.clear()
            else:
                self.status_return_levels[id_] = srl

    def _status_return_level_write(self, id_: int, address: int, data: bytes) -> int | None:
        """The new Status Return Level when this write sets it, else None."""
        srl_address = 68 if self.protocol == 2 else 16
        model = self._models.get(id_)
        if model is not None:
            register = model.table.get("Status Return Level")
            srl_address = register.address if register is not None else srl_address
        if address <= srl_address < address + len(data):
            return data[srl_address - address]
        return None

    def _simple(self, packet: InstructionPacket, code: int) -> None:
        if packet.id == BROADCAST_ID or self._level(packet.id) < 2:
            self._run(_Exchange(packet, []))
            return
        self._check(self._one(packet, reply_bytes=self._status_size(0)), code, packet.id)

    def _one(self, packet: InstructionPacket, *, reply_bytes: int, level: int = 0) -> StatusPacket:
        """Send ``packet`` to one servo and return its status."""
        if self._level(packet.id) < level:
            raise HwBridgeError(
                f"servo {packet.id} is set to Status Return Level {self._level(packet.id)}: it "
                f"does not answer {packet.name}; set it to {level} or more"
            )
        return self._run(_Exchange(packet, [packet.id], reply_bytes))[packet.id]

    def _run(self, exchange: _Exchange) -> dict[int, StatusPacket]:
        """Send, and collect the statuses the exchange waits for, with retries."""
        with self._lock:
            attempt = 0
            while True:
                try:
                    return self._once(exchange)
                except (HwBridgeTimeoutError, _CorruptReply):
                    if attempt >= self.retries:
                        raise
                    attempt += 1
                    self.stats.retries += 1
                    log.debug(
                        "retry %d of %s to %d", attempt, exchange.packet.name, exchange.packet.id
                    )

    def _drain(self) -> None:
        """Drop whatever is waiting on the line (late answers of an earlier exchange)."""
        while True:
            data = self.link.read(4096, timeout=0)
            if not data:
                break
            for item in self._parser.feed(data):
                self._count_stray(item)
        self._parser.reset()

    def _count_stray(self, item: StatusPacket | InstructionPacket | CorruptPacket) -> None:
        if isinstance(item, CorruptPacket):
            self.stats.corrupt += 1
        else:
            self.stats.unexpected += 1

    def _once(self, exchange: _Exchange) -> dict[int, StatusPacket]:
        packet = exchange.packet
        raw = encode(packet)
        try:
            self._drain()
            self.link.write(raw)
        except LinkError as exc:
            raise LinkError(f"{packet.name} to servo {packet.id}: {exc}") from exc
        self.stats.instructions += 1
        pending = list(exchange.ids)
        got: dict[int, StatusPacket] = {}
        if not pending and exchange.window is None:
            return got
        start = self._clock()
        if exchange.window is not None:
            deadline = start + self._byte_time(len(raw)) + exchange.window + self.timeout
        else:
            deadline = (
                start
                + self.timeout
                + self._byte_time(len(raw) + exchange.reply_bytes)
                + len(pending) * _MAX_RETURN_DELAY
            )
        while pending or exchange.window is not None:
            remaining = deadline - self._clock()
            if remaining <= 0:
                break
            try:
                data = self.link.read(4096, timeout=remaining)
            except LinkError as exc:
                raise LinkError(f"waiting for servo {packet.id}'s status: {exc}") from exc
            for item in self._parser.feed(data):
                if isinstance(item, StatusPacket) and (
                    item.id in pending or (exchange.window is not None and item.id not in got)
                ):
                    self.stats.statuses += 1
                    got[item.id] = item
                    if item.id in pending:
                        pending.remove(item.id)
                elif isinstance(item, CorruptPacket) and item.id in pending:
                    self.stats.corrupt += 1
                    raise _CorruptReply(
                        f"servo {item.id}: corrupt status for {packet.name} ({item.reason})"
                    )
                else:
                    self._count_stray(item)
        if pending:
            self.stats.timeouts += 1
            raise HwBridgeTimeoutError(self._timeout_message(packet, pending, got))
        return got

    def _timeout_message(
        self, packet: InstructionPacket, pending: list[int], got: Mapping[int, StatusPacket]
    ) -> str:
        waited = self.timeout
        who = (
            f"servo {pending[0]}"
            if len(pending) == 1
            else f"servos {', '.join(str(i) for i in pending)}"
        )
        partial = f" (answered: {', '.join(str(i) for i in got)})" if got else ""
        baud = f" at {self.baud} baud" if self.baud else ""
        return (
            f"{who}: no status packet for {packet.name} within {waited:g} s{partial}; check "
            f"power, wiring, the ID, Protocol {self.protocol}.0{baud} and the Status Return Level"
        )

    def _check(
        self,
        status: StatusPacket,
        instruction: int,
        id_: int | None = None,
        address: int | None = None,
    ) -> None:
        """Raise DynamixelStatusError for a failed instruction; note hardware alerts."""
        error = status.error
        if self.protocol == 2:
            failure = error & 0x7F
            alert = error & ALERT_BIT
        else:
            failure = error & ~_P1_HARDWARE_BITS & 0xFF
            alert = error & _P1_HARDWARE_BITS
        if alert:
            if status.id not in self.alerts:
                log.warning(
                    "servo %d reports %s", status.id, ", ".join(error_names(self.protocol, alert))
                )
            self.alerts[status.id] = error
        else:
            self.alerts.pop(status.id, None)
        if not failure:
            return
        self.stats.errors += 1
        register = None
        model = self._models.get(status.id)
        if address is not None and model is not None:
            found = model.table.covering(address)
            register = found.name if found is not None else None
        raise DynamixelStatusError(
            status.id,
            self.protocol,
            failure,
            instruction,
            address=address,
            register=register,
            hint=self._hint(failure, instruction, address, model),
        )

    def _hint(
        self, failure: int, instruction: int, address: int | None, model: ServoModel | None
    ) -> str | None:
        if self.protocol == 1:
            if failure & Error1.ANGLE_LIMIT:
                return "Goal Position outside the CW/CCW Angle Limits"
            if failure & Error1.RANGE:
                return "value, address or instruction out of range"
            if failure & Error1.INSTRUCTION:
                return "unknown instruction, or ACTION without REG_WRITE"
            return None
        if failure == Error2.ACCESS:
            if instruction not in (Instruction.WRITE, Instruction.REG_WRITE) or address is None:
                return "read of an undefined address"
            eeprom_end = model.eeprom_end if model is not None else 64
            register = model.table.covering(address) if model is not None else None
            if register is not None and not register.writable:
                return "read-only register"
            if address < eeprom_end:
                return "EEPROM write while torque on"
            return "read-only or undefined address"
        return _HINTS_2.get(failure)
