// hwbridge_wire.h: the library's one set of byte helpers. Every place that reads or writes
// bytes on the wire uses these: little-endian loads and stores at a pointer (get16/put32...),
// the bounded Reader and Writer (the control codec and, extended, the ROS 1 message codec),
// and the frame CRC. Copied by `hwbridge firmware generate` from its template; do not edit.
// C++11, header-only, no heap, no exceptions.
#ifndef HWBRIDGE_WIRE_H
#define HWBRIDGE_WIRE_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

namespace hwbridge {

// ---------------------------------------------------------------------------------------------
// CRC-16/CCITT-FALSE of the native protocol (PROTOCOL.md 1.5): polynomial 0x1021, initial
// value 0xFFFF, not reflected, no final XOR; crc16("123456789") == 0x29B1.

/** Initial value of the CRC. */
static const uint16_t kCrcInit = 0xFFFF;

#if defined(__AVR__)
/**
 * One byte of the CRC in AVR instructions, for inline assembly with the operands [crc] (the CRC,
 * a register pair), [c] (the byte), [t] (a scratch register from r16 up) and [t2] (a scratch
 * register): the byte form of CRC-16/CCITT, x = crc.hi ^ c, x ^= x >> 4, then
 * crc = crc << 8 ^ x << 12 ^ x << 5 ^ x, which is new hi = lo ^ (x << 4 & 0xF0) ^ x >> 3 and
 * new lo = x ^ (x << 5 & 0xE0). 18 instructions of one cycle, no branch.
 */
#define HWBRIDGE_AVR_CRC_STEP              \
  "eor %B[crc], %[c]\n\t" /* x */          \
  "mov %[t], %B[crc]\n\t"                  \
  "swap %[t]\n\t"                          \
  "andi %[t], 0x0f\n\t"                    \
  "eor %B[crc], %[t]\n\t" /* x ^= x >> 4 */ \
  "mov %[t], %B[crc]\n\t"                  \
  "swap %[t]\n\t"                          \
  "andi %[t], 0xf0\n\t" /* x << 4 */       \
  "mov %[t2], %B[crc]\n\t"                 \
  "lsr %[t2]\n\t"                          \
  "lsr %[t2]\n\t"                          \
  "lsr %[t2]\n\t" /* x >> 3 */             \
  "eor %[t2], %[t]\n\t"                    \
  "eor %[t2], %A[crc]\n\t" /* new hi */    \
  "lsl %[t]\n\t" /* x << 5 */              \
  "eor %[t], %B[crc]\n\t" /* new lo */     \
  "mov %A[crc], %[t]\n\t"                  \
  "mov %B[crc], %[t2]\n\t"
#endif

/** The CRC after one more byte. */
inline uint16_t crc16_update(uint16_t crc, uint8_t byte) {
#if defined(__AVR__) && !defined(HWBRIDGE_SMALL_CRC)
  uint8_t t, t2;  // 18 cycles a byte (avr-libc's _crc_xmodem_update takes about 25)
  __asm__(HWBRIDGE_AVR_CRC_STEP : [crc] "+r"(crc), [t] "=&d"(t), [t2] "=&r"(t2) : [c] "r"(byte));
  return crc;
#elif defined(__AVR__)
  // -DHWBRIDGE_SMALL_CRC: the bit loop below in 9 instructions (the compiler makes 17 of it):
  // shift the top bit out, fold the polynomial back in when it was set. 2 B less flash than
  // the step above in a hello world (whose frame writer has its own), about 80 cycles a byte.
  uint8_t bits;
  const uint8_t lo = 0x21, hi = 0x10;
  __asm__(
      "eor %B0, %4\n\t"
      "ldi %1, 8\n"
      "1:\tlsl %A0\n\t"
      "rol %B0\n\t"
      "brcc 2f\n\t"
      "eor %A0, %2\n\t"
      "eor %B0, %3\n"
      "2:\tdec %1\n\t"
      "brne 1b"
      : "+r"(crc), "=&d"(bits)
      : "r"(lo), "r"(hi), "r"(byte));
  return crc;
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
#if defined(__AVR__) && !defined(HWBRIDGE_SMALL_CRC)
  if (n != 0) {  // the loop in assembly too: 24 cycles a byte, 10 B less than in C
    uint8_t c, t, t2;
    __asm__("1:\tld %[c], %a[p]+\n\t" HWBRIDGE_AVR_CRC_STEP
            "sbiw %[n], 1\n\t"
            "brne 1b"
            : [p] "+e"(data), [n] "+w"(n), [crc] "+r"(crc), [c] "=&r"(c), [t] "=&d"(t),
              [t2] "=&r"(t2)
            :
            : "memory");
  }
#else
  for (size_t i = 0; i < n; ++i) crc = crc16_update(crc, data[i]);
#endif
  return crc;
}

namespace wire {

// ---------------------------------------------------------------------------------------------
// Little-endian loads and stores at a pointer (the caller knows the bytes are there).

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
// little-endian targets (AVR, ARM, x86): the wire order is the memory order, plain copies
inline uint16_t get16(const uint8_t* p) {
  uint16_t v;
  memcpy(&v, p, 2);
  return v;
}
inline uint32_t get32(const uint8_t* p) {
  uint32_t v;
  memcpy(&v, p, 4);
  return v;
}
inline uint8_t* put16(uint8_t* p, uint16_t v) {
  memcpy(p, &v, 2);
  return p + 2;
}
inline uint8_t* put32(uint8_t* p, uint32_t v) {
  memcpy(p, &v, 4);
  return p + 4;
}
#else
inline uint16_t get16(const uint8_t* p) { return static_cast<uint16_t>(p[0] | p[1] << 8); }
inline uint32_t get32(const uint8_t* p) {
  return static_cast<uint32_t>(get16(p)) | static_cast<uint32_t>(get16(p + 2)) << 16;
}
inline uint8_t* put16(uint8_t* p, uint16_t v) {
  p[0] = static_cast<uint8_t>(v);
  p[1] = static_cast<uint8_t>(v >> 8);
  return p + 2;
}
inline uint8_t* put32(uint8_t* p, uint32_t v) {
  put16(p, static_cast<uint16_t>(v));
  return put16(p + 2, static_cast<uint16_t>(v >> 16));
}
#endif

/** A run of bytes: a view into a decoded payload, or the caller's data to encode. */
struct Bytes {
  const uint8_t* data;
  size_t size;
  Bytes() : data(nullptr), size(0) {}
  Bytes(const uint8_t* d, size_t n) : data(d), size(n) {}
};

// ---------------------------------------------------------------------------------------------
// Bounded streams: a Writer never writes at or past buf + cap, a Reader never reads at or past
// buf + len; both stop at the first problem and report it.

/** Bounded little-endian writes: once one does not fit, nothing more is written. */
class Writer {
 public:
  Writer(uint8_t* buf, size_t cap) : buf_(buf), cap_(cap), pos_(0), ok_(true) {}
  void u8(uint8_t v) {
    if (room(1)) buf_[pos_++] = v;
  }
  void u16(uint16_t v) { le(v, 2); }
  void u32(uint32_t v) { le(v, 4); }
  void i32(int32_t v) { le(static_cast<uint32_t>(v), 4); }
  void u64(uint64_t v) { le64(v); }
  void f32(float v) {
    uint32_t u;
    memcpy(&u, &v, 4);
    le(u, 4);
  }
  /** n bytes from p. */
  void raw(const uint8_t* p, size_t n) {
    if (n == 0 || !room(n)) return;
    memcpy(buf_ + pos_, p, n);
    pos_ += n;
  }
  void fail() { ok_ = false; }
  bool ok() const { return ok_; }
  /** Bytes written, or 0 if something did not fit. */
  size_t finish() const { return ok_ ? pos_ : 0; }

