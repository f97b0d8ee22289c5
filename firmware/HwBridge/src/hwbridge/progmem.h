// Strings in flash on AVR (PROGMEM), in RAM elsewhere: one way to read both.
#ifndef HWBRIDGE_PROGMEM_H
#define HWBRIDGE_PROGMEM_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

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

/** Copies n bytes that the generated headers keep in flash on AVR. */
inline void flash_copy(uint8_t* to, const char* from, size_t n) {
#ifdef __AVR__
  memcpy_P(to, from, n);
#else
  memcpy(to, from, n);
#endif
}

}  // namespace hwbridge

#endif  // HWBRIDGE_PROGMEM_H
