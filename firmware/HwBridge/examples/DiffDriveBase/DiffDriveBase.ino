// DiffDriveBase: the firmware of the demo robot, written by hand (examples/robots/diffbot.yaml is
// the Mega's, examples/robots/diffbot_uno.yaml the Uno's). You need not write this: the robot
// file names each device's pins, and
//   hwbridge firmware generate examples/robots/diffbot_uno.yaml --board uno
// writes and builds the equivalent sketch from it (the settings compiled in, so host and board
// read them from one file; tools/bench/generated_firmware.py compares the two). This sketch
// stays as the reference the generator is measured against. Two motors with quadrature
// encoders, a front HC-SR04, an MPU-6050 and, on a Mega, the Dynamixel pan servo. The same topics and types as the emulated
// board, so the same host nodes run against either:
//
//   wheel_ticks       hwbridge_msgs/WheelTicks    out, 50 Hz   (diffdrive -> odom, /tf)
//   wheel_targets     hwbridge_msgs/WheelTargets  in           (diffdrive <- cmd_vel)
//   sonar_echo        hwbridge_msgs/SonarEcho     out, 15 Hz   (hcsr04 -> range)
//   imu_raw           hwbridge_msgs/ImuRaw        out, 50 Hz   (mpu6050 -> imu)
//   joint_states      sensor_msgs/JointState      out, 20 Hz   (Mega: the pan servo)
//   pan/goal_position std_msgs/Float64            in           (Mega: the pan servo)
// and, beyond the emulated board:
//   reset_counters    std_srvs/Trigger            service: both counters to zero, motors stopped
//   max_wheel_speed   parameter (rad/s at full PWM, default 20), followed when it changes (the
//                     generated firmware compiles the robot file's motor_max_speed in instead)
//   logs: the encoders' decoding at each connection, parameter changes
//
//   hwbridge up examples/robots/diffbot.yaml --link base=/dev/ttyACM0
//   hwbridge topic pub -r 10 /diffbot/cmd_vel geometry_msgs/Twist '{linear: {x: 0.2}}'
//
// Wiring (Uno | Mega):
//   left encoder A, B      2, 4 | 2, 3         right encoder A, B   3, 5 | 18, 19
//   left motor PWM, DIR    6, 7 | 6, 7         right motor PWM, DIR 10, 11 | 10, 11
//   HC-SR04 trigger, echo  8, 12 (echo polled: the interrupt pins go to the encoders)
//   MPU-6050 SDA, SCL      A4, A5 | 20, 21
//   Dynamixel bus          - | Serial2 (16, 17) through a 74LS241, direction pin 22
// Encoders: a Mega decodes every edge of both channels (x4: counts_per_rev 1320 for the demo's
// 330 PPR encoders, as diffbot.yaml says). An Uno has two interrupt pins, one per wheel: it
// decodes x2, so give the robot file counts_per_rev 660 there (as diffbot_uno.yaml does; the board
// logs which at connect).
// The counters are 16 bits and wrap, as `counter_bits: 16` says; motors stop 0.5 s after the
// last wheel targets, as the emulated board does.
#include <HwBridge.h>
#include <Wire.h>
#include <hwbridge/drivers/hcsr04.h>
#include <hwbridge/drivers/motor.h>
#include <hwbridge/drivers/mpu.h>
#include <hwbridge/drivers/quadrature.h>
#include <hwbridge_msgs/ImuRaw.h>
#include <hwbridge_msgs/SonarEcho.h>
#include <hwbridge_msgs/WheelTargets.h>
#include <hwbridge_msgs/WheelTicks.h>
#include <std_srvs/Trigger.h>

#if defined(HAVE_HWSERIAL2)
#define WITH_PAN_SERVO 1
#include <hwbridge/drivers/dynamixel.h>
#include <sensor_msgs/JointState.h>
#include <std_msgs/Float64.h>
#endif

using namespace hwbridge::drivers;

