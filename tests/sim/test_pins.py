"""The emulator's world on the pins of tests/sim/avr/probe.c: its PWM moves the world's wheel,
the wheel's encoder edges reach its counter, the sonar's echo is as wide as the world's distance
says, and the MPU-6050's register file answers its I2C reads."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from hwbridge.devices.ultrasonic.hcsr04 import echo_for_distance
from hwbridge.emulator.board import BoardConfig, load_board
from hwbridge.emulator.pins import PinWorld
from hwbridge.errors import HwBridgeError
from hwbridge.firmware.boards import mcu_board
from hwbridge.firmware.sim import SimAvr
from tests.sim.conftest import Terminal

# probe.c's wiring: encoder A/B on 2/4, PWM on 5 (OC0B) with direction on 7, sonar 9/10; the
# right-hand devices on analog pins the program leaves alone. Given as the devices' own pin
# settings, as a robot file gives them.
PROBE_PINS = {
    "diffdrive": {
        "left_encoder": [2, 4],
        "right_encoder": ["A0", "A1"],
        "left_motor": [5, 7],
        "right_motor": ["A2", "A3"],
    },
    "hcsr04": {"trigger": 9, "echo": 10},
}


def _probe_board() -> BoardConfig:
    """diffbot's board with probe.c's wiring in its devices' pin settings."""
    config = load_board("diffbot")
    devices = tuple(
        dataclasses.replace(d, settings={**d.settings, "pins": PROBE_PINS[d.type]})
        if d.type in PROBE_PINS
        else d
        for d in config.devices
    )
    return dataclasses.replace(config, devices=devices)


def test_pin_table() -> None:
    uno, mega = mcu_board("uno"), mcu_board("mega")
    assert uno.number("A4") == uno.sda == 18
    assert mega.number("A0") == 54
    assert mcu_board("nano").number("A7") == 21
    with pytest.raises(HwBridgeError, match="no pin 20"):
        uno.number(20)
    with pytest.raises(HwBridgeError, match="no pin A6"):
        uno.number("A6")
    with pytest.raises(HwBridgeError, match="unknown MCU board"):
        mcu_board("due")


def test_world_on_the_probe(probe_elf: Path, terminal_factory: type[Terminal]) -> None:
    with SimAvr(probe_elf) as sim:
        sim.start(hold=True)
        world = PinWorld(sim, _probe_board(), seed=3).attach()
        assert world.skipped == ["dynamixel"]
        uart = terminal_factory(sim.path)
        sim.go()
        uart.read_until(b"boot\n")
        # the sonar: the round trip to the wall ahead (the robot starts in the room's centre)
        with world.lock:
            distance = world.world.sonar_distance()
        assert distance is not None
        uart.write(b"s")
        echo = int(uart.read_until(b"\n")[1:])
        # (diffbot's sonar has 2 mm of range noise: 12 us a standard deviation)
        assert echo == pytest.approx(echo_for_distance(distance, 20.0) * 1e6, abs=60)
        # the MPU-6050: asleep at power-on (SLEEP set, no data), woken by the program's write,
        # then burst reads
        uart.write(b"r")
        assert uart.read_until(b"\n") == b"R40 000000000000\n"
        uart.write(b"i")
        uart.read_until(b"\n")
        sim.wait_time(sim.time + 0.02)
        uart.write(b"i")
        reply = uart.read_until(b"\n").decode()
        assert reply.startswith("I68 ")  # WHO_AM_I
        data = bytes.fromhex(reply.split()[1])
        z = int.from_bytes(data[4:6], "big", signed=True)
        # 1 g at the +-2 g reset range, within the chip's drawn offset and scale errors
        assert z == pytest.approx(16384, rel=0.1)
        # +-4 g: half the counts per g
        uart.write(b"a\x08")
        uart.read_until(b"A\n")
        sim.wait_time(sim.time + 0.02)
        uart.write(b"r")
        reply = uart.read_until(b"\n").decode()
        assert reply.startswith("R00 ")
        z4 = int.from_bytes(bytes.fromhex(reply.split()[1])[4:6], "big", signed=True)
        assert z4 == pytest.approx(z / 2, rel=0.02)
        # the motor: half duty forwards -> the left wheel turns at half the top speed
        uart.write(b"p\x80")
        uart.read_until(b"P\n")
        sim.wait_time(sim.time + 0.6)
        with world.lock:
            left, right = world.world.base.wheel_speeds
        top = world.world.config.max_wheel_speed
        assert left == pytest.approx(top * 128 / 255, rel=0.02)
        assert right == 0.0
        # the encoder: the program's x2 count follows the wheel's angle
        uart.write(b"p\x00")
        uart.read_until(b"P\n")
        sim.wait_time(sim.time + 0.5)
        with world.lock:
            angle = world.world.base.wheel_angles[0]
        steps = math.floor(angle / (2 * math.pi) * world.world.config.counts_per_rev)
        assert steps > 1000
        uart.write(b"c")
        count = int(uart.read_until(b"\n")[1:])
        # two encoder steps per count; the program's counter is 16-bit signed
        assert count == pytest.approx(((steps // 2 + 32768) % 65536) - 32768, abs=1)
