// The fixed start of hwbridge_control_base.h (copied by `hwbridge firmware generate` from
// hwbridge/firmware/templates/control_prelude.h): the control codec reads and writes with the
// library's bounded Reader and Writer and checks frames with its CRC (hwbridge_wire.h).
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "hwbridge_wire.h"

namespace hwbridge {
namespace control {

static_assert(sizeof(float) == 4, "f32 fields need a 4-byte IEEE-754 float");

/** A run of bytes: a view into a decoded payload, or the caller's data to encode. */
using wire::Bytes;
/** The frame CRC (CRC-16/CCITT-FALSE, chain calls with crc). */
using ::hwbridge::crc16;

namespace detail {

using wire::Reader;
using wire::Writer;

/** Ends an encode: false when something did not fit, else true with *len the bytes written. */
inline bool finish(const Writer& w, size_t* len) {
  if (!w.ok()) return false;
  *len = w.finish();
  return true;
}

/** True if b is well-formed UTF-8 (no overlong forms, surrogates or code points > U+10FFFF). */
inline bool utf8_valid(const Bytes& b) {
  size_t i = 0;
  while (i < b.size) {
    uint8_t c = b.data[i];
    if (c < 0x80) {
      ++i;
      continue;
    }
    size_t n;
    uint8_t lo = 0x80, hi = 0xBF;
    if (c >= 0xC2 && c <= 0xDF) {
      n = 1;
    } else if (c >= 0xE0 && c <= 0xEF) {
      n = 2;
      if (c == 0xE0) lo = 0xA0;
      if (c == 0xED) hi = 0x9F;
    } else if (c >= 0xF0 && c <= 0xF4) {
      n = 3;
      if (c == 0xF0) lo = 0x90;
      if (c == 0xF4) hi = 0x8F;
    } else {
      return false;
    }
    if (b.size - i - 1 < n) return false;
    for (size_t k = 1; k <= n; ++k) {
      uint8_t d = b.data[i + k];
      if (d < (k == 1 ? lo : 0x80) || d > (k == 1 ? hi : 0xBF)) return false;
    }
    i += n + 1;
  }
  return true;
}

}  // namespace detail
