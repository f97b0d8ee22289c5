// Strings in flash on AVR (PROGMEM), in RAM elsewhere: one way to read both.
#ifndef HWBRIDGE_PROGMEM_H
#define HWBRIDGE_PROGMEM_H

#include <stddef.h>
#include <stdint.h>

#ifdef __AVR__
#include <avr/pgmspace.h>
#endif

/** Puts a constant table in flash on AVR (read it with flash_byte); plain const elsewhere. */
#ifdef __AVR__
#define HWBRIDGE_PROGMEM PROGMEM
#else
#define HWBRIDGE_PROGMEM
#endif

namespace hwbridge {

/** Byte i of a string that the generated headers keep in flash on AVR. */
inline uint8_t flash_byte(const char* p) {
#ifdef __AVR__
  return pgm_read_byte(p);
#else
  return static_cast<uint8_t>(*p);
#endif
}

/** Value of one hex digit, either case: letters (bit 6 set) are 9 above their low nibble (the
 * generated md5 sums are valid hex: anything else gives some value below 16). */
inline uint8_t hex_value(uint8_t c) {
  return static_cast<uint8_t>((c & 0x40 ? c + 9 : c) & 0x0F);
}

}  // namespace hwbridge

#endif  // HWBRIDGE_PROGMEM_H
