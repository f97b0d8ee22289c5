"""hwbridge.devices.imu: the emulated MPU-6050 / MPU-9250 and the host plugin."""

from __future__ import annotations

import math
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge import msg
from hwbridge.devices.imu import (
    ChipErrors,
    I2CBus,
    I2CError,
    ImuConfigError,
    ImuError,
    ImuTruth,
    Mpu6050,
    Mpu9250,
    MpuImu,
    decode_burst,
)
from hwbridge.devices.imu.host import (
    accel_scale,
    gyro_scale,
    sample_rate_divider,
    sensitivity_adjustment,
)
from hwbridge.devices.imu.mpu import (
    ACCEL_CONFIG,
    ACCEL_LSB_PER_G,
    ACCEL_XOUT_H,
    AK8963_ADDRESS,
    AK8963_ASAX,
    AK8963_CNTL1,
    AK8963_HXL,
    AK8963_ST1,
    AK8963_WIA,
    CONFIG,
    GYRO_CONFIG,
    GYRO_LSB_PER_DPS,
    INT_PIN_CFG,
    MPU6050,
    MPU9250,
    PWR_MGMT_1,
    SMPLRT_DIV,
    WHO_AM_I,
    ChipSpec,
    MpuChip,
)
from hwbridge.devices.world import STANDARD_GRAVITY
from hwbridge.emulator.board import load_board
from hwbridge.errors import HwBridgeError

G = STANDARD_GRAVITY
RANGES = [(2, 250), (4, 500), (8, 1000), (16, 2000)]
SIGMAS = 5.0  # noise bound in standard deviations


def _burst(bus: I2CBus, address: int = 0x68) -> tuple[int, ...]:
    return struct.unpack(">7h", bus.read(address, ACCEL_XOUT_H, 14))


# ---------------------------------------------------------------------- registers
@pytest.mark.parametrize(
    ("chip_class", "who", "pwr"), [(Mpu6050, 0x68, 0x40), (Mpu9250, 0x71, 0x01)]
)
@pytest.mark.parametrize("address", [0x68, 0x69])
def test_who_am_i_and_reset_values(
    chip_class: type[MpuChip], who: int, pwr: int, address: int
) -> None:
    bus = I2CBus(chip_class(address))
    assert bus.read(address, WHO_AM_I, 1) == bytes([who])
    assert bus.read(address, PWR_MGMT_1, 1) == bytes([pwr])
    assert bus.read(address, SMPLRT_DIV, 4) == bytes(4)
    other = 0x69 if address == 0x68 else 0x68
    with pytest.raises(I2CError, match="no acknowledge"):
        bus.read(other, WHO_AM_I, 1)
    bus.write(address, WHO_AM_I, b"\x00")  # read-only
    assert bus.read(address, WHO_AM_I, 1) == bytes([who])


def test_acceptance_6050_asleep_after_reset_reads_zero_until_woken() -> None:
    chip = Mpu6050(seed=1)
    bus = I2CBus(chip)
    chip.advance(1.0)
    chip.sample()
    assert _burst(bus) == (0,) * 7  # asleep: nothing latched
    bus.write(0x68, PWR_MGMT_1, b"\x00")  # wake
    chip.advance(0.01)
    awake = _burst(bus)
    assert awake[2] == pytest.approx(16384, abs=0.12 * 16384)  # ~ +1 g on z
    bus.write(0x68, PWR_MGMT_1, b"\x40")  # back to sleep: data frozen
    chip.set_truth(ImuTruth(specific_force=(G, 0.0, 0.0)))
    chip.advance(1.0)
    assert _burst(bus) == awake
    bus.write(0x68, PWR_MGMT_1, b"\x80")  # DEVICE_RESET: asleep again, data zero
    assert bus.read(0x68, PWR_MGMT_1, 1) == b"\x40"
    chip.advance(1.0)
    assert _burst(bus) == (0,) * 7


def test_9250_is_awake_after_reset() -> None:
    chip = Mpu9250(seed=1)
    chip.advance(0.01)
    assert _burst(I2CBus(chip))[2] != 0


