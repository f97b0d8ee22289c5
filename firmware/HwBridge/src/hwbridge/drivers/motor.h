// DC motors driven by PWM + direction outputs, from hwbridge_msgs/WheelTargets (rad/s).
//
// Pairs with the `diffdrive` device plugin: the host node turns cmd_vel into wheel targets on
// `wheel_targets`; the board drives each motor at |target| / max_wheel_speed of full PWM in the
// target's direction (open loop) and stops both when no targets came for 0.5 s (the plugin's
// TARGET_TIMEOUT, as the emulated board does).
//
//   hwbridge::drivers::Motor left(5, 7), right(6, 8);       // PWM pin, direction pin
//   hwbridge::drivers::DiffDriveMotors motors(left, right, 20.0f);
//   motors.begin();                                         // setup()
//   motors.command(targets.left, targets.right);            // the wheel_targets callback
//   motors.update();                                        // loop(): the timeout
//
// Drivers with one direction input (DRV8871-like boards with PWM/DIR, L298N with IN2 tied to
// an inverter) take the direction pin; a driver with two inputs per motor (IN1/IN2) takes a
// second direction pin that gets the opposite level. A brake is not used: a stopped motor
// coasts (PWM 0).
#ifndef HWBRIDGE_DRIVERS_MOTOR_H
#define HWBRIDGE_DRIVERS_MOTOR_H

#include "arduino_api.h"
#include <stdint.h>

namespace hwbridge {
namespace drivers {

/** Milliseconds without wheel targets after which the motors stop (the plugin's 0.5 s). */
const uint16_t kWheelTargetTimeoutMs = 500;

/** One motor: a PWM output (analogWrite, 0..255) and one or two direction outputs. */
class Motor {
 public:
  static const uint8_t kNoPin = 0xFF;

  Motor(uint8_t pwm_pin, uint8_t dir_pin, uint8_t dir2_pin = kNoPin, bool reversed = false)
      : pwm_pin_(pwm_pin), dir_pin_(dir_pin), dir2_pin_(dir2_pin), reversed_(reversed) {}

  /** Outputs configured, motor stopped. */
  void begin() {
    pinMode(pwm_pin_, OUTPUT);
    pinMode(dir_pin_, OUTPUT);
    if (dir2_pin_ != kNoPin) pinMode(dir2_pin_, OUTPUT);
    set(0);
  }
  /** Duty in -255..255 (clamped): the sign is the direction (negative = backwards). */
  void set(int16_t duty) {
    if (duty > 255) duty = 255;
    if (duty < -255) duty = -255;
    bool forward = (duty >= 0) != reversed_;
    digitalWrite(dir_pin_, forward ? HIGH : LOW);
    if (dir2_pin_ != kNoPin) digitalWrite(dir2_pin_, forward ? LOW : HIGH);
    analogWrite(pwm_pin_, duty >= 0 ? duty : -duty);
    duty_ = duty;
  }
  /** The duty last set. */
  int16_t duty() const { return duty_; }

 private:
  uint8_t pwm_pin_;
  uint8_t dir_pin_;
  uint8_t dir2_pin_;
  bool reversed_;
  int16_t duty_ = 0;
};

/** A wheel speed (rad/s) as a duty for a motor whose full PWM turns the wheel at
    `max_speed` rad/s: rounded, clamped to -255..255; NaN and a non-positive max give 0. */
inline int16_t speed_to_duty(float speed, float max_speed) {
  if (!(max_speed > 0.0f) || speed != speed) return 0;
  float duty = speed / max_speed * 255.0f;
  if (duty >= 255.0f) return 255;
  if (duty <= -255.0f) return -255;
  return static_cast<int16_t>(duty >= 0.0f ? duty + 0.5f : duty - 0.5f);
}

/** The two motors of a differential-drive base, commanded by wheel targets with a timeout. */
class DiffDriveMotors {
 public:
  DiffDriveMotors(Motor& left, Motor& right, float max_wheel_speed,
                  uint16_t timeout_ms = kWheelTargetTimeoutMs)
      : left_(left), right_(right), max_speed_(max_wheel_speed), timeout_ms_(timeout_ms) {}

  void begin() {
    left_.begin();
    right_.begin();
    active_ = false;
  }
  /** New targets in rad/s (positive drives forward); restarts the timeout. */
  void command(float left, float right) {
    left_.set(speed_to_duty(left, max_speed_));
    right_.set(speed_to_duty(right, max_speed_));
    commanded_at_ = millis();
    active_ = true;
  }
  /** From a hwbridge_msgs/WheelTargets (any struct with float `left` and `right`). */
  template <class Targets>
  void command(const Targets& targets) {
    command(targets.left, targets.right);
  }
  /** Call from loop(): stops both motors once the targets are older than the timeout. */
  void update() {
    if (active_ && static_cast<uint32_t>(millis() - commanded_at_) > timeout_ms_) stop();
  }
  /** Both motors stopped now (a board reset, a lost link). */
  void stop() {
    left_.set(0);
    right_.set(0);
    active_ = false;
  }
  /** The wheel speed (rad/s) that full PWM gives (a calibration; used from the next command). */
  void set_max_speed(float max_wheel_speed) { max_speed_ = max_wheel_speed; }
  float max_speed() const { return max_speed_; }
  /** True while targets are being applied (not timed out). */
  bool active() const { return active_; }

 private:
  Motor& left_;
  Motor& right_;
  float max_speed_;
  uint16_t timeout_ms_;
  uint32_t commanded_at_ = 0;
  bool active_ = false;
};

}  // namespace drivers
}  // namespace hwbridge

#endif  // HWBRIDGE_DRIVERS_MOTOR_H
