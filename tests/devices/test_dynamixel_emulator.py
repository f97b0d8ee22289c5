"""The emulated Dynamixel bus, sans-I/O: raw packets in, raw status packets out, simulated time."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

import hwbridge.protocols
from hwbridge.devices.dynamixel import (
    EmulatedDynamixelBus,
    EmulatedServo,
    Error1,
    Error2,
    StatusPacket,
    bus_configs,
    emulated_bus,
)
from hwbridge.devices.dynamixel import packets as p
from hwbridge.errors import HwBridgeError

VECTORS = {
    (v["protocol"], v["name"]): bytes.fromhex(v["bytes"])
    for v in json.loads(
        (Path(hwbridge.protocols.__file__).parent / "vectors" / "dynamixel.json").read_text()
    )["vectors"]
}


class Clock:
    """Simulated time for a sans-I/O bus."""

    def __init__(self) -> None:
        self.now = 0.0

    def send(self, bus: EmulatedDynamixelBus, data: bytes | p.InstructionPacket) -> list[Any]:
        """Feed an instruction and collect every status that comes within 50 ms."""
        raw = p.encode(data) if isinstance(data, p.InstructionPacket) else data
        out = bus.feed(raw, self.now)
        self.now += 0.05
        out += bus.advance(self.now)
        return p.PacketParser(bus.protocol).feed(out)

    def wait(self, bus: EmulatedDynamixelBus, seconds: float) -> None:
        self.now += seconds
        bus.advance(self.now)


def x_bus(*servos: EmulatedServo) -> EmulatedDynamixelBus:
    return EmulatedDynamixelBus(servos or [EmulatedServo("XL430-W250", 1)], protocol=2)


def write(id_: int, address: int, value: int, size: int, protocol: int = 2) -> p.InstructionPacket:
    return p.write_packet(protocol, id_, address, value.to_bytes(size, "little", signed=value < 0))


def test_ready_buses_are_data() -> None:
    configs = bus_configs()
    assert configs["dxl-bus"]["protocol"] == 2 and configs["dxl-bus"]["baud"] == 57600
    assert [s["model"] for s in configs["dxl-bus"]["servos"]] == ["XL430-W250"] * 2
    assert configs["dxl-bus-p1"]["baud"] == 1_000_000
    bus = emulated_bus("dxl-bus-p1")
    assert bus.protocol == 1 and [s.id for s in bus.servos] == [1, 2]
    assert bus.servos[0].model.number == 12
    with pytest.raises(HwBridgeError, match="ready ones: dxl-bus, dxl-bus-p1"):
        emulated_bus("nope")
    with pytest.raises(HwBridgeError, match="bad emulated Dynamixel bus"):
        EmulatedDynamixelBus.from_config({"servos": [{"id": 1}]})


def test_servos_answer_the_manual_vectors_byte_for_byte() -> None:
    """Two XM430-W210 (model 1030, firmware 38) as in the e-manual examples."""
    one = EmulatedServo("XM430-W210", 1, firmware=38, voltage=119)
    two = EmulatedServo("XM430-W210", 2, firmware=38, temperature=36)
    one.position, two.position = 166.0, 2079.0
    bus = EmulatedDynamixelBus([one, two], protocol=2)
    clock = Clock()

    def answer(name: str) -> bytes:
        out = bus.feed(VECTORS[(2, name)], clock.now)
        clock.now += 0.05
        return out + bus.advance(clock.now)

    ping_reply = VECTORS[(2, "ping reply, XM430-W210 model 1030 firmware 38")]
    assert answer("ping ID 1") == ping_reply
    assert (
        answer("broadcast ping")
        == ping_reply + VECTORS[(2, "ping reply ID 2, model 1030 firmware 38")]
    )
    assert answer("read Present Position (132, 4)") == VECTORS[(2, "read reply 166")]
    assert answer("sync read Present Position of ID 1 and 2") == (
        VECTORS[(2, "read reply 166")] + VECTORS[(2, "sync read reply ID 2 = 2079")]
    )
    assert answer("bulk read voltage of ID 1, temperature of ID 2") == (
        VECTORS[(2, "bulk read reply ID 1 = 119")] + VECTORS[(2, "bulk read reply ID 2 = 36")]
    )
    ok = VECTORS[(2, "status without parameters")]
    assert answer("write 512 to Goal Position (116)") == ok
    assert one.get("Goal Position") == 512
    assert answer("sync write Goal Position ID1=150 ID2=170") == b""  # broadcast: no status
    assert (one.get("Goal Position"), two.get("Goal Position")) == (150, 170)
    assert answer("reg write 200 to Goal Velocity (104)") == ok
    assert (one.get("Goal Velocity"), one.get("Registered Instruction")) == (0, 1)
    assert answer("action ID 1") == ok
    assert (one.get("Goal Velocity"), one.get("Registered Instruction")) == (200, 0)


def test_ax12_answers_the_protocol_1_vectors() -> None:
    bus = emulated_bus("dxl-bus-p1")
    clock = Clock()
    for ask, reply in [
        ("ping ID 1", "ping reply"),
        ("read address 43 length 1", "read reply 0x20"),
        ("write 0x64 0xAA at address 12 (ID 1)", "ping reply"),  # the same empty status
    ]:
        out = bus.feed(VECTORS[(1, ask)], clock.now)
        clock.now += 0.01
        assert out + bus.advance(clock.now) == VECTORS[(1, reply)], ask
    servo = bus.servo(1)
    assert (servo.get("Min Voltage Limit"), servo.get("Max Voltage Limit")) == (0x64, 0xAA)


def test_return_delay_and_one_talker_at_a_time() -> None:
    bus = emulated_bus("dxl-bus")
    ping = p.encode(p.ping_packet(2, 1))
    assert bus.feed(ping, 10.0) == b""  # Return Delay Time 250 = 500 us
    assert bus.next_deadline() == pytest.approx(10.0005)
    assert bus.advance(10.0004) == b""
    assert p.decode(bus.advance(10.0006)).id == 1
    bus.servo(1).set("Return Delay Time", 0)
    assert p.decode(bus.feed(ping, 11.0)).id == 1  # no delay: at once
    # Broadcast PING: both answer, in ID order even when listed the other way round, the
    # second after the first has finished talking (14 bytes at 57600 baud).
    bus = EmulatedDynamixelBus(
        [EmulatedServo("XL430-W250", 2), EmulatedServo("XL430-W250", 1)], protocol=2
    )
    bus.feed(p.encode(p.ping_packet(2, p.BROADCAST_ID)), 0.0)
    first = bus.next_deadline()
    assert [s.id for s in p.PacketParser(2).feed(bus.advance(first or 0))] == [1]
    second = bus.next_deadline()
    assert second is not None and second - (first or 0) >= 14 * 10 / 57600
    assert [s.id for s in p.PacketParser(2).feed(bus.advance(second))] == [2]


@pytest.mark.parametrize(
    ("level", "ping", "read", "written"),
    [(0, True, False, False), (1, True, True, False), (2, True, True, True)],
)
def test_status_return_level(level: int, ping: bool, read: bool, written: bool) -> None:
    bus = x_bus()
    bus.servo(1).set("Status Return Level", level)
    clock = Clock()
    assert bool(clock.send(bus, p.ping_packet(2, 1))) is ping
    assert bool(clock.send(bus, p.read_packet(2, 1, 132, 4))) is read
    assert bool(clock.send(bus, write(1, 65, 1, 1))) is written
    assert bus.servo(1).get("LED") == 1  # executed even when not answered
    assert clock.send(bus, write(p.BROADCAST_ID, 65, 0, 1)) == []  # broadcasts: never
    assert bus.servo(1).get("LED") == 0


@pytest.mark.parametrize(
    ("address", "value", "size", "torque", "error"),
    [
        (11, 1, 1, True, Error2.ACCESS),  # Operating Mode is EEPROM: torque must be off
        (11, 1, 1, False, 0),
        (11, 2, 1, False, Error2.DATA_RANGE),  # not a mode of the XL430
        (132, 5, 4, False, Error2.ACCESS),  # Present Position is read-only
        (66, 1, 1, False, Error2.ACCESS),  # nothing at 66
        (116, 5, 2, False, Error2.DATA_LENGTH),  # half of Goal Position
        (117, 5, 1, False, Error2.DATA_LENGTH),
        (116, 4096, 4, False, Error2.DATA_LIMIT),  # beyond Max Position Limit
        (104, -266, 4, False, Error2.DATA_LIMIT),  # beyond -Velocity Limit (265)
        (104, -265, 4, False, 0),
        (68, 3, 1, False, Error2.DATA_RANGE),
        (7, 253, 1, False, Error2.DATA_RANGE),
        (64, 1, 1, False, 0),
    ],
)
def test_write_rules_of_the_x_series(
    address: int, value: int, size: int, torque: bool, error: int
) -> None:
    bus = x_bus()
    bus.servo(1).set("Torque Enable", int(torque))
    span = slice(address, address + size)
    before = bytes(bus.servo(1).memory[span])
    (status,) = Clock().send(bus, write(1, address, value, size))
    assert status.error == error
    changed = bytes(bus.servo(1).memory[span]) != before
    assert changed is (error == 0 and not (address == 64 and torque))


def test_read_rules_and_bad_instructions() -> None:
    bus = x_bus()
    clock = Clock()
    (status,) = clock.send(bus, p.read_packet(2, 1, 0, 147))  # the whole table at once
    assert status.error == 0 and status.params[:2] == (1060).to_bytes(2, "little")
    (status,) = clock.send(bus, p.read_packet(2, 1, 140, 20))  # past the end
    assert status.error == Error2.ACCESS
    (status,) = clock.send(bus, p.InstructionPacket(1, 0x77, b"", 2))
    assert status.error == Error2.INSTRUCTION
    (status,) = clock.send(bus, p.action_packet(2, 1))  # ACTION without REG_WRITE
    assert status.error == Error2.INSTRUCTION
    (status,) = clock.send(bus, p.InstructionPacket(1, p.Instruction.READ, b"\x84\x00", 2))
    assert status.error == Error2.INSTRUCTION  # malformed parameters
    assert clock.send(bus, p.ping_packet(2, 7)) == []  # nobody there


def test_corrupt_packets_get_a_crc_error() -> None:
    bus = x_bus()
    wire = bytearray(p.encode(p.read_packet(2, 1, 132, 4)))
    wire[-1] ^= 0x01
    (status,) = Clock().send(bus, bytes(wire))
    assert (status.id, status.error) == (1, Error2.CRC)
    assert bus.stats.corrupt == 1
    ax = emulated_bus("dxl-bus-p1")
    (status,) = Clock().send(ax, bytes.fromhex("FF FF 01 02 01 FA"))
    assert status.error == Error1.CHECKSUM


def test_position_mode_trapezoid_profile() -> None:
    """Profile Velocity 100 (22.9 rpm = 1563 ticks/s), Profile Acceleration 50: 2000 ticks take
    0.128 s up, 1.152 s cruising, 0.128 s down (1.408 s)."""
    bus = x_bus()
    servo = bus.servo(1)
    clock = Clock()
    for address, value in [(112, 100), (108, 50), (64, 1)]:
        assert clock.send(bus, write(1, address, value, 4 if address != 64 else 1))[0].error == 0
    assert servo.get("Goal Position") == 2048  # torque on holds where it is
    start = clock.now
    clock.send(bus, write(1, 116, 4048, 4))
    clock.now = start + 0.7
    (status,) = clock.send(bus, p.read_packet(2, 1, 122, 1))
    assert status.params == b"\x01"  # Moving
    assert servo.get("Present Velocity") == 100
    assert servo.get("Moving Status") & 0x02  # profile ongoing
    clock.now = start + 1.3  # decelerating, not there yet
    bus.advance(clock.now)
    assert 3800 < servo.get("Present Position") < 4048
    assert 0 < servo.get("Present Velocity") < 100
    clock.now = start + 1.5
    bus.advance(clock.now)
    assert servo.get("Present Position") == 4048
    assert (servo.get("Present Velocity"), servo.get("Moving")) == (0, 0)
    assert servo.get("Moving Status") & 0x01  # in position


def test_profile_zero_moves_at_the_velocity_limit() -> None:
    bus = x_bus()
    servo = bus.servo(1)
    clock = Clock()
    clock.send(bus, write(1, 64, 1, 1))
    clock.send(bus, write(1, 116, 3048, 4))
    clock.wait(bus, 0.1)
    # Velocity Limit 265 (60.7 rpm) = 4143 ticks/s, no ramp: 1000 ticks in 0.24 s.
    assert servo.get("Present Velocity") == 265
    clock.wait(bus, 0.2)
    assert servo.get("Present Position") == 3048


def test_velocity_mode_and_clear_multi_turn() -> None:
    bus = x_bus()
    servo = bus.servo(1)
    clock = Clock()
    assert clock.send(bus, write(1, 11, 1, 1))[0].error == 0  # velocity mode
    clock.send(bus, write(1, 64, 1, 1))
    clock.send(bus, write(1, 104, -200, 4))
    clock.wait(bus, 2.0)
    assert servo.get("Present Velocity") == -200
    assert servo.get("Present Position") < -4096  # multi-turn
    (status,) = clock.send(bus, p.clear_packet(1))
    assert status.error == Error2.RESULT_FAIL  # still turning
    clock.send(bus, write(1, 104, 0, 4))
    clock.wait(bus, 0.1)
    (status,) = clock.send(bus, p.clear_packet(1))
    assert status.error == 0
    assert 0 <= servo.get("Present Position") < 4096


def test_ax12_wheel_mode_and_angle_limits() -> None:
    bus = emulated_bus("dxl-bus-p1")
    servo = bus.servo(1)
    clock = Clock()
    (status,) = clock.send(bus, write(1, 30, 1000, 2, protocol=1))
    assert status.error == 0
    clock.send(bus, write(1, 8, 900, 2, protocol=1))  # CCW Angle Limit below the goal asked
    (status,) = clock.send(bus, write(1, 30, 950, 2, protocol=1))
    assert status.error == Error1.ANGLE_LIMIT
    (status,) = clock.send(bus, write(1, 36, 5, 2, protocol=1))
    assert status.error == Error1.RANGE  # read-only
    # Wheel mode: both limits 0; Moving Speed 300 clockwise (bit 10).
    clock.send(bus, p.write_packet(1, 1, 6, bytes(4)))
    assert servo.wheel_mode
    clock.send(bus, write(1, 24, 1, 1, protocol=1))
    clock.send(bus, write(1, 32, 1024 + 300, 2, protocol=1))
    before = servo.position
    clock.wait(bus, 0.5)
    assert servo.get("Present Speed") == 1024 + 300
    assert servo.get("Moving") == 1
    # 300 x 0.111 rpm = 33.3 rpm = 682 ticks/s, clockwise, wrapping within 0-1023.
    assert (before - servo.position) % 1024 == pytest.approx(0.5 * 682, abs=3)
    assert 0 <= servo.get("Present Position") <= 1023
    clock.send(bus, write(1, 47, 1, 1, protocol=1))  # Lock the EEPROM
    (status,) = clock.send(bus, write(1, 5, 0, 1, protocol=1))
    assert status.error == Error1.RANGE
    (status,) = clock.send(bus, p.reboot_packet(1, 1))
    assert status.error == Error1.INSTRUCTION  # the AX-12A has no REBOOT


def test_ax12_joint_mode_speed() -> None:
    bus = emulated_bus("dxl-bus-p1")
    servo = bus.servo(2)
    clock = Clock()
    clock.send(bus, write(2, 24, 1, 1, protocol=1))
    clock.send(bus, write(2, 32, 200, 2, protocol=1))  # 22.2 rpm = 454.6 ticks/s
    clock.send(bus, write(2, 30, 812, 2, protocol=1))
    clock.now += 0.3
    bus.advance(clock.now)
    assert servo.get("Present Speed") == 200
    assert servo.get("Moving") == 1
    clock.wait(bus, 0.5)
    assert (servo.get("Present Position"), servo.get("Moving")) == (812, 0)


def test_hardware_error_alert_shutdown_and_reboot() -> None:
    bus = x_bus()
    servo = bus.servo(1)
    clock = Clock()
    clock.send(bus, write(1, 64, 1, 1))
    servo.inject_hardware_error(0x20)  # overload, in Shutdown (52) by default
    assert not servo.torque
    (status,) = clock.send(bus, p.ping_packet(2, 1))
    assert status.alert and status.error & 0x7F == 0
    (status,) = clock.send(bus, p.read_packet(2, 1, 70, 1))
    assert status.params == b"\x20" and status.alert
    (status,) = clock.send(bus, write(1, 64, 1, 1))
    assert status.error == Error2.RESULT_FAIL | p.ALERT_BIT
    (status,) = clock.send(bus, p.reboot_packet(2, 1))
    assert status.error == p.ALERT_BIT  # answered before rebooting
    assert (
        bus.feed(p.encode(p.ping_packet(2, 1)), clock.now) + bus.advance(clock.now + 0.001) == b""
    )
    clock.now += 0.1
    (status,) = clock.send(bus, p.ping_packet(2, 1))
    assert status.error == 0
    assert servo.hardware_error == 0
    assert clock.send(bus, write(1, 64, 1, 1))[0].error == 0


def test_ax12_hardware_error_bits() -> None:
    bus = emulated_bus("dxl-bus-p1")
    bus.servo(1).inject_hardware_error(Error1.OVERHEATING)
    (status,) = Clock().send(bus, p.ping_packet(1, 1))
    assert status.error == Error1.OVERHEATING


def test_factory_reset_options_and_baud_rate() -> None:
    bus = x_bus()
    servo = bus.servo(1)
    clock = Clock()
    clock.send(bus, write(1, 7, 5, 1))  # ID 5
    assert servo.id == 5
    clock.send(bus, write(5, 9, 0, 1))  # Return Delay Time 0
    (status,) = clock.send(bus, p.factory_reset_packet(2, 5, 0x01))
    assert status.id == 5 and status.error == 0
    assert (servo.id, servo.get("Return Delay Time")) == (5, 250)
    assert clock.send(bus, p.factory_reset_packet(2, p.BROADCAST_ID, 0xFF)) == []
    assert servo.id == 5  # a broadcast reset-all is refused
    clock.send(bus, p.factory_reset_packet(2, 5, 0xFF))
    assert servo.id == 1
    (status,) = clock.send(bus, write(1, 8, 3, 1))  # 1 Mbaud: gone from this 57600 bus
    assert status.error == 0
    assert clock.send(bus, p.ping_packet(2, 1)) == []
    bus.baud = 1_000_000
    assert clock.send(bus, p.ping_packet(2, 1))[0].id == 1


def test_protocol_type_1_silences_an_x_servo_on_a_2_0_bus() -> None:
    bus = x_bus()
    clock = Clock()
    clock.send(bus, write(1, 13, 1, 1))
    assert clock.send(bus, p.ping_packet(2, 1)) == []
    assert bus.stats.ignored >= 1


def test_group_instructions() -> None:
    bus = emulated_bus("dxl-bus")
    clock = Clock()
    clock.send(bus, p.bulk_write_packet([(1, 65, b"\x01"), (2, 116, (300).to_bytes(4, "little"))]))
    assert bus.servo(1).get("LED") == 1 and bus.servo(2).get("Goal Position") == 300
    replies = clock.send(bus, p.bulk_read_packet(2, [(2, 116, 4), (1, 65, 1)]))
    assert replies == [
        StatusPacket(2, 0, (300).to_bytes(4, "little")),
        StatusPacket(1, 0, b"\x01"),
    ]
    replies = clock.send(bus, p.sync_read_packet(2, 65, 1, [2, 9, 1]))  # 9 is absent
    assert [(s.id, s.params) for s in replies] == [(2, b"\x00"), (1, b"\x01")]
    # A group instruction to one ID is not how they are sent: ignored.
    assert (
        clock.send(bus, p.InstructionPacket(1, p.Instruction.SYNC_READ, b"\x41\x00\x01\x00\x01", 2))
        == []
    )
