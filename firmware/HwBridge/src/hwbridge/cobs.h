// Consistent Overhead Byte Stuffing with 0x00 as the frame delimiter (PROTOCOL.md 1.3).
// The encoder writes the canonical (shortest) form; the decoder also accepts a final empty
// group after 254 non-zero bytes (as the Arduino PacketSerial library writes it).
#ifndef HWBRIDGE_COBS_H
#define HWBRIDGE_COBS_H

#include <stddef.h>
#include <stdint.h>

namespace hwbridge {

/** Most data bytes one code byte covers (code 0xFF: 254 bytes, no implied zero). */
static const size_t kCobsMaxGroup = 254;

/** Longest COBS encoding of n bytes that cobs_decode() accepts: n + n / 254 + 1. */
inline constexpr size_t cobs_max_encoded(size_t n) { return n + n / kCobsMaxGroup + 1; }

/** A contiguous run of bytes, read by index (the source type of cobs_encode_to()). */
struct ByteSpan {
  const uint8_t* data;
  size_t size;
  uint8_t at(size_t i) const { return data[i]; }
};

namespace detail {
/**
 * The COBS encoder of cobs_encode_to() and write_frame(): an optional 0x00 first (lead), the
 * encoding of src, and a 0x00 delimiter last (delimit). Every byte goes through one
 * sink.put() (one copy of the sink's code in flash): a group's code byte, found by scanning
 * ahead to the next zero, then its data bytes. Returns the number of bytes written.
 */
template <class Source, class Sink>
inline __attribute__((always_inline)) size_t cobs_write(const Source& src, Sink& sink, bool lead,
                                                     bool delimit) {
  const size_t n = src.size;
  size_t i = 0;  // the next source byte (never past n)
  size_t written = 0;
  uint8_t b = 0;            // the byte to write (first the lead)
  bool put = lead;          // b is to be written
  bool done = false;        // b is the delimiter
  uint8_t run = 0;          // data bytes of the current group still to write
  uint8_t last = 0xFF;      // data bytes of the group before (0xFF: none yet)
  for (;;) {
    if (put) {
      sink.put(b);
      ++written;
    }
    put = true;
    if (done) break;
    if (run != 0) {
      b = src.at(i++);
      --run;
      continue;
    }
    if (last != 0xFF) {
      // the source ends after a group (canonical: a final full group takes no empty group)
      if (i == n) {
        if (!delimit) break;
        b = 0;
        done = true;
        continue;
      }
      if (last != kCobsMaxGroup) ++i;  // the zero the group's code stands for (0xFF: none)
    }
    uint8_t k = 0;
    while (k < kCobsMaxGroup && i + k < n && src.at(i + k) != 0) ++k;
    last = run = k;
    b = static_cast<uint8_t>(k + 1);
  }
  return written;
}
}  // namespace detail

/**
 * Encodes the src.size bytes of src (anything with `size` and `uint8_t at(size_t)`) and hands
 * each encoded byte to sink.put(uint8_t), scanning ahead for zeros so that no buffer is needed.
 * Returns the number of bytes written (without a delimiter).
 */
template <class Source, class Sink>
size_t cobs_encode_to(const Source& src, Sink& sink) {
  return detail::cobs_write(src, sink, false, false);
}

namespace detail {
/** A sink that writes into a bounded buffer and remembers an overflow. */
struct BufferSink {
  uint8_t* buf;
  size_t cap;
  size_t len;
  bool overflow;
  void put(uint8_t b) {
    if (len < cap) {
      buf[len++] = b;
    } else {
      overflow = true;
    }
  }
};
}  // namespace detail

/**
 * Encodes n bytes into dst (room for cap bytes; cobs_max_encoded(n) is always enough).
 * Returns the encoded length, or 0 when it does not fit (never writes at or past dst + cap).
 * src and dst must not overlap.
 */
inline size_t cobs_encode(const uint8_t* src, size_t n, uint8_t* dst, size_t cap) {
  ByteSpan span = {src, n};
  detail::BufferSink sink = {dst, cap, 0, false};
  cobs_encode_to(span, sink);
  return sink.overflow ? 0 : sink.len;
}

/**
 * Decodes one run (the bytes between two delimiters, no 0x00 inside) into dst, which has room
 * for n bytes; dst == src works (decoding in place). Returns false when the run is not valid
 * COBS (a code 0x00, or a code pointing past the end); otherwise sets *out_len.
 */
inline bool cobs_decode(const uint8_t* src, size_t n, uint8_t* dst, size_t* out_len) {
  size_t i = 0;
  size_t out = 0;
  while (i < n) {
    const uint8_t code = src[i++];
    if (code == 0 || static_cast<size_t>(code - 1) > n - i) return false;
    for (uint8_t k = 1; k < code; ++k) dst[out++] = src[i++];
    if (code != 0xFF && i < n) dst[out++] = 0;
  }
  *out_len = out;
  return true;
}

}  // namespace hwbridge

#endif  // HWBRIDGE_COBS_H
