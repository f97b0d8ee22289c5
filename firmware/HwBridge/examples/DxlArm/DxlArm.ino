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
// polled until the status comes or 10 ms pass. torque_enable answers at once and the writes
// follow (a servo that does not answer is logged).
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
int8_t torque_request = -1;  // -1: none; 0 or 1: to write to both servos
uint8_t torque_next = 0;     // the servo the torque write goes to next
enum BusJob : uint8_t { kNoJob, kTorqueJob, kGoalJob, kReadJob };
BusJob job = kNoJob;
uint8_t job_joint = 0;
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
  // Queued for the bus (written at the next free moments, both servos): the answer says so.
  torque_request = req.data ? 1 : 0;
  torque_next = 0;
  res.success = true;
  res.message.assign(req.data ? "torque on requested" : "torque off requested");
}
hwbridge::ServiceServer<std_srvs::SetBool> torque_srv("torque_enable", &on_torque);

// One transaction at a time, never waited for: torque writes, then goals, else the position of
// each joint in turn every 50 ms; joint_states goes out when the last joint has answered.
void bus_step() {
  if (job != kNoJob) {
    DxlResult r = bus.poll();
    if (r == kDxlPending) return;
    int32_t ticks;
    if (job == kTorqueJob && r != kDxlDone) {
      char line[40];
      snprintf(line, sizeof line, "torque_enable: servo %u did not answer", kIds[job_joint]);
      nh.logWarn(line);
    } else if (job == kReadJob && r == kDxlDone && bus.status_int(ticks, 4)) {
      state_msg.position[job_joint] = dxl::x_ticks_to_radians(ticks);
      any_answer = true;
    }
    bool read_next = job == kReadJob && job_joint + 1 < kJoints;
    bool publish = job == kReadJob && job_joint + 1 == kJoints && any_answer;
    job = kNoJob;
    if (read_next) {
      job_joint = static_cast<uint8_t>(job_joint + 1);
      if (bus.start_read(kIds[job_joint], kPresentPosition, 4)) job = kReadJob;
    } else if (publish) {
      nh.now(&state_msg.header.stamp.sec, &state_msg.header.stamp.nsec);
      ++state_msg.header.seq;
      state_pub.publish(state_msg);
    }
    return;
  }
  if (torque_request >= 0) {
    job_joint = torque_next;
    if (bus.start_write_int(kIds[job_joint], kTorqueEnable, torque_request, 1)) job = kTorqueJob;
    if (++torque_next >= kJoints) torque_request = -1;
    return;
  }
  for (uint8_t j = 0; j < kJoints; ++j) {
    if (goal_pending[j]) {
      goal_pending[j] = false;
      job_joint = j;
      if (bus.start_write_int(kIds[j], kGoalPosition, goal[j], 4)) job = kGoalJob;
      return;
    }
  }
  if (millis() - state_ms >= kStatePeriodMs) {
    state_ms = millis();
    any_answer = false;
    job_joint = 0;
    if (bus.start_read(kIds[0], kPresentPosition, 4)) job = kReadJob;
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
