// A minimal Arduino stand-in for the bare Cortex-M boards of `hwbridge firmware build --board
// stm32f405|microbit`: enough for sketches like the HwBridge examples (HelloWorld,
// ServiceServer, Parameters), not the Arduino core. main() (arduino_arm.cpp) calls setup() then
// loop() forever; millis(), micros(), delay() come from the board's start-up code (TIM2 on
// the STM32F4, TIMER0 on the nRF51); pins are values in memory (digitalWrite/digitalRead,
// pinMode; no GPIO is driven); Serial is the board's UART (the one the node uses: a sketch
// that gives it to a node should not write to it too).
#ifndef HWBRIDGE_ARM_ARDUINO_H
#define HWBRIDGE_ARM_ARDUINO_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define HIGH 0x1
#define LOW 0x0
#define INPUT 0x0
#define OUTPUT 0x1
#define INPUT_PULLUP 0x2
#define LED_BUILTIN 13
#define NUM_DIGITAL_PINS 32
#define PROGMEM
#define F(s) (s)

typedef bool boolean;
typedef uint8_t byte;

extern "C" uint32_t hwbridge_board_micros(void);
extern "C" uint32_t hwbridge_board_millis(void);
extern "C" void hwbridge_board_reset(void);

inline unsigned long millis() { return hwbridge_board_millis(); }
inline unsigned long micros() { return hwbridge_board_micros(); }
void delay(unsigned long ms);
void delayMicroseconds(unsigned int us);
void pinMode(uint8_t pin, uint8_t mode);
void digitalWrite(uint8_t pin, uint8_t value);
int digitalRead(uint8_t pin);

/** The board's UART as a byte stream (write, read, available). */
class HardwareSerial {
 public:
  void begin(unsigned long baud);
  int available();
  int read();
  size_t write(uint8_t b);
  size_t write(const char* text);
  size_t print(const char* text) { return write(text); }
  size_t println(const char* text) { return write(text) + write("\r\n"); }
  void flush() {}
  operator bool() const { return true; }

 private:
  int held_ = -1;  // a byte available() read ahead
};

extern HardwareSerial Serial;

void setup();
void loop();

#endif  // HWBRIDGE_ARM_ARDUINO_H