 protected:
  bool room(size_t n) {
    if (!ok_ || cap_ - pos_ < n) ok_ = false;
    return ok_;
  }
  // 32-bit words (no 64-bit shifts on an 8-bit board); 64-bit values as two words
  // n is 2 or 4: plain stores, no loop over the bytes (on AVR some 30 cycles less a word)
  void le(uint32_t v, uint8_t n) {
    if (!room(n)) return;
    uint8_t* const p = buf_ + pos_;
    pos_ += n;
    if (n == 4) {
      put32(p, v);
    } else {
      put16(p, static_cast<uint16_t>(v));
    }
  }
  void le64(uint64_t v) {
    if (!room(8)) return;
    le(static_cast<uint32_t>(v), 4);
    le(static_cast<uint32_t>(v >> 32), 4);
  }
  uint8_t* buf_;
  size_t cap_;
  size_t pos_;
  bool ok_;
};

/** Bounded little-endian reads: a read past the end yields 0 and marks the reader failed. */
class Reader {
 public:
  Reader(const uint8_t* buf, size_t len) : buf_(buf), len_(len), pos_(0), ok_(true) {}
  uint8_t u8() { return have(1) ? buf_[pos_++] : 0; }
  uint16_t u16() { return static_cast<uint16_t>(le(2)); }
  uint32_t u32() { return static_cast<uint32_t>(le(4)); }
  int32_t i32() { return static_cast<int32_t>(le(4)); }
  uint64_t u64() {
    if (!have(8)) return 0;
    const uint32_t lo = le(4);
    return static_cast<uint64_t>(le(4)) << 32 | lo;
  }
  float f32() {
    uint32_t u = static_cast<uint32_t>(le(4));
    float v;
    memcpy(&v, &u, 4);
    return v;
  }
  /** A view of the next n bytes (empty, and the reader failed, when they are not there). */
  Bytes take(size_t n) {
    if (!have(n)) return Bytes();
    Bytes b(buf_ + pos_, n);
    pos_ += n;
    return b;
  }
  /** A view of every byte left. */
  Bytes rest() { return take(len_ - pos_); }
  /** The next n bytes into out. */
  void copy(uint8_t* out, size_t n) {
    Bytes b = take(n);
    if (ok_ && n) memcpy(out, b.data, n);
  }
  void fail() { ok_ = false; }
  bool ok() const { return ok_; }
  /** True if every read fitted and every byte was read. */
  bool finish() const { return ok_ && pos_ == len_; }

 protected:
  bool have(size_t n) {
    if (!ok_ || len_ - pos_ < n) ok_ = false;
    return ok_;
  }
  uint32_t le(uint8_t n) {
    if (!have(n)) return 0;
    uint32_t v = 0;
    for (uint8_t i = 0; i < n; ++i) v |= static_cast<uint32_t>(buf_[pos_++]) << (8 * i);
    return v;
  }
  const uint8_t* buf_;
  size_t len_;
  size_t pos_;
  bool ok_;
};

}  // namespace wire
}  // namespace hwbridge

#endif  // HWBRIDGE_WIRE_H
