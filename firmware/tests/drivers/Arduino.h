// A pin- and time-level stand-in for the Arduino core, for host tests of the drivers: pins hold
// levels and modes, an input changed by the test runs the interrupt attached to it (as the
// AVR's external interrupts do: CHANGE, RISING, FALLING), time moves only when the test moves
// it, and analogWrite records the duty. Pins 2 and 3 have interrupts 0 and 1 (an Uno); the test
// can give more pins interrupts (the Mega's 18 and 19, ...).
#ifndef HWBRIDGE_TESTS_FAKE_ARDUINO_H
#define HWBRIDGE_TESTS_FAKE_ARDUINO_H

#include <stddef.h>
#include <stdint.h>

#define LOW 0x0
#define HIGH 0x1
#define INPUT 0x0
#define OUTPUT 0x1
#define INPUT_PULLUP 0x2
#define CHANGE 1
#define FALLING 2
#define RISING 3
#define NOT_AN_INTERRUPT -1

namespace fake {

const int kPins = 70;

struct Board {
  uint8_t mode[kPins];
  uint8_t level[kPins];
  int pwm[kPins];
  int irq_of_pin[kPins];
  void (*handler[8])(void);
  int handler_mode[8];
  unsigned long now_us;
  int interrupts_off;      // nesting of noInterrupts() (never more than 1 on a real AVR)
  unsigned long writes[kPins];  // digitalWrite calls per pin
  // The trigger pulse of an HC-SR04: when it rose and fell.
  unsigned long last_high_us[kPins];
  unsigned long last_low_us[kPins];
};

inline Board& board() {
  static Board b;
  return b;
}

inline void reset(bool mega = false) {
  Board& b = board();
  for (int i = 0; i < kPins; ++i) {
    b.mode[i] = INPUT;
    b.level[i] = LOW;
    b.pwm[i] = -1;
    b.irq_of_pin[i] = NOT_AN_INTERRUPT;
    b.writes[i] = 0;
    b.last_high_us[i] = b.last_low_us[i] = 0;
  }
  for (int i = 0; i < 8; ++i) {
    b.handler[i] = 0;
    b.handler_mode[i] = 0;
  }
  b.irq_of_pin[2] = 0;
  b.irq_of_pin[3] = 1;
  if (mega) {  // the Mega's INT numbers as Arduino maps them
    b.irq_of_pin[18] = 5;
    b.irq_of_pin[19] = 4;
    b.irq_of_pin[20] = 3;
    b.irq_of_pin[21] = 2;
  }
  b.now_us = 1000;
  b.interrupts_off = 0;
}

/** An input driven from outside (a sensor): runs the attached interrupt on a matching edge. */
inline void drive(uint8_t pin, uint8_t level) {
  Board& b = board();
  uint8_t old = b.level[pin];
  b.level[pin] = level ? HIGH : LOW;
  int irq = b.irq_of_pin[pin];
  if (old == b.level[pin] || irq == NOT_AN_INTERRUPT || !b.handler[irq]) return;
  int m = b.handler_mode[irq];
  if (m == CHANGE || (m == RISING && level) || (m == FALLING && !level)) b.handler[irq]();
}

inline void advance_us(unsigned long us) { board().now_us += us; }

}  // namespace fake

inline void pinMode(uint8_t pin, uint8_t mode) {
  fake::board().mode[pin] = mode;
  if (mode == INPUT_PULLUP) fake::board().level[pin] = HIGH;
}
inline void digitalWrite(uint8_t pin, uint8_t value) {
  fake::Board& b = fake::board();
  b.level[pin] = value ? HIGH : LOW;
  ++b.writes[pin];
  if (value) {
    b.last_high_us[pin] = b.now_us;
  } else {
    b.last_low_us[pin] = b.now_us;
  }
}
inline int digitalRead(uint8_t pin) { return fake::board().level[pin]; }
inline void analogWrite(uint8_t pin, int value) { fake::board().pwm[pin] = value; }
inline unsigned long micros(void) { return fake::board().now_us; }
inline unsigned long millis(void) { return fake::board().now_us / 1000; }
inline void delayMicroseconds(unsigned int us) { fake::board().now_us += us; }
inline void delay(unsigned long ms) { fake::board().now_us += ms * 1000; }
inline int digitalPinToInterrupt(uint8_t pin) {
  return pin < fake::kPins ? fake::board().irq_of_pin[pin] : NOT_AN_INTERRUPT;
}
inline void attachInterrupt(uint8_t irq, void (*handler)(void), int mode) {
  fake::board().handler[irq] = handler;
  fake::board().handler_mode[irq] = mode;
}
inline void detachInterrupt(uint8_t irq) { fake::board().handler[irq] = 0; }
inline void noInterrupts(void) { ++fake::board().interrupts_off; }
inline void interrupts(void) { --fake::board().interrupts_off; }

#endif  // HWBRIDGE_TESTS_FAKE_ARDUINO_H
