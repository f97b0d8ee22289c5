"""``dynamixel`` (a servo the board drives) on an MCU board: its bus on a spare hardware UART
(``serial: Serial2``; an Uno or a Nano has none besides the link's) through a half-duplex buffer
whose direction pin is ``direction_pin``, and its part of a generated sketch
(``drivers/dynamixel.h``): one bus transaction at a time, never waited for (torque on until the
servo answers, a new goal, else a position read each period), as DiffDriveBase's pan servo.
Register addresses, sizes and the tick scale come from the servo model's control table."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hwbridge.devices.dynamixel.tables import find_model
from hwbridge.firmware.boards import McuBoard
from hwbridge.robot.plugin import PinUse, SketchContext, SketchPart, Wiring, WiringError

__all__ = ["sketch", "uart_number", "wiring"]


def uart_number(serial: str) -> str | None:
    """The simulator's UART number of ``Serial2`` ("2"); None for ``Serial``."""
    digits = serial[len("Serial") :]
    return digits if serial.startswith("Serial") and digits.isdigit() else None


def wiring(settings: Mapping[str, Any], board: McuBoard) -> Wiring:
    return Wiring(
        pins=(PinUse(settings["direction_pin"], "Dynamixel bus direction", "direction_pin"),),
        uarts=((str(settings["serial"]), "serial"),),
    )


def _servo_model(settings: Mapping[str, Any]) -> Any:
    servo_id = int(settings["id"])
    for entry in settings["bus"].get("servos", []):
        if int(entry.get("id", -1)) == servo_id:
            return find_model(str(entry["model"]))
    raise WiringError("bus", f"bus: no servo with id {servo_id} in servos (its model is needed)")


def sketch(settings: Mapping[str, Any], context: SketchContext) -> SketchPart:
    p, nh = context.name, context.node
    model = _servo_model(settings)
    table = model.table
    torque, goal, present = (
        table[name] for name in ("Torque Enable", "Goal Position", "Present Position")
    )
    protocol = int(settings["bus"].get("protocol", 2))
    baud = int(settings["bus"].get("baud", 57600))
    period = max(1, round(1000.0 / float(settings["rate"])))
    serial, direction = str(settings["serial"]), context.board.number(settings["direction_pin"])
    per_tick, zero = float(model.radians_per_tick), float(model.zero_tick)
    joint, servo = str(settings["joint"]), int(settings["id"])
    return SketchPart(
        includes=(
            "hwbridge/drivers/dynamixel.h",
            "sensor_msgs/JointState.h",
            "std_msgs/Float64.h",
        ),
        globals=f"""\
// {p}: {model.name} id {int(settings["id"])}, Protocol {protocol} at {baud} baud on {serial}
DynamixelBus<HardwareSerial> {p}_bus({serial}, {direction}, {protocol});
sensor_msgs::JointState {p}_msg;
hwbridge::Publisher<sensor_msgs::JointState> {p}_pub("{settings["state_topic"]}");
bool {p}_goal_pending = false;
int32_t {p}_goal_ticks = {round(zero)};
bool {p}_torque_on = false;
uint8_t {p}_job = 0;  // 0 none, 1 torque, 2 goal, 3 read
unsigned long {p}_ms = 0;

void {p}_on_goal(const std_msgs::Float64& goal) {{
  float t = static_cast<float>(goal.data) / {per_tick!r}f + {zero!r}f;
  {p}_goal_ticks = static_cast<int32_t>(t >= 0.0f ? t + 0.5f : t - 0.5f);
  {p}_goal_pending = true;
}}
hwbridge::Subscriber<std_msgs::Float64> {p}_goal_sub("{joint}/goal_position", &{p}_on_goal);

void {p}_step() {{
  if ({p}_job != 0) {{
    DxlResult r = {p}_bus.poll();
    if (r == kDxlPending) return;
    int32_t ticks;
    if ({p}_job == 1) {{
      {p}_torque_on = r == kDxlDone;
    }} else if ({p}_job == 3 && r == kDxlDone && {p}_bus.status_int(ticks, {present.size})) {{
      {p}_msg.position[0] = (static_cast<float>(ticks) - {zero!r}f) * {per_tick!r}f;
      {nh}.now(&{p}_msg.header.stamp.sec, &{p}_msg.header.stamp.nsec);
      ++{p}_msg.header.seq;
      {p}_pub.publish({p}_msg);
    }}
    {p}_job = 0;
    return;
  }}
  if (millis() - {p}_ms < {period} && !{p}_goal_pending) return;
  if (!{p}_torque_on) {{
    {p}_ms = millis();
    if ({p}_bus.start_write_int({servo}, {torque.address}, 1, {torque.size})) {p}_job = 1;
  }} else if ({p}_goal_pending) {{
    {p}_goal_pending = false;
    if ({p}_bus.start_write_int({servo}, {goal.address}, {p}_goal_ticks, {goal.size})) {{
      {p}_job = 2;
    }}
  }} else {{
    {p}_ms = millis();
    if ({p}_bus.start_read({servo}, {present.address}, {present.size})) {p}_job = 3;
  }}
}}
""",
        setup=f"""\
{nh}.advertise({p}_pub);
{nh}.subscribe({p}_goal_sub);
{p}_msg.name.size = 1;
{p}_msg.name[0].assign("{joint}");
{p}_msg.position.size = 1;
{p}_bus.begin({baud});
""",
        loop=f"{p}_step();\n",
    )
