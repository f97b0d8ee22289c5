// Host-native checks of HwBridge's framing against protocols/vectors/native_frames.json.
//
// Reads the vectors on stdin, one per line (tests/firmware/test_cpp_core.py writes them):
//   V NAME HEX TYPE CHANNEL SEQ FRAG PAYLOAD        encode gives HEX, decode gives the frame
//   D NAME HEX TYPE CHANNEL SEQ FRAG PAYLOAD        decode only
//   B NAME HEX EXPECT MAX_PAYLOAD                   one bad run ("-": the default MTU)
//   F NAME TYPE CHANNEL FIRST_SEQ MTU MESSAGE HEX,HEX,...   fragmentation
//   S NAME HEX                                      the selective ACK of native_session.json
// (TYPE and FRAG as numbers, "-" for empty hex), then runs its own unit checks. Exit status 1
// with the first mismatch on stderr.
#include <stdio.h>
#include <stdlib.h>

#include <sstream>
#include <string>
#include <vector>

#include "HwBridge.h"
#include "check.h"
#if !defined(__AVR__)
#include "hwbridge/hardware_posix.h"
#include <poll.h>
#endif

using check::Bytes;
using check::hex;
using check::unhex;
using namespace hwbridge;

namespace {

const size_t kMtu = 1024;
typedef FrameDecoder<kMtu> HostDecoder;

struct Event {
  Decoded kind;
  FrameError error;
  Frame frame;
  Bytes payload;
};

template <class Decoder>
std::vector<Event> decode_all(Decoder& d, const Bytes& wire) {
  std::vector<Event> out;
  for (size_t i = 0; i < wire.size(); ++i) {
    Decoded r = d.push(wire[i]);
    if (r == Decoded::Nothing) continue;
    Event e;
    e.kind = r;
    e.error = d.error();
    e.frame = d.frame();
    if (r == Decoded::Frame) e.payload.assign(d.frame().payload, d.frame().payload + d.frame().size);
    out.push_back(e);
  }
  CHECK(d.buffered() == 0 || wire.empty() || wire.back() != 0, "bytes left after a delimiter");
  return out;
}

FrameHeader header(int type, int channel, int seq, int frag) {
  FrameHeader h;
  h.type = static_cast<FrameType>(type);
  h.frag = static_cast<Frag>(frag);
  h.channel = static_cast<uint8_t>(channel);
  h.seq = static_cast<uint8_t>(seq);
  return h;
}

void expect_frame(const std::string& name, const Event& e, int type, int channel, int seq, int frag,
                  const Bytes& payload) {
  CHECK(e.kind == Decoded::Frame, "%s: decoded as %s, not a frame", name.c_str(),
        frame_error_name(e.error));
  CHECK(static_cast<int>(e.frame.type) == type && static_cast<int>(e.frame.frag) == frag &&
            e.frame.channel == channel && e.frame.seq == seq,
        "%s: header type %d frag %d channel %d seq %d, expected %d %d %d %d", name.c_str(),
        static_cast<int>(e.frame.type), static_cast<int>(e.frame.frag), e.frame.channel,
        e.frame.seq, type, frag, channel, seq);
  CHECK(e.payload == payload, "%s: payload %s, expected %s", name.c_str(), hex(e.payload).c_str(),
        hex(payload).c_str());
}

void frame_vector(const std::string& name, const Bytes& wire, int type, int channel, int seq,
                  int frag, const Bytes& payload, bool encode) {
  if (encode) {
    const FrameHeader h = header(type, channel, seq, frag);
    uint8_t out[2 * kMtu];
    size_t n = encode_frame(h, payload.data(), payload.size(), out, sizeof out);
    CHECK(Bytes(out, out + n) == wire, "%s: encoded %s, expected %s", name.c_str(),
          hex(out, n).c_str(), hex(wire).c_str());
    n = encode_frame(h, payload.data(), payload.size(), out, sizeof out, true);
    CHECK(n == wire.size() + 1 && out[0] == 0 && Bytes(out + 1, out + n) == wire,
          "%s: with a lead, encoded %s", name.c_str(), hex(out, n).c_str());
    // Exactly wire.size() bytes of room fit; one fewer is refused without writing past it.
    uint8_t tight[2 * kMtu + 1];
    memset(tight, 0xAA, sizeof tight);
    CHECK(encode_frame(h, payload.data(), payload.size(), tight, wire.size()) == wire.size(),
          "%s: no fit in exactly its size", name.c_str());
    memset(tight, 0xAA, sizeof tight);
    CHECK(encode_frame(h, payload.data(), payload.size(), tight, wire.size() - 1) == 0 &&
              tight[wire.size() - 1] == 0xAA,
          "%s: a too small buffer was not refused (or written past)", name.c_str());
    check::VecSink sink;
    write_frame(sink, h, payload.data(), payload.size());
    CHECK(sink.bytes == wire, "%s: write_frame gave %s", name.c_str(), hex(sink.bytes).c_str());
    // The datagram form is the body itself (1.13).
    uint8_t body[kMtu + kEnvelope];
    const size_t bn = encode_datagram(h, payload.data(), payload.size(), body, sizeof body);
    Frame f;
    CHECK(bn == payload.size() + kEnvelope && parse_body(body, bn, kMtu, &f) == FrameError::Ok &&
              f.size == payload.size(),
          "%s: datagram round trip", name.c_str());
  }
  HostDecoder d;
  std::vector<Event> events = decode_all(d, wire);
  CHECK(events.size() == 1, "%s: %zu events, expected one frame", name.c_str(), events.size());
  expect_frame(name, events[0], type, channel, seq, frag, payload);
  CHECK(d.stats().frames == 1, "%s: frames counter", name.c_str());
  // Also as a device without text detection, and with the smallest MTU that holds it.
  FrameDecoder<kMtu, false> quiet;
  quiet.set_max_payload(payload.size());
  events = decode_all(quiet, wire);
  CHECK(events.size() == 1, "%s: %zu events at the smallest MTU", name.c_str(), events.size());
  expect_frame(name, events[0], type, channel, seq, frag, payload);
}

/** A frame that carries an ACK (ACK_IN_DATA, PROTOCOL.md 1.4): the ACK byte after the payload
 * and flag bit 0 (kCarryAck), encoded byte for byte on both links; decoded back with its ACK and
 * without it in the payload; the ACK byte counts towards the MTU. */
void acked_vector(const std::string& name, const Bytes& wire, int type, int channel, int seq, int frag,
                  const Bytes& payload, int ack) {
  const FrameHeader h = header(type, channel, seq, frag);
  const uint8_t a = static_cast<uint8_t>(ack);
  check::VecSink sink;
  write_frame(sink, h, payload.data(), payload.size(), &a, 1, kCarryAck);
  CHECK(sink.bytes == wire, "%s: write_frame gave %s, expected %s", name.c_str(), hex(sink.bytes).c_str(),
        hex(wire).c_str());
  check::VecSink led;
  write_frame(led, h, payload.data(), payload.size(), &a, 1, kCarryAck | kLead);
  CHECK(led.bytes.size() == wire.size() + 1 && led.bytes[0] == 0 && Bytes(led.bytes.begin() + 1, led.bytes.end()) == wire,
        "%s: with a lead", name.c_str());
  HostDecoder d;
  std::vector<Event> events = decode_all(d, wire);
  CHECK(events.size() == 1, "%s: %zu events, expected one frame", name.c_str(), events.size());
  expect_frame(name, events[0], type, channel, seq, frag, payload);
  CHECK(events[0].frame.acked && events[0].frame.ack == a, "%s: ACK %d (carried %d), expected %d", name.c_str(),
        events[0].frame.ack, events[0].frame.acked, ack);
  FrameDecoder<kMtu, false> quiet;
  quiet.set_max_payload(payload.size() + 1);
  events = decode_all(quiet, wire);
  CHECK(events.size() == 1 && events[0].kind == Decoded::Frame && events[0].frame.acked,
        "%s: not a frame at MTU payload + 1", name.c_str());
  quiet.set_max_payload(payload.size());
  events = decode_all(quiet, wire);
  CHECK(events.size() == 1 && events[0].kind == Decoded::Bad && events[0].error == FrameError::Oversize,
        "%s: the ACK byte does not count towards the MTU", name.c_str());
  // The datagram form (1.13): the body, flag and ACK byte included.
  check::DatagramSink dg;
  write_frame(dg, h, payload.data(), payload.size(), &a, 1, kCarryAck);
  Frame f;
  CHECK(dg.datagrams.size() == 1 && parse_body(dg.datagrams[0].data(), dg.datagrams[0].size(), kMtu, &f) == FrameError::Ok &&
            f.acked && f.ack == a && f.size == payload.size(),
        "%s: datagram round trip", name.c_str());
}

FrameError reason(const std::string& name) {
  static const FrameError all[] = {FrameError::Crc, FrameError::Cobs, FrameError::TooShort,
                                   FrameError::Version, FrameError::ReservedType,
                                   FrameError::Oversize, FrameError::Text};
  for (size_t i = 0; i < sizeof all / sizeof all[0]; ++i) {
    if (name == frame_error_name(all[i])) return all[i];
  }
  check::fail("unknown bad-frame reason %s", name.c_str());
  return FrameError::Ok;
}

Counter counted(const DecoderStats& s, FrameError e, size_t run) {
  switch (e) {
    case FrameError::Crc: return s.crc_errors;
    case FrameError::Cobs: return s.cobs_errors;
    case FrameError::TooShort: return s.too_short;
    case FrameError::Version: return s.version_errors;
    case FrameError::ReservedType: return s.reserved_type;
    case FrameError::Oversize: return s.oversize;
    case FrameError::Text: return s.non_frame_bytes == run ? 1 : 0;
    case FrameError::Ok: break;
  }
  return 0;
}

template <bool Text>
void bad_one(const std::string& name, const Bytes& wire, FrameError expect, size_t max_payload) {
  FrameDecoder<kMtu, Text> d;
  d.set_max_payload(max_payload);
  std::vector<Event> events = decode_all(d, wire);
  CHECK(events.size() == 1 && events[0].kind == Decoded::Bad,
        "%s: expected one bad run (%s), got %zu events", name.c_str(), frame_error_name(expect),
        events.size());
  CHECK(events[0].error == expect, "%s: rejected as %s, expected %s (text detection %d)",
        name.c_str(), frame_error_name(events[0].error), frame_error_name(expect), Text);
  CHECK(counted(d.stats(), expect, wire.size() - 1) == 1 && d.stats().frames == 0,
        "%s: not counted once as %s", name.c_str(), frame_error_name(expect));
  // The decoder carries on: a valid frame right after it is decoded.
  static const uint8_t ack[] = {0x06, 0x60, 0x05, 0x07, 0xe5, 0xd8, 0x00};
  events = decode_all(d, Bytes(ack, ack + sizeof ack));
  CHECK(events.size() == 1 && events[0].kind == Decoded::Frame, "%s: no frame after it",
        name.c_str());
}

void bad_vector(const std::string& name, const Bytes& wire, const std::string& expect,
                size_t max_payload) {
  FrameError e = reason(expect);
  bad_one<true>(name, wire, e, max_payload);
  // A device without text detection reports text as its failure: cobs (PROTOCOL.md 1.12).
  bad_one<false>(name, wire, e == FrameError::Text ? FrameError::Cobs : e, max_payload);
  if (e == FrameError::Version) {
    HostDecoder d;
    decode_all(d, wire);
    Bytes body(wire.size());
    size_t n = 0;
    CHECK(cobs_decode(wire.data(), wire.size() - 1, body.data(), &n) &&
              d.peer_version() == body[0] >> 6,
          "%s: peer version", name.c_str());
  }
}

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::string item;
  std::istringstream in(s);
  while (std::getline(in, item, sep)) out.push_back(item);
  return out;
}

