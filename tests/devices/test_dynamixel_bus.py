"""The host bus driver against the emulated bus through a real pty (a thread serves it)."""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest

from hwbridge.devices.dynamixel import (
    DynamixelBus,
    DynamixelStatusError,
    EmulatedDynamixelBus,
    PingResult,
)
from hwbridge.errors import FramingError, HwBridgeError, HwBridgeTimeoutError
from hwbridge.links import Link
from tests.devices.dxl_helpers import Bench, bench


@pytest.fixture
def p2() -> Iterator[Bench]:
    with bench("dxl-bus") as b:
        yield b


@pytest.fixture
def p1() -> Iterator[Bench]:
    with bench("dxl-bus-p1") as b:
        yield b


def servo_get(b: Bench, id_: int, name: str) -> int:
    return b.runner.call(lambda bus: bus.servo(id_).get(name))


def test_scan_protocol_2_finds_both_servos(p2: Bench) -> None:
    found = p2.bus.scan(range(0, 21))
    assert found == [PingResult(1, 1060, 45), PingResult(2, 1060, 45)]
    assert [r.model_name for r in found] == ["XL430-W250", "XL430-W250"]
    assert p2.bus.stats.instructions == 1  # one broadcast PING


def test_scan_protocol_1_finds_both_servos(p1: Bench) -> None:
    p1.bus.timeout = 0.1
    found = p1.bus.scan([0, 1, 2, 3])
    assert [(r.id, r.model_name) for r in found] == [(1, "AX-12A"), (2, "AX-12A")]
    assert p1.bus.stats.timeouts == 2  # IDs 0 and 3
    with pytest.raises(HwBridgeError, match=r"broadcast PING needs Protocol 2\.0"):
        p1.bus.broadcast_ping()


def test_read_and_write_registers(p2: Bench) -> None:
    bus = p2.bus
    assert bus.read_register(1, "Model Number") == 1060
    assert bus.model(1).name == "XL430-W250"
    assert bus.read_register(2, "present_position") == 2048
    assert bus.position(2) == 0.0
    bus.write_register(2, "LED", 1)
    assert bus.read_register(2, "LED") == 1
    assert servo_get(p2, 2, "LED") == 1
    assert bus.read(1, 132, 4) == (2048).to_bytes(4, "little")
    with pytest.raises(HwBridgeError, match="no register 'Goal Possition'"):
        bus.read_register(1, "Goal Possition")
    with pytest.raises(ValueError, match="does not fit Torque Enable"):
        bus.write_register(1, "Torque Enable", 256)


def test_sync_write_then_sync_read_positions(p2: Bench) -> None:
    bus = p2.bus
    bus.sync_write_register("Torque Enable", {1: 1, 2: 1})
    bus.sync_write_register("Goal Position", {1: 1000, 2: 3000})
    assert bus.sync_read_register("Goal Position", [1, 2]) == {1: 1000, 2: 3000}
    p2.settle(2.0)
    assert bus.sync_read_register("Present Position", [2, 1]) == {2: 3000, 1: 1000}
    raw = bus.sync_read(128, 8, [1, 2])  # Present Velocity + Present Position in one go
    assert raw[1] == bytes(4) + (1000).to_bytes(4, "little")
    bus.bulk_write([(1, 65, b"\x01"), (2, 116, (2048).to_bytes(4, "little"))])
    assert bus.bulk_read([(1, 65, 1), (2, 116, 4)]) == {1: b"\x01", 2: (2048).to_bytes(4, "little")}


def test_eeprom_write_with_torque_on_is_an_access_error(p2: Bench) -> None:
    bus = p2.bus
    bus.set_torque(1, True)
    with pytest.raises(DynamixelStatusError) as caught:
        bus.write_register(1, "Operating Mode", 1)
    error = caught.value
    assert str(error).startswith("servo 1: Access Error (EEPROM write while torque on)")
    assert "WRITE at address 11 (Operating Mode)" in str(error)
    assert (error.id, error.error, error.names) == (1, 7, ["Access Error"])
    assert servo_get(p2, 1, "Operating Mode") == 3
    bus.set_torque(1, False)
    bus.write_register(1, "Operating Mode", 1)
    assert servo_get(p2, 1, "Operating Mode") == 1
    with pytest.raises(DynamixelStatusError, match=r"Data Range Error .* \(Operating Mode\)"):
        bus.write_register(1, "Operating Mode", 2)
    with pytest.raises(DynamixelStatusError, match=r"Access Error \(read-only register"):
        bus.write(1, 132, bytes(4))


