"""The ``bme280`` device: the datasheet's compensation, the emulated chip's registers, its
model in the emulator end to end (robot file, virtual board, host node, graph), and the
Bme280 example sketch in simavr reading the pin-level model."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge import msg
from hwbridge.devices.bme280.chip import (
    CHIP_ID,
    CONFIG,
    CTRL_HUM,
    CTRL_MEAS,
    DATA,
    ID,
    MEASURING,
    MODE_NORMAL,
    MODE_SLEEP,
    RESET,
    RESET_VALUE,
    STATUS,
    Bme280,
    adc_values,
    decode_data,
    measurement_time,
)
from hwbridge.devices.bme280.compensation import (
    TYPICAL,
    Calibration,
    compensate_h,
    compensate_p,
    compensate_t,
    t_fine,
)
from hwbridge.devices.bme280.node import from_raw
from hwbridge.devices.bme280.plugin import BoardDriver
from hwbridge.devices.buses import I2CBus, I2CError
from hwbridge.devices.world import Air
from hwbridge.emulator import VirtualBoard, load_board
from hwbridge.emulator.world import WorldConfig
from hwbridge.errors import HwBridgeError
from hwbridge.graph import Graph
from hwbridge.links import open_link
from hwbridge.robot.config import load_robot
from hwbridge.robot.runtime import RobotRuntime
from tests.netutil import free_port, wait_until

OSRS = (1, 2, 4, 8, 16)
ROBOT = """\
robot: weather
world:
  air: {{temperature: 23.5, pressure: 98000.0, humidity: 61.0}}
boards:
  - name: station
    link: {link}
    protocol: native
    namespace: /weather
    devices:
      - {{type: bme280, rate: 10}}
