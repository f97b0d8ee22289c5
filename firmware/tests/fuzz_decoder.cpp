// Fuzzing of HwBridge's board-side receive path: the stream decoder, reassembly, and the
// stream receivers and sender fed whatever the decoder lets through.
//
// Built two ways:
// - a seeded random driver (the default): `fuzz_decoder SEED SECONDS [ITERATIONS]` feeds
//   arbitrary bytes, valid frames with random fields, fragmented messages, text lines, and all
//   of them mutated (bit flips, inserted zeros, deletions, truncations, splices) until the time
//   or the iteration count runs out; exit status 1 on a broken invariant;
// - a libFuzzer target with -DHWBRIDGE_LIBFUZZER (clang++ -fsanitize=fuzzer,address,undefined;
//   Debian's clang-14 with libclang-rt-14-dev works), each input fed to a fresh receiver.
// Build it with -fsanitize=address,undefined: the library allocates nothing, so every buffer is
// a global or stack object that ASan guards; guard words around each object and the checks
// below catch what ASan cannot see inside an object.
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <vector>

// 32-bit counters: the summary printed at the end counts millions of events.
#define HWBRIDGE_COUNTER_TYPE uint32_t
#include "HwBridge.h"
#include "check.h"

using namespace hwbridge;

namespace {

const uint32_t kGuard = 0xC0FFEE11u;

template <class T>
struct Guarded {
  uint32_t before[4];
  T value;
  uint32_t after[4];
  Guarded() : value() {
    for (int i = 0; i < 4; ++i) before[i] = after[i] = kGuard;
  }
  void check_guards(const char* what) const {
    for (int i = 0; i < 4; ++i) {
      CHECK(before[i] == kGuard && after[i] == kGuard, "%s: a write outside the object", what);
    }
  }
};

/** The smallest reassembly size from N on whose buffer ends the object exactly (no padding
 * after it), so that a write one byte past the buffer lands in the guard words after it. */
template <size_t N, bool Done>
struct Tight;
template <size_t N>
struct Tight<N, true> {
  static const size_t value = N;
};
template <size_t N>
struct Tight<N, false> {
  static const size_t value =
      Tight<N + 1, (sizeof(Reassembler<N + 2>) > sizeof(Reassembler<N + 1>))>::value;
};
const size_t kRa = Tight<40, (sizeof(Reassembler<41>) > sizeof(Reassembler<40>))>::value;

/** The decoder as PROTOCOL.md 1.6 words it: the whole run kept, COBS-decoded at its delimiter
 * (cobs_decode), then parse_body. The decoders, which decode as the bytes arrive, must give the
 * same result for every run. */
struct Reference {
  std::vector<uint8_t> run;
  bool text;  // the decoder detects text

  static bool printable(uint8_t b) { return (b >= 0x20 && b <= 0x7E) || b == 9 || b == 10 || b == 13; }

  bool looks_like_text() const {
    if (!text || run.empty()) return false;
    size_t total = 0, printable_bytes = 0;
    for (size_t i = 0; i < run.size() && total < 0xFFFFu; ++i, ++total) printable_bytes += printable(run[i]);
    return printable_bytes * 10 >= total * 9;
  }

  /** The result of a run (Ok: *body is the frame's body), then forgets it. */
  FrameError classify(size_t capacity, size_t max_payload, std::vector<uint8_t>* body, Frame* f) {
    FrameError e;
    body->assign(run.size(), 0);
    size_t n = 0;
    if (run.size() > capacity) {
      e = looks_like_text() ? FrameError::Text : FrameError::Oversize;
    } else if (!cobs_decode(run.data(), run.size(), body->data(), &n)) {
      e = looks_like_text() ? FrameError::Text : FrameError::Cobs;
    } else {
      e = parse_body(body->data(), n, max_payload, f);
      if ((e == FrameError::TooShort || e == FrameError::Crc) && looks_like_text()) e = FrameError::Text;
    }
    body->resize(n);
    run.clear();
    return e;
  }

