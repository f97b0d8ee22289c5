// A count of boots for the session id's seed (the Hardware classes' seed()).
//
// A board's clock reads the same at every boot when nothing it waits for varies, and so does an
// analog input with a steady voltage on it: seeded from those alone, every reset would bring the
// last boot's session id back, and the host would take the new boot for the old session
// (PROTOCOL.md 2.10 needs a new id per boot). A reset keeps the RAM's contents (only power-on
// leaves them undefined), and the start-up code clears .bss but never .noinit, so a count kept
// there tells the boots apart. The ARM boards' linker scripts (hwbridge/firmware/arm/core) and
// avr-gcc's default one place .noinit; other toolchains may clear it, and then the count only
// adds nothing.
#ifndef HWBRIDGE_BOOT_COUNT_H
#define HWBRIDGE_BOOT_COUNT_H

#include <stdint.h>

namespace hwbridge {
namespace detail {

/** Boots since power-on, counted from whatever the RAM held then. Weak: one variable however
 * many files include this header (an inline function's static would be one too, but gcc puts
 * it in .bss whatever section it names). */
__attribute__((weak, section(".noinit"))) uint8_t boot_count;

/** Counts this boot; the count placed in bits 8-15, clear of bit 0, which the node sets in
 * every session id: XORed into a seed it makes each boot's id differ from the one before. */
inline uint32_t count_boot() { return static_cast<uint32_t>(++boot_count) << 8; }

}  // namespace detail
}  // namespace hwbridge

#endif  // HWBRIDGE_BOOT_COUNT_H
