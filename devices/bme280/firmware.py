"""``bme280`` on an MCU board: the chip on the board's I2C bus at its ``address`` and its part of
a generated sketch (``drivers/bme280.h``: a forced measurement triggered each period and read
when it is done, or normal mode read each period), as the Bme280 example does."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final

from hwbridge.firmware.boards import McuBoard
from hwbridge.robot.plugin import SketchContext, SketchPart, Wiring

__all__ = ["sketch", "wiring"]

_I2C_PRELUDE: Final = ("Wire.begin();", "Wire.setClock(400000);")


def wiring(settings: Mapping[str, Any], board: McuBoard) -> Wiring:
    return Wiring(i2c=((int(settings["address"]), "address"),))


def sketch(settings: Mapping[str, Any], context: SketchContext) -> SketchPart:
    p, nh = context.name, context.node
    period = max(1, round(1000.0 / float(settings["rate"])))
    oversampling = ", ".join(str(int(settings[f"oversampling_{k}"])) for k in ("t", "p", "h"))
    normal = "true" if settings["mode"] == "normal" else "false"
    return SketchPart(
        includes=("Wire.h", "hwbridge/drivers/bme280.h", "hwbridge_msgs/Bme280.h"),
        prelude=_I2C_PRELUDE,
        globals=f"""\
// {p}: a BME280 at 0x{int(settings["address"]):02x}
Bme280<TwoWire> {p}_air(Wire, 0x{int(settings["address"]):02x});
hwbridge_msgs::Bme280 {p}_msg;
hwbridge::Publisher<hwbridge_msgs::Bme280> {p}_pub("{settings["topic"]}");
uint8_t {p}_error = 0;
bool {p}_waiting = false;
unsigned long {p}_ms = 0;
""",
        setup=f"""\
{nh}.advertise({p}_pub);
{p}_msg.header.frame_id.assign("{settings["frame_id"]}");
{p}_error = {p}_air.begin({oversampling}, {normal});
""",
        connect=f"""\
if ({p}_error != kBme280Ok) {{
  char line[40];
  snprintf(line, sizeof line, "{p}: not ready, error %u", {p}_error);
  {nh}.logError(line);
}}
""",
        loop=f"""\
if ({p}_waiting) {{
  if ({p}_air.done()) {{
    {p}_waiting = false;
    if ({p}_air.read()) {{
      {p}_air.fill({p}_msg);
      {nh}.now(&{p}_msg.header.stamp.sec, &{p}_msg.header.stamp.nsec);
      ++{p}_msg.header.seq;
      {p}_pub.publish({p}_msg);
    }}
  }}
}} else if (now - {p}_ms >= {period}) {{
  {p}_ms = now;
  {p}_waiting = {p}_air.trigger();
}}
""",
    )
