"""The Arduino library's device drivers (``firmware/HwBridge/src/hwbridge/drivers``), host-native.

``firmware/tests/drivers/test_drivers.cpp`` runs each driver against a pin- and time-level fake of
the Arduino core (``firmware/tests/drivers/Arduino.h``): encoder edges through the attached
interrupts, motor outputs and the target timeout, the HC-SR04's trigger and echo timing
(interrupt and polling), the MPU's I2C register traffic, Dynamixel packets (DEVICES.md's
vectors) over a fake half-duplex UART; built with ``-Wall -Wextra -Werror`` under ASan and
UBSan. Its output is then checked against the host side: each message a driver filled (with the
generated message headers) decodes with the host's registry and, published on the graph, makes
the host device nodes (``hcsr04``, ``mpu6050``, ``mpu9250``) produce the expected Range and Imu;
each Dynamixel packet equals what ``devices/dynamixel`` encodes.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from hwbridge import msg
from hwbridge.devices.dynamixel.framing import InstructionPacket, encode
from hwbridge.graph import Graph
from hwbridge.robot.config import device_config
from hwbridge.robot.plugin import HostContext
from hwbridge.robot.registry import get_device
from tests.netutil import wait_until

ROOT = Path(__file__).resolve().parents[2]
INCLUDE = ROOT / "firmware" / "HwBridge" / "src"
TESTS = ROOT / "firmware" / "tests" / "drivers"
TYPES = (
    "hwbridge_msgs/WheelTicks",
    "hwbridge_msgs/SonarEcho",
    "hwbridge_msgs/ImuRaw",
    "hwbridge_msgs/WheelTargets",
)
NAMESPACE = "/drv"

pytestmark = pytest.mark.skipif(
    shutil.which("g++") is None, reason="g++ is not installed (Debian package g++)"
)


@pytest.fixture(scope="module")
def driver_output(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    """The lines the driver test program prints (it exits 1 on its first failed check)."""
    out = tmp_path_factory.mktemp("drivers")
    generated = out / "msgs"
    subprocess.run(
        [sys.executable, "-m", "hwbridge", "firmware", "generate", str(generated), *TYPES],
        check=True,
        capture_output=True,
    )
    program = out / "test_drivers"
    build = subprocess.run(
        [
            "g++",
            "-std=c++11",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-Wshadow",
            "-O1",
            "-fsanitize=address,undefined",
            "-fno-sanitize-recover=all",
            f"-I{TESTS}",
            f"-I{INCLUDE}",
            f"-I{generated}",
            str(TESTS / "test_drivers.cpp"),
            "-o",
            str(program),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert build.returncode == 0, build.stderr
    run = subprocess.run([str(program)], capture_output=True, text=True, timeout=60, check=False)
    assert run.returncode == 0, run.stderr + run.stdout
    assert "checks passed" in run.stderr
    return run.stdout.splitlines()


def _messages(lines: list[str], type_name: str) -> list[Any]:
    return [
        msg.decode(bytes.fromhex(line.split()[2]), type_name)
        for line in lines
        if line.startswith(f"MSG {type_name} ")
    ]


def test_wheel_ticks_are_the_counters_as_the_emulated_board_sends_them(
    driver_output: list[str],
) -> None:
    (ticks,) = _messages(driver_output, "hwbridge_msgs/WheelTicks")
    # x2 encoder: 400 steps forward, 800 back = -200 edges of A, as a 16-bit counter; the x4
    # one: 5 after wrapping past 65536, plus nothing for the missed edge.
    assert (ticks.left, ticks.right, ticks.counter_bits) == (65536 - 200, 5, 16)
    assert ticks.header.frame_id == "base_link"


def test_sonar_echo_and_imu_raw_decode_with_the_hosts_types(driver_output: list[str]) -> None:
    (echo,) = _messages(driver_output, "hwbridge_msgs/SonarEcho")
    assert 1980 <= echo.echo_us <= 2020
    assert float(echo.temperature) == 20.0
    mpu6050, mpu9250 = _messages(driver_output, "hwbridge_msgs/ImuRaw")
    assert (mpu6050.chip, mpu6050.accel_config, mpu6050.gyro_config) == (0, 1 << 3, 2 << 3)
    assert [int(v) for v in mpu6050.burst] == [100, -200, 16384, -1000, 131, -262, 32767]
    assert not mpu6050.mag_valid
    assert mpu9250.chip == 1 and mpu9250.mag_valid
    assert [int(v) for v in mpu9250.mag] == [100, -200, 300]
    assert [int(v) for v in mpu9250.mag_asa] == [0xB0, 0xB1, 0xA5]
    assert mpu9250.mag_st2 == 0x10


@pytest.fixture
def host(router: Graph) -> Iterator[Callable[[dict[str, Any]], Any]]:
    """A device's host node from a robot-file entry, as ``hwbridge up`` starts it."""
    started: list[Any] = []

    def start(entry: dict[str, Any]) -> Any:
        device = device_config(entry)
        node = router.node(f"dev_{device.name}_{len(started)}", namespace=NAMESPACE)
        context = HostContext(router, node, NAMESPACE, "base", None)
        started.append(get_device(device.type).host_node(device.settings, context))
        return started[-1]

    yield start
    for node in started:
        node.close()