void fragmentation_vector(const std::string& name, int type, int channel, int first_seq, size_t mtu,
                          const Bytes& message, const std::vector<Bytes>& frames) {
  // Fragmenter + write_frame.
  Fragmenter fr;
  CHECK(fr.begin(static_cast<FrameType>(type), static_cast<uint8_t>(channel), message.data(),
                 message.size(), mtu),
        "%s: cannot fragment", name.c_str());
  CHECK(fr.remaining() == frames.size() && fragment_count(message.size(), mtu) == frames.size(),
        "%s: %zu fragments, expected %zu", name.c_str(), fr.remaining(), frames.size());
  Fragment f;
  for (size_t i = 0; i < frames.size(); ++i) {
    CHECK(fr.next(static_cast<uint8_t>(first_seq + i), &f), "%s: fragment %zu missing", name.c_str(), i);
    check::VecSink sink;
    f.write(sink);
    CHECK(sink.bytes == frames[i], "%s: fragment %zu is %s, expected %s", name.c_str(), i,
          hex(sink.bytes).c_str(), hex(frames[i]).c_str());
  }
  CHECK(!fr.next(0, &f) && fr.done(), "%s: extra fragment", name.c_str());
  Bytes all;
  for (size_t i = 0; i < frames.size(); ++i) all.insert(all.end(), frames[i].begin(), frames[i].end());
  // The stream senders number and send them the same way.
  if (type == static_cast<int>(FrameType::BestEffort)) {
    BestEffortSender s(static_cast<uint8_t>(first_seq));
    check::VecSink sink;
    CHECK(s.send(sink, static_cast<uint8_t>(channel), message.data(), message.size(), mtu),
          "%s: best-effort send refused", name.c_str());
    CHECK(sink.bytes == all && s.next_seq() == static_cast<uint8_t>(first_seq + frames.size()),
          "%s: best-effort sender wrote %s", name.c_str(), hex(sink.bytes).c_str());
  } else {
    ReliableSender<8, 64> s(static_cast<uint8_t>(first_seq));
    s.reset(static_cast<uint8_t>(first_seq), 8, mtu);
    CHECK(s.send(static_cast<uint8_t>(channel), message.data(), message.size()), "%s: refused",
          name.c_str());
    check::VecSink sink;
    Frame out;
    while (s.poll(0, &out)) {
      FrameHeader h = header(static_cast<int>(out.type), out.channel, out.seq, static_cast<int>(out.frag));
      write_frame(sink, h, out.payload, out.size);
    }
    CHECK(sink.bytes == all, "%s: reliable sender wrote %s", name.c_str(), hex(sink.bytes).c_str());
  }
  // Decoding and reassembly give the message back, in a buffer of exactly its size.
  FrameDecoder<kMtu> d;
  d.set_max_payload(mtu);
  Reassembler<64> ra;
  Message m;
  int delivered = 0;
  for (size_t i = 0; i < all.size(); ++i) {
    if (d.push(all[i]) != Decoded::Frame) continue;
    if (ra.feed(d.frame(), &m)) {
      ++delivered;
      CHECK(Bytes(m.data, m.data + m.size) == message && m.channel == channel &&
                m.seq == static_cast<uint8_t>(first_seq),
            "%s: reassembled %s", name.c_str(), hex(m.data, m.size).c_str());
    }
  }
  CHECK(delivered == 1 && ra.stats().messages == 1 && !ra.in_progress(static_cast<FrameType>(type)),
        "%s: %d messages", name.c_str(), delivered);
  // A buffer one byte too small refuses the message (if it needs one), counted as oversize.
  if (frames.size() > 1) {
    Reassembler<19> small;
    FrameDecoder<kMtu> d2;
    bool any = false;
    for (size_t i = 0; i < all.size(); ++i) {
      if (d2.push(all[i]) == Decoded::Frame) any = small.feed(d2.frame(), &m) || any;
    }
    const bool fits = message.size() <= small.capacity();
    CHECK(any == fits && small.stats().oversize == (fits ? 0 : 1) && small.stats().orphans == 0,
          "%s: small reassembler: delivered %d oversize %u", name.c_str(), any,
          static_cast<unsigned>(small.stats().oversize));
  }
}