  /** Checks what decoder d said about this byte. */
  template <class D>
  void check(const D& d, Decoded r, uint8_t byte, size_t max_payload) {
    if (byte != 0) {
      run.push_back(byte);
      CHECK(r == Decoded::Nothing, "a result before the delimiter");
      return;
    }
    if (run.empty()) {
      CHECK(r == Decoded::Nothing, "a result for an empty run");
      return;
    }
    std::vector<uint8_t> body;
    Frame f;
    const FrameError e = classify(D::kCapacity, max_payload, &body, &f);
    CHECK(r == (e == FrameError::Ok ? Decoded::Frame : Decoded::Bad) && d.error() == e,
          "decoder<%zu>: %s, the reference says %s", D::kCapacity, frame_error_name(d.error()),
          frame_error_name(e));
    if (e != FrameError::Ok) return;
    const Frame& g = d.frame();
    CHECK(g.type == f.type && g.frag == f.frag && g.channel == f.channel && g.seq == f.seq &&
              g.size == f.size && memcmp(g.payload, body.data() + kHeaderSize, f.size) == 0,
          "decoder<%zu>: the frame differs from the reference's", D::kCapacity);
  }
};

/** Everything the board keeps on the receive side, with small and odd sizes. */
struct Receiver {
  Guarded<FrameDecoder<16> > small;          // MTU 16, text detection
  Guarded<FrameDecoder<64, false> > device;  // MTU 64, no text detection
  Guarded<FrameDecoder<300> > large;         // a run longer than 254 bytes needs two COBS groups
  Reference small_ref, device_ref, large_ref;
  Guarded<Reassembler<kRa> > ra;
  Guarded<Reassembler<0> > ra0;
  Guarded<BestEffortReceiver> be;
  Guarded<ReliableReceiver<4, 64> > rx;
  Guarded<ReliableReceiver<1, 16> > rx1;
  Guarded<ReliableSender<3, 64> > tx;
  uint32_t now;
  unsigned long frames;

  Receiver() : now(0), frames(0) {
    small_ref.text = large_ref.text = true;
    device_ref.text = false;
    reset_sender();
  }

  void reset_sender() {
    tx.value.reset(7, 3, 64);
    static const uint8_t msg[150] = {1, 2, 3};
    tx.value.send(1, msg, sizeof msg);  // a static buffer: valid while the sender needs it
    Frame f;
    while (tx.value.poll(now, &f)) {}
  }

  template <class D>
  void push(D& d, Reference& ref, size_t max_payload, uint8_t byte) {
    const Decoded r = d.push(byte);
    ref.check(d, r, byte, max_payload);
    CHECK(d.buffered() <= D::kCapacity, "decoder holds %zu > %zu", d.buffered(), D::kCapacity);
    if (r != Decoded::Frame) {
      CHECK(r == Decoded::Nothing || d.error() != FrameError::Ok, "a bad run without a reason");
      return;
    }
    const Frame& f = d.frame();
    CHECK(f.size <= max_payload && static_cast<uint8_t>(f.type) <= 2 && static_cast<uint8_t>(f.frag) <= 3,
          "a frame above the MTU or with a bad header");
    handle(f);
  }

  void handle(const Frame& f) {
    handle_frame(f);
    CHECK(ra.value.buffered() <= ra.value.capacity() && ra0.value.buffered() == 0,
          "reassembly holds %zu bytes in a buffer of %zu", ra.value.buffered(), ra.value.capacity());
  }

  void handle_frame(const Frame& f) {
    ++frames;
    now += 1000;
    Message m;
    if (f.type == FrameType::Ack) {
      tx.value.on_ack(f, now);
      CHECK(tx.value.in_flight() <= tx.value.window(), "more in flight than the window");
      Frame out;
      for (int i = 0; i < 8 && tx.value.poll(now, &out); ++i) CHECK(out.size <= 64, "slot size");
      if (tx.value.dead() || tx.value.idle()) reset_sender();
      return;
    }
    if (f.type == FrameType::BestEffort) {
      if (be.value.accept(f.seq) && ra.value.feed(f, &m)) {
        CHECK(m.size <= (f.frag == Frag::Whole ? f.size : kRa), "message above the buffer");
      }
      if (ra0.value.feed(f, &m)) CHECK(f.frag == Frag::Whole, "Reassembler<0> joined fragments");
      return;
    }
    if (rx.value.receive(f) == Received::Deliver) {
      Frame cur = f;
      do {
        if (ra.value.feed(cur, &m)) CHECK(m.size <= (cur.frag == Frag::Whole ? cur.size : kRa), "message above the buffer");
      } while (rx.value.pop(&cur));
    }
    CHECK(rx.value.held() <= 3, "holds more than Hold frames");
    rx1.value.receive(f);
    CHECK(rx1.value.held() == 0, "a window-1 receiver held a frame");
    uint8_t bitmap[kMaxSackBytes + 4];
    memset(bitmap, 0xEE, sizeof bitmap);
    size_t n = 99;
    rx.value.make_ack(bitmap, &n);
    CHECK(n <= 1 && bitmap[kMaxSackBytes] == 0xEE, "ACK bitmap of %zu bytes for window 4", n);
  }