def test_status_return_level_1_and_0(p2: Bench) -> None:
    bus = p2.bus
    bus.write_register(1, "Status Return Level", 1)
    assert bus.status_return_levels[1] == 1
    bus.write_register(1, "LED", 1)  # not answered any more: the bus does not wait
    assert bus.read_register(1, "LED") == 1  # reads still are
    assert bus.stats.timeouts == 0
    bus.write_register(1, "Status Return Level", 0)
    with pytest.raises(HwBridgeError, match="Status Return Level 0: it does not answer READ"):
        bus.read_register(1, "LED")
    assert bus.ping(1).model_number == 1060  # PING always is
    # A bus that assumes level 2 times out, naming the servo and the instruction.
    other = DynamixelBus(p2.link, 2, timeout=0.1)
    with pytest.raises(HwBridgeTimeoutError, match="servo 1: no status packet for READ"):
        other.read(1, 65, 1)
    # Broadcast write of level 2 to everyone: the bus believes it for every ID.
    bus.write(254, 68, b"\x02")
    assert bus.default_status_return_level == 2 and not bus.status_return_levels
    assert bus.read_register(1, "LED") == 1


def test_reg_write_then_action(p2: Bench) -> None:
    bus = p2.bus
    bus.sync_write_register("Torque Enable", {1: 1, 2: 1})
    bus.reg_write(1, 116, (1500).to_bytes(4, "little"))
    bus.reg_write(2, 116, (2500).to_bytes(4, "little"))
    assert bus.read_register(1, "Registered Instruction") == 1
    assert bus.read_register(1, "Goal Position") == 2048
    bus.action()
    assert bus.sync_read_register("Goal Position", [1, 2]) == {1: 1500, 2: 2500}
    with pytest.raises(DynamixelStatusError, match=r"Instruction Error \(unknown instruction, or "):
        bus.action(1)


def test_position_mode_reaches_the_goal(p2: Bench) -> None:
    bus = p2.bus
    bus.set_torque(1, True)
    bus.write_register(1, "Profile Velocity", 50)
    bus.set_goal_position(1, 1.0)
    p2.clock.jump(0.05)
    assert bus.read_register(1, "Moving") == 1
    p2.settle(3.0)
    assert bus.read_register(1, "Moving") == 0
    assert bus.position(1) == pytest.approx(1.0, abs=2 * math.pi / 4096)
    assert bus.velocity(1) == 0.0


def test_velocity_mode(p2: Bench) -> None:
    bus = p2.bus
    bus.write_register(2, "Operating Mode", 1)
    bus.set_torque(2, True)
    bus.set_goal_velocity(2, 3.0)  # rad/s
    p2.settle(1.0)
    assert bus.velocity(2) == pytest.approx(3.0, abs=0.03)
    assert bus.position(2) > 2.5


def test_reboot_clears_a_hardware_error(p2: Bench) -> None:
    bus = p2.bus
    bus.set_torque(1, True)
    p2.runner.call(lambda e: e.servo(1).inject_hardware_error(0x04))  # overheating
    assert bus.read_register(1, "Hardware Error Status") == 0x04  # data still comes
    assert 1 in bus.alerts
    with pytest.raises(DynamixelStatusError, match="Result Fail"):
        bus.set_torque(1, True)
    bus.reboot(1)
    with pytest.raises(HwBridgeTimeoutError):
        DynamixelBus(p2.link, 2, timeout=0.02).ping(1)  # still booting
    p2.clock.jump(0.2)
    assert bus.read_register(1, "Hardware Error Status") == 0
    assert 1 not in bus.alerts
    assert not bus.torque_enabled(1)
    bus.set_torque(1, True)


def test_factory_reset(p2: Bench) -> None:
    bus = p2.bus
    bus.write_register(2, "Return Delay Time", 0)
    bus.factory_reset(2, 0x01)
    assert bus.read_register(2, "Return Delay Time") == 250