void selective_ack_vector(const std::string& name, const Bytes& wire) {
  // PROTOCOL.md 2.12 O: window 4, frame 10 lost, 11 and 13 held: ACK seq 9, bitmap 05.
  ReliableReceiver<4, 16> rx(10);
  static const uint8_t p[] = {1};
  Frame f = {FrameType::Reliable, Frag::Whole, 3, 11, p, 1, false, 0};
  CHECK(rx.receive(f) == Received::Held, "%s: 11 not held", name.c_str());
  f.seq = 13;
  CHECK(rx.receive(f) == Received::Held, "%s: 13 not held", name.c_str());
  CHECK(rx.ack_needed() && rx.ack_urgent(), "%s: ACK not due at once", name.c_str());
  check::VecSink sink;
  rx.write_ack(sink);
  CHECK(sink.bytes == wire, "%s: ACK %s, expected %s", name.c_str(), hex(sink.bytes).c_str(),
        hex(wire).c_str());
  // And a sender with 10..13 in flight takes it: 11 and 13 no longer resent, 10 fast-resent.
  ReliableSender<4, 16> tx(10);
  for (int i = 0; i < 4; ++i) CHECK(tx.send(3, p, 1), "send %d", i);
  Frame out;
  for (int i = 0; i < 4; ++i) CHECK(tx.poll(0, &out) && out.seq == 10 + i, "poll %d", i);
  HostDecoder d;
  std::vector<Event> ev = decode_all(d, wire);
  tx.on_ack(ev[0].frame, 300000);  // later than the initial RTO: the hole is resent
  CHECK(tx.poll(300000, &out) && out.seq == 10 && tx.stats().fast_retransmits == 1,
        "%s: no fast retransmit of 10", name.c_str());
  CHECK(tx.poll(300001, &out) && out.seq == 12, "%s: 12 not resent after its timeout", name.c_str());
  CHECK(!tx.poll(300002, &out), "%s: a selectively acknowledged frame was resent", name.c_str());
}