  void feed(const uint8_t* data, size_t size) {
    for (size_t i = 0; i < size; ++i) {
      push(small.value, small_ref, 16, data[i]);
      push(device.value, device_ref, 64, data[i]);
      push(large.value, large_ref, 300, data[i]);
    }
    small.check_guards("FrameDecoder<16>");
    device.check_guards("FrameDecoder<64>");
    large.check_guards("FrameDecoder<300>");
    ra.check_guards("Reassembler<kRa>");
    ra0.check_guards("Reassembler<0>");
    be.check_guards("BestEffortReceiver");
    rx.check_guards("ReliableReceiver<4>");
    rx1.check_guards("ReliableReceiver<1>");
    tx.check_guards("ReliableSender<3>");
  }
};

#ifndef HWBRIDGE_LIBFUZZER
/** The seeded driver keeps one receiver over all inputs: long histories of state. */
Receiver& receiver() {
  static Receiver r;
  return r;
}

void fuzz_one(const uint8_t* data, size_t size) {
  receiver().feed(data, size);
  // COBS alone, in place and not, must stay within the run.
  if (size) {
    std::vector<uint8_t> copy(data, data + size);
    size_t n = 0;
    if (cobs_decode(copy.data(), copy.size(), copy.data(), &n)) CHECK(n <= size, "COBS grew");
  }
}

// --- the seeded driver ----------------------------------------------------------------------

void append_frame(check::Rng& rng, std::vector<uint8_t>& out) {
  static uint8_t payload[400];
  size_t n = rng.below(rng.chance(80) ? 70 : 400);
  // Some payloads without zeros: full COBS groups of 254 bytes (code 0xFF) in the long ones.
  const unsigned zeros = rng.chance(30) ? 0 : 20;
  for (size_t i = 0; i < n; ++i) {
    payload[i] = rng.chance(zeros) ? 0 : static_cast<uint8_t>(rng.next() | (zeros ? 0 : 1));
  }
  FrameHeader h;
  h.type = static_cast<FrameType>(rng.below(3));
  h.frag = h.type == FrameType::Ack ? Frag::Whole : static_cast<Frag>(rng.below(4));
  h.channel = static_cast<uint8_t>(rng.chance(50) ? rng.below(4) : rng.next());
  h.seq = static_cast<uint8_t>(rng.next());
  if (h.type == FrameType::Ack) n = rng.below(10);
  check::VecSink sink;
  write_frame(sink, h, payload, n, nullptr, 0, rng.chance(10));
  out.insert(out.end(), sink.bytes.begin(), sink.bytes.end());
}

void append_message(check::Rng& rng, std::vector<uint8_t>& out) {
  static uint8_t msg[200];
  const size_t len = rng.below(sizeof msg);
  for (size_t i = 0; i < len; ++i) msg[i] = static_cast<uint8_t>(rng.next());
  const size_t mtu = 5 + rng.below(70);
  static uint8_t seq = 0;
  Fragmenter fr;
  fr.begin(rng.chance(50) ? FrameType::Reliable : FrameType::BestEffort,
           static_cast<uint8_t>(rng.below(3)), msg, len, mtu);
  Fragment f;
  check::VecSink sink;
  while (fr.next(seq++, &f)) f.write(sink);
  out.insert(out.end(), sink.bytes.begin(), sink.bytes.end());
}

/** A FIRST announcing a length near the reassembly buffer's (kRa), then consecutive MIDDLE and
 * LAST frames of random sizes: lengths that add up wrong, overshoot, or just fit. */
void append_boundary_fragments(check::Rng& rng, std::vector<uint8_t>& out) {
  static uint8_t seq = 100;
  uint8_t payload[24];
  for (size_t i = 0; i < sizeof payload; ++i) payload[i] = static_cast<uint8_t>(rng.next());
  const uint32_t total = static_cast<uint32_t>(kRa - 3 + rng.below(7));
  payload[0] = static_cast<uint8_t>(total);
  payload[1] = payload[2] = payload[3] = 0;
  const FrameType type = rng.chance(50) ? FrameType::Reliable : FrameType::BestEffort;
  check::VecSink sink;
  FrameHeader h = {type, Frag::First, 2, seq++};
  write_frame(sink, h, payload, 4 + rng.below(12));
  const unsigned more = 1 + rng.below(5);
  for (unsigned i = 0; i < more; ++i) {
    h.frag = i + 1 == more || rng.chance(20) ? Frag::Last : Frag::Middle;
    h.seq = seq++;
    write_frame(sink, h, payload, rng.below(sizeof payload));
  }
  out.insert(out.end(), sink.bytes.begin(), sink.bytes.end());
}

void append_noise(check::Rng& rng, std::vector<uint8_t>& out) {
  switch (rng.below(3)) {
    case 0: {  // random bytes, few zeros
      const size_t n = rng.below(600);
      for (size_t i = 0; i < n; ++i) out.push_back(static_cast<uint8_t>(rng.next() | (rng.chance(95) ? 1 : 0)));
      break;
    }
    case 1: {  // a debug print
      static const char* lines[] = {"debug: x=3\r\n", "hello", "a long line without an end ...........................................................................................................................................................................................................................................................................................................................", "\n\n\t"};
      const char* s = lines[rng.below(4)];
      out.insert(out.end(), s, s + strlen(s));
      break;
    }
    default:
      out.push_back(0);
  }
}

void mutate(check::Rng& rng, std::vector<uint8_t>& data) {
  const unsigned edits = rng.below(6);
  for (unsigned e = 0; e < edits && !data.empty(); ++e) {
    const size_t at = rng.below(static_cast<uint32_t>(data.size()));
    switch (rng.below(6)) {
      case 0: data[at] ^= static_cast<uint8_t>(1u << rng.below(8)); break;
      case 1: data[at] = 0; break;
      case 2: data.erase(data.begin() + static_cast<long>(at)); break;
      case 3: data.insert(data.begin() + static_cast<long>(at), static_cast<uint8_t>(rng.next())); break;
      case 4: data.resize(at); break;  // truncation
      default: {                        // splice a copy of a piece elsewhere
        const size_t len = rng.below(static_cast<uint32_t>(data.size() - at)) + 1;
        std::vector<uint8_t> piece(data.begin() + static_cast<long>(at), data.begin() + static_cast<long>(at + len));
        const size_t to = rng.below(static_cast<uint32_t>(data.size()));
        data.insert(data.begin() + static_cast<long>(to), piece.begin(), piece.end());
      }
    }
  }
}

#endif  // HWBRIDGE_LIBFUZZER

}  // namespace

