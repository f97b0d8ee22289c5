// main() and the pieces of Arduino.h (this folder) that are not inline, for the bare Cortex-M
// boards. The board's UART is the hardware class the node uses (hwbridge/hardware_<target>.h).
#include "Arduino.h"

#if defined(HWBRIDGE_BOARD_STM32F4)
#include <hwbridge/hardware_stm32f4.h>
typedef hwbridge::Stm32f4Hardware BoardUart;
#elif defined(HWBRIDGE_BOARD_NRF51)
#include <hwbridge/hardware_nrf51.h>
typedef hwbridge::Nrf51Hardware BoardUart;
#else
#error "define HWBRIDGE_BOARD_STM32F4 or HWBRIDGE_BOARD_NRF51"
#endif

namespace {
uint8_t pins[NUM_DIGITAL_PINS];
BoardUart uart;
}  // namespace

HardwareSerial Serial;

void delay(unsigned long ms) {
  const unsigned long start = millis();
  while (millis() - start < ms) {
  }
}

void delayMicroseconds(unsigned int us) {
  const unsigned long start = micros();
  while (micros() - start < us) {
  }
}

void pinMode(uint8_t pin, uint8_t mode) {
  if (pin < NUM_DIGITAL_PINS && mode == INPUT_PULLUP) pins[pin] = HIGH;
}

void digitalWrite(uint8_t pin, uint8_t value) {
  if (pin < NUM_DIGITAL_PINS) pins[pin] = value != LOW ? HIGH : LOW;
}

int digitalRead(uint8_t pin) { return pin < NUM_DIGITAL_PINS ? pins[pin] : LOW; }

void HardwareSerial::begin(unsigned long baud) { uart.init(static_cast<uint32_t>(baud)); }

int HardwareSerial::available() {
  if (held_ < 0) held_ = uart.read();
  return held_ < 0 ? 0 : 1;
}

int HardwareSerial::read() {
  const int b = held_ >= 0 ? held_ : uart.read();
  held_ = -1;
  return b;
}

size_t HardwareSerial::write(uint8_t b) {
  uart.put(b);
  return 1;
}

size_t HardwareSerial::write(const char* text) {
  size_t n = 0;
  for (; text[n] != 0; ++n) uart.put(static_cast<uint8_t>(text[n]));
  return n;
}

int main() {
  setup();
  for (;;) loop();
}
