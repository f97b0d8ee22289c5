// The frame encoder (PROTOCOL.md 1.3-1.5): a frame to COBS wire bytes and the delimiter,
// streamed to a sink without a second buffer, with the leading-0x00 rule.
#ifndef HWBRIDGE_ENCODER_H
#define HWBRIDGE_ENCODER_H

#include <stddef.h>
#include <stdint.h>

#include "cobs.h"
#include "config.h"
#include "../hwbridge_wire.h"
#include "frame.h"

namespace hwbridge {

/** What a frame is, without its payload. */
struct FrameHeader {
  FrameType type;
  Frag frag;
  uint8_t channel;
  uint8_t seq;
};

/** write_frame()'s last argument: bits of these. kLead (the value of `true`): a leading 0x00
 * (1.3). kCarryAck: a data frame whose payload ends with an ACK byte (p2, n2 = 1), flag bit 0
 * set in header byte 0 (ACK_IN_DATA, PROTOCOL.md 1.4). */
static const uint8_t kLead = 1;
static const uint8_t kCarryAck = 2;

namespace detail {
/**
 * A frame body seen as one run of bytes without copying the payload: header, the payload in
 * up to two pieces (a FIRST fragment's length prefix and its chunk), and the CRC, computed here.
 */
struct Body {
  ByteSpan pieces[2];         ///< the payload
  size_t size;                ///< body bytes
  uint8_t env[kEnvelope];     ///< the header, then the CRC
  Body(const FrameHeader& h, const uint8_t* p1, size_t n1, const uint8_t* p2, size_t n2,
       uint8_t opts = 0) {
    env[0] = static_cast<uint8_t>(header_byte0(h.type, h.frag) | (HWBRIDGE_ACK_IN_DATA ? opts >> 1 : 0));
    env[1] = h.channel;
    env[2] = h.seq;
    pieces[0].data = p1;
    pieces[0].size = n1;
    pieces[1].data = p2;
    pieces[1].size = n2;
    size = kEnvelope + n1 + n2;
    uint16_t v = crc16(env, kHeaderSize);
    for (const ByteSpan* s = pieces; s != pieces + 2; ++s) v = crc16(s->data, s->size, v);
    wire::put16(env + kHeaderSize, v);
  }
  /** Body byte i (i < size). */
  __attribute__((noinline)) uint8_t at(size_t i) const {
    if (i >= kHeaderSize) {
      i -= kHeaderSize;
      for (const ByteSpan* s = pieces; s != pieces + 2; ++s) {
        if (i < s->size) return s->data[i];
        i -= s->size;
      }
      i += kHeaderSize;  // the CRC, after the header in env
    }
    return env[i];
  }
};
}  // namespace detail

namespace detail {
// The traits below look for a `static const bool` member: where it is true the first test()
// takes a pointer to char[1]; where it is false the array would have size -1, which takes that
// test() out (SFINAE), as a missing member does. (With `? 1 : 2` false counted as true.)

/** Whether a sink is a datagram link: it declares `static const bool kDatagram = true` (the
 * UdpHardware does). Any other sink is a byte stream. */
template <class Sink>
struct IsDatagramSink {
  template <class S> static char test(char (*)[S::kDatagram ? 1 : -1]);
  template <class S> static long test(...);
  static const bool value = sizeof(test<Sink>(nullptr)) == 1;
};
/** Whether a Hardware shares its CPU with other programs (a host build: it can go unscheduled
 * for longer than the link timeout): it declares `static const bool kSharesCpu = true`
 * (PosixHardware does). The node then applies PROTOCOL.md 2.9's stall rule; on bare metal the
 * rule compiles to nothing. */
template <class H>
struct SharesCpu {
  template <class S> static char test(char (*)[S::kSharesCpu ? 1 : -1]);
  template <class S> static long test(...);
  static const bool value = sizeof(test<H>(nullptr)) == 1;
};
/** Whether a Hardware cannot carry flag bit 0 of a frame (CAN format 2): it declares
 * `static const bool kNoAckInData = true`, and the node then leaves ACK_IN_DATA out. */
template <class H>
struct NoAckInData {
  template <class S> static char test(char (*)[S::kNoAckInData ? 1 : -1]);
  template <class S> static long test(...);
  static const bool value = sizeof(test<H>(nullptr)) == 1;
};
template <bool B, class T> struct EnableIf {};
template <class T> struct EnableIf<true, T> { typedef T type; };

/** n bytes to sink: its put_block(p, n) when it has one (ArduinoHardware: a run into the UART's
 * ring), else put() for each. */
template <class Sink>
inline auto put_run(Sink& sink, const uint8_t* p, size_t n, int)
    -> decltype(sink.put_block(p, n), void()) {
  sink.put_block(p, n);
}
template <class Sink>
inline void put_run(Sink& sink, const uint8_t* p, size_t n, long) {
  for (; n != 0; --n) sink.put(*p++);
}

/** Room encode_wire() needs for a payload of n bytes: the lead, the body (n + 5) with a code
 * byte for every 254 of its bytes and one more, and the delimiter; n >> 7 for n / 254 (no
 * division on AVR), which leaves the copy of the body at least two bytes ahead of the writer. */
inline constexpr size_t wire_room(size_t n) { return n + kEnvelope + ((n + kEnvelope) >> 7) + 3; }

#if defined(__AVR__)
/**
 * The AVR's pass of encode_wire(): the CRC-16 of the n bytes at body, stored after them, and the
 * COBS of all n + 2, in one loop, forward and in place (*w, the writer, stays behind the body).
 * On entry *w is one past the first group's (open) code byte; the writer is always its open
 * group's code byte plus the group's count so far (run: 1 + its data bytes), so that no third
 * pointer is needed: a group closes with its code stored at w - run. The CRC step is
 * HWBRIDGE_AVR_CRC_STEP (hwbridge_wire.h). About 33 cycles a data byte, where crc16() and the C
 * loop took some 55. At the end the last group's code byte is stored, or, when the last group
 * ended full (254 data bytes), its empty slot dropped (canonical: no empty group after it);
 * *wp is then where the delimiter goes.
 */
inline void avr_encode_body(uint8_t* body, size_t n, uint8_t** wp) {
  const uint8_t* r = body;
  uint8_t* w = *wp;
  const uint8_t* end = body + n;  // first the body, then its CRC
  uint16_t crc = kCrcInit;
  uint8_t run = 1, c, t, t2, phase = 0, full = 0;
  __asm__ volatile(
      "1:\tld %[c], %a[r]+\n\t"
      HWBRIDGE_AVR_CRC_STEP
      // COBS: a data byte is copied; a zero, or a group's 254th data byte, closes the group
      "tst %[c]\n\t"
      "breq 3f\n\t"
      "st %a[w]+, %[c]\n\t"
      "inc %[run]\n\t"
      "cpi %[run], 0xff\n\t"
      "brne 4f\n\t"
      "set\n\t"  // T: the group closed full
      "rjmp 5f\n"
      "3:\tclt\n"
      "5:\tsub %A[w], %[run]\n\t"  // the group's code byte is at w - run
      "sbc %B[w], __zero_reg__\n\t"
      "st %a[w], %[run]\n\t"
      "add %A[w], %[run]\n\t"
      "adc %B[w], __zero_reg__\n\t"
      "adiw %A[w], 1\n\t"  // the next group's code byte, left open
      "ldi %[run], 1\n\t"
      "rjmp 6f\n"
      "4:\tclt\n"
      "6:\tcp %A[r], %A[end]\n\t"
      "cpc %B[r], %B[end]\n\t"
      "brne 1b\n\t"
      // the body's end: store the CRC after it and go on over its two bytes; then stop
      "tst %[phase]\n\t"
      "brne 7f\n\t"
      "inc %[phase]\n\t"
      "st %a[r]+, %A[crc]\n\t"
      "st %a[r], %B[crc]\n\t"
      "sbiw %A[r], 1\n\t"
      "subi %A[end], 0xfe\n\t"
      "sbci %B[end], 0xff\n\t"
      "rjmp 1b\n"
      "7:\tbld %[full], 0"
      : [r] "+x"(r), [w] "+z"(w), [crc] "+r"(crc), [run] "+d"(run), [end] "+d"(end),
        [phase] "+r"(phase), [full] "+r"(full), [c] "=&r"(c), [t] "=&d"(t), [t2] "=&r"(t2)
      :
      : "memory");
  if (run == 1 && full) {
    --w;
  } else {
    *(w - run) = run;
  }
  *wp = w;
}
#endif

/**
 * The wire bytes of one frame into out (wire_room(n1 + n2) bytes): an optional lead 0x00,
 * COBS(header, p1, p2, CRC) and the delimiter. The body is first copied to the end of out (and
 * its CRC computed there; on AVR, avr_encode_body() sums the CRC in the encoding's own pass),
 * then encoded forward from there to out's start, in place: the writer never catches up with
 * the reader, as the encoding adds at most one byte for 254.
 * Each data byte is copied, each zero becomes the code of the group before it (a group's code
 * byte is kept open until its group ends: no look-ahead). The canonical encoding (that of
 * cobs_write), byte for byte. Returns the wire length.
 */
inline size_t encode_wire(uint8_t* out, const FrameHeader& h, const uint8_t* p1, size_t n1,
                          const uint8_t* p2, size_t n2, uint8_t opts) {
  const size_t n = kHeaderSize + n1 + n2;  // the body without its CRC
  uint8_t* const body = out + wire_room(n1 + n2) - n - kCrcSize;
  // kCarryAck: bit 0 (compiled where ACK_IN_DATA can be announced: not on an AVR sketch that
  // leaves it out, whose node never asks for it)
  body[0] = static_cast<uint8_t>(header_byte0(h.type, h.frag) | (HWBRIDGE_ACK_IN_DATA ? opts >> 1 : 0));
  body[1] = h.channel;
  body[2] = h.seq;
  if (n1 != 0) memcpy(body + kHeaderSize, p1, n1);
  if (n2 != 0) memcpy(body + kHeaderSize + n1, p2, n2);
#if defined(__AVR__)
  uint8_t* w = out;
  if (opts & kLead) *w++ = 0;
  ++w;  // after the first group's code byte, at out + run - 1
  avr_encode_body(body, n, &w);
#else
  wire::put16(body + n, crc16(body, n));
  const uint8_t* r = body;
  const uint8_t* const end = body + n + kCrcSize;
  uint8_t* w = out;
  if (opts & kLead) *w++ = 0;
  uint8_t* code = w++;  // the open group's code byte
  uint8_t run = 1;      // its code so far: 1 + its data bytes
  bool full = false;    // the group before the open one ended full (254 bytes, no zero)
  do {
    const uint8_t c = *r++;
    full = false;
    if (c != 0) {
      *w++ = c;
      if (++run != 0xFF) continue;
      full = true;  // 254 data bytes: the group ends without a zero
    }
    *code = run;
    code = w++;
    run = 1;
  } while (r != end);
  if (run == 1 && full) {
    --w;  // canonical: no empty group after a final full one
  } else {
    *code = run;
  }
#endif
  *w++ = 0;
  return static_cast<size_t>(w - out);
}
}  // namespace detail

#if defined(__AVR__)
namespace detail {
/** Where write_frame_early's encoding stands: the writer, and its open group's count so far
 * (run: 1 + its data bytes; the group's code byte is at w - run), as in avr_encode_body. */
struct CobsCursor {
  uint8_t* w;
  uint8_t run;
};

/** n bytes at r, then n2 bytes at r2 (either count may be 0; no group reaching 254 bytes),
 * COBS-encoded at the cursor, without a CRC: 10 cycles a data byte. With stop, it stops after
 * the first zero of the second run (the end of a group) and returns the bytes of it not taken
 * (else 0). */
__attribute__((noinline)) inline uint8_t avr_cobs_piece(CobsCursor& at, const uint8_t* r, uint8_t n,
                                                        const uint8_t* r2 = nullptr, uint8_t n2 = 0,
                                                        uint8_t stop = 0) {
  uint8_t* w = at.w;
  uint8_t run = at.run, c;
  __asm__ volatile(
      "tst %[n]\n\t"
      "breq 4f\n"
      "1:\tld %[c], %a[r]+\n\t"
      "tst %[c]\n\t"
      "breq 2f\n\t"
      "st %a[w]+, %[c]\n\t"
      "inc %[run]\n\t"
      "dec %[n]\n\t"
      "brne 1b\n\t"
      "rjmp 4f\n"
      "2:\tsub %A[w], %[run]\n\t"  // a zero: its group's code at w - run, the zero's place next
      "sbc %B[w], __zero_reg__\n\t"
      "st %a[w], %[run]\n\t"
      "add %A[w], %[run]\n\t"
      "adc %B[w], __zero_reg__\n\t"
      "adiw %A[w], 1\n\t"
      "ldi %[run], 1\n\t"
      "dec %[n]\n\t"
      "breq 4f\n\t"
      "sbrs %[stop], 1\n\t"  // bit 1: stop, in the second run
      "rjmp 1b\n\t"
      "rjmp 5f\n"
      "4:\ttst %[n2]\n\t"  // a run done: the second one, once
      "breq 5f\n\t"
      "movw %A[r], %A[r2]\n\t"
      "mov %[n], %[n2]\n\t"
      "clr %[n2]\n\t"
      "lsl %[stop]\n\t"
      "rjmp 1b\n"
      "5:"
      : [r] "+x"(r), [w] "+z"(w), [run] "+d"(run), [n] "+r"(n), [n2] "+r"(n2), [stop] "+r"(stop),
        [c] "=&r"(c)
      : [r2] "r"(r2)
      : "memory");
  at.w = w;
  at.run = run;
  return n;
}

/**
 * write_frame() on an AVR in a sketch that serves a service (EarlyWriter): the same bytes, in
 * three runs, so that the line starts as soon as the first group is known, long before the CRC
 * is summed. Only the group after the body's last zero holds the CRC; every group before it is
 * complete once its zero is found. So the body is read where it lies (header, p1, p2) and
 * written encoded to a buffer on the stack (each zero's place the code of the group before it):
 * first the header and p1 as far as its first zero, and what that completed goes to the sink at
 * once (with an idle UART its first byte leaves at once too: EagerWrites); then the rest of the
 * body, and the groups it completed; then the CRC (crc16() of the same pieces, while the line
 * sends) and the last group with the CRC and the delimiter. A service's answer (its request id
 * and status hold zeros) starts once its header and two or three bytes are encoded: some 180
 * cycles sooner than when every group before the last zero went first, 630 sooner than after
 * encode_wire()'s copy and one pass. Bodies of 254 bytes or more (a full group) are not taken.
 */
template <class Sink>
__attribute__((noinline)) size_t write_frame_early(Sink& sink, const FrameHeader& h, const uint8_t* p1,
                                                   size_t n1, const uint8_t* p2, size_t n2, uint8_t opts) {
  const size_t n = kHeaderSize + n1 + n2;  // the body without its CRC
  uint8_t* const buf = static_cast<uint8_t*>(__builtin_alloca(n + kCrcSize + 3));  // lead, code, body, CRC, 0
  const uint8_t head[kHeaderSize] = {
      static_cast<uint8_t>(header_byte0(h.type, h.frag) | (HWBRIDGE_ACK_IN_DATA ? opts >> 1 : 0)), h.channel,
      h.seq};
  buf[0] = 0;
  uint8_t* const first = (opts & kLead) ? buf : buf + 1;  // the lead, or the first code byte
  // The body, written encoded after the first group's code byte (buf[1]): the header and p1 as
  // far as its first zero, and what is done goes out; then the rest of p1 and p2, and the same.
  CobsCursor at = {buf + 2, 1};
  const uint8_t left = avr_cobs_piece(at, head, kHeaderSize, p1, static_cast<uint8_t>(n1), 1);
  uint8_t* sent = first;
  uint8_t* done = at.w - at.run;
  if (done != sent) {
    put_run(sink, sent, static_cast<size_t>(done - sent), 0);
    sent = done;
  }
  avr_cobs_piece(at, p1 + (n1 - left), left, p2, static_cast<uint8_t>(n2));
  done = at.w - at.run;
  if (done != sent) {
    put_run(sink, sent, static_cast<size_t>(done - sent), 0);
    sent = done;
  }
  // the CRC, of the header and the payload where they are, while the line sends; a byte of it
  // may be a zero too
  const uint16_t crc = crc16(p2, n2, crc16(p1, n1, crc16(head, kHeaderSize)));
  const uint8_t tail[kCrcSize] = {static_cast<uint8_t>(crc), static_cast<uint8_t>(crc >> 8)};
  avr_cobs_piece(at, tail, kCrcSize);
  uint8_t* w = at.w;
  *(w - at.run) = at.run;
  *w++ = 0;  // the delimiter
  put_run(sink, sent, static_cast<size_t>(w - sent), 0);
  return static_cast<size_t>(w - first);
}

/** The frame writer write_frame() hands frames to on this sink instead of its own (nullptr:
 * none): write_frame_early, set by the node's advertiseService with EagerWrites. A sketch that
 * serves nothing never names write_frame_early, so it links none of it, and nothing writes the
 * pointer, so the test of it is folded away. */
template <class Sink>
struct EarlyWriter {
  typedef size_t (*Fn)(Sink&, const FrameHeader&, const uint8_t*, size_t, const uint8_t*, size_t, uint8_t);
  static Fn fn;
};
template <class Sink>
typename EarlyWriter<Sink>::Fn EarlyWriter<Sink>::fn = nullptr;

/** Hands a byte stream's frames to write_frame_early (datagram links write no COBS). */
template <class Sink>
void use_early_writer(typename EnableIf<!IsDatagramSink<Sink>::value, int>::type = 0) {
  EarlyWriter<Sink>::fn = &write_frame_early<Sink>;
}
template <class Sink>
void use_early_writer(typename EnableIf<IsDatagramSink<Sink>::value, long>::type = 0) {}
}  // namespace detail
#endif

namespace detail {
/** write_frame()'s own encoder: encode_wire() into a buffer on the stack, handed to the sink in
 * one run. */
template <class Sink>
__attribute__((noinline)) size_t write_wire(Sink& sink, const FrameHeader& h, const uint8_t* p1, size_t n1,
                                            const uint8_t* p2, size_t n2, uint8_t opts) {
  uint8_t* const out = static_cast<uint8_t*>(__builtin_alloca(wire_room(n1 + n2)));
  const size_t n = encode_wire(out, h, p1, n1, p2, n2, opts);
  put_run(sink, out, n, 0);
  return n;
}
}  // namespace detail

/**
 * Writes one frame to sink: an optional leading 0x00, COBS(body), the 0x00 delimiter. The
 * payload is p1 followed by p2 (either may be empty). The frame is encoded into a buffer on
 * the stack (wire_room(n1 + n2) bytes, some 70 for a 64-byte payload) and handed to the sink in
 * one put_block() when it has one, else a put() a byte (on an AVR with EagerWrites on, in two:
 * write_frame_early). Returns the bytes written. The caller keeps the payload within the peer's
 * MTU.
 */
template <class Sink>
typename detail::EnableIf<!detail::IsDatagramSink<Sink>::value, size_t>::type write_frame(
    Sink& sink, const FrameHeader& h, const uint8_t* p1, size_t n1, const uint8_t* p2 = nullptr,
    size_t n2 = 0, uint8_t opts = 0) {
#if defined(__AVR__)
  // tested before write_wire() saves the registers its encoder needs (some 40 cycles sooner)
  if (detail::EarlyWriter<Sink>::fn != nullptr && n1 + n2 + kEnvelope < 254) {
    return detail::EarlyWriter<Sink>::fn(sink, h, p1, n1, p2, n2, opts);
  }
#endif
  return detail::write_wire(sink, h, p1, n1, p2, n2, opts);
}

/**
 * The same for a datagram sink (detail::IsDatagramSink; PROTOCOL.md 1.13): the body as it is
 * (header, payload, CRC; no COBS, no delimiter, no lead), then sink.endDatagram() sends it.
 */
template <class Sink>
typename detail::EnableIf<detail::IsDatagramSink<Sink>::value, size_t>::type write_frame(
    Sink& sink, const FrameHeader& h, const uint8_t* p1, size_t n1, const uint8_t* p2 = nullptr,
    size_t n2 = 0, uint8_t opts = 0) {
  const detail::Body body(h, p1, n1, p2, n2, opts & kCarryAck);
  for (size_t i = 0; i < body.size; ++i) sink.put(body.at(i));
  sink.endDatagram();
  return body.size;
}

/**
 * Encodes one frame into out (room for cap bytes; max_wire_size(n) + 1 is always enough with
 * a lead). Returns the wire length, or 0 when it does not fit: never writes at or past
 * out + cap.
 */
inline size_t encode_frame(const FrameHeader& h, const uint8_t* payload, size_t n, uint8_t* out,
                           size_t cap, bool lead = false) {
  detail::BufferSink sink = {out, cap, 0, false};
  write_frame(sink, h, payload, n, nullptr, 0, lead);
  return sink.overflow ? 0 : sink.len;
}

/**
 * Encodes a frame for a datagram link (1.13): header + payload + CRC, no COBS, no delimiter.
 * Returns the length, or 0 when it does not fit in cap bytes.
 */
inline size_t encode_datagram(const FrameHeader& h, const uint8_t* payload, size_t n, uint8_t* out,
                              size_t cap) {
  if (cap < kEnvelope || n > cap - kEnvelope) return 0;
  const detail::Body body(h, payload, n, nullptr, 0);
  for (size_t i = 0; i < body.size; ++i) out[i] = body.at(i);
  return body.size;
}

/**
 * The leading-delimiter rule (1.3): a 0x00 before the first frame after the link opens (or the
 * board restarts), and before a frame sent after the line was idle for kIdleMicros.
 */
class LeadTracker {
 public:
  static const uint32_t kIdleMicros = 100000UL;  ///< 0.1 s (2.11)

  constexpr LeadTracker() : last_(0), sent_(false) {}
  /** The link (re)opened: the next frame gets a lead. */
  void reset() { sent_ = false; }
  /** Whether a frame sent at now_us needs a leading 0x00; records the send. */
  __attribute__((noinline)) bool lead(uint32_t now_us) {
    const bool need = !sent_ || static_cast<uint32_t>(now_us - last_) >= kIdleMicros;
    sent_ = true;
    last_ = now_us;
    return need;
  }

 private:
  uint32_t last_;
  bool sent_;  // false until the first frame (zero-filled: a fresh tracker)
};

/** A sink that counts bytes: write_frame(counter, ...) measures a frame without sending it. */
struct CountingSink {
  size_t count;
  void put(uint8_t) { ++count; }
};

}  // namespace hwbridge

#endif  // HWBRIDGE_ENCODER_H
