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
#if defined(__AVR__)
  return _crc_xmodem_update(crc, byte);  // the same CRC, in a few instructions
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