// ---------------------------------------------------------------------------------------------
// Unit checks beyond the vectors

void unit_crc_and_cobs() {
  const uint8_t digits[] = {'1', '2', '3', '4', '5', '6', '7', '8', '9'};
  CHECK(crc16(digits, 9) == 0x29B1, "CRC check value %04x", crc16(digits, 9));
  check::Rng rng(1);
  for (int round = 0; round < 2000; ++round) {
    Bytes data(rng.below(700));
    for (size_t i = 0; i < data.size(); ++i) data[i] = rng.chance(30) ? 0 : static_cast<uint8_t>(rng.next());
    Bytes enc(cobs_max_encoded(data.size()));
    size_t n = cobs_encode(data.data(), data.size(), enc.data(), enc.size());
    CHECK(n > 0 && memchr(enc.data(), 0, n) == nullptr, "COBS output holds 0x00");
    CHECK(n <= data.size() + (data.size() + 253) / 254 + 1, "COBS longer than canonical");
    Bytes dec(n);
    size_t m = 0;
    CHECK(cobs_decode(enc.data(), n, dec.data(), &m) && m == data.size() &&
              memcmp(dec.data(), data.data(), m) == 0,
          "COBS round trip of %zu bytes", data.size());
    CHECK(cobs_decode(enc.data(), n, enc.data(), &m) && Bytes(enc.begin(), enc.begin() + m) == data,
          "COBS in place");
  }
  const uint8_t empty_enc[] = {1};
  size_t m = 99;
  uint8_t out[4];
  CHECK(cobs_encode(nullptr, 0, out, 4) == 1 && out[0] == 1, "COBS of nothing");
  CHECK(cobs_decode(empty_enc, 1, out, &m) && m == 0, "COBS 01");
  const uint8_t zero_code[] = {2, 1, 0};
  CHECK(!cobs_decode(zero_code, 3, out, &m), "a 0x00 code is an error");
}

/** COBS the plain way (a buffer and a code byte patched afterwards), canonical: no empty
 * group after a final full one. The reference of the streaming encoder. */
Bytes ref_cobs(const Bytes& d) {
  Bytes out(1, 0);
  size_t code_at = 0;
  uint8_t code = 1;
  bool full_last = false;  // the last byte closed a full group
  for (size_t i = 0; i < d.size(); ++i) {
    full_last = false;
    if (d[i] != 0) {
      out.push_back(d[i]);
      if (++code != 0xFF) continue;
      full_last = true;
    }
    out[code_at] = code;
    code_at = out.size();
    out.push_back(0);
    code = 1;
  }
  if (full_last) {
    out.pop_back();
  } else {
    out[code_at] = code;
  }
  return out;
}

/** A sink with put_block(), as ArduinoHardware has: write_frame() must hand it each frame in
 * one call. */
struct BlockSink {
  Bytes bytes;
  int blocks;
  int puts;
  BlockSink() : blocks(0), puts(0) {}
  void put(uint8_t b) {
    bytes.push_back(b);
    ++puts;
  }
  void put_block(const uint8_t* p, size_t n) {
    bytes.insert(bytes.end(), p, p + n);
    ++blocks;
  }
};

/** CRC-16/CCITT-FALSE a bit at a time, straight from its definition (poly 0x1021, init 0xFFFF,
 * no reflection, no final XOR): the reference of crc16(). */
uint16_t ref_crc(const Bytes& d) {
  uint16_t crc = 0xFFFF;
  for (size_t i = 0; i < d.size(); ++i) {
    for (int bit = 7; bit >= 0; --bit) {
      const bool top = ((crc >> 15) & 1) != ((d[i] >> bit) & 1);
      crc = static_cast<uint16_t>(crc << 1);
      if (top) crc ^= 0x1021;
    }
  }
  return crc;
}

/** Random bytes: zeros at the given percentage (0: long runs of non-zero bytes). */
Bytes random_bytes(check::Rng& rng, size_t n, uint32_t zeros) {
  Bytes b(n);
  for (size_t i = 0; i < n; ++i) b[i] = rng.chance(zeros) ? 0 : static_cast<uint8_t>(1 + rng.below(255));
  return b;
}

/**
 * The streaming encoder against ref_cobs(): cobs_encode() byte for byte (lengths around the
 * 254-byte group), and write_frame() with the payload cut in two pieces anywhere, with and
 * without a lead (the body is header + payload + CRC), its count, encode_frame() and
 * encode_datagram().
 */