// The robot (diffbot.yaml): 20 rad/s at full PWM; readings' rates.
const float kMaxWheelSpeed = 20.0f;
const unsigned long kTicksPeriodMs = 20;  // 50 Hz
const unsigned long kImuPeriodMs = 20;    // 50 Hz
const uint16_t kSonarPeriodMs = 66;       // 15 Hz
const float kTemperatureC = 20.0f;

#if defined(HAVE_HWSERIAL2)
typedef QuadratureEncoder<2, 3> LeftEncoder;
typedef QuadratureEncoder<18, 19> RightEncoder;
#else
typedef QuadratureEncoder<2, 4> LeftEncoder;
typedef QuadratureEncoder<3, 5> RightEncoder;
#endif
Motor left_motor(6, 7);
Motor right_motor(10, 11);
DiffDriveMotors motors(left_motor, right_motor, kMaxWheelSpeed);
HcSr04<8, 12> sonar;
Mpu<TwoWire> imu(Wire);

hwbridge::NodeHandle nh;
hwbridge_msgs::WheelTicks ticks_msg;
hwbridge_msgs::SonarEcho echo_msg;
hwbridge_msgs::ImuRaw imu_msg;
hwbridge::Publisher<hwbridge_msgs::WheelTicks> ticks_pub("wheel_ticks");
hwbridge::Publisher<hwbridge_msgs::SonarEcho> echo_pub("sonar_echo");
hwbridge::Publisher<hwbridge_msgs::ImuRaw> imu_pub("imu_raw");

void on_targets(const hwbridge_msgs::WheelTargets& targets) { motors.command(targets); }
hwbridge::Subscriber<hwbridge_msgs::WheelTargets> targets_sub("wheel_targets", &on_targets);

void on_reset(const std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  LeftEncoder::reset();
  RightEncoder::reset();
  motors.stop();
  res.success = true;
  res.message.assign("counters reset, motors stopped");
}
hwbridge::ServiceServer<std_srvs::Trigger> reset_srv("reset_counters", &on_reset);

void on_max_speed(const hwbridge::ParamValue& value) {
  if (!value.ok() || !(value.asFloat() > 0.0f)) return;  // unset: keep the default
  motors.set_max_speed(value.asFloat());
  char line[48];
  snprintf(line, sizeof line, "max_wheel_speed = %d.%02d rad/s", static_cast<int>(value.asFloat()),
           static_cast<int>(value.asFloat() * 100) % 100);
  nh.logInfo(line);
}

#if defined(WITH_PAN_SERVO)
// The pan servo: an XL430-W250, id 1, Protocol 2.0 at 57600 baud.
const uint8_t kPanId = 1;
const uint16_t kTorqueEnable = 64, kGoalPosition = 116, kPresentPosition = 132;
const unsigned long kJointPeriodMs = 50;  // 20 Hz
DynamixelBus<HardwareSerial> dxl_bus(Serial2, 22, 2);
sensor_msgs::JointState joint_msg;
hwbridge::Publisher<sensor_msgs::JointState> joint_pub("joint_states");
bool goal_pending = false;
int32_t goal_ticks = 2048;
bool torque_on = false;
enum BusJob : uint8_t { kNoJob, kTorqueJob, kGoalJob, kReadJob };
BusJob job = kNoJob;
unsigned long joint_ms = 0;

void on_goal(const std_msgs::Float64& goal) {
  goal_ticks = dxl::x_radians_to_ticks(static_cast<float>(goal.data));
  goal_pending = true;
}
hwbridge::Subscriber<std_msgs::Float64> goal_sub("pan/goal_position", &on_goal);