def test_timeouts_name_the_servo_and_the_instruction(p2: Bench) -> None:
    p2.bus.timeout = 0.05
    with pytest.raises(HwBridgeTimeoutError, match="servo 9: no status packet for PING"):
        p2.bus.ping(9)
    with pytest.raises(HwBridgeTimeoutError, match=r"servo 7: .*SYNC_READ.*\(answered: 1\)"):
        p2.bus.sync_read(132, 4, [1, 7])
    assert p2.bus.stats.timeouts == 2


class DropFirstReads(Link):
    """Loses the first ``drops`` chunks coming from the servos (a noisy line)."""

    scheme = "test"

    def __init__(self, inner: Link, drops: int) -> None:
        super().__init__(f"drop+{inner.url}")
        self.inner = inner
        self.drops = drops

    def _open(self) -> None:
        self.inner.open()

    def _read(self, max_bytes: int, timeout: float | None) -> bytes:
        data = self.inner.read(max_bytes, timeout)
        if data and self.drops:
            self.drops -= 1
            return b""
        return data

    def _write(self, data: memoryview) -> None:
        self.inner.write(data)

    def _close(self) -> None:
        pass  # the bench closes the inner link


def test_retries_after_a_lost_status(p2: Bench) -> None:
    lossy = DropFirstReads(p2.link, drops=1)
    lossy.open()
    with pytest.raises(HwBridgeTimeoutError):
        DynamixelBus(lossy, 2, timeout=0.1).ping(1)
    lossy.drops = 1
    # (the dropped status costs this timeout; the answered one, on a busy machine, may need it)
    bus = DynamixelBus(lossy, 2, timeout=1.0, retries=2)
    assert bus.ping(1).model_number == 1060
    assert bus.stats.retries == 1
    lossy.close()


class GarbleFirstStatus(DropFirstReads):
    """Flips one bit in the first status packet (collected whole first) from the servos."""

    def _read(self, max_bytes: int, timeout: float | None) -> bytes:
        if not self.drops:
            return self.inner.read(max_bytes, timeout)
        data = bytearray()
        while len(data) < 14:  # a Protocol 2.0 PING status
            chunk = self.inner.read(14 - len(data), timeout)
            if not chunk:
                return b""
            data += chunk
        self.drops -= 1
        data[9] ^= 0x10
        return bytes(data)


def test_a_corrupt_status_is_reported_or_retried(p2: Bench) -> None:
    garbled = GarbleFirstStatus(p2.link, drops=1)
    garbled.open()
    bus = DynamixelBus(garbled, 2, timeout=0.2)
    with pytest.raises(FramingError, match=r"servo 1: corrupt status for PING \(CRC"):
        bus.ping(1)
    assert bus.stats.corrupt == 1
    garbled.drops = 1
    bus.retries = 1
    assert bus.ping(1).model_number == 1060
    assert (bus.stats.corrupt, bus.stats.retries) == (2, 1)
    garbled.close()


def test_ax12_read_write_and_wheel_mode(p1: Bench) -> None:
    bus = p1.bus
    assert bus.model(1).name == "AX-12A"
    assert bus.read_register(1, "Present Temperature") == 32
    assert bus.position(1) == 0.0  # tick 512
    bus.write_register(1, "CW Angle Limit", 0)
    bus.write_register(1, "CCW Angle Limit", 0)  # both 0: wheel mode
    bus.set_torque(1, True)
    bus.set_goal_velocity(1, -2.0)  # clockwise
    assert bus.read_register(1, "Moving Speed") & 0x400
    p1.settle(0.5)
    assert bus.velocity(1) == pytest.approx(-2.0, abs=0.02)
    assert bus.read_register(1, "Moving") == 1
    bus.write_register(2, "CCW Angle Limit", 600)
    with pytest.raises(DynamixelStatusError, match="servo 2: Angle Limit Error"):
        bus.write_register(2, "Goal Position", 700)
    bus.sync_write_register("Goal Position", {2: 300})  # Protocol 1.0 SYNC_WRITE
    assert bus.read_register(2, "Goal Position") == 300
    with pytest.raises(HwBridgeError, match=r"SYNC_READ is a Protocol 2\.0 instruction"):
        bus.sync_read(36, 2, [1, 2])


def test_bus_refuses_bad_arguments() -> None:
    with pytest.raises(ValueError, match="protocol must be 1 or 2"):
        DynamixelBus("memory://dxl-bad", 3)
    emulated = EmulatedDynamixelBus()
    assert emulated.next_deadline() is None