void unit_frame_encoder() {
  check::Rng rng(7);
  const size_t edges[] = {0, 1, 253, 254, 255, 256, 507, 508, 509, 762};
  for (int round = 0; round < 3000; ++round) {
    const size_t n = round < 100 ? edges[round % 10] : rng.below(800);
    const uint32_t zeros = round % 3 == 0 ? 0 : rng.below(40);
    Bytes data = random_bytes(rng, n, zeros);
    if (round % 5 == 1 && n) data[n - 1] = 0;  // a zero last
    const Bytes want = ref_cobs(data);
    Bytes enc(cobs_max_encoded(n));
    const size_t m = cobs_encode(data.data(), n, enc.data(), enc.size());
    CHECK(m == want.size() && Bytes(enc.begin(), enc.begin() + m) == want,
          "cobs_encode of %zu bytes (zeros %u %%): %s", n, zeros, hex(enc.data(), m).c_str());

    FrameHeader h;
    h.type = static_cast<FrameType>(rng.below(3));
    h.frag = static_cast<Frag>(rng.below(4));
    h.channel = static_cast<uint8_t>(rng.below(256));
    h.seq = static_cast<uint8_t>(rng.below(256));
    Bytes body;
    body.push_back(header_byte0(h.type, h.frag));
    body.push_back(h.channel);
    body.push_back(h.seq);
    body.insert(body.end(), data.begin(), data.end());
    const uint16_t crc = crc16(body.data(), body.size());
    CHECK(crc == ref_crc(body), "crc16 of %zu bytes: %04x, the bitwise CRC %04x", body.size(), crc,
          ref_crc(body));
    body.push_back(static_cast<uint8_t>(crc));
    body.push_back(static_cast<uint8_t>(crc >> 8));
    const bool lead = rng.chance(50);
    Bytes wire(lead ? 1 : 0, 0);
    const Bytes cobs = ref_cobs(body);
    wire.insert(wire.end(), cobs.begin(), cobs.end());
    wire.push_back(0);
    const size_t cut = rng.below(static_cast<uint32_t>(n + 1));
    check::VecSink sink;
    const size_t w = write_frame(sink, h, data.data(), cut, data.data() + cut, n - cut, lead);
    CHECK(sink.bytes == wire && w == wire.size(),
          "write_frame of %zu payload bytes cut at %zu (lead %d): %s", n, cut, lead ? 1 : 0,
          hex(sink.bytes).c_str());
    BlockSink block;
    CHECK(write_frame(block, h, data.data(), cut, data.data() + cut, n - cut, lead) == wire.size() &&
              block.bytes == wire && block.blocks == 1 && block.puts == 0,
          "write_frame to a put_block sink: %d blocks, %d puts, %s", block.blocks, block.puts,
          hex(block.bytes).c_str());
    Bytes out(wire.size());
    CHECK(encode_frame(h, data.data(), n, out.data(), out.size(), lead) == wire.size() && out == wire,
          "encode_frame of %zu payload bytes", n);
    Bytes dg(body.size());
    CHECK(encode_datagram(h, data.data(), n, dg.data(), dg.size()) == body.size() && dg == body,
          "encode_datagram of %zu payload bytes", n);
  }
}

/** The run-length rule at its edge (PROTOCOL.md 1.6 step 2 counts the encoded bytes): a frame
 * whose run is exactly max_frame long is taken, one byte more is oversize, at the full MTU and
 * at a lowered one, with and without text detection, below one full COBS group and above. */
template <size_t Max, bool Text>
void decoder_limits(size_t mtu) {
  FrameDecoder<Max, Text> d;
  if (mtu != Max) d.set_max_payload(mtu);
  const size_t limit = max_frame(mtu);
  Bytes payload(mtu, 0x85);  // not text
  payload[1] = 0;  // two groups (three from 254 bytes on)
  if (mtu > 200) payload[199] = 0x01;  // a CRC without a 0x00 byte (the size check below)
  check::VecSink sink;
  write_frame(sink, header(1, 3, 7, 0), payload.data(), payload.size());
  Bytes wire = sink.bytes;
  CHECK(wire.size() == limit + 1, "MTU %zu: a run of %zu bytes, not max_frame", mtu, wire.size() - 1);
  std::vector<Event> ev = decode_all(d, wire);
  CHECK(ev.size() == 1 && ev[0].kind == Decoded::Frame && ev[0].payload == payload,
        "MTU %zu: the longest frame was not taken", mtu);
  wire.insert(wire.end() - 1, 0x01);  // one more (empty) group
  ev = decode_all(d, wire);
  CHECK(ev.size() == 1 && ev[0].error == FrameError::Oversize && d.stats().oversize == 1,
        "MTU %zu: a run of max_frame + 1 bytes is not oversize", mtu);
  // Empty groups only (valid COBS, zeros): limit bytes fail the CRC, limit + 1 are oversize.
  Bytes ones(limit, 0x01);
  ones.push_back(0);
  ev = decode_all(d, ones);
  CHECK(ev.size() == 1 && ev[0].error == FrameError::Crc, "MTU %zu: zeros: %s", mtu,
        frame_error_name(ev[0].error));
  ones.insert(ones.begin(), 0x01);
  ev = decode_all(d, ones);
  CHECK(ev.size() == 1 && ev[0].error == FrameError::Oversize, "MTU %zu: zeros + 1: %s", mtu,
        frame_error_name(ev[0].error));
  CHECK(d.stats().frames == 1 && d.stats().oversize == 2 && d.stats().crc_errors == 1,
        "MTU %zu: counters", mtu);
}

void unit_decoder_limits() {
  decoder_limits<64, true>(64);
  decoder_limits<64, false>(64);
  decoder_limits<64, true>(10);
  decoder_limits<64, false>(10);
  decoder_limits<300, true>(300);
  decoder_limits<300, false>(260);
}

