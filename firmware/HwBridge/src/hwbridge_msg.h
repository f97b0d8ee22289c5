// hwbridge_msg.h: what the generated message headers share.
// ROS 1 serialization, little-endian, bounded (the Writer and Reader of hwbridge_wire.h with
// ROS 1's strings, arrays, time and float64 on top).
// C++11, header-only, no heap, no exceptions. Copied by `hwbridge firmware generate` from
// its template; do not edit.
#ifndef HWBRIDGE_MSG_H
#define HWBRIDGE_MSG_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "hwbridge_wire.h"

#ifdef __AVR__
#include <avr/pgmspace.h>
#define HWBRIDGE_PROGMEM PROGMEM
#else
#define HWBRIDGE_PROGMEM
#endif

// float64 fields are 8 bytes on the wire everywhere. Where double is 4 bytes (AVR) they are
// held as float and converted by hand; -DHWBRIDGE_FLOAT64_AS_FLOAT forces that anywhere.
#if defined(HWBRIDGE_FLOAT64_AS_FLOAT) || (defined(__SIZEOF_DOUBLE__) && __SIZEOF_DOUBLE__ == 4)
#define HWBRIDGE_SOFT_FLOAT64 1
#endif

namespace hwbridge {
namespace msg {

static_assert(sizeof(float) == 4, "float32 fields need a 4-byte IEEE-754 float");
#ifdef HWBRIDGE_SOFT_FLOAT64
typedef float float64;
#else
typedef double float64;
static_assert(sizeof(double) == 8, "double is neither 4 nor 8 bytes");
#endif

/** ROS 1 time: unsigned seconds and nanoseconds. */
struct Time {
  uint32_t sec = 0;
  uint32_t nsec = 0;
};

/** ROS 1 duration: signed seconds and nanoseconds. */
struct Duration {
  int32_t sec = 0;
  int32_t nsec = 0;
};

/** A string of at most N bytes (NUL-terminated in data, the NUL not counted in size). */
template <uint16_t N>
struct String {
  static const uint16_t capacity = N;
  union {
    char data[N + 1];
    char end_;  // data[0]: the one byte an empty string sets
  };
  uint16_t size;
  /** Empty; constexpr, so a global message needs no static constructor. It sets the size and
   * the terminator alone (data[0], through end_): a message the library makes on the stack for
   * a callback (a received message, a service's request and response) does not clear the other
   * N bytes of its strings first (5 cycles a byte on AVR). */
  constexpr String() : end_(), size(0) {}
  /** Copies s; false (and the string left as it was) if it has more than N bytes. */
  bool assign(const char* s) { return assign(s, strlen(s)); }
  /** msg.data = "hello": as assign(s) (a string above N bytes leaves it as it was). */
  String& operator=(const char* s) {
    assign(s);
    return *this;
  }
  bool assign(const char* s, size_t n) {
    if (n > N) return false;
    if (n) memcpy(data, s, n);
    data[n] = '\0';
    size = static_cast<uint16_t>(n);
    return true;
  }
  const char* c_str() const { return data; }
};

/** A variable-length array of at most N elements; size is the count in use. */
template <class T, uint16_t N>
struct Array {
  static const uint16_t capacity = N;
  T data[N];
  uint16_t size;
  constexpr Array() : data(), size(0) {}
  /** Appends v; false if the array is full. */
  bool push_back(const T& v) {
    if (size >= N) return false;
    data[size++] = v;
    return true;
  }
  T& operator[](uint16_t i) { return data[i]; }
  const T& operator[](uint16_t i) const { return data[i]; }
};

namespace detail {

/** IEEE-754 binary32 bits -> binary64 bits (exact). */
inline uint64_t f32_to_f64(uint32_t f) {
  uint64_t sign = static_cast<uint64_t>(f >> 31) << 63;
  uint16_t exp = static_cast<uint16_t>((f >> 23) & 0xFF);
  uint32_t man = f & 0x7FFFFFUL;
  if (exp == 0xFF) return sign | (0x7FFULL << 52) | (static_cast<uint64_t>(man) << 29);
  int16_t e = static_cast<int16_t>(exp) - 127;
  if (exp == 0) {
    if (man == 0) return sign;
    e = -126;  // a subnormal float is a normal double
    while (!(man & 0x800000UL)) {
      man <<= 1;
      --e;
    }
    man &= 0x7FFFFFUL;
  }
  return sign | (static_cast<uint64_t>(e + 1023) << 52) | (static_cast<uint64_t>(man) << 29);
}

/** m >> shift, rounded to nearest, ties to even (shift 1..63). */
inline uint64_t round_shift(uint64_t m, uint8_t shift) {
  uint64_t half = 1ULL << (shift - 1);
  uint64_t rem = m & ((half << 1) - 1);
  uint64_t q = m >> shift;
  if (rem > half || (rem == half && (q & 1))) ++q;
  return q;
}

/** IEEE-754 binary64 bits -> binary32 bits, rounded to nearest even (too large: infinity). */
inline uint32_t f64_to_f32(uint64_t d) {
  uint32_t sign = static_cast<uint32_t>(d >> 63) << 31;
  int16_t exp = static_cast<int16_t>((d >> 52) & 0x7FF);
  uint64_t man = d & 0xFFFFFFFFFFFFFULL;
  if (exp == 0x7FF) {
    return sign | 0x7F800000UL | (man ? 0x400000UL | static_cast<uint32_t>(man >> 29) : 0);
  }
  if (exp == 0) return sign;  // double subnormals are far below the float range
  int16_t e = static_cast<int16_t>(exp - 1023 + 127);
  if (e >= 0xFF) return sign | 0x7F800000UL;
  if (e <= 0) {  // a float subnormal (or zero)
    if (e < -24) return sign;
    uint8_t shift = static_cast<uint8_t>(30 - e);
    return sign | static_cast<uint32_t>(round_shift(man | (1ULL << 52), shift));
  }
  uint32_t bits = (static_cast<uint32_t>(e) << 23) + static_cast<uint32_t>(round_shift(man, 29));
  if (bits >= 0x7F800000UL) return sign | 0x7F800000UL;  // rounding carried into infinity
  return sign | bits;
}

}  // namespace detail

/** The ROS 1 writes on top of the library's bounded little-endian Writer (hwbridge_wire.h). */
class Writer : public wire::Writer {
 public:
  Writer(uint8_t* buf, size_t cap) : wire::Writer(buf, cap) {}
  void i8(int8_t v) { u8(static_cast<uint8_t>(v)); }
  void boolean(bool v) { u8(v ? 1 : 0); }
  void i16(int16_t v) { le(static_cast<uint16_t>(v), 2); }
  void i64(int64_t v) { le64(static_cast<uint64_t>(v)); }
  void f64(float64 v) {
#ifdef HWBRIDGE_SOFT_FLOAT64
    uint32_t u;
    memcpy(&u, &v, 4);
    le64(detail::f32_to_f64(u));
#else
    uint64_t u;
    memcpy(&u, &v, 8);
    le64(u);
#endif
  }
  void time(const Time& t) {
    u32(t.sec);
    u32(t.nsec);
  }
  void duration(const Duration& t) {
    i32(t.sec);
    i32(t.nsec);
  }
  template <uint16_t N>
  void string(const String<N>& s) {
    if (s.size > N) ok_ = false;
    u32(s.size);
    if (s.size && room(s.size)) {
      memcpy(buf_ + pos_, s.data, s.size);
      pos_ += s.size;
    }
  }
  /** A variable-length array's count; fails if it is above the array's capacity. */
  void count(uint16_t n, uint16_t capacity) {
    if (n > capacity) ok_ = false;
    u32(n);
  }
};

/** The ROS 1 reads on top of the library's bounded little-endian Reader (hwbridge_wire.h). */
class Reader : public wire::Reader {
 public:
  Reader(const uint8_t* buf, size_t len) : wire::Reader(buf, len) {}
  int8_t i8() { return static_cast<int8_t>(u8()); }
  bool boolean() { return u8() != 0; }
  int16_t i16() { return static_cast<int16_t>(le(2)); }
  int64_t i64() { return static_cast<int64_t>(u64()); }
  float64 f64() {
    uint64_t u = u64();
    float64 v;
#ifdef HWBRIDGE_SOFT_FLOAT64
    uint32_t f = detail::f64_to_f32(u);
    memcpy(&v, &f, 4);
#else
    memcpy(&v, &u, 8);
#endif
    return v;
  }
  void time(Time* t) {
    t->sec = u32();
    t->nsec = u32();
  }
  void duration(Duration* t) {
    t->sec = i32();
    t->nsec = i32();
  }
  template <uint16_t N>
  void string(String<N>* s) {
    uint32_t n = u32();
    if (!ok_ || n > N || !have(n)) {
      ok_ = false;
      return;
    }
    s->assign(reinterpret_cast<const char*>(buf_ + pos_), n);
    pos_ += n;
  }
  /** A variable-length array's count; fails if it is above the array's capacity. */
  uint16_t count(uint16_t capacity) {
    uint32_t n = u32();
    if (n > capacity) ok_ = false;
    return ok_ ? static_cast<uint16_t>(n) : 0;
  }
};

}  // namespace msg
}  // namespace hwbridge

#endif
