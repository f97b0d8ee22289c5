// DxlArm: a board driving the two-joint Dynamixel arm of examples/robots/dxl_arm.yaml (two
// XL430-W250, ids 1 and 2, Protocol 2.0 at 57600 baud) in place of the host's U2D2, with the
// same interface as the host's `dynamixel_bus` node:
//
//   joint_states   sensor_msgs/JointState  out, 20 Hz: shoulder and elbow positions (rad)
//   joint_command  sensor_msgs/JointState  in: goal positions by joint name
//   torque_enable  std_srvs/SetBool        service: torque on or off for both servos
//
//   hwbridge connect /dev/ttyACM0
//   hwbridge service call /torque_enable '{data: true}'
//   hwbridge topic pub -r 5 /joint_command sensor_msgs/JointState '{name: [elbow], position: [0.5]}'
//   hwbridge topic echo /joint_states
//
// The bus: a Mega's Serial1 (pins 18, 19); an Uno has one UART, which the host link takes, so
// there the bus is a SoftwareSerial on pins 10 (RX) and 11 (TX) (57600 baud is its limit).
// Either way through a half-duplex buffer (74LS241 or similar) whose direction pin is pin 2
// (high: the board talks). Bus transactions never stall loop(): one at a time, sent, then
// polled until the status comes or 10 ms pass.
#include <HwBridge.h>
#include <hwbridge/drivers/dynamixel.h>
#include <sensor_msgs/JointState.h>
#include <std_srvs/SetBool.h>

#if defined(HAVE_HWSERIAL1)
typedef HardwareSerial BusSerial;
BusSerial& bus_serial = Serial1;
#else
#include <SoftwareSerial.h>
typedef SoftwareSerial BusSerial;
SoftwareSerial bus_serial(10, 11);
#endif

using namespace hwbridge::drivers;

const uint8_t kJoints = 2;
const char* const kNames[kJoints] = {"shoulder", "elbow"};
const uint8_t kIds[kJoints] = {1, 2};
const uint16_t kTorqueEnable = 64, kGoalPosition = 116, kPresentPosition = 132;
const unsigned long kStatePeriodMs = 50;

hwbridge::NodeHandle nh;
DynamixelBus<BusSerial> bus(bus_serial, 2, 2);
sensor_msgs::JointState state_msg;
hwbridge::Publisher<sensor_msgs::JointState> state_pub("joint_states");

int32_t goal[kJoints];
bool goal_pending[kJoints] = {false, false};
int8_t torque_request = -1;  // -1 none, 0 off, 1 on
uint8_t reading = 0;         // the joint being read, + 1 (0: none)
bool any_answer = false;
unsigned long state_ms = 0;

void on_command(const sensor_msgs::JointState& cmd) {
  for (uint16_t i = 0; i < cmd.name.size && i < cmd.position.size; ++i) {
    for (uint8_t j = 0; j < kJoints; ++j) {
      if (strcmp(cmd.name[i].c_str(), kNames[j]) == 0) {
        goal[j] = dxl::x_radians_to_ticks(static_cast<float>(cmd.position[i]));
        goal_pending[j] = true;
      }
    }
  }
}
hwbridge::Subscriber<sensor_msgs::JointState> command_sub("joint_command", &on_command);

void on_torque(const std_srvs::SetBool::Request& req, std_srvs::SetBool::Response& res) {
  // Both servos now (two short writes; the service answer waits for them).
  bool ok = true;
  for (uint8_t j = 0; j < kJoints; ++j) ok = bus.write_u8(kIds[j], kTorqueEnable, req.data) && ok;
  res.success = ok;
  res.message.assign(ok ? (req.data ? "torque on" : "torque off") : "a servo did not answer");
}
hwbridge::ServiceServer<std_srvs::SetBool> torque_srv("torque_enable", &on_torque);

void bus_step() {
  if (reading) {
    DxlResult r = bus.poll();
    if (r == kDxlPending) return;
    uint8_t j = reading - 1;
    reading = 0;
    if (r == kDxlDone && bus.status_size() == 4) {
      const uint8_t* p = bus.status_params();
      int32_t ticks = static_cast<int32_t>(
          static_cast<uint32_t>(p[0]) | (static_cast<uint32_t>(p[1]) << 8) |
          (static_cast<uint32_t>(p[2]) << 16) | (static_cast<uint32_t>(p[3]) << 24));
      state_msg.position[j] = dxl::x_ticks_to_radians(ticks);
      any_answer = true;
    }
    if (j + 1 < kJoints) {
      reading = static_cast<uint8_t>(j + 2);  // the next joint at once
      uint8_t params[4] = {kPresentPosition & 0xFF, kPresentPosition >> 8, 4, 0};
      if (!bus.send(kIds[j + 1], dxl::kRead, params, sizeof params)) reading = 0;
    } else if (any_answer) {
      nh.now(&state_msg.header.stamp.sec, &state_msg.header.stamp.nsec);
      ++state_msg.header.seq;
      state_pub.publish(state_msg);
    }
    return;
  }
  for (uint8_t j = 0; j < kJoints; ++j) {
    if (goal_pending[j]) {
      goal_pending[j] = false;
      bus.write_int(kIds[j], kGoalPosition, goal[j], 4);
      return;
    }
  }
  if (millis() - state_ms >= kStatePeriodMs) {
    state_ms = millis();
    any_answer = false;
    uint8_t params[4] = {kPresentPosition & 0xFF, kPresentPosition >> 8, 4, 0};
    reading = bus.send(kIds[0], dxl::kRead, params, sizeof params) ? 1 : 0;
  }
}

void setup() {
  nh.initNode(115200, "dxl_arm");
  nh.advertise(state_pub);
  nh.subscribe(command_sub);
  nh.advertiseService(torque_srv);
  state_msg.name.size = kJoints;
  state_msg.position.size = kJoints;
  for (uint8_t j = 0; j < kJoints; ++j) state_msg.name[j].assign(kNames[j]);
  bus.begin(57600);
}

void loop() {
  bus_step();
  nh.spinOnce();
}