void unit_reassembly() {
  static const uint8_t msg[40] = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20,
                                  21, 22, 23, 24, 25, 26, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36, 37, 38, 39, 40};
  Fragmenter fr;
  fr.begin(FrameType::Reliable, 7, msg, sizeof msg, 8);
  std::vector<Fragment> frags;
  std::vector<Bytes> payloads;
  Fragment f;
  for (uint8_t seq = 250; fr.next(seq, &f); ++seq) {
    frags.push_back(f);
    Bytes p(f.prefix, f.prefix + f.prefix_size);
    p.insert(p.end(), f.data, f.data + f.size);
    payloads.push_back(p);
  }
  CHECK(frags.size() == 6, "40 bytes at MTU 8: %zu frames", frags.size());
  struct Feed {
    static bool one(Reassembler<64>& ra, const Fragment& f, const Bytes& p, Message* m) {
      Frame fr = {f.header.type, f.header.frag, f.header.channel, f.header.seq, p.data(), p.size(), false, 0};
      return ra.feed(fr, m);
    }
  };
  Reassembler<64> ra;
  Message m;
  // A lost MIDDLE: the message is dropped, the rest are orphans; a repeat is ignored.
  for (size_t i = 0; i < frags.size(); ++i) {
    if (i == 2) continue;
    CHECK(!Feed::one(ra, frags[i], payloads[i], &m), "delivered with a fragment missing");
    if (i == 0) CHECK(!Feed::one(ra, frags[0], payloads[0], &m) && ra.stats().duplicates == 1, "duplicate");
  }
  CHECK(ra.stats().dropped_partial == 1 && ra.stats().orphans == 3 && ra.stats().messages == 0,
        "loss counters: partial %u orphans %u", static_cast<unsigned>(ra.stats().dropped_partial),
        static_cast<unsigned>(ra.stats().orphans));
  // Then the whole message goes through; a best-effort WHOLE in between does not disturb it, a
  // best-effort FIRST does (one buffer shared by both spaces).
  static const uint8_t be[] = {0x55};
  Frame whole = {FrameType::BestEffort, Frag::Whole, 2, 9, be, 1, false, 0};
  for (size_t i = 0; i < frags.size(); ++i) {
    const bool done = Feed::one(ra, frags[i], payloads[i], &m);
    if (i == 1) {
      Message w;
      CHECK(ra.feed(whole, &w) && w.size == 1 && w.data[0] == 0x55, "best-effort WHOLE");
    }
    CHECK(done == (i + 1 == frags.size()), "delivery at fragment %zu", i);
  }
  CHECK(m.size == sizeof msg && memcmp(m.data, msg, sizeof msg) == 0 && m.seq == 250 && m.channel == 7,
        "reassembled message");
  const uint8_t first_be[] = {4, 0, 0, 0, 1, 2};
  Frame bf = {FrameType::BestEffort, Frag::First, 2, 10, first_be, sizeof first_be, false, 0};
  const Counter partial = ra.stats().dropped_partial;
  Feed::one(ra, frags[0], payloads[0], &m);
  ra.feed(bf, &m);
  CHECK(ra.stats().dropped_partial == partial + 1 && !ra.in_progress(FrameType::Reliable) &&
            ra.in_progress(FrameType::BestEffort),
        "a FIRST of the other space takes the shared buffer");
  // Malformed: a FIRST shorter than its prefix, a LAST that overshoots.
  const Counter malformed = ra.stats().malformed;
  const uint8_t big_last[] = {3, 4, 5, 6, 7};
  Frame bl = {FrameType::BestEffort, Frag::Last, 2, 11, big_last, sizeof big_last, false, 0};
  CHECK(!ra.feed(bl, &m) && ra.stats().malformed == malformed + 1 &&
            !ra.in_progress(FrameType::BestEffort),
        "overshooting LAST");
  const uint8_t short_first[] = {1, 0};
  Frame sf = {FrameType::Reliable, Frag::First, 1, 1, short_first, 2, false, 0};
  ra.feed(sf, &m);
  CHECK(ra.stats().malformed == malformed + 2, "short FIRST");
  // A reassembler without a buffer delivers WHOLE frames and refuses the rest.
  Reassembler<0> none;
  CHECK(none.feed(whole, &m) && m.size == 1, "Reassembler<0> WHOLE");
  Frame first0 = {frags[0].header.type, frags[0].header.frag, 7, 250, payloads[0].data(), payloads[0].size(), false, 0};
  none.feed(first0, &m);
  CHECK(none.stats().oversize == 1, "Reassembler<0> refuses fragments");
}

void unit_best_effort() {
  BestEffortReceiver rx;
  CHECK(rx.accept(200) && rx.stats().frames_lost == 0 && rx.stats().resyncs == 1, "first frame");
  CHECK(rx.accept(203) && rx.stats().frames_lost == 2, "gap of two");
  CHECK(!rx.accept(202) && rx.stats().frames_late == 1, "late");
  CHECK(!rx.accept(203) && rx.stats().frames_late == 2, "duplicate");
  CHECK(rx.accept(4) && rx.stats().frames_lost == 2 + 56, "gap across the wrap");
  rx.resync();
  CHECK(rx.accept(100) && rx.stats().frames_lost == 58 && rx.stats().resyncs == 2, "resync");
  BestEffortSender tx(255);
  CHECK(tx.take() == 255 && tx.take() == 0, "wraps");
}

