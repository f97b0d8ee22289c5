// The AVR crc16 on the chip itself (host builds take the C loop): by default the library's
// HWBRIDGE_AVR_CRC_STEP, with -DHWBRIDGE_SMALL_CRC its bit loop, each against avr-libc's
// _crc_xmodem_update (the same CRC) and on the check value; prints "CRC OK" or "CRC BAD" on
// UART 0 (tests/firmware/test_cpp_core.py).
//   avr-g++ -mmcu=atmega328p -std=gnu++11 -Os -flto -I../HwBridge/src avr_crc.cpp -o avr_crc.elf
//   simavr -m atmega328p -f 16000000 avr_crc.elf
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/interrupt.h>
#include <util/crc16.h>
#include "hwbridge_wire.h"

static void out(char c) {
  while (!(UCSR0A & (1 << UDRE0))) {}
  UDR0 = c;
}
static void outs(const char* s) { while (*s) out(*s++); }

int main() {
  UBRR0 = 8;
  UCSR0B = (1 << TXEN0);
  uint8_t buf[300];
  uint32_t x = 12345;
  uint16_t bad = 0;
  for (uint16_t trial = 0; trial < 200; ++trial) {
    uint16_t n = trial < 40 ? trial : (uint16_t)(x % 300);
    for (uint16_t i = 0; i < n; ++i) {
      x ^= x << 13; x ^= x >> 17; x ^= x << 5;
      buf[i] = (uint8_t)x;
    }
    uint16_t start = (trial & 1) ? 0xFFFF : (uint16_t)x;
    uint16_t ref = start;
    for (uint16_t i = 0; i < n; ++i) ref = _crc_xmodem_update(ref, buf[i]);
    volatile uint16_t got = hwbridge::crc16(buf, n, start);
    if (got != ref) ++bad;
  }
  const uint8_t digits[] = "123456789";
  if (hwbridge::crc16(digits, 9) != 0x29B1) ++bad;
  outs(bad ? "CRC BAD\n" : "CRC OK\n");
  cli();
  sleep_cpu();
  return 0;
}
