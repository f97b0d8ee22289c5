// The AVR's frame encoder on the chip itself (host builds take the C loop of encode_wire): every
// frame write_frame() makes on the ATmega328P, with avr_encode_body's fused CRC and COBS pass,
// against the reference written from the frame's definition (the body with crc16() and the
// look-ahead COBS of cobs_encode_to). Random headers and payloads in one or two pieces, with
// runs of non-zero bytes around the 254-byte group (full groups at the end and in the middle),
// with and without a lead and a carried ACK; then the same frames through write_frame_early (the
// frame writer of a sketch that serves a service: the groups before the body's last zero first,
// then the CRC and the last group); prints "ENCODE OK n" (n: frames whose last group was full,
// of the first 400) or "ENCODE BAD" on UART 0 (tests/firmware/test_cpp_core.py).
//   avr-g++ -mmcu=atmega328p -std=gnu++11 -Os -flto -I../HwBridge/src avr_encode.cpp -o avr_encode.elf
//   simavr -m atmega328p -f 16000000 avr_encode.elf
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/interrupt.h>
#include "hwbridge/encoder.h"

static void out(char c) {
  while (!(UCSR0A & (1 << UDRE0))) {}
  UDR0 = c;
}
static void outs(const char* s) { while (*s) out(*s++); }
static void outn(uint16_t v) {
  char digits[6];
  uint8_t k = 0;
  do digits[k++] = static_cast<char>('0' + v % 10); while ((v /= 10) != 0);
  while (k) out(digits[--k]);
}

static uint32_t x = 2463534242UL;
static uint8_t next() {
  x ^= x << 13; x ^= x >> 17; x ^= x << 5;
  return static_cast<uint8_t>(x);
}

static const uint16_t kMax = 300;
static uint8_t payload[kMax];
static uint8_t got[hwbridge::detail::wire_room(kMax) + 2];
static uint8_t want[hwbridge::detail::wire_room(kMax) + 2];

int main() {
  UBRR0 = 8;
  UCSR0B = (1 << TXEN0);
  uint16_t bad = 0, full_last = 0;
  for (uint16_t trial = 0; trial < 800; ++trial) {
    // the second 400: through write_frame_early, as in a sketch that serves a service
    if (trial == 400) {
      hwbridge::detail::use_early_writer<hwbridge::detail::BufferSink>();
      x = 2463534242UL;
    }
    // sizes: all small ones, the ones around a full group (254 - 5 header/CRC bytes), random
    uint16_t n = trial < 64 ? trial : trial < 96 ? static_cast<uint16_t>(240 + (trial - 64)) : next() % kMax;
    const uint8_t zeros = next() & 3;  // 0: no zero at all; else one in about 4, 16 or 64
    for (uint16_t i = 0; i < n; ++i) {
      uint8_t b = next();
      if (zeros != 0 && (next() & ((1 << (2 * zeros)) - 1)) == 0) b = 0;
      else if (b == 0) b = 1;
      payload[i] = b;
    }
    hwbridge::FrameHeader h;
    h.type = static_cast<hwbridge::FrameType>(next() % 3);
    h.frag = static_cast<hwbridge::Frag>(next() & 3);
    h.channel = (next() & 1) ? 0 : next();
    h.seq = next();
    const uint8_t opts = next() & (hwbridge::kLead | hwbridge::kCarryAck);
    const uint16_t n1 = (opts & hwbridge::kCarryAck) && n ? n - 1 : (next() & 1) && n ? next() % n : n;
    const uint8_t* p2 = payload + n1;
    const uint16_t n2 = n - n1;
    hwbridge::detail::BufferSink sink = {got, sizeof got, 0, false};
    const size_t len = hwbridge::write_frame(sink, h, payload, n1, n2 ? p2 : nullptr, n2, opts);
    // the reference: the body from its definition, then the look-ahead COBS
    const hwbridge::detail::Body body(h, payload, n1, p2, n2, opts & hwbridge::kCarryAck);
    hwbridge::detail::BufferSink ref = {want, sizeof want, 0, false};
    if (opts & hwbridge::kLead) ref.put(0);
    hwbridge::cobs_encode_to(body, ref);
    ref.put(0);
    if (len != ref.len || sink.len != len || sink.overflow || ref.overflow) {
      ++bad;
      continue;
    }
    for (size_t i = 0; i < len; ++i) {
      if (got[i] != want[i]) {
        ++bad;
        break;
      }
    }
    // whether the last group was a full one (code 0xFF): walk the groups
    size_t at = (opts & hwbridge::kLead) ? 1 : 0;
    uint8_t code = 0;
    while (at < len - 1) {
      code = want[at];
      at += code;
    }
    if (code == 0xFF && trial < 400) ++full_last;
  }
  if (bad) {
    outs("ENCODE BAD ");
    outn(bad);
    out('\n');
  } else {
    outs("ENCODE OK ");
    outn(full_last);
    out('\n');
  }
  cli();
  sleep_cpu();
  return 0;
}
