// Library-wide settings that a sketch may override before including HwBridge.h.
#ifndef HWBRIDGE_CONFIG_H
#define HWBRIDGE_CONFIG_H

#include <stdint.h>

namespace hwbridge {

#ifdef HWBRIDGE_COUNTER_TYPE
typedef HWBRIDGE_COUNTER_TYPE Counter;
#else
/** Type of every statistics counter: 16 bits (wrapping) keeps a board's RAM small. */
typedef uint16_t Counter;
#endif

}  // namespace hwbridge

#endif  // HWBRIDGE_CONFIG_H
