// The definitions behind the host Arduino.h, and main(): included by the one extra source file
// `hwbridge firmware build --board host` compiles next to the sketch. See Arduino.h here.
#ifndef HWBRIDGE_HOST_ARDUINO_IMPL_H
#define HWBRIDGE_HOST_ARDUINO_IMPL_H

#include <signal.h>
#include <time.h>
#include <unistd.h>

#include "Arduino.h"
#include "Wire.h"

HardwareSerial Serial;
HardwareSerial Serial1;
HardwareSerial Serial2;
HardwareSerial Serial3;
TwoWire Wire;

namespace {

struct Pin {
  uint8_t mode;
  int value;  // level, PWM duty or analog reading
  void (*isr)(void);
  int isr_mode;
};
Pin g_pins[NUM_DIGITAL_PINS];
bool g_interrupts = true;

uint64_t host_now_us() {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<uint64_t>(ts.tv_sec) * 1000000u + static_cast<uint64_t>(ts.tv_nsec) / 1000u;
}
const uint64_t g_start = host_now_us();

Pin* pin_at(uint8_t pin) { return pin < NUM_DIGITAL_PINS ? &g_pins[pin] : nullptr; }

int interrupt_pin(uint8_t interrupt) {
  for (uint8_t p = 0; p < NUM_DIGITAL_PINS; ++p) {
    if (digitalPinToInterrupt(p) == interrupt) return p;
  }
  return -1;
}

}  // namespace

unsigned long millis() { return static_cast<unsigned long>(static_cast<uint32_t>((host_now_us() - g_start) / 1000u)); }
unsigned long micros() { return static_cast<unsigned long>(static_cast<uint32_t>(host_now_us() - g_start)); }
void delay(unsigned long ms) { usleep(static_cast<useconds_t>(ms * 1000u)); }
void delayMicroseconds(unsigned int us) { usleep(us); }

void pinMode(uint8_t pin, uint8_t mode) {
  if (Pin* p = pin_at(pin)) {
    p->mode = mode;
    if (mode == INPUT_PULLUP) p->value = HIGH;
  }
}
void digitalWrite(uint8_t pin, uint8_t value) {
  if (Pin* p = pin_at(pin)) p->value = value ? HIGH : LOW;
}
int digitalRead(uint8_t pin) {
  Pin* p = pin_at(pin);
  return p && p->value ? HIGH : LOW;
}
void analogWrite(uint8_t pin, int value) {
  if (Pin* p = pin_at(pin)) p->value = value;
}
int analogRead(uint8_t pin) {
  if (pin < 8) pin = static_cast<uint8_t>(pin + A0);
  Pin* p = pin_at(pin);
  return p && p->mode == 0x80 ? p->value : 512;
}
unsigned long pulseIn(uint8_t, uint8_t, unsigned long) { return 0; }
void attachInterrupt(uint8_t interrupt, void (*handler)(void), int mode) {
  const int pin = interrupt_pin(interrupt);
  if (pin >= 0) {
    g_pins[pin].isr = handler;
    g_pins[pin].isr_mode = mode;
  }
}
void detachInterrupt(uint8_t interrupt) {
  const int pin = interrupt_pin(interrupt);
  if (pin >= 0) g_pins[pin].isr = nullptr;
}
void noInterrupts() { g_interrupts = false; }
void interrupts() { g_interrupts = true; }
long random(long max) { return max > 0 ? static_cast<long>(rand() % max) : 0; }
long random(long min, long max) { return max > min ? min + random(max - min) : min; }
void randomSeed(unsigned long seed) { srand(static_cast<unsigned>(seed)); }
long map(long x, long in_min, long in_max, long out_min, long out_max) {
  return in_max == in_min ? out_min : (x - in_min) * (out_max - out_min) / (in_max - in_min) + out_min;
}

void host_pin_set(uint8_t pin, uint8_t level) {
  Pin* p = pin_at(pin);
  if (p == nullptr) return;
  const int before = p->value;
  p->value = level ? HIGH : LOW;
  const bool rose = !before && p->value, fell = before && !p->value;
  if (p->isr && g_interrupts &&
      ((p->isr_mode == CHANGE && (rose || fell)) || (p->isr_mode == RISING && rose) ||
       (p->isr_mode == FALLING && fell))) {
    p->isr();
  }
}
void host_pin_set_analog(uint8_t pin, int value) {
  if (Pin* p = pin_at(pin)) {
    p->mode = 0x80;  // an analog reading set by the host
    p->value = value;
  }
}
int host_pin_value(uint8_t pin) {
  Pin* p = pin_at(pin);
  return p ? p->value : 0;
}

/** setup(), then loop() forever with a 0.2 ms nap between calls (a real board spins; a host
 * program should not take a whole core). SIGTERM and SIGINT end it. */
int main(int argc, char** argv) {
  if (argc > 1) setenv("HWBRIDGE_LINK", argv[1], 1);
  signal(SIGPIPE, SIG_IGN);
  setvbuf(stdout, nullptr, _IOLBF, 0);
  setup();
  for (;;) {
    loop();
    usleep(200);
  }
}

#endif  // HWBRIDGE_HOST_ARDUINO_IMPL_H