@pytest.mark.parametrize(("dlpf", "div", "rate"), [(0, 7, 1000.0), (3, 9, 100.0), (7, 0, 8000.0)])
def test_sample_rate_from_divider_and_dlpf(dlpf: int, div: int, rate: float) -> None:
    chip = Mpu6050()
    bus = I2CBus(chip)
    bus.write(0x68, SMPLRT_DIV, bytes([div, dlpf]))  # SMPLRT_DIV, then CONFIG (auto-increment)
    assert bus.read(0x68, CONFIG, 1) == bytes([dlpf])
    bus.write(0x68, PWR_MGMT_1, b"\x01")
    assert chip.sample_rate == rate
    for _ in range(200):
        chip.advance(0.5e-3)
    assert chip.samples == pytest.approx(rate * 0.1, abs=1)
    assert sample_rate_divider(rate, dlpf) == div


# ---------------------------------------------------------------------- full scale
@pytest.mark.parametrize("fs_sel", [0, 1, 2, 3])
def test_full_scale_lsb_factors(fs_sel: int) -> None:
    chip = Mpu6050(errors=ChipErrors(), noise=False)
    bus = I2CBus(chip)
    bus.write(0x68, PWR_MGMT_1, b"\x00")
    bus.write(0x68, GYRO_CONFIG, bytes([fs_sel << 3, fs_sel << 3]))  # GYRO_ and ACCEL_CONFIG
    assert bus.read(0x68, ACCEL_CONFIG, 1) == bytes([fs_sel << 3])
    assert (ACCEL_LSB_PER_G[fs_sel], GYRO_LSB_PER_DPS[fs_sel]) == (
        (16384, 131.0),
        (8192, 65.5),
        (4096, 32.8),
        (2048, 16.4),
    )[fs_sel]
    chip.set_truth(
        ImuTruth(
            specific_force=(0.5 * G, -0.25 * G, 1.0 * G),
            angular_velocity=(math.radians(100.0), math.radians(-200.0), math.radians(10.0)),
            temperature_c=36.53,
        )
    )
    chip.sample()
    ax, ay, az, temp, gx, gy, gz = _burst(bus)
    a_lsb, g_lsb = ACCEL_LSB_PER_G[fs_sel], GYRO_LSB_PER_DPS[fs_sel]
    assert (ax, ay, az) == (round(0.5 * a_lsb), round(-0.25 * a_lsb), round(a_lsb))
    assert (gx, gy, gz) == (round(100 * g_lsb), round(-200 * g_lsb), round(10 * g_lsb))
    assert temp == 0  # 6050: C = raw / 340 + 36.53


def test_outputs_saturate_at_full_scale() -> None:
    chip = Mpu6050(errors=ChipErrors(), noise=False)
    bus = I2CBus(chip)
    bus.write(0x68, PWR_MGMT_1, b"\x00")
    chip.set_truth(ImuTruth(specific_force=(3 * G, -3 * G, 0.0), angular_velocity=(10, 0, -10)))
    chip.sample()
    assert _burst(bus)[0:2] == (32767, -32768)
    assert _burst(bus)[4:] == (32767, 0, -32768)


def test_temperature_formulas() -> None:
    for chip_class, spec in ((Mpu6050, MPU6050), (Mpu9250, MPU9250)):
        chip = chip_class(errors=ChipErrors(), noise=False, truth=ImuTruth(temperature_c=41.0))
        imu = MpuImu(I2CBus(chip))
        imu.configure()
        chip.sample()
        reading = imu.read(0.0)
        assert reading.temperature_c == pytest.approx(41.0, abs=1 / spec.temp_lsb_per_c)
    assert (MPU6050.temp_lsb_per_c, MPU6050.temp_offset_c) == (340.0, 36.53)


@pytest.mark.parametrize(
    ("spec", "lsb_per_c", "room_c", "accel_density", "gyro_density"),
    [
        (MPU6050, 340.0, 36.53, 400e-6, 0.005),  # DEVICES.md: C = raw/340 + 36.53
        # MPU-9250: TEMP_degC = (TEMP_OUT - RoomTemp_Offset) / 333.87 + 21, offset 0
        (MPU9250, 333.87, 21.0, 300e-6, 0.01),
    ],
)
def test_a_known_chip_converts_with_its_own_datasheet_figures(
    spec: ChipSpec, lsb_per_c: float, room_c: float, accel_density: float, gyro_density: float
) -> None:
    """Given the chip (as a board reports it), no configure() round trip: temperature and
    the noise-derived covariances are that chip's, not the MPU-6050's."""
    imu = MpuImu(_FakeChipBus(0), chip=spec, dlpf_cfg=0)
    for word in (-32768, -3339, 0, 3339, 32767):
        _, _, temperature = imu.convert(decode_burst(struct.pack(">7h", 0, 0, 0, word, 0, 0, 0)))
        assert temperature == pytest.approx(word / lsb_per_c + room_c)
    assert imu.accel_variance == pytest.approx((accel_density * math.sqrt(260) * G) ** 2)
    assert imu.gyro_variance == pytest.approx(math.radians(gyro_density * math.sqrt(256)) ** 2)


