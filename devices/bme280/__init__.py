"""BME280 temperature, pressure and humidity sensor on I2C.

- :mod:`.compensation`: the chip's trimming parameters (their register packing) and the
  datasheet's integer compensation formulas, which the board's driver runs too;
- :mod:`.chip`: the emulated chip at register level (id, reset, ctrl_hum, status, ctrl_meas,
  config, raw data; forced and normal mode), measuring the world's air;
- :mod:`.plugin`: the device plugin ``bme280`` (settings, the model on a virtual board, the
  pin-level model, the host node, the firmware driver ``hwbridge/drivers/bme280.h``);
- :mod:`.node`: the host node, ``air_raw`` (hwbridge_msgs/Bme280) -> ``temperature``,
  ``pressure`` and ``humidity`` (sensor_msgs/Temperature, FluidPressure, RelativeHumidity);
- :mod:`.pins`: the chip's register file on the TWI bus of firmware in simavr.
"""
