// The Arduino functions the drivers call: <Arduino.h> where there is one (a sketch built by the
// Arduino IDE, arduino-builder, `hwbridge firmware build`, or a host build with its shim);
// otherwise only their declarations, so that each driver header still compiles alone (linking
// then needs an Arduino core or a host shim that defines them).
#ifndef HWBRIDGE_DRIVERS_ARDUINO_API_H
#define HWBRIDGE_DRIVERS_ARDUINO_API_H

#include <stdint.h>

#if defined(__has_include)
#if __has_include(<Arduino.h>)
#include <Arduino.h>
#define HWBRIDGE_DRIVERS_HAVE_ARDUINO 1
#endif
#endif

#ifndef HWBRIDGE_DRIVERS_HAVE_ARDUINO
#define LOW 0x0
#define HIGH 0x1
#define INPUT 0x0
#define OUTPUT 0x1
#define INPUT_PULLUP 0x2
#define CHANGE 1
#define NOT_AN_INTERRUPT -1
extern "C" {
void pinMode(uint8_t pin, uint8_t mode);
void digitalWrite(uint8_t pin, uint8_t value);
int digitalRead(uint8_t pin);
void analogWrite(uint8_t pin, int value);
unsigned long millis(void);
unsigned long micros(void);
void delayMicroseconds(unsigned int us);
void attachInterrupt(uint8_t interrupt, void (*handler)(void), int mode);
void detachInterrupt(uint8_t interrupt);
int digitalPinToInterrupt(uint8_t pin);
void noInterrupts(void);
void interrupts(void);
}
#endif

#endif  // HWBRIDGE_DRIVERS_ARDUINO_API_H