def test_an_unknown_chip_is_not_silently_taken_for_an_mpu6050() -> None:
    imu = MpuImu(_FakeChipBus(0))
    with pytest.raises(ImuError, match="configure"):
        imu.convert(decode_burst(bytes(14)))
    with pytest.raises(ImuError, match="configure"):
        _ = imu.accel_variance


@settings(max_examples=200, deadline=None, derandomize=True)
@given(words=st.lists(st.integers(-32768, 32767), min_size=7, max_size=7))
def test_decode_burst_is_big_endian_signed(words: list[int]) -> None:
    data = b"".join(w.to_bytes(2, "big", signed=True) for w in words)
    raw = decode_burst(data)
    assert (*raw.accel, raw.temperature, *raw.gyro) == tuple(words)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(
    ranges=st.sampled_from(RANGES),
    accel=st.floats(min_value=-1.0, max_value=1.0),
    rate=st.floats(min_value=-1.0, max_value=1.0),
)
def test_si_conversion_within_one_lsb(ranges: tuple[int, int], accel: float, rate: float) -> None:
    """Fractions of full scale -> counts (ideal chip) -> SI, for every full-scale setting."""
    range_g, range_dps = ranges
    a_true = accel * range_g * G * 0.999
    w_true = math.radians(rate * range_dps * 0.999)
    a_counts = round(a_true / G * 32768 / range_g)
    assert a_counts * accel_scale(range_g) == pytest.approx(a_true, abs=accel_scale(range_g))
    w_counts = round(math.degrees(w_true) * GYRO_LSB_PER_DPS[RANGES.index(ranges)])
    assert w_counts * gyro_scale(range_dps) == pytest.approx(w_true, abs=gyro_scale(range_dps))


def test_invalid_settings() -> None:
    bus = I2CBus(Mpu6050())
    with pytest.raises(ImuConfigError, match="accel_range_g"):
        MpuImu(bus, accel_range_g=3)
    with pytest.raises(ImuConfigError, match="gyro_range_dps"):
        MpuImu(bus, gyro_range_dps=300)
    with pytest.raises(ImuConfigError):
        MpuImu(bus, dlpf_cfg=7)
    with pytest.raises(ImuError, match="WHO_AM_I"):
        MpuImu(_FakeChipBus(0x12)).configure()
    with pytest.raises(I2CError):
        MpuImu(bus, address=0x69).configure()
    with pytest.raises(I2CError):
        bus.read(0x68, 0x7F, 2)  # beyond the register map


@pytest.mark.parametrize(
    ("setting", "value", "choices"),
    [("accel_range_g", 3, "2, 4, 8, 16"), ("gyro_range_dps", 300, "250, 500, 1000, 2000")],
)
@pytest.mark.parametrize("kind", ["mpu6050", "mpu9250"])
def test_an_unsupported_range_in_a_board_yaml_names_the_setting_value_and_choices(
    kind: str, setting: str, value: int, choices: str, tmp_path: Path
) -> None:
    path = tmp_path / "imubot.yaml"
    path.write_text(
        "robot: imubot\nboards:\n  - name: base\n    link: pty://\n    devices:\n"
        f"      - type: {kind}\n        rate: 50\n        {setting}: {value}\n"
    )
    with pytest.raises(HwBridgeError) as info:
        load_board(str(path))
    text = str(info.value)
    assert text.startswith(f"{path}:8: ")
    assert setting in text and f"not {value}" in text and choices in text


def test_an_unsupported_range_reaches_the_user_as_an_error_line(tmp_path: Path) -> None:
    path = tmp_path / "imubot.yaml"
    path.write_text(
        "robot: imubot\nboards:\n  - name: base\n    link: pty://\n    devices:\n"
        "      - {type: mpu6050, accel_range_g: 32}\n"
    )
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "emulate", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 1, done.stderr
    assert done.stderr.startswith(
        f"error: {path}:6: board base: mpu6050: accel_range_g: must be one of 2, 4, 8, 16"
    ), done.stderr
    assert "not 32" in done.stderr and "Traceback" not in done.stderr