void unit_rtt() {
  RttEstimator rtt;
  CHECK(rtt.rto() == 250000 && rtt.timeout(1) == 500000 && rtt.timeout(5) == 1000000, "initial RTO");
  rtt.sample(10000);  // 10 ms: SRTT 10, RTTVAR 5, RTO max(50, 30) = 50 ms
  CHECK(rtt.srtt() == 10000 && rtt.rttvar() == 5000 && rtt.rto() == 50000, "first sample");
  rtt.sample(200000);  // RTTVAR = 3/4*5 + 1/4*190 = 51.25; SRTT = 7/8*10 + 1/8*200 = 33.75
  CHECK(rtt.rttvar() == 51250 && rtt.srtt() == 33750 && rtt.rto() == 33750 + 4 * 51250, "second sample");
  rtt.sample(5000000);
  CHECK(rtt.rto() == 1000000, "capped at rto_max");
}

void unit_reliable_sender() {
  // Window 2, MTU 8: a 20-byte message takes 3 frames, released as the window opens.
  ReliableSender<2, 8> tx(0, 3);
  uint8_t msg[20];
  for (int i = 0; i < 20; ++i) msg[i] = static_cast<uint8_t>(i);
  CHECK(tx.send(1, msg, sizeof msg) && tx.sending(), "fragmented send");
  CHECK(!tx.send(1, msg, 1) && tx.stats().refused == 1, "second message refused while busy");
  Frame f;
  CHECK(tx.poll(0, &f) && f.seq == 0 && f.frag == Frag::First, "first");
  CHECK(tx.poll(0, &f) && f.seq == 1 && f.frag == Frag::Middle, "middle");
  CHECK(!tx.poll(0, &f), "window full");
  Frame ack = {FrameType::Ack, Frag::Whole, 0, 0, nullptr, 0, false, 0};
  tx.on_ack(ack, 20000);
  CHECK(tx.rtt().sampled() && tx.rtt().srtt() == 20000, "RTT sample from the ACK");
  CHECK(tx.poll(20000, &f) && f.seq == 2 && f.frag == Frag::Last && !tx.sending(), "last released");
  // Retransmissions: RTO = 20 + 4 * 10 ms, doubling; dead after max_retries (3).
  uint32_t at = 0;
  CHECK(tx.rtt().rto() == 60000, "RTO %u", static_cast<unsigned>(tx.rtt().rto()));
  CHECK(tx.next_deadline(&at) && at == 0 + 60000, "deadline of seq 1: %u", static_cast<unsigned>(at));
  CHECK(!tx.poll(59999, &f), "resent early");
  CHECK(tx.poll(60000, &f) && f.seq == 1 && tx.stats().retransmits == 1, "timeout resend");
  ack.seq = 1;
  tx.on_ack(ack, 60000);  // acknowledges a retransmitted frame: no sample (Karn)
  CHECK(tx.rtt().srtt() == 20000 && tx.in_flight() == 1 && tx.base() == 2, "Karn's rule");
  uint32_t now = 20000;
  for (int i = 0; i < 3; ++i) {
    now += tx.rtt().timeout(static_cast<uint8_t>(i));
    CHECK(tx.poll(now, &f) && f.seq == 2, "retry %d", i);
  }
  now += tx.rtt().timeout(3);
  CHECK(!tx.poll(now, &f) && tx.dead(), "dead after the retry limit");
  tx.reset(77);
  CHECK(tx.idle() && !tx.dead() && tx.send(4, msg, 3) && tx.poll(now, &f) && f.seq == 77, "reset");
  // A stale ACK (outside what is in flight) changes nothing.
  ack.seq = 10;
  tx.on_ack(ack, now);
  CHECK(tx.in_flight() == 1 && tx.base() == 77, "stale ACK ignored");
  // Window 1 (the hello-world board) with a 2-frame message.
  ReliableSender<1, 8> one(5);
  CHECK(one.send(1, msg, 12) && one.poll(0, &f) && f.seq == 5 && !one.poll(0, &f), "window 1");
  ack.seq = 5;
  one.on_ack(ack, 1000);
  CHECK(one.poll(1000, &f) && f.seq == 6 && f.frag == Frag::Last, "window 1, second fragment");
}

void unit_reliable_receiver() {
  ReliableReceiver<4, 8> rx(254);
  static const uint8_t p[] = {42};
  Frame f = {FrameType::Reliable, Frag::Whole, 1, 254, p, 1, false, 0};
  CHECK(rx.receive(f) == Received::Deliver && rx.expected() == 255, "in order");
  CHECK(!rx.ack_urgent() && rx.ack_needed(), "an in-order ACK may wait (W=4: every 2nd)");
  CHECK(rx.receive(f) == Received::Duplicate && rx.ack_urgent(), "duplicate");
  uint8_t bm[8];
  size_t n = 9;
  CHECK(rx.make_ack(bm, &n) == 254 && n == 0, "bare ACK");
  f.seq = 1;
  CHECK(rx.receive(f) == Received::Held, "early (across the wrap)");
  f.seq = 3;
  CHECK(rx.receive(f) == Received::OutOfWindow, "outside the window");
  f.seq = 0;
  CHECK(rx.receive(f) == Received::Held, "early");
  CHECK(rx.receive(f) == Received::Duplicate, "already held");
  CHECK(rx.make_ack(bm, &n) == 254 && n == 1 && bm[0] == 3, "bitmap %02x", bm[0]);
  f.seq = 255;
  CHECK(rx.receive(f) == Received::Deliver && rx.ack_urgent(), "gap filled");
  Frame h;
  CHECK(rx.pop(&h) && h.seq == 0 && rx.pop(&h) && h.seq == 1 && !rx.pop(&h) && rx.expected() == 2,
        "held frames released in order");
  // Hold 0: early frames are dropped.
  ReliableReceiver<4, 8, 0> strict(0);
  f.seq = 1;
  CHECK(strict.receive(f) == Received::Dropped && strict.stats().early_dropped == 1, "no hold");
}

