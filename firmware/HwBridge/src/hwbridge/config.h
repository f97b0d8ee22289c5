// Library-wide settings that a sketch may override before including HwBridge.h.
#ifndef HWBRIDGE_CONFIG_H
#define HWBRIDGE_CONFIG_H

#include <stdint.h>

namespace hwbridge {

#ifdef HWBRIDGE_COUNTER_TYPE
typedef HWBRIDGE_COUNTER_TYPE Counter;
#elif defined(__AVR__)
/** Type of every statistics counter: 8 bits (wrapping) on an 8-bit board, where ~40 counters
 * over the layers would otherwise cost 80 B of a 2 KB RAM. */
typedef uint8_t Counter;
#else
/** Type of every statistics counter: 16 bits (wrapping). */
typedef uint16_t Counter;
#endif

}  // namespace hwbridge

#endif  // HWBRIDGE_CONFIG_H