class _FakeChipBus:
    """Answers every read with one byte value (a different part at the address)."""

    def __init__(self, value: int) -> None:
        self.value = value

    def write(self, address: int, reg: int, data: bytes) -> None:
        pass

    def read(self, address: int, reg: int, n: int) -> bytes:
        return bytes([self.value] * n)


# ---------------------------------------------------------------------- acceptance
@pytest.mark.parametrize("chip_class", [Mpu6050, Mpu9250])
def test_acceptance_at_rest_z_up_reads_plus_g_on_z(chip_class: type[MpuChip]) -> None:
    ideal = chip_class(errors=ChipErrors(), noise=False)
    imu = MpuImu(I2CBus(ideal))
    imu.configure()
    ideal.advance(0.01)
    reading = imu.read(1.0)
    assert reading.linear_acceleration[2] == pytest.approx(9.81, abs=0.005)
    assert reading.linear_acceleration[:2] == (0.0, 0.0)
    assert reading.angular_velocity == (0.0, 0.0, 0.0)

    real = chip_class(seed=42)  # offsets, scale errors and noise within the datasheet
    imu = MpuImu(I2CBus(real))
    imu.configure()
    spec = real.spec
    bound = (
        spec.accel_offset_max[2] * G
        + spec.scale_tolerance * G
        + SIGMAS * spec.accel_noise_std(3) * G
        + accel_scale(2)
    )
    values = []
    for _ in range(100):
        real.advance(0.01)
        values.append(imu.read(0.0).linear_acceleration[2])
        assert abs(values[-1] - G) <= bound
    # The mean sits on this chip's own scale and offset.
    expected = G * (1 + real.errors.accel_scale[2]) + real.errors.accel_offset[2]
    assert np.mean(values) == pytest.approx(expected, abs=spec.accel_noise_std(3) * G)


def _vector3(values: np.ndarray) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in values)
    return (x, y, z)


def _truths(count: int, range_g: int, range_dps: int, seed: int) -> list[ImuTruth]:
    rng = np.random.default_rng(seed)
    return [
        ImuTruth(
            specific_force=_vector3(rng.uniform(-0.8, 0.8, 3) * range_g * G),
            angular_velocity=_vector3(np.radians(rng.uniform(-0.8, 0.8, 3) * range_dps)),
            temperature_c=float(rng.uniform(-10, 60)),
        )
        for _ in range(count)
    ]


@pytest.mark.parametrize("chip_class", [Mpu6050, Mpu9250])
@pytest.mark.parametrize(("range_g", "range_dps"), RANGES)
def test_acceptance_imu_within_quantization_noise_and_offsets(
    chip_class: type[MpuChip], range_g: int, range_dps: int
) -> None:
    chip = chip_class(seed=range_g)
    imu = MpuImu(I2CBus(chip), accel_range_g=range_g, gyro_range_dps=range_dps, dlpf_cfg=2)
    assert imu.configure() is chip.spec
    spec: ChipSpec = chip.spec
    errors = chip.errors
    a_noise = spec.accel_noise_std(2) * G
    g_noise = math.radians(spec.gyro_noise_std(2))
    a_lsb, g_lsb = accel_scale(range_g), gyro_scale(range_dps)
    for truth in _truths(40, range_g, range_dps, seed=range_dps):
        chip.set_truth(truth)
        chip.advance(0.01)
        reading = imu.read(2.0)
        for axis in range(3):
            a_true = truth.specific_force[axis]
            w_true = truth.angular_velocity[axis]
            a_got = reading.linear_acceleration[axis]
            w_got = reading.angular_velocity[axis]
            # Datasheet bounds, whatever this chip's errors are.
            a_bound = (
                spec.accel_offset_max[axis] * G
                + spec.scale_tolerance * abs(a_true)
                + SIGMAS * a_noise
                + a_lsb
            )
            w_bound = (
                math.radians(spec.gyro_offset_max)
                + spec.scale_tolerance * abs(w_true)
                + SIGMAS * g_noise
                + g_lsb
            )
            assert abs(a_got - a_true) <= a_bound
            assert abs(w_got - w_true) <= w_bound
            # With this chip's own errors known: one quantization step plus noise.
            a_expected = a_true * (1 + errors.accel_scale[axis]) + errors.accel_offset[axis]
            w_expected = w_true * (1 + errors.gyro_scale[axis]) + errors.gyro_offset[axis]
            assert abs(a_got - a_expected) <= a_lsb + SIGMAS * a_noise
            assert abs(w_got - w_expected) <= g_lsb + SIGMAS * g_noise


