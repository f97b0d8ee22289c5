"""``bme280``: a BME280 on a board's I2C bus, as a device plugin (:mod:`hwbridge.robot.plugin`):
its settings, its model on a virtual board, its pin-level model (:mod:`.pins`) and its host node
(:mod:`.node`).

The board's driver reads the trimming parameters once, configures the oversampling (and, in
normal mode, the standby time), then for each reading either triggers a forced measurement and
waits for the chip to go back to sleep, or reads the newest measurement of normal mode; it
compensates with the datasheet's integer formulas and publishes ``air_raw``
(hwbridge_msgs/Bme280). :class:`BoardDriver` makes the same register transfers on the emulated
bus."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, ClassVar, Final

from hwbridge.devices.bme280 import firmware as onboard
from hwbridge.devices.bme280.chip import (
    ADDRESSES,
    CHIP_ID,
    CONFIG,
    CTRL_HUM,
    CTRL_MEAS,
    DATA,
    ID,
    MEASURING,
    MODE_FORCED,
    MODE_NORMAL,
    MODE_SLEEP,
    STATUS,
    Bme280,
    decode_data,
    measurement_time,
)
from hwbridge.devices.bme280.compensation import (
    CALIB_H1,
    CALIB_H2,
    CALIB_TP,
    Calibration,
    compensate_h,
    compensate_p,
    compensate_t,
    t_fine,
)
from hwbridge.devices.bme280.node import Bme280Node
from hwbridge.devices.bme280.pins import Bme280Pins
from hwbridge.devices.buses import I2CBus, I2CError
from hwbridge.devices.common import encode
from hwbridge.robot.plugin import (
    Closeable,
    DevicePlugin,
    EmulatedBoard,
    Field,
    HostContext,
    PinBoard,
    PinModel,
    SketchContext,
    SketchPart,
    TopicUse,
    Wiring,
)

if TYPE_CHECKING:
    from hwbridge.firmware.boards import McuBoard

__all__ = ["OVERSAMPLING_CHOICES", "Bme280Plugin", "BoardDriver"]

OVERSAMPLING_CHOICES: Final = (1, 2, 4, 8, 16)
_OSRS_CODE: Final = {1: 1, 2: 2, 4: 3, 8: 4, 16: 5}
NORMAL_STANDBY: Final = 0
"""config t_sb in normal mode: 0.5 ms between measurements (the driver reads the newest)."""


class BoardDriver:
    """What the firmware's driver does, on the emulated bus: :meth:`begin` once, then
    :meth:`read` for each reading (compensated: 0.01 degC, Pa Q24.8, %RH Q22.10)."""

    def __init__(self, bus: I2CBus, address: int, osrs: tuple[int, int, int], mode: str) -> None:
        self.bus, self.address, self.osrs, self.mode = bus, address, osrs, mode
        self.calibration: Calibration | None = None

    def begin(self) -> None:
        if self.bus.read(self.address, ID, 1)[0] != CHIP_ID:
            raise I2CError(f"no BME280 at 0x{self.address:02X} (chip id is not 0x60)")
        self.calibration = Calibration.from_registers(
            self.bus.read(self.address, CALIB_TP, 24),
            self.bus.read(self.address, CALIB_H1, 1)[0],
            self.bus.read(self.address, CALIB_H2, 7),
        )
        osrs_t, osrs_p, osrs_h = (_OSRS_CODE[o] for o in self.osrs)
        mode = MODE_NORMAL if self.mode == "normal" else MODE_SLEEP
        self.bus.write(self.address, CTRL_HUM, bytes([osrs_h]))
        self.bus.write(self.address, CONFIG, bytes([NORMAL_STANDBY << 5]))
        self.ctrl_meas = (osrs_t << 5) | (osrs_p << 2)
        self.bus.write(self.address, CTRL_MEAS, bytes([self.ctrl_meas | mode]))

    def trigger(self) -> None:
        """Forced mode: start one measurement (normal mode measures on its own)."""
        if self.mode == "forced":
            self.bus.write(self.address, CTRL_MEAS, bytes([self.ctrl_meas | MODE_FORCED]))

    def done(self) -> bool:
        """The measurement is over (forced: the chip went back to sleep)."""
        status, ctrl_meas = self.bus.read(self.address, STATUS, 2)
        return self.mode == "normal" or (not status & MEASURING and ctrl_meas & 3 == 0)

    def read(self) -> tuple[int, int, int]:
        assert self.calibration is not None, "begin() first"
        adc_t, adc_p, adc_h = decode_data(self.bus.read(self.address, DATA, 8))
        fine = t_fine(adc_t, self.calibration)
        return (
            compensate_t(fine),
            compensate_p(adc_p, fine, self.calibration),
            compensate_h(adc_h, fine, self.calibration),
        )


class Bme280Plugin(DevicePlugin):
    """A BME280: compensated readings on ``air_raw``; the host node makes ``temperature``,
    ``pressure`` and ``humidity``."""

    type = "bme280"
    summary = "BME280 on I2C: air_raw -> temperature, pressure, humidity"
    firmware = "hwbridge/drivers/bme280.h: Bme280"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("address", int, ADDRESSES[0], "I2C address (0x76: SDO low, 0x77: high)", ADDRESSES),
        Field("topic", str, "air_raw", "board topic of the compensated readings"),
        Field("temperature_topic", str, "temperature", "host topic of sensor_msgs/Temperature"),
        Field("pressure_topic", str, "pressure", "host topic of sensor_msgs/FluidPressure"),
        Field("humidity_topic", str, "humidity", "host topic of sensor_msgs/RelativeHumidity"),
        Field("rate", float, 10.0, "readings per second", minimum=0.1, maximum=50.0),
        Field(
            "mode",
            str,
            "forced",
            "one measurement per reading, or measuring continuously",
            ("forced", "normal"),
        ),
        Field("oversampling_t", int, 1, "temperature oversampling", OVERSAMPLING_CHOICES),
        Field("oversampling_p", int, 1, "pressure oversampling", OVERSAMPLING_CHOICES),
        Field("oversampling_h", int, 1, "humidity oversampling", OVERSAMPLING_CHOICES),
        Field("frame_id", str, "air_sensor_link"),
    )

    @staticmethod
    def _oversampling(settings: Mapping[str, Any]) -> tuple[int, int, int]:
        return (
            int(settings["oversampling_t"]),
            int(settings["oversampling_p"]),
            int(settings["oversampling_h"]),
        )

    def emulate(self, settings: Mapping[str, Any], board: EmulatedBoard) -> None:
        world = board.world
        osrs = self._oversampling(settings)
        chip = Bme280(lambda: world.air, address=settings["address"])
        driver = BoardDriver(I2CBus(chip), chip.address, osrs, settings["mode"])
        driver.begin()
        clock = {"last": world.time}

        def read() -> bytes:
            chip.advance(max(0.0, world.time - clock["last"]))
            clock["last"] = world.time
            driver.trigger()
            if not driver.done():
                chip.advance(measurement_time(*osrs))
            temperature, pressure, humidity = driver.read()
            return encode(
                board,
                "hwbridge_msgs/Bme280",
                {
                    "header": board.header(settings["frame_id"]),
                    "temperature": temperature,
                    "pressure": pressure,
                    "humidity": humidity,
                },
            )

        def reset() -> None:
            chip.reset()
            driver.begin()
            clock["last"] = world.time

        board.on_reset(reset)
        board.publisher(settings["topic"], "hwbridge_msgs/Bme280", settings["rate"], read)

    def topics(self, settings: Mapping[str, Any]) -> tuple[TopicUse, ...]:
        return (
            TopicUse(settings["topic"], "hwbridge_msgs/Bme280", "publishes", "board"),
            TopicUse(settings["topic"], "hwbridge_msgs/Bme280", "subscribes"),
            TopicUse(settings["temperature_topic"], "sensor_msgs/Temperature", "publishes"),
            TopicUse(settings["pressure_topic"], "sensor_msgs/FluidPressure", "publishes"),
            TopicUse(settings["humidity_topic"], "sensor_msgs/RelativeHumidity", "publishes"),
        )

    def pin_model(self, settings: Mapping[str, Any], board: PinBoard) -> PinModel:
        return Bme280Pins(Bme280(lambda: board.world.air, address=settings["address"]))

    def wiring(self, settings: Mapping[str, Any], board: McuBoard) -> Wiring:
        return onboard.wiring(settings, board)

    def sketch(self, settings: Mapping[str, Any], context: SketchContext) -> SketchPart:
        return onboard.sketch(settings, context)

    def host_node(self, settings: Mapping[str, Any], context: HostContext) -> Closeable:
        return Bme280Node(
            context.node,
            raw_topic=settings["topic"],
            temperature_topic=settings["temperature_topic"],
            pressure_topic=settings["pressure_topic"],
            humidity_topic=settings["humidity_topic"],
        )