// One bus transaction at a time, never waited for: torque on (until the servo answers), a new
// goal, else a position read every 50 ms whose answer is published when it comes.
void servo_step() {
  if (job != kNoJob) {
    DxlResult r = dxl_bus.poll();
    if (r == kDxlPending) return;
    int32_t ticks;
    if (job == kTorqueJob) {
      torque_on = r == kDxlDone;
    } else if (job == kReadJob && r == kDxlDone && dxl_bus.status_int(ticks, 4)) {
      joint_msg.position[0] = dxl::x_ticks_to_radians(ticks);
      nh.now(&joint_msg.header.stamp.sec, &joint_msg.header.stamp.nsec);
      ++joint_msg.header.seq;
      joint_pub.publish(joint_msg);
    }
    job = kNoJob;
    return;
  }
  if (millis() - joint_ms < kJointPeriodMs && !goal_pending) return;
  if (!torque_on) {
    joint_ms = millis();
    if (dxl_bus.start_write_int(kPanId, kTorqueEnable, 1, 1)) job = kTorqueJob;
  } else if (goal_pending) {
    goal_pending = false;
    if (dxl_bus.start_write_int(kPanId, kGoalPosition, goal_ticks, 4)) job = kGoalJob;
  } else {
    joint_ms = millis();
    if (dxl_bus.start_read(kPanId, kPresentPosition, 4)) job = kReadJob;
  }
}
#endif

bool announced = false;
unsigned long ticks_ms = 0;
unsigned long imu_ms = 0;

void setup() {
  nh.initNode(115200, "base");
  nh.advertise(ticks_pub);
  nh.advertise(echo_pub);
  nh.advertise(imu_pub);
  nh.subscribe(targets_sub);
  nh.advertiseService(reset_srv);
  ticks_msg.header.frame_id.assign("base_link");
  echo_msg.header.frame_id.assign("sonar_link");
  imu_msg.header.frame_id.assign("imu_link");

  LeftEncoder::begin();
  RightEncoder::begin();
  motors.begin();
  sonar.begin(kSonarPeriodMs);
  Wire.begin();
  Wire.setClock(400000);
  imu.begin(kMpu6050, 2, 250);
#if defined(WITH_PAN_SERVO)
  nh.advertise(joint_pub);
  nh.subscribe(goal_sub);
  joint_msg.name.size = 1;
  joint_msg.name[0].assign("pan");
  joint_msg.position.size = 1;
  dxl_bus.begin(57600);
#endif
}

void loop() {
  unsigned long now = millis();
  if (!nh.connected()) {
    motors.stop();  // no host, no driving
    announced = false;
  } else if (!announced) {
    announced = true;
    char line[80];
    snprintf(line, sizeof line, "encoders x%u (counts_per_rev = PPR x %u), 16-bit counters%s",
             LeftEncoder::decoding(), LeftEncoder::decoding(), imu.ok() ? "" : "; no MPU-6050");
    nh.logInfo(line);
    nh.requestParam("max_wheel_speed", hwbridge::kParamFloat32, &on_max_speed, true);
  }
  motors.update();

  if (now - ticks_ms >= kTicksPeriodMs) {
    ticks_ms = now;
    fill_wheel_ticks<LeftEncoder, RightEncoder>(ticks_msg);
    nh.now(&ticks_msg.header.stamp.sec, &ticks_msg.header.stamp.nsec);
    ++ticks_msg.header.seq;
    ticks_pub.publish(ticks_msg);
  }
  if (sonar.update()) {
    sonar.fill(echo_msg, kTemperatureC);
    nh.now(&echo_msg.header.stamp.sec, &echo_msg.header.stamp.nsec);
    ++echo_msg.header.seq;
    echo_pub.publish(echo_msg);
  }
  if (now - imu_ms >= kImuPeriodMs) {
    imu_ms = now;
    if (imu.read()) {
      imu.fill(imu_msg);
      nh.now(&imu_msg.header.stamp.sec, &imu_msg.header.stamp.nsec);
      ++imu_msg.header.seq;
      imu_pub.publish(imu_msg);
    }
  }
#if defined(WITH_PAN_SERVO)
  servo_step();
#endif
  nh.spinOnce();
}