def test_noise_matches_datasheet_density() -> None:
    chip = Mpu6050(errors=ChipErrors(), seed=8)
    imu = MpuImu(I2CBus(chip), dlpf_cfg=0)
    imu.configure()
    accel, gyro = [], []
    for _ in range(2000):
        chip.sample()
        reading = imu.read(0.0)
        accel.append(reading.linear_acceleration[0])
        gyro.append(reading.angular_velocity[0])
    # 400 ug/sqrt(Hz) over 260 Hz; 0.005 deg/s/sqrt(Hz) over 256 Hz.
    assert np.std(accel) == pytest.approx(400e-6 * math.sqrt(260) * G, rel=0.1)
    assert np.std(gyro) == pytest.approx(math.radians(0.005 * math.sqrt(256)), rel=0.1)
    assert imu.accel_variance == pytest.approx((400e-6 * math.sqrt(260) * G) ** 2)


@pytest.mark.parametrize("chip_class", [Mpu6050, Mpu9250])
def test_chip_errors_stay_within_datasheet_bounds(chip_class: type[MpuChip]) -> None:
    spec = chip_class.spec
    drawn = [chip_class(seed=seed).errors for seed in range(200)]
    for errors in drawn:
        for axis in range(3):
            assert abs(errors.accel_offset[axis]) <= spec.accel_offset_max[axis] * G
            assert abs(errors.gyro_offset[axis]) <= math.radians(spec.gyro_offset_max)
            assert abs(errors.accel_scale[axis]) <= spec.scale_tolerance
            assert abs(errors.gyro_scale[axis]) <= spec.scale_tolerance
    assert len({e.gyro_offset for e in drawn}) == len(drawn)  # each chip is different
    assert chip_class(seed=5).errors == chip_class(seed=5).errors  # and seeded


def test_plugin_bias_calibration() -> None:
    chip = Mpu6050(seed=3, noise=False)
    errors = chip.errors
    imu = MpuImu(I2CBus(chip), accel_bias=errors.accel_offset, gyro_bias=errors.gyro_offset)
    imu.configure()
    chip.set_truth(ImuTruth(specific_force=(0.0, 0.0, 0.0)))
    chip.advance(0.01)
    reading = imu.read(0.0)
    assert reading.linear_acceleration == pytest.approx((0, 0, 0), abs=accel_scale(2))
    assert reading.angular_velocity == pytest.approx((0, 0, 0), abs=gyro_scale(250))


# ---------------------------------------------------------------------- magnetometer
def test_ak8963_behind_bypass() -> None:
    chip = Mpu9250(asa=(128, 160, 200))
    bus = I2CBus(chip)
    with pytest.raises(I2CError, match="bypass"):
        bus.read(AK8963_ADDRESS, AK8963_WIA, 1)
    bus.write(0x68, INT_PIN_CFG, b"\x02")
    assert bus.read(AK8963_ADDRESS, AK8963_WIA, 1) == b"\x48"
    chip.set_truth(ImuTruth(magnetic_field=(30e-6, -15e-6, 45e-6)))
    chip.advance(0.1)
    assert bus.read(AK8963_ADDRESS, AK8963_HXL, 6) == bytes(6)  # power-down after reset
    assert bus.read(AK8963_ADDRESS, AK8963_ASAX, 3) == bytes(3)  # fuse ROM mode only
    bus.write(AK8963_ADDRESS, AK8963_CNTL1, b"\x0f")
    assert bus.read(AK8963_ADDRESS, AK8963_ASAX, 3) == bytes([128, 160, 200])
    bus.write(AK8963_ADDRESS, AK8963_CNTL1, b"\x11")  # 16-bit, single measurement
    chip.advance(0.01)
    assert bus.read(AK8963_ADDRESS, AK8963_ST1, 1) == b"\x01"
    hx, hy, hz, st2 = struct.unpack("<3hB", bus.read(AK8963_ADDRESS, AK8963_HXL, 7))
    # Chip axes: x = IMU y, y = IMU x, z = -IMU z; 0.15 uT/LSB; divided by the adjustment.
    assert (hx, hy, hz) == (
        round(-15 / 0.15),
        round(30 / 0.15 / 1.125),
        round(-45 / 0.15 / 1.28125),
    )
    assert st2 == 0x10  # 16-bit output, no overflow
    assert bus.read(AK8963_ADDRESS, AK8963_ST1, 1) == b"\x00"  # reading ST2 cleared DRDY
    assert bus.read(AK8963_ADDRESS, AK8963_CNTL1, 1) == b"\x10"  # back to power-down


