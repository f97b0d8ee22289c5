"""``mpu6050`` / ``mpu9250`` on an MCU board: the chip on the board's I2C bus at its ``address``
(0x68, or 0x69 with AD0 high; an MPU-9250's AK8963 also answers at 0x0C) and its part of a
generated sketch (``drivers/mpu.h``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final

from hwbridge.firmware.boards import McuBoard
from hwbridge.robot.plugin import SketchContext, SketchPart, Wiring

__all__ = ["ADDRESSES", "AK8963_I2C", "I2C_PRELUDE", "sketch", "wiring"]

ADDRESSES: Final = (0x68, 0x69)
AK8963_I2C: Final = 0x0C
I2C_PRELUDE: Final = ("Wire.begin();", "Wire.setClock(400000);")


def wiring(settings: Mapping[str, Any], board: McuBoard, magnetometer: bool) -> Wiring:
    addresses = [(int(settings["address"]), "address")]
    if magnetometer:
        addresses.append((AK8963_I2C, "magnetometer"))
    return Wiring(i2c=tuple(addresses))


def sketch(
    settings: Mapping[str, Any], context: SketchContext, chip: int, magnetometer: bool
) -> SketchPart:
    p, nh = context.name, context.node
    period = max(1, round(1000.0 / float(settings["rate"])))
    name = "kMpu9250" if chip == 1 else "kMpu6050"
    mag = ", true" if magnetometer else (", false" if chip == 1 else "")
    return SketchPart(
        includes=("Wire.h", "hwbridge/drivers/mpu.h", "hwbridge_msgs/ImuRaw.h"),
        prelude=I2C_PRELUDE,
        globals=f"""\
// {p}: an {"MPU-9250" if chip == 1 else "MPU-6050"} at 0x{int(settings["address"]):02x}
Mpu<TwoWire> {p}_imu(Wire, 0x{int(settings["address"]):02x});
hwbridge_msgs::ImuRaw {p}_msg;
hwbridge::Publisher<hwbridge_msgs::ImuRaw> {p}_pub("{settings["topic"]}");
uint8_t {p}_error = 0;
unsigned long {p}_ms = 0;
""",
        setup=f"""\
{nh}.advertise({p}_pub);
{p}_msg.header.frame_id.assign("{settings["frame_id"]}");
{p}_error = {p}_imu.begin({name}, {int(settings["accel_range_g"])}, \
{int(settings["gyro_range_dps"])}{mag});
""",
        connect=f"""\
if ({p}_error != 0) {{
  char line[40];
  snprintf(line, sizeof line, "{p}: not ready, error %u", {p}_error);
  {nh}.logError(line);
}}
""",
        loop=f"""\
if (now - {p}_ms >= {period}) {{
  {p}_ms = now;
  if ({p}_imu.read()) {{
    {p}_imu.fill({p}_msg);
    {nh}.now(&{p}_msg.header.stamp.sec, &{p}_msg.header.stamp.nsec);
    ++{p}_msg.header.seq;
    {p}_pub.publish({p}_msg);
  }}
}}
""",
    )