"""
TRUTH = Air(23.5, 98000.0, 61.0)


def _resolution(osrs: int) -> tuple[float, float]:
    """The datasheet's resolution of temperature (degC) and pressure (Pa) at an oversampling
    (16 bits at x1, one more bit per doubling, filter off)."""
    step = {1: 1, 2: 2, 4: 4, 8: 8, 16: 16}[osrs]
    return 0.0050 / step, 2.62 / step


def _compensated(raw: tuple[int, int, int], cal: Calibration = TYPICAL) -> Air:
    adc_t, adc_p, adc_h = raw
    fine = t_fine(adc_t, cal)
    return Air(
        compensate_t(fine) / 100.0,
        compensate_p(adc_p, fine, cal) / 256.0,
        compensate_h(adc_h, fine, cal) / 1024.0,
    )


# ------------------------------------------------------------------ compensation


def test_the_datasheets_worked_example() -> None:
    """The worked example of Bosch's datasheets: adc_T 519888 -> 25.08 degC, t_fine 128422;
    adc_P 415148 -> 100653.27 Pa (their floating-point result; the 64-bit integer formula
    agrees within 0.05 Pa) with dig_T1.. / dig_P1.. of :data:`TYPICAL`."""
    fine = t_fine(519888, TYPICAL)
    assert fine == 128422
    assert compensate_t(fine) == 2508
    assert compensate_p(415148, fine, TYPICAL) / 256.0 == pytest.approx(100653.27, abs=0.05)


@given(
    temperature=st.floats(-40.0, 85.0),
    pressure=st.floats(30000.0, 110000.0),
    humidity=st.floats(0.0, 100.0),
    osrs_t=st.sampled_from(OSRS),
    osrs_p=st.sampled_from(OSRS),
)
@settings(max_examples=150, deadline=None)
def test_compensating_the_models_raw_values_gives_back_the_air(
    temperature: float, pressure: float, humidity: float, osrs_t: int, osrs_p: int
) -> None:
    truth = Air(temperature, pressure, humidity)
    raw = adc_values(truth, TYPICAL, (osrs_t, osrs_p, 1))
    got = _compensated(raw)
    t_res, _ = _resolution(osrs_t)
    _, p_res = _resolution(osrs_p)
    assert abs(got.temperature - temperature) <= 0.01 + t_res  # output LSB 0.01 degC
    assert abs(got.pressure - pressure) <= p_res + 1 / 256
    assert abs(got.humidity - humidity) <= 0.008 + 1 / 1024  # 16-bit humidity: 0.008 %RH


@given(
    h4=st.integers(-2048, 2047),
    h5=st.integers(-2048, 2047),
    h2=st.integers(-32768, 32767),
    h6=st.integers(-128, 127),
)
def test_trimming_parameters_survive_the_register_packing(
    h4: int, h5: int, h2: int, h6: int
) -> None:
    cal = dataclasses.replace(TYPICAL, h2=h2, h4=h4, h5=h5, h6=h6)
    assert Calibration.from_registers(cal.tp_bytes(), cal.h1, cal.h_bytes()) == cal


def test_h4_and_h5_share_the_nibbles_of_0xe5() -> None:
    cal = dataclasses.replace(TYPICAL, h4=0x123, h5=-0x2A5)  # -0x2A5 is 0xD5B in 12 bits
    assert cal.h_bytes()[3:6] == bytes([0x12, 0xB3, 0xD5])


# ------------------------------------------------------------------ registers


def test_chip_id_and_calibration_at_their_addresses() -> None:
    chip = Bme280()
    assert chip.read(ID, 1) == bytes([CHIP_ID])
    assert chip.read(0x88, 2) == TYPICAL.t1.to_bytes(2, "little")
    assert chip.read(0xA1, 1) == bytes([TYPICAL.h1])
    assert chip.read(0xE7, 1) == TYPICAL.h6.to_bytes(1, "little", signed=True)
    assert decode_data(chip.read(DATA, 8)) == (0x80000, 0x80000, 0x8000)  # reset values


def test_reset_brings_back_power_on() -> None:
    chip = Bme280()
    chip.write(CTRL_HUM, bytes([0x01]))
    chip.write(CONFIG, bytes([0xA0]))
    chip.write(CTRL_MEAS, bytes([0x27]))  # x1, x1, normal
    chip.advance(0.05)
    assert chip.measurements > 0
    chip.write(RESET, bytes([0x12]))  # anything but 0xB6 does nothing
    assert chip.mode == MODE_NORMAL
    chip.write(RESET, bytes([RESET_VALUE]))
    assert chip.read(CTRL_HUM, 4) == bytes(4)  # ctrl_hum, status, ctrl_meas, config
    assert chip.read(RESET, 1) == b"\x00"
    assert chip.mode == MODE_SLEEP
    assert decode_data(chip.read(DATA, 8)) == (0x80000, 0x80000, 0x8000)


def test_forced_mode_measures_once_then_sleeps() -> None:
    air = Air(30.0, 95000.0, 20.0)
    chip = Bme280(lambda: air)
    chip.write(CTRL_HUM, bytes([0x01]))
    chip.write(CTRL_MEAS, bytes([0x25]))  # osrs_t x1, osrs_p x1, forced
    assert chip.read(STATUS, 1)[0] & MEASURING
    assert chip.read(CTRL_MEAS, 1)[0] & 3 == 1
    busy = measurement_time(1, 1, 1)
    chip.advance(busy / 2)
    assert chip.read(STATUS, 1)[0] & MEASURING  # still measuring
    chip.advance(busy)
    assert not chip.read(STATUS, 1)[0] & MEASURING
    assert chip.read(CTRL_MEAS, 1)[0] == 0x24  # back to sleep, oversampling kept
    assert chip.measurements == 1
    got = _compensated(decode_data(chip.read(DATA, 8)))
    assert got.temperature == pytest.approx(30.0, abs=0.02)
    assert got.pressure == pytest.approx(95000.0, abs=3.0)
    assert got.humidity == pytest.approx(20.0, abs=0.01)
    chip.advance(1.0)
    assert chip.measurements == 1  # asleep: no more


def test_ctrl_hum_takes_effect_at_the_next_ctrl_meas_write() -> None:
    chip = Bme280()
    chip.write(CTRL_MEAS, bytes([0x25]))
    chip.write(CTRL_HUM, bytes([0x01]))  # too late for this measurement
    chip.advance(0.1)
    assert decode_data(chip.read(DATA, 8))[2] == 0x8000  # humidity skipped
    chip.write(CTRL_MEAS, bytes([0x25]))
    chip.advance(0.1)
    assert decode_data(chip.read(DATA, 8))[2] != 0x8000


def test_normal_mode_measures_after_each_standby_time() -> None:
    chip = Bme280()
    chip.write(CONFIG, bytes([0x20]))  # t_sb 62.5 ms
    chip.write(CTRL_MEAS, bytes([0x27]))
    period = measurement_time(1, 1, 0) + 0.0625
    chip.advance(10 * period + 0.001)
    assert chip.measurements == 10
    assert chip.mode == MODE_NORMAL


def test_the_driver_sequence_on_the_bus() -> None:
    chip = Bme280(lambda: TRUTH, address=0x77)
    bus = I2CBus(chip)
    with pytest.raises(I2CError):
        BoardDriver(bus, 0x76, (1, 1, 1), "forced").begin()
    driver = BoardDriver(bus, 0x77, (2, 4, 1), "forced")
    driver.begin()
    assert driver.calibration == TYPICAL
    driver.trigger()
    assert not driver.done()
    chip.advance(measurement_time(2, 4, 1))
    assert driver.done()
    got = from_raw(*driver.read())
    assert got.temperature == pytest.approx(23.5, abs=0.01)
    assert got.pressure == pytest.approx(98000.0, abs=1.0)
    assert got.humidity == pytest.approx(0.61, abs=1e-4)


def test_world_air_from_a_robot_file_and_its_defaults() -> None:
    assert WorldConfig().air == Air(20.0, 101325.0, 45.0)
    config = WorldConfig.from_dict({"air": {"temperature": 5, "humidity": 80}})
    assert config.air == Air(5.0, 101325.0, 80.0)
    with pytest.raises(TypeError):
        WorldConfig.from_dict({"air": {"temprature": 5}})


# ------------------------------------------------------------------ emulator end to end


def test_the_emulated_board_publishes_the_air_of_its_world(tmp_path: Path) -> None:
    robot_file = tmp_path / "weather.yaml"
    robot_file.write_text(ROBOT.format(link="/dev/ttyACM0"))
    board = VirtualBoard(load_board(str(robot_file)), seed=1)
    pty = open_link(f"pty://?symlink={tmp_path / 'ttySTATION'}")
    board.start(pty)
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="bme280")
    robot = load_robot(robot_file).with_links({"station": str(tmp_path / "ttySTATION")})
    runtime = RobotRuntime(robot, graph)
    try:
        runtime.start()
        seen = _watch(graph)
        assert wait_until(lambda: all(len(v) >= 2 for v in seen.values()), 30), {
            k: len(v) for k, v in seen.items()
        }
        _check(seen)
    finally:
        runtime.stop()
        graph.close()
        board.stop()
        pty.close()


def _watch(graph: Graph) -> dict[str, list[Any]]:
    seen: dict[str, list[Any]] = {"temperature": [], "pressure": [], "humidity": []}
    node = graph.node("watch")
    node.subscriber("/weather/temperature", "sensor_msgs/Temperature", seen["temperature"].append)
    node.subscriber("/weather/pressure", "sensor_msgs/FluidPressure", seen["pressure"].append)
    node.subscriber("/weather/humidity", "sensor_msgs/RelativeHumidity", seen["humidity"].append)
    return seen


def _check(seen: dict[str, list[Any]]) -> None:
    temperature, pressure, humidity = (seen[k][-1] for k in ("temperature", "pressure", "humidity"))
    assert float(temperature.temperature) == pytest.approx(TRUTH.temperature, abs=0.02)
    assert float(pressure.fluid_pressure) == pytest.approx(TRUTH.pressure, abs=3.0)
    assert float(humidity.relative_humidity) == pytest.approx(TRUTH.humidity / 100, abs=1e-4)
    assert temperature.header.frame_id == "air_sensor_link"
    assert msg.type_of(humidity) == "sensor_msgs/RelativeHumidity"


# ------------------------------------------------------------------ firmware in simavr


def test_the_example_sketch_in_simavr_reads_the_pin_level_model(tmp_path: Path) -> None:
    from hwbridge.emulator.pins import PinWorld
    from hwbridge.firmware.sim import SimAvr, SimToolchainMissingError, runner_binary
    from hwbridge.firmware.sim.examples import build_example

    try:
        runner_binary()
        elf = build_example("Bme280", "uno")
    except (SimToolchainMissingError, HwBridgeError) as exc:
        pytest.skip(f"Bme280 does not build or run here: {str(exc).splitlines()[0]}")
    robot_file = tmp_path / "weather.yaml"
    robot_file.write_text(ROBOT.format(link="/dev/null"))
    sim = SimAvr(elf)
    graph: Graph | None = None
    runtime: RobotRuntime | None = None
    try:
        sim.start(hold=True)
        world = PinWorld(sim, load_board(str(robot_file))).attach()
        assert world.skipped == []
        sim.go()
        graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="bme280sim")
        robot = load_robot(robot_file).with_links({"station": sim.url})
        runtime = RobotRuntime(robot, graph).start()
        seen = _watch(graph)
        assert wait_until(lambda: all(len(v) >= 2 for v in seen.values()), 60), {
            k: len(v) for k, v in seen.items()
        }
        _check(seen)
        chip = world.models[0].chip  # type: ignore[attr-defined]
        assert chip.measurements >= 2  # forced measurements the firmware triggered
    finally:
        if runtime is not None:
            runtime.stop()
        if graph is not None:
            graph.close()
        sim.close()
