"""One emulated Dynamixel servo: its control-table memory, the rules of writes, and motion.

:class:`~hwbridge.devices.dynamixel.emulator.EmulatedDynamixelBus` puts servos on a bus and
answers packets; what they model and what they leave out is listed in that module's docs.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Final

from hwbridge.devices.dynamixel.framing import Error1, Error2
from hwbridge.devices.dynamixel.tables import Register, ServoModel, find_model

__all__ = ["EmulatedServo"]

_REBOOT_TIME: Final = 0.1
"""Seconds a rebooting servo does not listen (modelled)."""


def _sign(value: float) -> float:
    return (value > 0) - (value < 0)


class EmulatedServo:
    """One servo: its control-table memory and a simple motion model.

    ``settings`` overrides initial values by register name (``{"Return Delay Time": 0}``),
    written straight into memory. :meth:`get` / :meth:`set` read and write registers without
    any checks (for tests and fault injection); the bus applies the real rules to packets.
    """

    def __init__(
        self,
        model: ServoModel | str | int,
        id: int = 1,
        *,
        firmware: int | None = None,
        settings: Mapping[str, int] | None = None,
        temperature: int = 32,
        voltage: int | None = None,
    ) -> None:
        self.model = model if isinstance(model, ServoModel) else find_model(model)
        self.firmware = self.model.firmware if firmware is None else firmware
        self.temperature = temperature
        self.voltage = (
            voltage if voltage is not None else (120 if self.model.series == "X" else 110)
        )
        self.memory = bytearray(self.model.table.size)
        self.position = float(self.model.zero_tick)
        """Shaft position in ticks (continuous; multi-turn in the X velocity and extended modes)."""
        self.velocity = 0.0
        """Ticks per second."""
        self.alarm = 0
        """AX-12A hardware error bits (Error1) reported in every status."""
        self.registered: tuple[int, bytes] | None = None
        self.listening_after = -math.inf
        self._reset_memory(keep=())
        self.set("ID", id)
        for name, value in (settings or {}).items():
            self.set(name, value)
        self._publish(0.0)

    # -------------------------------------------------------------- registers
    def __repr__(self) -> str:
        return f"<EmulatedServo {self.model.name} id={self.id}>"

    def register(self, name: str) -> Register:
        return self.model.table[name]

    def get(self, name: str) -> int:
        """A register's value (no access check)."""
        reg = self.model.table[name]
        return reg.decode(bytes(self.memory[reg.address : reg.end]))

    def set(self, name: str, value: int) -> None:
        """Write a register straight into memory (no checks, no side effects)."""
        reg = self.model.table[name]
        self.memory[reg.address : reg.end] = reg.encode(value)

    @property
    def id(self) -> int:
        return self.get("ID")

    @property
    def x_series(self) -> bool:
        return self.model.series == "X"

    @property
    def registered_name(self) -> str:
        """The register that flags a pending REG_WRITE."""
        return "Registered Instruction" if self.x_series else "Registered"

    @property
    def protocol(self) -> int:
        return self.get("Protocol Type") if self.x_series else 1

    @property
    def baud(self) -> int:
        return self.model.baud_of(self.get("Baud Rate"))

    @property
    def status_return_level(self) -> int:
        return self.get("Status Return Level")

    @property
    def return_delay(self) -> float:
        """Seconds between the end of an instruction and the start of the status."""
        return self.get("Return Delay Time") * 2e-6

    @property
    def torque(self) -> bool:
        return bool(self.get("Torque Enable"))

    @property
    def wheel_mode(self) -> bool:
        """AX-12A: both angle limits 0."""
        return (
            not self.x_series
            and self.get("CW Angle Limit") == 0
            and self.get("CCW Angle Limit") == 0
        )

    @property
    def hardware_error(self) -> int:
        return self.get("Hardware Error Status") if self.x_series else self.alarm

    def inject_hardware_error(self, bits: int) -> None:
        """Raise hardware error ``bits`` (X: Hardware Error Status bits; AX: Error1 bits, e.g.
        ``Error1.OVERHEATING``); torque goes off when ``bits`` meet the Shutdown register."""
        if self.x_series:
            self.set("Hardware Error Status", self.get("Hardware Error Status") | bits)
        else:
            self.alarm |= bits
        if bits & self.get("Shutdown"):
            self.set("Torque Enable", 0)
            self.velocity = 0.0

    def _reset_memory(self, keep: Iterable[str]) -> None:
        """Every register to its initial value, except the ones in ``keep``."""
        kept = {name: self.get(name) for name in keep}
        for reg in self.model.table.registers:
            self.memory[reg.address : reg.end] = reg.encode(reg.default)
        self.set("Model Number", self.model.number)
        self.set("Firmware Version", self.firmware)
        for name, value in kept.items():
            self.set(name, value)
        self._hold()

    def _reset_ram(self) -> None:
        self._reset_memory(keep=[r.name for r in self.model.table.registers if r.eeprom])

    def _hold(self) -> None:
        """Goal Position := where the shaft is (torque on, reboot)."""
        if self._position_control():
            self.set("Goal Position", round(self.position))
        self.velocity = 0.0

    def _position_control(self) -> bool:
        if self.x_series:
            return self.get("Operating Mode") in (3, 4, 5)
        return not self.wheel_mode

    # ------------------------------------------------------------------ motion
    def _ticks_per_s(self, rpm: float) -> float:
        return rpm * self.model.ticks_per_turn / 60.0

    def _max_speed(self) -> float:
        return self._ticks_per_s(self.model.max_speed_rpm)

    def step(self, dt: float) -> None:
        """Advance the motion by ``dt`` seconds."""
        if dt <= 0:
            return
        if not self.torque:
            self.velocity = 0.0
            return
        if self.x_series:
            self._step_x(dt)
        else:
            self._step_ax(dt)

    def _step_x(self, dt: float) -> None:
        mode = self.get("Operating Mode")
        unit = self.model.velocity_unit_rpm
        limit = self._ticks_per_s(self.get("Velocity Limit") * unit)
        top = min(limit, self._max_speed())
        accel_units = self.get("Profile Acceleration")
        accel = self._ticks_per_s(accel_units * 214.577 / 60.0) if accel_units else math.inf
        if mode in (3, 4, 5):
            profile = self.get("Profile Velocity")
            vmax = min(self._ticks_per_s(profile * unit), top) if profile else top
            self._track(float(self.get("Goal Position")), vmax, accel, dt)
        elif mode == 1:
            goal = self._ticks_per_s(self.get("Goal Velocity") * unit)
            goal = max(-top, min(top, goal))
            self._ramp(goal, accel, dt)
            self.position += self.velocity * dt
        else:
            self.velocity = 0.0

    def _step_ax(self, dt: float) -> None:
        speed = self.get("Moving Speed")
        magnitude = speed & 0x3FF
        top = self._max_speed()
        rate = min(self._ticks_per_s(magnitude * self.model.velocity_unit_rpm), top)
        if self.wheel_mode:
            self.velocity = -rate if speed & 0x400 else rate
            self.position = (self.position + self.velocity * dt) % 1024
        else:
            self._track(float(self.get("Goal Position")), rate if magnitude else top, math.inf, dt)

    def _ramp(self, goal: float, accel: float, dt: float) -> None:
        change = goal - self.velocity
        most = accel * dt
        self.velocity = goal if abs(change) <= most else self.velocity + _sign(change) * most

    def _track(self, target: float, vmax: float, accel: float, dt: float) -> None:
        """Trapezoid towards ``target``: brake in time, never overshoot."""
        distance = target - self.position
        if abs(distance) < 1e-9 and self.velocity == 0.0:
            return
        wanted = _sign(distance) * min(
            vmax, math.sqrt(2 * accel * abs(distance)) if accel != math.inf else vmax
        )
        self._ramp(wanted, accel, dt)
        move = self.velocity * dt
        if (move and _sign(move) == _sign(distance) and abs(move) >= abs(distance)) or (
            abs(distance) < 1e-6
        ):
            self.position = target
            self.velocity = 0.0
        else:
            self.position += move

    def _moving(self) -> bool:
        if not self.torque:
            return False
        if self._position_control():
            return abs(float(self.get("Goal Position")) - self.position) >= 0.5 or bool(
                self.velocity
            )
        return bool(self.velocity)

    def _publish(self, now: float) -> None:
        """Write the present values into the control table."""
        velocity_units = round(
            self.velocity * 60.0 / self.model.ticks_per_turn / self.model.velocity_unit_rpm
        )
        if self.x_series:
            position = round(self.position)
            self.set("Present Position", position)
            self.set("Position Trajectory", position)
            self.set("Present Velocity", velocity_units)
            self.set("Velocity Trajectory", velocity_units)
            threshold = self.get("Moving Threshold")
            moving = self._moving() and (
                abs(velocity_units) > threshold or self._position_control()
            )
            self.set("Moving", int(moving))
            in_position = not moving and self.torque
            self.set("Moving Status", (1 if in_position else 0) | (2 if moving else 0))
            self.set("Realtime Tick", int(now * 1000) % 32768)
            self.set("Present Input Voltage", self.voltage)
            self.set("Present Temperature", self.temperature)
        else:
            speed = min(abs(velocity_units), 0x3FF) | (0x400 if self.velocity < 0 else 0)
            self.set("Present Position", max(0, min(1023, round(self.position))))
            self.set("Present Speed", speed)
            self.set("Moving", int(self._moving()))
            self.set("Present Voltage", self.voltage)
            self.set("Present Temperature", self.temperature)

    # ------------------------------------------------------------------ rules
    def check_write(self, address: int, data: bytes) -> int:
        """The error a WRITE of ``data`` at ``address`` earns (0: accepted)."""
        return self._check_x(address, data) if self.x_series else self._check_ax(address, data)

    def _touched(self, address: int, data: bytes) -> tuple[list[Register], bool, bool]:
        """Registers a write touches, whether every byte is defined, whether it is aligned."""
        table = self.model.table
        regs: list[Register] = []
        defined = True
        for addr in range(address, address + len(data)):
            reg = table.covering(addr)
            if reg is None:
                defined = False
            elif not regs or regs[-1] is not reg:
                regs.append(reg)
        aligned = bool(regs) and regs[0].address == address and regs[-1].end == address + len(data)
        return regs, defined, aligned

    def _merged(self, address: int, data: bytes, reg: Register) -> int:
        image = bytearray(self.memory[reg.address : reg.end])
        for offset in range(reg.size):
            addr = reg.address + offset
            if address <= addr < address + len(data):
                image[offset] = data[addr - address]
        return reg.decode(bytes(image))

    def _limits(self, reg: Register, address: int, data: bytes) -> tuple[int, int] | None:
        if reg.limit is None:
            return None
        low_name, high_name = reg.limit
        table = self.model.table
        high = self._merged(address, data, table[high_name])
        low = -high if low_name == high_name else self._merged(address, data, table[low_name])
        return low, high

    def _check_x(self, address: int, data: bytes) -> int:
        regs, defined, aligned = self._touched(address, data)
        if not defined or not regs or any(not r.writable for r in regs):
            return Error2.ACCESS
        if not aligned:
            return Error2.DATA_LENGTH
        if self.torque and any(r.eeprom for r in regs):
            return Error2.ACCESS
        mode = self.get("Operating Mode")
        for reg in regs:
            value = self._merged(address, data, reg)
            if reg.allowed is not None and value not in reg.allowed:
                return Error2.DATA_RANGE
            if not reg.in_range(value):
                return Error2.DATA_RANGE
            if reg.name == "Goal Position" and mode != 3:
                if abs(value) > 1_048_575:
                    return Error2.DATA_RANGE
                continue
            limits = self._limits(reg, address, data)
            if limits is not None and not limits[0] <= value <= limits[1]:
                return Error2.DATA_LIMIT
            if reg.name == "Torque Enable" and value and self.hardware_error & self.get("Shutdown"):
                return Error2.RESULT_FAIL
        return 0

    def _check_ax(self, address: int, data: bytes) -> int:
        regs, defined, _ = self._touched(address, data)
        if not defined or not regs or any(not r.writable for r in regs):
            return Error1.RANGE
        if self.get("Lock") and any(r.eeprom for r in regs):
            return Error1.RANGE
        for reg in regs:
            value = self._merged(address, data, reg)
            if not reg.in_range(value):
                return Error1.RANGE
            if reg.name == "Goal Position":
                cw = self._merged(address, data, self.register("CW Angle Limit"))
                ccw = self._merged(address, data, self.register("CCW Angle Limit"))
                if (cw or ccw) and not cw <= value <= ccw:
                    return Error1.ANGLE_LIMIT
            if reg.name == "Torque Enable" and value and self.alarm & self.get("Shutdown"):
                return Error1.RANGE
        return 0

    def write(self, address: int, data: bytes) -> int:
        """:meth:`check_write`, then :meth:`apply_write` if accepted; the error (0: written)."""
        error = self.check_write(address, data)
        if not error:
            self.apply_write(address, data)
        return error

    def apply_write(self, address: int, data: bytes) -> None:
        """Store a checked write and apply its side effects."""
        torque_before = self.torque
        mode_before = self.get("Operating Mode") if self.x_series else 0
        self.memory[address : address + len(data)] = data
        if self.torque and not torque_before:
            self._hold()
        if not self.torque:
            self.velocity = 0.0
        if self.x_series and self.get("Operating Mode") != mode_before:
            self.velocity = 0.0

    def factory_reset(self, option: int) -> None:
        """0xFF everything (ID 1), 0x01 all but ID, 0x02 all but ID and baud rate."""
        keep = {0x01: ("ID",), 0x02: ("ID", "Baud Rate")}.get(option, ())
        self._reset_memory(keep=keep)
        self.registered = None
        self.alarm = 0

    def clear_multi_turn(self, now: float) -> bool:
        """CLEAR: Present Position back within one turn; False (refused) while moving."""
        if self._moving() or self.velocity:
            return False
        self.position = self.position % 4096
        self._hold()
        self._publish(now)
        return True

    def reboot(self, now: float) -> None:
        """RAM back to initial values, hardware errors cleared, deaf for a moment."""
        self._reset_ram()
        self.registered = None
        self.listening_after = now + _REBOOT_TIME
