// A host stand-in for the Arduino core, so that a sketch builds and runs as a native program
// (`hwbridge firmware build SKETCH --board host`). Only on the include path of host builds.
//
// What it does: setup() then loop() forever (main() is in arduino_host_impl.h); millis(),
// micros(), delay(), delayMicroseconds() on the monotonic clock; pins as values in memory
// (digitalWrite/digitalRead/analogWrite/analogRead/pinMode; an input reads what the sketch last
// wrote, or its pull-up; analogRead gives 512 unless host_pin_set_analog() says otherwise);
// attachInterrupt() records the handler (host_pin_set() fires it on a matching edge);
// Serial..Serial3 and SoftwareSerial accept and discard bytes and never receive any; Wire
// answers nothing (endTransmission() returns 2, NACK). The HwBridge node itself does not use
// Serial on a host build: its link is a PosixHardware (a pty or a socket).
#ifndef HWBRIDGE_HOST_ARDUINO_H
#define HWBRIDGE_HOST_ARDUINO_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define HWBRIDGE_HOST 1

#define HIGH 0x1
#define LOW 0x0
#define INPUT 0x0
#define OUTPUT 0x1
#define INPUT_PULLUP 0x2
#define CHANGE 1
#define FALLING 2
#define RISING 3
#define NOT_AN_INTERRUPT -1
#define LED_BUILTIN 13
#define NUM_DIGITAL_PINS 70
#define A0 54
#define A1 55
#define A2 56
#define A3 57
#define A4 58
#define A5 59
#define SDA 20
#define SCL 21
#define HAVE_HWSERIAL1
#define HAVE_HWSERIAL2
#define HAVE_HWSERIAL3
#define PROGMEM
#define F(s) (s)
#define pgm_read_byte(p) (*reinterpret_cast<const uint8_t*>(p))
#define digitalPinToInterrupt(p) ((p) == 2 ? 0 : (p) == 3 ? 1 : (p) == 18 ? 5 : (p) == 19 ? 4 : (p) == 20 ? 3 : (p) == 21 ? 2 : NOT_AN_INTERRUPT)

typedef bool boolean;
typedef uint8_t byte;

unsigned long millis();
unsigned long micros();
void delay(unsigned long ms);
void delayMicroseconds(unsigned int us);
void pinMode(uint8_t pin, uint8_t mode);
void digitalWrite(uint8_t pin, uint8_t value);
int digitalRead(uint8_t pin);
void analogWrite(uint8_t pin, int value);
int analogRead(uint8_t pin);
unsigned long pulseIn(uint8_t pin, uint8_t state, unsigned long timeout = 1000000UL);
void attachInterrupt(uint8_t interrupt, void (*handler)(void), int mode);
void detachInterrupt(uint8_t interrupt);
void noInterrupts();
void interrupts();
long random(long max);
long random(long min, long max);
void randomSeed(unsigned long seed);
long map(long x, long in_min, long in_max, long out_min, long out_max);
template <class T, class U>
auto constrain(T x, U lo, U hi) -> decltype(x + lo) { return x < lo ? lo : (x > hi ? hi : x); }

/** Host builds only: set an input pin's level (an interrupt attached to it fires on a matching
 * edge), an analog input's value, and read what the sketch wrote to a pin (PWM duty or level). */
void host_pin_set(uint8_t pin, uint8_t level);
void host_pin_set_analog(uint8_t pin, int value);
int host_pin_value(uint8_t pin);

class Print {
 public:
  virtual ~Print() {}
  virtual size_t write(uint8_t b) = 0;
  virtual size_t write(const uint8_t* p, size_t n) {
    for (size_t i = 0; i < n; ++i) write(p[i]);
    return n;
  }
  size_t write(const char* s) { return write(reinterpret_cast<const uint8_t*>(s), strlen(s)); }
  size_t print(const char* s) { return write(s); }
  size_t print(long v) { return printf_(v < 0 ? "%ld" : "%ld", v); }
  size_t print(int v) { return print(static_cast<long>(v)); }
  size_t print(unsigned long v) { return printf_("%lu", v); }
  size_t print(unsigned int v) { return print(static_cast<unsigned long>(v)); }
  size_t print(double v, int digits = 2) {
    char b[40];
    snprintf(b, sizeof b, "%.*f", digits, v);
    return write(b);
  }
  template <class T>
  size_t println(T v) { return print(v) + println(); }
  size_t println() { return write("\r\n"); }
  virtual void flush() {}

 private:
  template <class T>
  size_t printf_(const char* fmt, T v) {
    char b[24];
    snprintf(b, sizeof b, fmt, v);
    return write(b);
  }
};

class Stream : public Print {
 public:
  virtual int available() = 0;
  virtual int read() = 0;
  virtual int peek() = 0;
  void setTimeout(unsigned long) {}
};

/** A UART that goes nowhere: writes are discarded, nothing is ever received. */
class HardwareSerial : public Stream {
 public:
  void begin(unsigned long, uint8_t = 0) {}
  void end() {}
  int available() override { return 0; }
  int read() override { return -1; }
  int peek() override { return -1; }
  int availableForWrite() { return 64; }
  using Print::write;
  size_t write(uint8_t) override { return 1; }
  operator bool() const { return true; }
};

extern HardwareSerial Serial;
extern HardwareSerial Serial1;
extern HardwareSerial Serial2;
extern HardwareSerial Serial3;

void setup();
void loop();

#endif  // HWBRIDGE_HOST_ARDUINO_H
