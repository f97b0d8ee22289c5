// The session id's seed on an Arduino core with no random number generator to read: the seed()
// of ArduinoHardware, and of UdpHardware on boards other than the ESPs.
#ifndef HWBRIDGE_ARDUINO_SEED_H
#define HWBRIDGE_ARDUINO_SEED_H

#include <Arduino.h>
#include <stdint.h>

#include "boot_count.h"

namespace hwbridge {
namespace detail {

/** The clock and the floating analog input 0; on AVR also the count of boots (boot_count.h: a
 * steady A0 and the clock read the same at every boot). */
inline uint32_t arduino_seed() {
  uint32_t s = ::micros();
#ifdef A0
  for (uint8_t i = 0; i < 8; ++i) s = (s << 3) ^ static_cast<uint32_t>(analogRead(A0)) ^ (s >> 29);
#endif
#ifdef __AVR__
  s ^= count_boot();
#endif
  return s;
}

}  // namespace detail
}  // namespace hwbridge

#endif  // HWBRIDGE_ARDUINO_SEED_H