def test_acceptance_9250_magnetic_field_in_tesla() -> None:
    chip = Mpu9250(seed=21)
    imu = MpuImu(I2CBus(chip))
    imu.configure()
    assert imu.magnetometer_adjustment is not None
    rng = np.random.default_rng(2)
    for field in rng.uniform(-60e-6, 60e-6, size=(20, 3)):
        truth = (float(field[0]), float(field[1]), float(field[2]))
        chip.set_truth(ImuTruth(magnetic_field=truth))
        chip.advance(0.01)
        reading = imu.read(3.0)
        assert reading.field is not None
        for axis, adj in zip((1, 0, 2), imu.magnetometer_adjustment, strict=True):
            assert abs(reading.field[axis] - truth[axis]) <= 0.15e-6 * adj
        back = msg.decode(msg.encode(reading.magnetic_field), "sensor_msgs/MagneticField")
        assert back.header.frame_id == "imu_link"
        assert back.magnetic_field.z == reading.field[2]
        assert list(back.magnetic_field_covariance) == [0.0] * 9  # unknown
    chip.set_truth(ImuTruth(magnetic_field=(0.0, 0.0, 6e-3)))  # 6 mT > 4912 uT: overflow
    chip.advance(0.01)
    field = imu.read(4.0).field
    assert field is not None and all(math.isnan(v) for v in field)


def test_sensitivity_adjustment_follows_the_datasheet_formula() -> None:
    assert sensitivity_adjustment(bytes([128, 0, 255])) == (1.0, 0.5, 1.49609375)
    assert sensitivity_adjustment(np.array([176, 176, 176], dtype=np.uint8)) == (1.1875,) * 3
    for bad in ([1, 2], [1, 2, 3, 4], [0, 256, 0], [-1, 0, 0]):
        with pytest.raises(ImuError, match="sensitivity adjustment is 3 bytes"):
            sensitivity_adjustment(bad)


def test_6050_has_no_magnetometer() -> None:
    chip = Mpu6050()
    imu = MpuImu(I2CBus(chip))
    imu.configure()
    chip.advance(0.01)
    reading = imu.read(0.0)
    assert reading.magnetic_field is None and reading.field is None


# ---------------------------------------------------------------------- messages
def test_imu_message_serializes() -> None:
    chip = Mpu9250(seed=4)
    imu = MpuImu(I2CBus(chip), use_magnetometer=False)
    imu.configure()
    chip.set_truth(ImuTruth(angular_velocity=(0.1, -0.2, 0.3)))
    chip.advance(0.01)
    assert imu.data_ready()
    assert not imu.data_ready()  # reading INT_STATUS cleared it
    reading = imu.read(7.5)
    assert reading.magnetic_field is None
    back = msg.to_dict(msg.decode(msg.encode(reading.imu), "sensor_msgs/Imu"))
    assert back["header"]["frame_id"] == "imu_link"
    assert back["header"]["stamp"] == {"secs": 7, "nsecs": 500_000_000}
    assert back["orientation_covariance"][0] == -1.0  # raw IMU: no orientation
    av = back["angular_velocity_covariance"]
    assert av[0] == av[4] == av[8] == pytest.approx(imu.gyro_variance) and av[0] > 0
    assert av[1] == av[2] == av[3] == 0.0
    lin = back["linear_acceleration_covariance"]
    assert lin[0] == pytest.approx(imu.accel_variance) and lin[0] > 0
    assert back["angular_velocity"]["z"] == reading.angular_velocity[2]
    assert back["angular_velocity"]["z"] == pytest.approx(0.3, abs=math.radians(6))
    assert back["linear_acceleration"]["z"] == reading.linear_acceleration[2]