#if !defined(__AVR__)
void unit_posix_pty() {
  PosixHardware board;
  CHECK(board.init("pty"), "pty: %s", board.error());
  PosixHardware host;
  CHECK(host.init(board.device_path()), "open %s: %s", board.device_path(), host.error());
  static const uint8_t hi[] = {0x02, 0, 0, 0, 'h', 'i'};
  FrameHeader h = header(1, 5, 7, 0);
  write_frame(board, h, hi, sizeof hi, nullptr, 0, true);
  board.flush();
  HostDecoder d;
  bool got = false;
  for (int spins = 0; spins < 2000 && !got; ++spins) {
    int b = host.read();
    if (b < 0) {
      usleep(1000);
      continue;
    }
    if (d.push(static_cast<uint8_t>(b)) == Decoded::Frame) {
      got = d.frame().seq == 7 && d.frame().size == sizeof hi;
    }
  }
  CHECK(got, "a frame across the pty");
  uint32_t t0 = board.micros();
  usleep(2000);
  CHECK(board.micros() - t0 >= 2000, "micros advances");
  // TCP: a listening board, a host connecting.
  PosixHardware server;
  CHECK(server.init("listen://127.0.0.1:0"), "listen: %s", server.error());
  char url[64];
  snprintf(url, sizeof url, "socket://127.0.0.1:%u", static_cast<unsigned>(server.local_port()));
  PosixHardware client;
  CHECK(client.init(url), "connect %s: %s", url, client.error());
  for (int spins = 0; spins < 1000 && !server.connected(); ++spins) usleep(1000);
  const uint8_t ping[] = {1, 2, 3};
  CHECK(client.write(ping, 3) == 3, "TCP write");
  Bytes got_bytes;
  for (int spins = 0; spins < 1000 && got_bytes.size() < 3; ++spins) {
    int b = server.read();
    if (b >= 0) got_bytes.push_back(static_cast<uint8_t>(b)); else usleep(1000);
  }
  CHECK(got_bytes == Bytes(ping, ping + 3), "TCP bytes: %s", hex(got_bytes).c_str());
}
#endif

}  // namespace

int main(int argc, char** argv) {
  bool skip_posix = argc > 1 && strcmp(argv[1], "--no-posix") == 0;
  std::string line;
  int vectors = 0;
  Bytes stream;  // every valid frame one after another: one decoder must see them all
  std::vector<std::vector<std::string> > expected_frames;
  char buf[1 << 16];
  while (fgets(buf, sizeof buf, stdin)) {
    line = buf;
    while (!line.empty() && (line[line.size() - 1] == '\n' || line[line.size() - 1] == '\r')) line.erase(line.size() - 1);
    if (line.empty() || line[0] == '#') continue;
    std::vector<std::string> w = split(line, ' ');
    const std::string& kind = w[0];
    ++vectors;
    if ((kind == "V" || kind == "D") && w.size() == 8) {
      Bytes wire = unhex(w[2]);
      frame_vector(w[1], wire, atoi(w[3].c_str()), atoi(w[4].c_str()), atoi(w[5].c_str()),
                   atoi(w[6].c_str()), unhex(w[7]), kind == "V");
      stream.insert(stream.end(), wire.begin(), wire.end());
      expected_frames.push_back(w);
    } else if (kind == "A" && w.size() == 9) {
      acked_vector(w[1], unhex(w[2]), atoi(w[3].c_str()), atoi(w[4].c_str()), atoi(w[5].c_str()),
                   atoi(w[6].c_str()), unhex(w[7]), atoi(w[8].c_str()));
    } else if (kind == "B" && w.size() == 5) {
      bad_vector(w[1], unhex(w[2]), w[3], w[4] == "-" ? kMtu : strtoul(w[4].c_str(), nullptr, 10));
    } else if (kind == "F" && w.size() == 8) {
      std::vector<Bytes> frames;
      std::vector<std::string> parts = split(w[7], ',');
      for (size_t i = 0; i < parts.size(); ++i) frames.push_back(unhex(parts[i]));
      fragmentation_vector(w[1], atoi(w[2].c_str()), atoi(w[3].c_str()), atoi(w[4].c_str()),
                           strtoul(w[5].c_str(), nullptr, 10), unhex(w[6]), frames);
    } else if (kind == "S" && w.size() == 3) {
      selective_ack_vector(w[1], unhex(w[2]));
    } else {
      check::fail("bad input line: %s", line.c_str());
    }
  }
  if (vectors == 0) check::fail("no vectors on stdin");
  HostDecoder d;
  std::vector<Event> events = decode_all(d, stream);
  CHECK(events.size() == expected_frames.size(), "stream: %zu frames, expected %zu", events.size(),
        expected_frames.size());
  for (size_t i = 0; i < events.size(); ++i) {
    const std::vector<std::string>& w = expected_frames[i];
    expect_frame("stream " + w[1], events[i], atoi(w[3].c_str()), atoi(w[4].c_str()),
                 atoi(w[5].c_str()), atoi(w[6].c_str()), unhex(w[7]));
  }
  unit_crc_and_cobs();
  unit_frame_encoder();
  unit_decoder_limits();
  unit_reassembly();
  unit_best_effort();
  unit_rtt();
  unit_reliable_sender();
  unit_reliable_receiver();
#if !defined(__AVR__)
  if (!skip_posix) unit_posix_pty();
#endif
  printf("ok: %d vectors, %lu checks\n", vectors, check::count());
  return 0;
}