def _publish_until(
    router: Graph, topic: str, type_name: str, payload: bytes, got: list[Any]
) -> None:
    node = router.node("board_wire", namespace=NAMESPACE)
    publisher = node.raw_publisher(topic, type_name, msg.md5(type_name))
    try:
        assert publisher.wait_for_subscribers(10)

        def arrived() -> bool:
            publisher.publish_raw(payload)
            return bool(got)

        assert wait_until(arrived, 10)
    finally:
        publisher.close()


def _payload(lines: list[str], type_name: str, index: int = 0) -> bytes:
    found = [line.split()[2] for line in lines if line.startswith(f"MSG {type_name} ")]
    return bytes.fromhex(found[index])


def test_the_hcsr04_host_node_turns_the_drivers_echo_into_range(
    driver_output: list[str], host: Callable[[dict[str, Any]], Any], router: Graph, client: Graph
) -> None:
    host({"type": "hcsr04", "frame_id": "sonar_link"})
    ranges: list[Any] = []
    client.node("listener").subscriber(f"{NAMESPACE}/range", "sensor_msgs/Range", ranges.append)
    payload = _payload(driver_output, "hwbridge_msgs/SonarEcho")
    _publish_until(router, "sonar_echo", "hwbridge_msgs/SonarEcho", payload, ranges)
    echo_us = msg.decode(payload, "hwbridge_msgs/SonarEcho").echo_us
    expected = echo_us * 1e-6 * 331.3 * math.sqrt(1 + 20.0 / 273.15) / 2
    assert float(ranges[-1].range) == pytest.approx(expected, rel=1e-3)


@pytest.mark.parametrize(("chip", "index"), [("mpu6050", 0), ("mpu9250", 1)])
def test_the_imu_host_node_turns_the_drivers_registers_into_imu(
    chip: str,
    index: int,
    driver_output: list[str],
    host: Callable[[dict[str, Any]], Any],
    router: Graph,
    client: Graph,
) -> None:
    host({"type": chip, "topic": f"raw_{chip}", "imu_topic": f"imu_{chip}"})
    imus: list[Any] = []
    client.node("listener").subscriber(f"{NAMESPACE}/imu_{chip}", "sensor_msgs/Imu", imus.append)
    payload = _payload(driver_output, "hwbridge_msgs/ImuRaw", index)
    _publish_until(router, f"raw_{chip}", "hwbridge_msgs/ImuRaw", payload, imus)
    imu = imus[-1]
    # 16384 LSB: 2 g at the 6050's +-4 g (8192 LSB/g), 1 g at the 9250's +-2 g.
    g = 2.0 if chip == "mpu6050" else 1.0
    assert float(imu.linear_acceleration.z) == pytest.approx(g * 9.80665, rel=0.01)
    dps_per_lsb = 1 / 32.8 if chip == "mpu6050" else 1 / 131.0
    assert float(imu.angular_velocity.x) == pytest.approx(math.radians(131 * dps_per_lsb), rel=0.01)


def test_dynamixel_packets_equal_the_hosts_encoding(driver_output: list[str]) -> None:
    lines = [line.split() for line in driver_output if line.startswith("DXL ")]
    assert len(lines) >= 7
    for fields in lines:
        protocol, id_, instruction = (int(v) for v in fields[1:4])
        params, packet = (fields[4], fields[5]) if len(fields) == 6 else ("", fields[4])
        expected = encode(InstructionPacket(id_, instruction, bytes.fromhex(params), protocol))
        assert bytes.fromhex(packet) == expected, fields
