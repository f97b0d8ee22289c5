// A non-blocking HC-SR04 ultrasonic ranger (hwbridge_msgs/SonarEcho): the echo pulse's width in
// microseconds, as the `hcsr04` device plugin's host node converts it to sensor_msgs/Range.
//
//   hwbridge::drivers::HcSr04<9, 10> sonar;       // trigger pin 9, echo pin 10
//   sonar.begin(66);                               // setup(): one measurement every 66 ms
//   if (sonar.update()) { echo.echo_us = sonar.echo_us(); ... }   // loop(): true when one is new
//
// update() never waits for the echo: it raises the 10 us trigger pulse when a measurement is due
// and times the echo's edges either in the echo pin's external interrupt (when
// digitalPinToInterrupt(Echo) has one: exact to micros()' 4 us) or by sampling the pin at each
// call (polling: as exact as loop() is fast; call update() often). No pulseIn(). A measurement
// whose echo does not rise, or does not fall, within timeout_us (default 40 ms, past the 38 ms
// the module holds Echo with no return) gives echo_us 0, which the host reads as "timed out";
// a clone that never drops Echo is triggered again only once Echo is low.
#ifndef HWBRIDGE_DRIVERS_HCSR04_H
#define HWBRIDGE_DRIVERS_HCSR04_H

#include "arduino_api.h"
#include <stdint.h>

namespace hwbridge {
namespace drivers {

/** An HC-SR04 with its trigger on pin Trig and its echo on pin Echo. State is static per pair. */
template <uint8_t Trig, uint8_t Echo>
class HcSr04 {
 public:
  static const uint16_t kMinPeriodMs = 60;  // the datasheet's shortest measurement cycle
  static const uint32_t kDefaultTimeoutUs = 40000;

  /** Pins configured; a measurement every period_ms (at least 60 ms). */
  static void begin(uint16_t period_ms = 66, uint32_t timeout_us = kDefaultTimeoutUs) {
    pinMode(Trig, OUTPUT);
    digitalWrite(Trig, LOW);
    pinMode(Echo, INPUT);
    period_ms_ = period_ms < kMinPeriodMs ? kMinPeriodMs : period_ms;
    timeout_us_ = timeout_us;
    phase_ = kIdle;
    edges_ = 0;
    int irq = digitalPinToInterrupt(Echo);
    interrupt_ = irq != NOT_AN_INTERRUPT;
    if (interrupt_) attachInterrupt(irq, &on_echo, CHANGE);
    started_ms_ = millis() - period_ms_;  // the first measurement at once
  }
  /** Drive the measurement: true when a new width is ready (echo_us()). */
  static bool update() {
    if (phase_ == kIdle) {
      if (static_cast<uint32_t>(millis() - started_ms_) < period_ms_) return false;
      if (digitalRead(Echo)) return false;  // still high from a clone that never drops it
      started_ms_ = millis();
      noInterrupts();
      edges_ = 0;
      interrupts();
      digitalWrite(Trig, HIGH);
      delayMicroseconds(10);
      digitalWrite(Trig, LOW);
      trigger_us_ = micros();
      level_ = false;
      phase_ = kMeasuring;
      return false;
    }
    if (!interrupt_) poll();
    noInterrupts();
    uint8_t edges = edges_;
    uint32_t rise = rise_us_, fall = fall_us_;
    interrupts();
    if (edges >= 2) {
      finish(fall - rise);
      return true;
    }
    if (static_cast<uint32_t>(micros() - trigger_us_) > timeout_us_) {
      finish(0);
      return true;
    }
    return false;
  }
  /** The last measurement's echo width in microseconds (0: timed out). */
  static uint32_t echo_us() { return echo_us_; }
  /** Measurements that timed out so far. */
  static uint16_t timeouts() { return timeouts_; }
  /** True when the echo is timed by an interrupt, false when by polling. */
  static bool uses_interrupt() { return interrupt_; }
  /** The echo pin's interrupt handler (public: a sketch's own pin-change ISR may call it). */
  static void on_echo() { edge(digitalRead(Echo) != 0, micros()); }

  /** Fill a hwbridge_msgs/SonarEcho (any struct with `echo_us` and `temperature`). */
  template <class Msg>
  static void fill(Msg& msg, float temperature_c) {
    msg.echo_us = echo_us_;
    msg.temperature = temperature_c;
  }

 private:
  enum Phase : uint8_t { kIdle, kMeasuring };

  static void edge(bool high, uint32_t now) {
    if (phase_ != kMeasuring) return;
    if (high && edges_ == 0) {
      rise_us_ = now;
      edges_ = 1;
    } else if (!high && edges_ == 1) {
      fall_us_ = now;
      edges_ = 2;
    }
  }
  static void poll() {
    bool high = digitalRead(Echo) != 0;
    if (high != level_) {
      level_ = high;
      edge(high, micros());
    }
  }
  static void finish(uint32_t width) {
    echo_us_ = width;
    if (width == 0) ++timeouts_;
    phase_ = kIdle;
  }

  static volatile uint32_t rise_us_;
  static volatile uint32_t fall_us_;
  static volatile uint8_t edges_;
  static volatile uint8_t phase_;
  static uint32_t trigger_us_;
  static uint32_t started_ms_;
  static uint32_t timeout_us_;
  static uint32_t echo_us_;
  static uint16_t period_ms_;
  static uint16_t timeouts_;
  static bool level_;
  static bool interrupt_;
};

template <uint8_t T, uint8_t E>
volatile uint32_t HcSr04<T, E>::rise_us_ = 0;
template <uint8_t T, uint8_t E>
volatile uint32_t HcSr04<T, E>::fall_us_ = 0;
template <uint8_t T, uint8_t E>
volatile uint8_t HcSr04<T, E>::edges_ = 0;
template <uint8_t T, uint8_t E>
volatile uint8_t HcSr04<T, E>::phase_ = 0;
template <uint8_t T, uint8_t E>
uint32_t HcSr04<T, E>::trigger_us_ = 0;
template <uint8_t T, uint8_t E>
uint32_t HcSr04<T, E>::started_ms_ = 0;
template <uint8_t T, uint8_t E>
uint32_t HcSr04<T, E>::timeout_us_ = HcSr04<T, E>::kDefaultTimeoutUs;
template <uint8_t T, uint8_t E>
uint32_t HcSr04<T, E>::echo_us_ = 0;
template <uint8_t T, uint8_t E>
uint16_t HcSr04<T, E>::period_ms_ = 66;
template <uint8_t T, uint8_t E>
uint16_t HcSr04<T, E>::timeouts_ = 0;
template <uint8_t T, uint8_t E>
bool HcSr04<T, E>::level_ = false;
template <uint8_t T, uint8_t E>
bool HcSr04<T, E>::interrupt_ = false;

}  // namespace drivers
}  // namespace hwbridge

#endif  // HWBRIDGE_DRIVERS_HCSR04_H
