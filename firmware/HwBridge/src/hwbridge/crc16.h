// CRC-16/CCITT-FALSE of the native protocol (PROTOCOL.md 1.5): polynomial 0x1021, initial
// value 0xFFFF, not reflected, no final XOR; crc16("123456789") == 0x29B1.
#ifndef HWBRIDGE_CRC16_H
#define HWBRIDGE_CRC16_H

#include <stddef.h>
#include <stdint.h>

#if defined(__AVR__)
#include <util/crc16.h>
#endif

namespace hwbridge {

/** Initial value of the CRC. */
static const uint16_t kCrcInit = 0xFFFF;

/** The CRC after one more byte. */
inline uint16_t crc16_update(uint16_t crc, uint8_t byte) {
#if defined(__AVR__) && !defined(HWBRIDGE_SMALL_CRC)
  return _crc_xmodem_update(crc, byte);  // the same CRC, unrolled: ~25 cycles a byte
#elif defined(__AVR__)
  // -DHWBRIDGE_SMALL_CRC: the bit loop below in 9 instructions (the compiler makes 17 of it):
  // shift the top bit out, fold the polynomial back in when it was set. 12 B less flash than
  // avr-libc's, but about 80 cycles a byte (at 1 Mbaud, a third of a 16 MHz AVR's time).
  uint8_t bits;
  const uint8_t lo = 0x21, hi = 0x10;
  __asm__(
      "eor %B0, %4\n\t"
      "ldi %1, 8\n"
      "1:\tlsl %A0\n\t"
      "rol %B0\n\t"
      "brcc 2f\n\t"
      "eor %A0, %2\n\t"
      "eor %B0, %3\n"
      "2:\tdec %1\n\t"
      "brne 1b"
      : "+r"(crc), "=&d"(bits)
      : "r"(lo), "r"(hi), "r"(byte));
  return crc;
#else
  crc = static_cast<uint16_t>(crc ^ (static_cast<uint16_t>(byte) << 8));
  for (uint8_t bit = 0; bit < 8; ++bit) {
    crc = (crc & 0x8000u) ? static_cast<uint16_t>((crc << 1) ^ 0x1021u)
                          : static_cast<uint16_t>(crc << 1);
  }
  return crc;
#endif
}

/** The CRC of n bytes, continuing from crc (kCrcInit for a new one). */
__attribute__((noinline)) inline uint16_t crc16(const uint8_t* data, size_t n,
                                                uint16_t crc = kCrcInit) {
  for (size_t i = 0; i < n; ++i) crc = crc16_update(crc, data[i]);
  return crc;
}

}  // namespace hwbridge

#endif  // HWBRIDGE_CRC16_H