#ifdef HWBRIDGE_LIBFUZZER
extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  // A fresh receiver per input, so that every finding reproduces from its input alone.
  Receiver r;
  r.feed(data, size);
  std::vector<uint8_t> copy(data, data + size);
  size_t n = 0;
  if (size && cobs_decode(copy.data(), copy.size(), copy.data(), &n)) CHECK(n <= size, "COBS grew");
  return 0;
}
#else
int main(int argc, char** argv) {
  const uint64_t seed = argc > 1 ? strtoull(argv[1], nullptr, 10) : 1;
  const double seconds = argc > 2 ? atof(argv[2]) : 2.0;
  const unsigned long max_iterations = argc > 3 ? strtoul(argv[3], nullptr, 10) : 0;
  check::Rng rng(seed);
  const clock_t start = clock();
  unsigned long iterations = 0, bytes = 0;
  std::vector<uint8_t> data;
  while ((max_iterations == 0 || iterations < max_iterations) &&
         static_cast<double>(clock() - start) / CLOCKS_PER_SEC < seconds) {
    for (int batch = 0; batch < 64; ++batch, ++iterations) {
      data.clear();
      const unsigned parts = 1 + rng.below(6);
      for (unsigned p = 0; p < parts; ++p) {
        const uint32_t kind = rng.below(10);
        if (kind < 4) append_frame(rng, data);
        else if (kind < 6) append_message(rng, data);
        else if (kind < 8) append_boundary_fragments(rng, data);
        else append_noise(rng, data);
      }
      if (rng.chance(60)) mutate(rng, data);
      bytes += data.size();
      fuzz_one(data.data(), data.size());
    }
  }
  const Receiver& r = receiver();
  const DecoderStats& s = r.small.value.stats();
  const DecoderStats& d = r.device.value.stats();
  printf("ok: seed %llu, %lu inputs, %lu bytes, %lu frames handled; MTU 16: %u frames, %u crc, "
         "%u cobs, %u oversize, %u text bytes; MTU 64 (no text): %u frames, %u cobs; reassembled %u, "
         "reliable delivered %u, dropped partial %u; %lu checks\n",
         static_cast<unsigned long long>(seed), iterations, bytes, r.frames,
         static_cast<unsigned>(s.frames), static_cast<unsigned>(s.crc_errors),
         static_cast<unsigned>(s.cobs_errors), static_cast<unsigned>(s.oversize),
         static_cast<unsigned>(s.non_frame_bytes), static_cast<unsigned>(d.frames),
         static_cast<unsigned>(d.cobs_errors), static_cast<unsigned>(r.ra.value.stats().messages),
         static_cast<unsigned>(r.rx.value.stats().frames_received),
         static_cast<unsigned>(r.ra.value.stats().dropped_partial), check::count());
  return 0;
}
#endif
