// Small helpers shared by the host-native test programs (no framework: the first failed check
// prints what differed and exits 1).
#ifndef HWBRIDGE_TESTS_CHECK_H
#define HWBRIDGE_TESTS_CHECK_H

#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <string>
#include <vector>

namespace check {

typedef std::vector<uint8_t> Bytes;

inline unsigned long& count() {
  static unsigned long n = 0;
  return n;
}

inline void fail(const char* fmt, ...) {
  va_list args;
  va_start(args, fmt);
  fprintf(stderr, "FAIL: ");
  vfprintf(stderr, fmt, args);
  fprintf(stderr, "\n");
  va_end(args);
  exit(1);
}

#define CHECK(cond, ...)                                                   \
  do {                                                                     \
    ++check::count();                                                      \
    if (!(cond)) {                                                         \
      fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #cond); \
      check::fail(__VA_ARGS__);                                            \
    }                                                                      \
  } while (0)

inline std::string hex(const uint8_t* p, size_t n) {
  static const char digits[] = "0123456789abcdef";
  std::string s;
  for (size_t i = 0; i < n; ++i) {
    s += digits[p[i] >> 4];
    s += digits[p[i] & 15];
  }
  return s;
}
inline std::string hex(const Bytes& b) { return hex(b.data(), b.size()); }

inline Bytes unhex(const std::string& s) {
  Bytes out;
  if (s == "-") return out;
  if (s.size() % 2) fail("odd-length hex: %s", s.c_str());
  for (size_t i = 0; i < s.size(); i += 2) {
    out.push_back(static_cast<uint8_t>(strtoul(s.substr(i, 2).c_str(), nullptr, 16)));
  }
  return out;
}

/** A sink for write_frame() that appends to a vector. */
struct VecSink {
  Bytes bytes;
  void put(uint8_t b) { bytes.push_back(b); }
};

/** A datagram sink for write_frame() (PROTOCOL.md 1.13): each frame's body, one datagram. */
struct DatagramSink {
  static const bool kDatagram = true;
  std::vector<Bytes> datagrams;
  Bytes current;
  void put(uint8_t b) { current.push_back(b); }
  void endDatagram() {
    datagrams.push_back(current);
    current.clear();
  }
};

/** xorshift64*: a small seeded generator, the same on every platform. */
struct Rng {
  uint64_t s;
  explicit Rng(uint64_t seed) : s(seed ? seed : 0x9E3779B97F4A7C15ULL) {}
  uint64_t next() {
    s ^= s >> 12;
    s ^= s << 25;
    s ^= s >> 27;
    return s * 2685821657736338717ULL;
  }
  uint32_t below(uint32_t n) { return n ? static_cast<uint32_t>(next() % n) : 0; }
  bool chance(uint32_t percent) { return below(100) < percent; }
};

}  // namespace check

#endif  // HWBRIDGE_TESTS_CHECK_H
